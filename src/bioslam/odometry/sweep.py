"""The robot's turn during a scan's sweep, where the odometry cannot know it.

A scanner that sweeps its beams one after another measures each from where the robot is at
that beam's time; the odometry de-skews the endpoints back to the scan's stamp with the
motion model's twist (:func:`bioslam.matching.deskew.usable_endpoints`). At the scanner's
rate that twist is the last few scans' motion, good to a few hundredths of a radian per
second. After a gap, or in a log thinned to a scan a metre, it is the mean over seconds of
driving: a robot turning at 0.8 rad/s through a 360° scanner's seventh of a second turns 6.5°
between its first and last beams while the step's mean says a tenth of that, and every such
scan is matched and fused bent (simulated maze, RPLIDAR thinned to a scan per metre: heading
errors of 4-5° a step, lost within 40 scans, ATE 7.3 m).

The bend is in the scan itself where the sweep closes a circle: its last beams look where its
first did, a sweep later, and with the wrong turn rate the two ends of the scan disagree. So
the rate is the one whose de-skewed scan, matched from the chosen pose, fits the map best
(:func:`best_rate`: a grid over the turn rates a robot makes, then refined). A scanner with a
blind sector has no such seam: its bend trades against the pose along the walls it sees, and
so measured on a 240° URG-04LX thinned the same way it found rates of 0.9 rad/s on straight
aisles and lost as many routes as it found; it is left to the motion model.

A mixin of :class:`bioslam.odometry.LidarOdometry`. No file or terminal I/O here.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from bioslam.geometry import between
from bioslam.matching.gauss_newton import FloatArray
from bioslam.occupancy_grid import subsample_by_spacing
from bioslam.odometry.choice import match_quality
from bioslam.odometry_config import OdometryConfig
from bioslam.scan import LaserScan


def sweep_seconds(scan: LaserScan) -> float:
    """Seconds from the scan's first beam to its last (0 for a scan taken at one instant)."""
    return max(float(scan.time_increment), 0.0) * max(scan.num_beams - 1, 0)


def sweep_bend(deskew_rate: float, step_rate: float, scan: LaserScan) -> float:
    """How far a scan de-skewed at ``deskew_rate`` is bent if the robot turned at
    ``step_rate`` (rad/s) through its sweep (rad): the turn the de-skewing put between its
    first and last beams less the turn at that rate."""
    return abs(step_rate - deskew_rate) * sweep_seconds(scan)


def closes_circle(scan: LaserScan) -> bool:
    """Whether the scan's beams go round the whole circle (to within two beams)."""
    if scan.num_beams < 2:
        return False
    increment = scan.fov / (scan.num_beams - 1)
    return scan.fov + 2.0 * increment >= 2.0 * math.pi


def best_rate(
    quality: Callable[[float], float | None], limit: float, count: int, refinements: int
) -> float | None:
    """The turn rate in ``[-limit, limit]`` (rad/s) where ``quality`` is highest: the best of
    ``count`` rates evenly spaced over it, then ``refinements`` times the rates half the
    last spacing either side of the best so far. ``quality`` returns None where a rate
    cannot be judged; None when none can."""
    judged: dict[float, float] = {}

    def judge(rate: float) -> None:
        if rate not in judged and -limit <= rate <= limit:
            value = quality(rate)
            if value is not None:
                judged[rate] = value

    for rate in np.linspace(-limit, limit, count):
        judge(float(rate))
    spacing = 2.0 * limit / max(count - 1, 1)
    for _ in range(refinements):
        if not judged:
            break
        spacing /= 2.0
        best = max(judged, key=judged.__getitem__)
        judge(best - spacing)
        judge(best + spacing)
    return max(judged, key=judged.__getitem__) if judged else None


@dataclass
class SweepFit:
    """A scan de-skewed with turn ``rate`` (rad/s) and matched: its endpoints (sensor frame)
    and the kept ones among them, the levels and normals matched, the pose Gauss-Newton
    reached and its fit (:func:`~bioslam.odometry.choice.match_quality`: M* less the share of
    endpoints in known free space; no beams are traced through walls here)."""

    rate: float
    points: FloatArray
    keep: NDArray[np.bool_]
    levels: list[FloatArray]
    normals: FloatArray
    pose: FloatArray
    quality: float


class SweepMotion:
    """The turn rate a scan's sweep is de-skewed with, measured on the scan where the motion
    model cannot give it."""

    config: OdometryConfig

    def _sweep_unknown(self, scan: LaserScan, dt: float) -> bool:
        """Whether this scan's sweep is to be measured: it goes round the circle
        (:func:`closes_circle`), is long enough for the robot to turn ``sweep_min_skew`` in
        it at ``sweep_turn_rate``, and the motion model's twist is a mean over a gap or a
        thinned log's step (not :meth:`_gapless`, or the scans are :meth:`_sparse`; not
        the first scans of a log at the scanner's rate, searched while the motion model
        has no twist yet: it is measured within a few scans), or over steps of several
        sweeps each (:meth:`_steps_span_sweeps`)."""
        c = self.config
        if not (c.deskew and c.sweep_turn_rate > 0.0 and closes_circle(scan)):
            return False
        if c.sweep_turn_rate * sweep_seconds(scan) < c.sweep_min_skew:
            return False
        return not self._gapless(dt) or self._sparse() or self._steps_span_sweeps(scan, dt)

    def _steps_span_sweeps(self, scan: LaserScan, dt: float) -> bool:
        """Whether the step of ``dt`` seconds spans more than ``sweep_thinned`` of the scan's
        sweeps: a log thinned by count (or recorded throttled) that is neither after a gap
        nor sparse, whose motion model's twist lags a turn by a step of several sweeps."""
        thinned = self.config.sweep_thinned
        return thinned > 0.0 and dt > thinned * sweep_seconds(scan)

    def _settle_sweep(
        self, scan: LaserScan, previous: FloatArray, chosen: FloatArray, dt: float
    ) -> SweepFit | None:
        """The scan de-skewed with the turn rate whose match from the ``chosen`` pose fits the
        map best (:func:`best_rate`), its velocity the mean over the step from ``previous``;
        None when no rate leaves enough endpoints."""
        c = self.config
        velocity = between(previous, chosen)[:2] / max(dt, 1e-9)
        fits: dict[float, SweepFit | None] = {}

        def quality(rate: float) -> float | None:
            twist = (velocity[0], velocity[1], rate)
            fit = fits[rate] = self._sweep_fit(scan, chosen, twist)
            return None if fit is None else fit.quality

        rate = best_rate(quality, c.sweep_turn_rate, c.sweep_rates, c.sweep_refinements)
        return None if rate is None else fits[rate]

    def _deskewed(
        self, scan: LaserScan, twist: tuple[float, float, float]
    ) -> tuple[FloatArray, NDArray[np.bool_]] | None:
        """The scan's endpoints de-skewed with ``twist`` and the ones kept for matching
        (``point_spacing``); None with fewer than ``min_points``."""
        c = self.config
        points = self._sensor_points(scan, twist)
        if points.shape[0] < c.min_points:
            return None
        return points, subsample_by_spacing(points, c.point_spacing)

    def _sweep_fit(
        self, scan: LaserScan, start: FloatArray, twist: tuple[float, float, float]
    ) -> SweepFit | None:
        """The scan de-skewed with ``twist`` and matched from ``start`` on the finest levels
        (``sweep_iterations``)."""
        c = self.config
        deskewed = self._deskewed(scan, twist)
        if deskewed is None:
            return None
        points, keep = deskewed
        level_pts, normals = self._levels(points, keep, scan)
        iterations = (c.sweep_iterations + (0,) * c.levels)[: c.levels]
        pose, report = self._match_from(
            level_pts, start, normals, c.search_prior_weight, iterations=iterations
        )
        return SweepFit(twist[2], points, keep, level_pts, normals, pose, match_quality(report))
