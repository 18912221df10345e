"""BreezySLAM ``.dat`` logs (the Mines ParisTech rover logs shipped with BreezySLAM).

One line per scan: a timestamp in µs, 24 odometry/status fields, then the ranges in mm
(0 = no return). The wheel encoder counts are the 2nd and 3rd fields after the timestamp, as
BreezySLAM's own loader reads them (``examples/mines.py``: ``toks[2]``, ``toks[3]``; the 1st
holds a slowly varying status value, not a count). Beam ``k`` points at
``-fov/2 + k * fov / (beams - 1)``, counter-clockwise, as in BreezySLAM's ``scan_update_xy``.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bioslam.io.logs import MALFORMED, WRONG_BEAM_COUNT, LogSource, Pose
from bioslam.scan import LaserScan


@dataclass(frozen=True)
class BreezySlamConfig:
    """Sensor and rover of a BreezySLAM log; defaults describe the logs shipped with it.

    Attributes:
        beams, fov_deg: 682 beams over 240° (BreezySLAM's ``URG04LX`` sensor class).
        range_min_m, range_max_m: Hokuyo URG-04LX data sheet (20 mm - 5.6 m).
        scan_period_s: 0.1 s, the URG-04LX's 10 Hz (the rate used when the log's stamps are
            unusable, see :mod:`bioslam.io.timestamps`).
        time_increment_s: URG-04LX: 1024 angular steps per 100 ms mirror turn.
        status_fields: fields between the timestamp and the first range.
        left_ticks_field, right_ticks_field: indices (0 = timestamp) of the encoder counts.
        wheel_radius_m, half_axle_m, ticks_per_rev: BreezySLAM ``examples/mines.py`` ``Rover``
            (``WheeledVehicle(77, 165)``, 2000 ticks per wheel turn).
    """

    beams: int = 682
    fov_deg: float = 240.0
    range_min_m: float = 0.02
    range_max_m: float = 5.6
    scan_period_s: float = 0.1
    time_increment_s: float = 0.1 / 1024
    status_fields: int = 24
    left_ticks_field: int = 2
    right_ticks_field: int = 3
    wheel_radius_m: float = 0.077
    half_axle_m: float = 0.165
    ticks_per_rev: float = 2000.0


def integrate_wheel_odometry(
    pose: Pose, d_left: float, d_right: float, half_axle: float
) -> Pose:
    """Differential-drive dead reckoning: advance ``pose`` by wheel travels (m), using the
    mid-point heading (exact for arcs to second order)."""
    ds = 0.5 * (d_left + d_right)
    dtheta = (d_right - d_left) / (2.0 * half_axle)
    heading = pose[2] + 0.5 * dtheta
    theta = math.atan2(math.sin(pose[2] + dtheta), math.cos(pose[2] + dtheta))
    return (pose[0] + ds * math.cos(heading), pose[1] + ds * math.sin(heading), theta)


class BreezySlamLog(LogSource):
    """A BreezySLAM log; odometry is integrated from the wheel encoder counts."""

    format = "breezyslam"

    def __init__(
        self,
        path: str | Path,
        topic: str | None = None,
        strict: bool = False,
        config: BreezySlamConfig | None = None,
    ) -> None:
        super().__init__(path, None, strict)
        if topic is not None:
            raise ValueError(f"{self.path}: a BreezySLAM log has a single scan stream; "
                             f"--topic {topic!r} does not apply")
        self.config = config or BreezySlamConfig()
        c = self.config
        self._angles = np.radians(np.linspace(-c.fov_deg / 2, c.fov_deg / 2, c.beams))
        self._first = 1 + c.status_fields
        self._declared_period = c.scan_period_s

    def topics(self) -> list[dict[str, object]]:
        return []

    def _format_notes(self) -> list[str]:
        return ["odometry integrated from the wheel encoder counts (BreezySLAM rover geometry)"]

    def _records(self) -> Iterator[tuple[LaserScan, str, Pose | None]]:
        c = self.config
        metres_per_tick = 2.0 * math.pi * c.wheel_radius_m / c.ticks_per_rev
        pose: Pose = (0.0, 0.0, 0.0)
        ticks: tuple[float, float] | None = None
        for lineno, line in self._lines():
            if not line.strip():
                continue
            where = f"line {lineno}"
            values = self._parse(line, where)
            if values is None:
                continue
            stamp = values[0] * 1e-6
            now = (values[c.left_ticks_field], values[c.right_ticks_field])
            # The counts are cumulative: integrated in file order (the order they were
            # measured in), whatever the line's stamp; the pose takes the scan's planned stamp.
            if ticks is not None:
                d_left, d_right = (
                    (n - p) * metres_per_tick for n, p in zip(now, ticks, strict=True)
                )
                pose = integrate_wheel_odometry(pose, d_left, d_right, c.half_axle_m)
            ticks = now
            self._add_odometry(stamp, pose, where, of_scan=True)
            ranges = (values[self._first :] * 1e-3).astype(np.float32)
            scan = LaserScan(
                stamp, ranges, self._angles, c.range_min_m, c.range_max_m, c.time_increment_s
            )
            yield scan, where, None

    def _parse(self, line: str, where: str) -> np.ndarray | None:
        fields = line.split()
        expected = self._first + self.config.beams
        if len(fields) != expected:
            self._skip(WRONG_BEAM_COUNT, where,
                       f"{len(fields)} fields, expected {expected} "
                       f"(timestamp, {self.config.status_fields} status, "
                       f"{self.config.beams} ranges)")
            return None
        try:
            values = np.array(fields, dtype=np.float64)
        except ValueError as exc:
            self._skip(MALFORMED, where, str(exc))
            return None
        if not np.isfinite(values[: self._first]).all():
            self._skip(MALFORMED, where, "non-finite timestamp or odometry")
            return None
        return values
