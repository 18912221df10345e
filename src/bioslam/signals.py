"""Stopping a run cleanly on SIGINT (Ctrl-C) and SIGTERM.

A run must never lose what it computed because a signal arrived at the wrong moment. The
command installs :func:`installed` handlers; from then on a signal either raises
:class:`Interrupted` (inside an :func:`interruptible` section: start-up, the scan loop, the
figures, which are safe to abandon) or is only recorded (inside a :func:`protected` section:
writing the trajectories and the summary, which must be whole) and raised at the start of the
next interruptible section, or at the end of an :func:`atomic` step inside one (a scan).
:func:`received` tells what arrived, so that the command can mark its summary
``"interrupted": true`` and exit with ``128 + signal number`` (130, 143).

Without installed handlers (library use) the sections change nothing: Ctrl-C raises
``KeyboardInterrupt`` as Python does by default.
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading
from collections.abc import Iterator
from types import FrameType

HANDLED = (signal.SIGINT, signal.SIGTERM)


class Interrupted(KeyboardInterrupt):
    """A handled signal arrived; ``exit_code`` is the shell's ``128 + signum``."""

    def __init__(self, signum: int) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum

    @property
    def exit_code(self) -> int:
        return 128 + self.signum


class _State:
    installed = 0
    protected = 0
    received: int | None = None
    pending = False
    previous_unraisable_hook = sys.__unraisablehook__


#: Python swallows an exception raised where it cannot propagate (a weakref callback while the
#: garbage collector runs, ``__del__``, a ctypes callback) and prints it as "Exception ignored".
#: A signal raised there would be lost, so :func:`_unraisable_hook` sends it again a moment
#: later. Inside the ctypes callbacks of Numba's LLVM binding (while it compiles or loads cached
#: kernels) the handler does not raise at all, so that LLVM's callback is never cut short.
_CALLBACK_PACKAGES = frozenset({"llvmlite"})
REDELIVERY_DELAY_S = 0.05


def _in_native_callback(frame: FrameType | None) -> bool:
    while frame is not None:
        if frame.f_globals.get("__name__", "").partition(".")[0] in _CALLBACK_PACKAGES:
            return True
        frame = frame.f_back
    return False


#: Held while handlers are swapped and while a deferred signal is sent again, so that it is
#: never sent once the default handlers are back (it would kill the process with no summary).
_swap = threading.Lock()


def _send_again(signum: int) -> None:
    with _swap:
        if _State.installed and signal.getsignal(signum) is _handler:
            os.kill(os.getpid(), signum)


def _redeliver(signum: int) -> None:
    timer = threading.Timer(REDELIVERY_DELAY_S, _send_again, (signum,))
    timer.daemon = True
    timer.start()


def _handler(signum: int, frame: FrameType | None) -> None:
    if _State.received is None:
        _State.received = signum
    if _State.protected:
        _State.pending = True
        return
    if _in_native_callback(frame):
        _redeliver(signum)
        return
    raise Interrupted(signum)


def _unraisable_hook(unraisable: sys.UnraisableHookArgs) -> None:
    if isinstance(unraisable.exc_value, Interrupted):
        _redeliver(unraisable.exc_value.signum)
        return
    _State.previous_unraisable_hook(unraisable)


def received() -> int | None:
    """The first handled signal that arrived since :func:`installed`, or ``None``."""
    return _State.received


def exit_code() -> int | None:
    """``128 + signum`` of the signal received, ``None`` when none arrived."""
    return None if _State.received is None else 128 + _State.received


@contextlib.contextmanager
def installed(ignore_after: bool = False) -> Iterator[None]:
    """Handle SIGINT and SIGTERM inside the block (main thread only; elsewhere a no-op).

    ``ignore_after``: when the block ends, ignore both signals instead of restoring the
    previous handlers. A program whose work is done and written only has to exit; a signal
    during the interpreter's shutdown would otherwise kill it and lose its exit code.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = {sig: signal.getsignal(sig) for sig in HANDLED}
    if ignore_after:
        previous = dict.fromkeys(HANDLED, signal.SIG_IGN)
    _State.installed += 1
    _State.received, _State.pending, _State.protected = None, False, 0
    _State.previous_unraisable_hook = sys.unraisablehook
    sys.unraisablehook = _unraisable_hook
    for sig in HANDLED:
        signal.signal(sig, _handler)
    try:
        yield
    finally:
        with _swap:
            for sig, handler in previous.items():
                signal.signal(sig, handler)
            sys.unraisablehook = _State.previous_unraisable_hook
            _State.installed -= 1


@contextlib.contextmanager
def protected() -> Iterator[None]:
    """Signals arriving inside the block are recorded, not raised: what it writes is whole."""
    _State.protected += 1
    try:
        yield
    finally:
        _State.protected -= 1


@contextlib.contextmanager
def atomic() -> Iterator[None]:
    """Inside an interruptible section, a step that must not be left half done (one scan's
    update of the odometry, the pose cells and the map): a signal arriving in the block is
    raised when it ends. Cut short, an experience appended to some of the map's columns and
    not the others failed the map's writing after the run (index 9 of 9 stamps)."""
    with protected():
        yield
    if not _State.protected:
        _raise_pending()


def _raise_pending() -> None:
    """Raise the signal recorded during a protected block and not acted on yet."""
    if _State.pending and _State.installed and _State.received is not None:
        _State.pending = False
        raise Interrupted(_State.received)


@contextlib.contextmanager
def interruptible() -> Iterator[None]:
    """Signals raise :class:`Interrupted` inside the block, including one recorded before it
    that was not acted on yet (it arrived during a protected write)."""
    saved = _State.protected
    _State.protected = 0
    try:
        _raise_pending()
        try:
            yield
        except Exception as exc:
            interrupt = wrapped_interrupt(exc)
            if interrupt is None:
                raise
            raise interrupt from None
    finally:
        _State.protected = saved


def wrapped_interrupt(exc: BaseException) -> Interrupted | None:
    """The :class:`Interrupted` behind ``exc``, if a signal raised it somewhere Python wraps
    what is raised (Python 3.11 turns an exception in a class body's ``__set_name__``, e.g.
    while a lazily imported module defines its classes, into a ``RuntimeError``), else None."""
    seen: set[int] = set()
    cause: BaseException | None = exc
    while cause is not None and id(cause) not in seen:
        if isinstance(cause, Interrupted):
            return cause
        seen.add(id(cause))
        cause = cause.__cause__ or cause.__context__
    return None
