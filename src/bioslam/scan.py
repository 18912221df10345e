"""The LaserScan record every reader yields and every module consumes (no I/O here)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

#: A range this close to the scanner's maximum (a fraction of it) is no return: loggers and
#: drivers that do not use REP 117's +inf report a beam that met nothing as the maximum itself,
#: and a float32 of it rounds just below.
MAX_RANGE_TOLERANCE = 1e-6


def farthest_return(range_max: float) -> float:
    """The largest range that is a return of a scanner whose maximum is ``range_max``: a beam
    reported at the maximum met nothing there (a wall exactly at it is a set of measure
    zero), and taken for a hit it draws a phantom arc round the robot wherever the space is
    open (a URG-04LX in a pillar hall: 9 loop closures of 17 checks became 0 of 25)."""
    return range_max * (1.0 - MAX_RANGE_TOLERANCE)


def returns(ranges: NDArray[np.floating], range_min: float, range_max: float) -> NDArray[np.bool_]:
    """Which beams are returns: finite, above zero, at least ``range_min`` and short of the
    maximum (:func:`farthest_return`); NaN, the REP 117 codes and zero are not."""
    r = np.asarray(ranges)
    with np.errstate(invalid="ignore"):
        return np.isfinite(r) & (r > 0.0) & (r >= range_min) & (r <= farthest_return(range_max))


@dataclass(frozen=True, eq=False)
class LaserScan:
    """One 2D LiDAR scan.

    Attributes:
        stamp: time of the first beam, seconds.
        ranges: measured distances in metres (float32 or float64), one per beam; NaN, inf, 0
            and values outside ``[range_min, range_max)`` mean "no return" (a beam reported
            at ``range_max`` met nothing: :func:`farthest_return`).
        angles: beam angles in the sensor frame, radians, counter-clockwise, 0 = forward.
        range_min, range_max: the sensor's valid range interval, metres.
        time_increment: seconds between consecutive beams (0 when the sensor does not say);
            beam ``k`` was measured at ``stamp + k * time_increment``.
    """

    stamp: float
    ranges: NDArray[np.float64]
    angles: NDArray[np.float64]
    range_min: float = 0.0
    range_max: float = np.inf
    time_increment: float = 0.0
    _valid: NDArray[np.bool_] | None = field(default=None, init=False, repr=False)

    def __post_init__(self) -> None:
        # float32 ranges are kept as they are: long logs held in memory stay half the size.
        ranges = np.asarray(self.ranges)
        if not np.issubdtype(ranges.dtype, np.floating):
            ranges = ranges.astype(np.float64)
        angles = np.asarray(self.angles, dtype=np.float64)
        if ranges.ndim != 1 or ranges.shape != angles.shape:
            raise ValueError(
                f"ranges {ranges.shape} and angles {angles.shape} must be 1-D of equal length"
            )
        object.__setattr__(self, "ranges", ranges)
        object.__setattr__(self, "angles", angles)

    @classmethod
    def from_angle_min(
        cls,
        stamp: float,
        ranges: NDArray[np.float64],
        angle_min: float,
        angle_increment: float,
        range_min: float = 0.0,
        range_max: float = np.inf,
        time_increment: float = 0.0,
    ) -> LaserScan:
        """Build a scan from ROS-style ``angle_min`` + ``angle_increment``."""
        ranges = np.asarray(ranges, dtype=np.float64)
        angles = angle_min + angle_increment * np.arange(ranges.size, dtype=np.float64)
        return cls(stamp, ranges, angles, range_min, range_max, time_increment)

    @property
    def num_beams(self) -> int:
        return int(self.ranges.size)

    @property
    def fov(self) -> float:
        """Angular span from the first to the last beam, radians (:attr:`sweep`)."""
        if self.angles.size < 2:
            return 0.0
        first, last = self.sweep
        return last - first

    @property
    def sweep(self) -> tuple[float, float]:
        """The field of view as the angles ``(first, last)``, radians, that it spans
        counter-clockwise (``last >= first``), whichever way the beams were swept: a scanner
        whose angles count down (a negative ROS ``angle_increment``, as one mounted upside
        down reports) covers the same sector from its last beam to its first, and one whose
        angles were wrapped into a half-open turn jumps by a turn where it crosses it."""
        first, last = float(self.angles[0]), float(self.angles[-1])
        if last >= first or self.angles.size < 2:
            return first, last
        steps = np.diff(self.angles)
        turn = float(np.sum(np.mod(steps + np.pi, 2.0 * np.pi) - np.pi))
        return (first, first + turn) if turn > 0.0 else (last, last - turn)

    @property
    def valid_mask(self) -> NDArray[np.bool_]:
        """Beams with a usable return: finite, non-zero and within the range limits."""
        if self._valid is None:
            valid = returns(self.ranges, self.range_min, self.range_max)
            object.__setattr__(self, "_valid", valid)
        return self._valid  # type: ignore[return-value]

    def valid_polar(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """``(ranges, angles)`` of the valid returns."""
        m = self.valid_mask
        return self.ranges[m], self.angles[m]

    def endpoints(self) -> NDArray[np.float64]:
        """Valid endpoints ``(N, 2)`` in the sensor frame (the paper's Eq. 2)."""
        r, a = self.valid_polar()
        r = r.astype(np.float64, copy=False)
        return np.column_stack([r * np.cos(a), r * np.sin(a)])

    def beam_times(self) -> NDArray[np.float64]:
        """Time offsets of the valid beams from ``stamp``, seconds."""
        idx = np.flatnonzero(self.valid_mask)
        return idx * self.time_increment
