"""bioslam.signals: a signal that lands inside a native callback is not lost."""

import signal
import time

import pytest

from bioslam import signals

# A function whose module looks like llvmlite's: Numba's LLVM binding runs such Python code
# inside ctypes callbacks, where a raised exception is printed and dropped.
_CALLBACK_SOURCE = '''
import signal
def callback(log):
    signal.raise_signal(signal.SIGTERM)
    log.append("callback finished")
'''


def _fake_llvmlite_callback():
    namespace = {"__name__": "llvmlite.binding.fake"}
    exec(compile(_CALLBACK_SOURCE, "fake_llvmlite.py", "exec"), namespace)
    return namespace["callback"]


def test_a_signal_inside_a_native_callback_is_delivered_again_afterwards():
    callback, log = _fake_llvmlite_callback(), []
    with (
        signals.installed(),
        pytest.raises(signals.Interrupted) as stopped,
        signals.interruptible(),
    ):
        callback(log)  # the signal arrives here: the callback must run to its end
        log.append("after the callback")
        deadline = time.monotonic() + 5.0
        while time.monotonic() < deadline:
            time.sleep(0.01)
    assert log == ["callback finished", "after the callback"]
    assert stopped.value.signum == signal.SIGTERM and stopped.value.exit_code == 143


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
