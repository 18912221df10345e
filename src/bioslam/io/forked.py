"""A child process forked to work beside the command, exchanging pickles over pipes.

On a machine with a second core, work the run does not need the answer of at once (reading the
log ahead, drawing the figures) can run there. Forking shares the parent's data as it stands
(no copy until either side writes a page) and needs no import in the child; pipes carry what
the two say to each other afterwards.

The child is the command's helper, never on its own: it ignores SIGINT and SIGTERM (the
command decides what a signal means, and a Ctrl-C reaches the whole process group), is killed
by the system when the parent ends (Linux), keeps no file of the parent's open but its pipes
and the standard streams (a subprocess's pipe must end when the parent closes it), never
returns into the parent's code, and is killed and reaped by :meth:`Forked.close`.
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import gc
import os
import pickle
import signal
from collections.abc import Callable
from types import TracebackType
from typing import IO, Any, Self

#: Bytes a pipe may hold (Linux lets anyone raise its 64 kB to 1 MiB): one side writes ahead
#: while the other works, and a reader finds whole messages waiting instead of waking the
#: writer for every 64 kB of them.
PIPE_BYTES = 2**20
_SIGNALS = (signal.SIGINT, signal.SIGTERM)
_PR_SET_PDEATHSIG = 1
_MAX_FD = 65536


class ChildEndedError(RuntimeError):
    """The child ended (or closed its pipe) before sending what was asked of it."""


class Channel:
    """One side's ends of the two pipes: what :meth:`send` writes the other side's
    :meth:`receive` reads, in order."""

    def __init__(self, incoming: IO[bytes] | None, outgoing: IO[bytes] | None) -> None:
        self.incoming, self.outgoing = incoming, outgoing

    def send(self, message: Any) -> None:
        if self.outgoing is None:
            raise ChildEndedError("the other side no longer listens")
        pickle.dump(message, self.outgoing, protocol=pickle.HIGHEST_PROTOCOL)
        self.outgoing.flush()

    def receive(self) -> Any:
        if self.incoming is None:
            raise ChildEndedError("the other side no longer sends")
        try:
            return pickle.load(self.incoming)
        except (EOFError, pickle.UnpicklingError, OSError) as exc:
            raise ChildEndedError(f"the child process ended early ({type(exc).__name__})") from None

    def close(self) -> None:
        for stream in (self.incoming, self.outgoing):
            if stream is not None:
                with contextlib.suppress(OSError):
                    stream.close()
        self.incoming = self.outgoing = None


class Closing:
    """A context manager that calls ``close()`` on leaving."""

    def close(self) -> None:
        raise NotImplementedError

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self, kind: type[BaseException] | None, exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()


class Forked(Channel, Closing):
    """``work(channel)`` run in a forked child; this object is the parent's side of the
    channel. Use it as a context manager or call :meth:`close`."""

    def __init__(self, work: Callable[[Channel], None]) -> None:
        down_read, down_write = os.pipe()  # parent -> child
        up_read, up_write = os.pipe()  # child -> parent
        for fd in (down_write, up_write):
            _widen(fd)
        parent = os.getpid()
        # no signal between the fork and the child's ignoring it: the parent's handlers would
        # run in the child and raise there
        blocked = signal.pthread_sigmask(signal.SIG_BLOCK, _SIGNALS)
        try:
            pid = os.fork()
            if pid == 0:  # never returns
                _child(work, down_read, up_write, parent)
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, blocked)
        os.close(down_read)
        os.close(up_write)
        self.pid: int | None = pid
        super().__init__(os.fdopen(up_read, "rb"), os.fdopen(down_write, "wb"))

    def close(self) -> None:
        """Stop the child if it still runs, and reap it."""
        super().close()
        if self.pid is not None:
            with contextlib.suppress(ProcessLookupError):
                os.kill(self.pid, signal.SIGKILL)
            with contextlib.suppress(ChildProcessError):
                os.waitpid(self.pid, 0)
            self.pid = None



class Helper(Closing):
    """The parent's side of a helper process built on :class:`Forked` (``self._child``):
    closing it stops and reaps the child."""

    _child: Forked

    @property
    def pid(self) -> int | None:
        """The child's process id (None once it was reaped)."""
        return self._child.pid

    def close(self) -> None:
        """Stop the child (if it still runs) and reap it."""
        self._child.close()


def can_fork() -> bool:
    """Whether a forked helper can gain time here: ``fork`` exists and a second core too."""
    if not hasattr(os, "fork"):
        return False
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        cores = os.cpu_count() or 1
    return cores >= 2


def _child(work: Callable[[Channel], None], incoming: int, outgoing: int, parent: int) -> None:
    code = 1
    try:
        for sig in _SIGNALS:
            signal.signal(sig, signal.SIG_IGN)
        signal.pthread_sigmask(signal.SIG_UNBLOCK, _SIGNALS)
        low, high = sorted((incoming, outgoing))
        os.closerange(3, low)
        os.closerange(low + 1, high)
        os.closerange(high + 1, _MAX_FD)
        _die_with_parent()
        # the collector would visit every object the child inherited, writing to each and so
        # copying every page of the parent's heap into the child (tens of MB): those stay
        # out of its reach; what the child makes is still collected
        gc.freeze()
        if os.getppid() == parent:  # else it ended before the request
            channel = Channel(os.fdopen(incoming, "rb"), os.fdopen(outgoing, "wb"))
            work(channel)
            channel.close()
            code = 0
    except BaseException:  # a child must never return into the parent's code
        code = 1
    finally:
        os._exit(code)


def _widen(fd: int) -> None:
    with contextlib.suppress(Exception):
        import fcntl  # POSIX only, as is fork

        fcntl.fcntl(fd, fcntl.F_SETPIPE_SZ, PIPE_BYTES)


def _die_with_parent() -> None:
    """Ask Linux to kill this process when its parent ends (elsewhere: the pipe's closing
    ends it at its next write)."""
    with contextlib.suppress(Exception):
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        libc.prctl(_PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
