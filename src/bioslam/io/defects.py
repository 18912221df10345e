"""Time-stamp defects of real logs, applied to a text log, for tests and benchmarks.

Each defect is one way recorders, converters and users have mangled the stamps of public logs:
all zero, printed with six significant digits, counting down, sign-flipped, one scan an hour
late, a clock set back, the log concatenated with itself, seconds written where microseconds
are expected. The functions rewrite a CARMEN or BreezySLAM log's lines; the readers must still
get ≥ 99 % of the scans out of the result (see ``tests/test_io_timestamps.py``,
``benchmarks/bench_readers.py``).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

StampMap = Callable[[NDArray[np.float64]], NDArray[np.float64]]

# CARMEN messages whose last three fields are ipc_timestamp ipc_hostname logger_timestamp.
_TIMED_CARMEN = frozenset(
    {"FLASER", "RLASER", "ROBOTLASER1", "ROBOTLASER2", "RAWLASER1", "RAWLASER2", "RAWLASER3",
     "RAWLASER4", "ODOM"}
)


def _one_late(t: NDArray[np.float64], at: int) -> NDArray[np.float64]:
    out = t.copy()
    if t.size:
        out[at] += 3600.0
    return out


#: Defect name -> how it changes all the stamps of a log (file order).
STAMP_DEFECTS: dict[str, StampMap] = {
    "all-zero": lambda t: np.zeros_like(t),
    "decreasing": lambda t: (t.max() + t.min() - t) if t.size else t,
    "negative": lambda t: -t,
    "one-hour-late": lambda t: _one_late(t, t.size // 2),
    # the clock set back 30 s two thirds of the way through (a time server, a reboot)
    "set-back": lambda t: t - SET_BACK_S * (np.arange(t.size) >= 2 * t.size // 3),
    # epoch seconds (as most loggers write) printed with %g's six significant digits
    "six-digits": lambda t: t + EPOCH_S,
}
#: Defects of the file rather than of its stamps.
FILE_DEFECTS = ("concatenated",)
EPOCH_S = 1.134e9
SET_BACK_S = 30.0


def _format_stamp(value: float, defect: str) -> str:
    return f"{value:.6g}" if defect == "six-digits" else f"{value:.6f}"


def carmen_with_defect(lines: list[str], defect: str) -> list[str]:
    """The lines of a CARMEN log with ``defect`` (a :data:`STAMP_DEFECTS` name or one of
    :data:`FILE_DEFECTS`) applied to the ipc and logger stamps of every timed message (for
    ``one-hour-late``: of the middle laser message only)."""
    if defect == "concatenated":
        return lines + lines
    timed = [i for i, line in enumerate(lines)
             if line.split(None, 1)[:1] and line.split(None, 1)[0] in _TIMED_CARMEN]
    fields = [lines[i].split() for i in timed]
    laser = [k for k, f in enumerate(fields) if f[0] != "ODOM"]
    change = STAMP_DEFECTS[defect]
    if defect == "one-hour-late":
        middle = laser[len(laser) // 2] if laser else 0
        change = lambda t: _one_late(t, middle)  # noqa: E731
    out = list(lines)
    for col in (-3, -1):
        new = change(np.array([float(f[col]) for f in fields]))
        for f, value in zip(fields, new.tolist(), strict=True):
            f[col] = _format_stamp(value, defect)
    for i, f in zip(timed, fields, strict=True):
        out[i] = " ".join(f) + "\n"
    return out


def breezyslam_with_defect(lines: list[str], defect: str) -> list[str]:
    """The lines of a BreezySLAM log with ``defect`` applied to its µs stamps; besides the
    CARMEN ones, ``seconds`` writes the stamps in seconds (the µs/s mix-up)."""
    if defect == "concatenated":
        return lines + lines
    rows = [line.split() for line in lines if line.strip()]
    stamps = np.array([float(r[0]) for r in rows])
    if defect == "seconds":
        text = [f"{v * 1e-6:.6f}" for v in stamps]
    else:
        mapped = STAMP_DEFECTS[defect](stamps * 1e-6) * 1e6
        text = [f"{v:.6g}" if defect == "six-digits" else f"{v:.0f}" for v in mapped]
    return [" ".join([t, *r[1:]]) + "\n" for t, r in zip(text, rows, strict=True)]


#: Every defect each format can be given.
CARMEN_DEFECTS = (*STAMP_DEFECTS, *FILE_DEFECTS)
BREEZYSLAM_DEFECTS = (*CARMEN_DEFECTS, "seconds")
