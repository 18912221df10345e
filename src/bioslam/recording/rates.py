"""How often a recording or live view sends each kind of content, and the small helpers both
sides of a recording share (:mod:`.tap` in the run, :mod:`.recorder` in the writing process).

Light on purpose: the writing process imports this without the SLAM system.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Literal

Clock = Literal["log", "wall"]
Item = tuple[Any, ...]


@dataclass(frozen=True)
class RecorderConfig:
    """How often each kind of content goes out, and how the occupancy map is built.

    Periods are seconds on the recording's clock (the log's for a recording, the wall's for a
    live view); 0 means every scan.

    Attributes:
        scan_period: scans and the ``odom -> base_link`` transform.
        pose_period: the odometry and SLAM poses and the ``map -> odom`` transform.
        match_period: the odometry's match report.
        neuron_period: boundary cells, pose cells (at most once per look of the view cells).
        map_period, map_cells_per_second: the occupancy map, at most every ``map_period`` and
            at most this many cells per second (a 400 x 400 map at 80,000 goes every 2 s).
        scene_period, scene_items_per_second: the cognitive map likewise, counting
            experiences plus links.
        map_resolution: cell size of the occupancy map, metres.
        map_keyframe_distance, map_keyframe_angle: a scan is fused into the map when the
            robot has moved this far (m) or turned this much (rad) since the last one fused.
        map_point_spacing: the fused scan is thinned to one endpoint per this many metres.
        trajectory_points: the final scene's trajectory is thinned to about this many points.
        boundary_pixels: width and height of the boundary-cell picture.
        batch: items handed on together (fewer, larger transfers).
    """

    scan_period: float = 0.0
    pose_period: float = 0.1
    match_period: float = 0.1
    neuron_period: float = 1.0
    map_period: float = 2.0
    map_cells_per_second: float = 80_000.0
    scene_period: float = 2.0
    scene_items_per_second: float = 1000.0
    map_resolution: float = 0.05
    map_keyframe_distance: float = 0.3
    map_keyframe_angle: float = math.radians(15.0)
    map_point_spacing: float = 0.1
    trajectory_points: int = 5000
    boundary_pixels: int = 96
    batch: int = 64


#: A recording keeps every scan and throttles the rest on the log's clock.
RECORD_CONFIG = RecorderConfig()
#: A live view sends what a viewer can follow, on the wall clock, without delay.
LIVE_CONFIG = RecorderConfig(
    scan_period=0.05, pose_period=0.05, match_period=0.1, neuron_period=0.25, map_period=1.0,
    scene_period=1.0, batch=1,
)


class Throttle:
    """Lets content through when ``period`` has passed since the last time, and longer for large
    content: ``size / per_second`` seconds for ``size`` items."""

    #: stamps of a 10 Hz log are 0.1 s apart only to within rounding
    TOLERANCE = 1e-6

    def __init__(self, period: float, per_second: float = math.inf) -> None:
        self.period = period
        self.per_second = per_second
        self._last = -math.inf

    def ready(self, now: float, size: int | Callable[[], int] = 0) -> bool:
        """Whether to send now; ``size`` may be a callable, then asked only once the period
        has passed (sizing a map costs more than looking at the clock)."""
        elapsed = now - self._last
        if elapsed < self.period - self.TOLERANCE:
            return False
        if self.per_second != math.inf:
            items = size() if callable(size) else size
            if elapsed < items / self.per_second - self.TOLERANCE:
                return False
        self._last = now
        return True


def log_time(stamp: float) -> int:
    """A scan stamp (seconds) as an MCAP log time (integer nanoseconds, never negative)."""
    if not stamp >= 0.0:  # also rejects NaN
        raise ValueError(f"scan stamp {stamp} s cannot be a log time (needs >= 0)")
    return round(stamp * 1e9)
