"""Writing CARMEN logs (``FLASER``, ``ROBOTLASER1``, ``ODOM`` lines) that
:class:`bioslam.io.carmen.CarmenLog` reads back to the same scans.

Numbers are written in their shortest exact form (float32 ranges as float32, stamps and poses as
float64), so a log read, written and read again gives identical scans, stamps and poses. Lines
must be written in time order; a name ending in ``.gz`` is gzipped.
"""

from __future__ import annotations

import gzip
from pathlib import Path
from types import TracebackType
from typing import IO

import numpy as np
from numpy.typing import ArrayLike

from bioslam.scan import LaserScan

#: The host name CARMEN lines carry; the readers ignore it.
HOST = "bioslam"


def _num(value: float) -> str:
    return repr(float(value))


def _pose(pose: ArrayLike | None) -> str:
    p = np.zeros(3) if pose is None else np.asarray(pose, dtype=np.float64).reshape(3)
    return " ".join(_num(v) for v in p)


def _ranges(ranges: np.ndarray) -> str:
    return " ".join(map(str, np.asarray(ranges, dtype=np.float32)))


def flaser_line(scan: LaserScan, pose: ArrayLike | None, odometry: ArrayLike | None) -> str:
    """``FLASER n ranges x y theta odom_x odom_y odom_theta ipc_timestamp host logger_ts``:
    the beams' angles are implied by their count (180° field of view)."""
    stamp = _num(scan.stamp)
    return (
        f"FLASER {scan.num_beams} {_ranges(scan.ranges)} {_pose(pose)} "
        f"{_pose(odometry if odometry is not None else pose)} {stamp} {HOST} {stamp}"
    )


def robotlaser_line(scan: LaserScan, pose: ArrayLike | None) -> str:
    """``ROBOTLASER1`` with the scan's own angle layout; ``max_range`` stands for "no return"
    (how CARMEN writes it), so beams without a return read back as such."""
    angles = np.asarray(scan.angles, dtype=np.float64)
    increment = float(np.mean(np.diff(angles))) if len(angles) > 1 else 0.0
    layout = angles[0] + increment * np.arange(len(angles))
    if np.abs(angles - layout).max() > 1e-9:
        raise ValueError(f"scan at t = {scan.stamp} s: beams are not evenly spaced")
    ranges = np.asarray(scan.ranges, dtype=np.float32).copy()
    ranges[~np.isfinite(ranges)] = np.float32(scan.range_max)
    stamp = _num(scan.stamp)
    fov = increment * (len(angles) - 1)
    head = f"ROBOTLASER1 0 {_num(angles[0])} {_num(fov)} {_num(increment)} {_num(scan.range_max)}"
    tail = f"{_pose(pose)} {_pose(pose)} 0 0 0 0 0 {stamp} {HOST} {stamp}"
    return f"{head} 0.01 0 {scan.num_beams} {_ranges(ranges)} 0 {tail}"


def odom_line(stamp: float, pose: ArrayLike) -> str:
    """``ODOM x y theta tv rv accel ipc_timestamp host logger_timestamp``."""
    return f"ODOM {_pose(pose)} 0 0 0 {_num(stamp)} {HOST} {_num(stamp)}"


class CarmenWriter:
    """A CARMEN log being written; use as a context manager. ``message`` is ``FLASER`` (beam
    angles implied: 180°) or ``ROBOTLASER1`` (any evenly spaced layout)."""

    def __init__(self, path: str | Path, message: str = "FLASER", comment: str = "") -> None:
        if message not in ("FLASER", "ROBOTLASER1"):
            raise ValueError(f"can write FLASER or ROBOTLASER1 lines, not {message!r}")
        self.path = Path(path)
        self.message = message
        self.comment = comment
        self.count = 0
        self._fh: IO[str] | None = None

    def __enter__(self) -> CarmenWriter:
        opener = gzip.open if self.path.suffix == ".gz" else open
        self._fh = opener(self.path, "wt")  # type: ignore[operator]
        for line in self.comment.splitlines():
            self._fh.write(f"# {line}\n")
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        if self._fh is not None:
            self._fh.close()
            self._fh = None

    def _line(self, text: str) -> None:
        if self._fh is None:
            raise RuntimeError("CarmenWriter used outside its 'with' block")
        self._fh.write(text + "\n")

    def write_scan(
        self, scan: LaserScan, pose: ArrayLike | None, odometry: ArrayLike | None = None
    ) -> None:
        """A scan with its laser pose (the reference of a corrected log) and, for ``FLASER``,
        the odometry pose then."""
        if self.message == "FLASER":
            self._line(flaser_line(scan, pose, odometry))
        else:
            self._line(robotlaser_line(scan, pose))
        self.count += 1

    def write_odometry(self, stamp: float, pose: ArrayLike) -> None:
        self._line(odom_line(stamp, pose))
