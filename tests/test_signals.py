"""bioslam.signals: a signal that lands where Python swallows exceptions is not lost."""

import ctypes
import signal
import sys
import time
import weakref

import pytest

from bioslam import signals

# A function whose module looks like llvmlite's: Numba's LLVM binding runs such Python code
# inside ctypes callbacks, which must not be cut short.
_CALLBACK_SOURCE = '''
import signal
def callback(log):
    signal.raise_signal(signal.SIGTERM)
    log.append("callback finished")
'''


def _in_llvmlite_callback(log: list[str]) -> None:
    namespace = {"__name__": "llvmlite.binding.fake"}
    exec(compile(_CALLBACK_SOURCE, "fake_llvmlite.py", "exec"), namespace)
    namespace["callback"](log)


# Places where Python cannot propagate an exception and prints it as "Exception ignored":
# Numba's LLVM binding calls Python through ctypes callbacks, and the garbage collector runs
# finalizers and weakref callbacks wherever it happens to be triggered.


def _in_ctypes_callback(log: list[str]) -> None:
    @ctypes.CFUNCTYPE(None)
    def callback() -> None:
        signal.raise_signal(signal.SIGTERM)
        log.append("not reached: the signal raised")

    callback()


def _in_finalizer(log: list[str]) -> None:
    class Finalized:
        def __del__(self) -> None:
            signal.raise_signal(signal.SIGTERM)
            log.append("not reached: the signal raised")

    Finalized()


def _in_weakref_callback(log: list[str]) -> None:
    class Referent:
        pass

    def callback(_ref: weakref.ref) -> None:
        signal.raise_signal(signal.SIGTERM)
        log.append("not reached: the signal raised")

    referent = Referent()
    ref = weakref.ref(referent, callback)
    del referent
    assert ref() is None


@pytest.mark.parametrize(
    ("land_signal", "callback_log"),
    [
        (_in_llvmlite_callback, ["callback finished"]),
        (_in_ctypes_callback, []),
        (_in_finalizer, []),
        (_in_weakref_callback, []),
    ],
)
def test_a_signal_where_python_swallows_exceptions_is_delivered_again(
    land_signal, callback_log, capfd
):
    log: list[str] = []
    with (
        signals.installed(),
        pytest.raises(signals.Interrupted) as stopped,
        signals.interruptible(),
    ):
        land_signal(log)  # the signal arrives here and must not be lost
        log.append("after the callback")
        deadline = time.monotonic() + 5.0
        while time.monotonic() < deadline:
            time.sleep(0.01)
    assert log == [*callback_log, "after the callback"]
    assert stopped.value.signum == signal.SIGTERM and stopped.value.exit_code == 143
    assert "Exception ignored" not in capfd.readouterr().err


def test_other_swallowed_errors_still_reach_the_previous_hook(monkeypatch):
    reported: list[BaseException] = []
    monkeypatch.setattr(sys, "unraisablehook", lambda args: reported.append(args.exc_value))

    class Broken:
        def __del__(self) -> None:
            raise ValueError("finalizer failed")

    with signals.installed():
        Broken()
    assert [str(error) for error in reported] == ["finalizer failed"]
    assert sys.unraisablehook is not signals._unraisable_hook


def test_a_signal_in_plain_python_code_raises_at_once():
    log = []
    with signals.installed(), pytest.raises(signals.Interrupted), signals.interruptible():
        signal.raise_signal(signal.SIGINT)
        log.append("not reached")
    assert log == [] and signals.received() == signal.SIGINT


def test_an_interrupt_wrapped_by_python_is_still_an_interrupt() -> None:
    # Python 3.11 wraps an exception raised in __set_name__ (a signal landing while a lazily
    # imported module defines a class) in a RuntimeError: the section must still report the
    # signal, and an unrelated error must pass through unchanged.
    class Descriptor:
        def __set_name__(self, owner: type, name: str) -> None:
            raise signals.Interrupted(signal.SIGINT)

    with pytest.raises(signals.Interrupted) as caught, signals.interruptible():
        type("Lazy", (), {"field": Descriptor()})
    assert caught.value.exit_code == 130
    with pytest.raises(ValueError), signals.interruptible():
        raise ValueError("not a signal")
    assert signals.wrapped_interrupt(RuntimeError("plain")) is None


def test_a_signal_inside_an_atomic_step_is_raised_when_the_step_ends():
    """A scan's update is finished before the run stops: the signal that arrives in it is
    raised after its last line, and the loop runs no further step."""
    done: list[int] = []
    with (
        signals.installed(), pytest.raises(signals.Interrupted) as stopped,
        signals.interruptible(),
    ):
        for step in range(3):
            with signals.atomic():
                if step == 1:
                    signal.raise_signal(signal.SIGTERM)
                done.append(step)
    assert done == [0, 1]
    assert stopped.value.exit_code == 143


def test_outside_an_atomic_step_a_signal_still_stops_the_loop_at_once():
    done: list[int] = []
    with signals.installed(), pytest.raises(signals.Interrupted), signals.interruptible():
        for step in range(3):
            with signals.atomic():
                done.append(step)
            if step == 0:
                signal.raise_signal(signal.SIGINT)
                done.append(-1)  # not reached
    assert done == [0]
