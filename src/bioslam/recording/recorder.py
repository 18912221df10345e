"""The writing side of a recording: items from the run's :class:`~.tap.Tap` in, Foxglove
messages out on a context (whose sinks are an MCAP file or a WebSocket server).

Here live the occupancy map (built from the keyframes' endpoints), the cognitive map's links
(accumulated), the throttles of what the items carry at every scan (poses, match reports, the
map) and the odometry's log messages. A message is built only for a channel someone listens
to, so a live view nobody watches costs next to nothing.
"""

from __future__ import annotations

import math
import time
from typing import Any

import foxglove
import numpy as np
from foxglove.channels import (
    FrameTransformsChannel,
    GridChannel,
    LaserScanChannel,
    LogChannel,
    PoseInFrameChannel,
    RawImageChannel,
    SceneUpdateChannel,
)
from numpy.typing import NDArray

from bioslam.occupancy_grid import OccupancyGrid
from bioslam.recording import messages as msg
from bioslam.recording import topics as tp
from bioslam.recording.rates import RECORD_CONFIG, Clock, Item, RecorderConfig, Throttle

#: Seconds without a degenerate match that end a degenerate stretch in the log messages.
DEGENERACY_HOLD = 1.0


def _json_channel(topic: str, name: str, fields: dict[str, str], context: foxglove.Context):
    return foxglove.Channel(
        topic, schema=msg.json_schema(name, fields), message_encoding="json", context=context
    )


class Recorder:
    """Publishes the channels of :mod:`.topics` on ``context`` from a tap's items.

    Args:
        context: the Foxglove context whose sinks receive the messages (kept alive here: once
            a context is garbage, its channels lose their sinks).
        odometry_only: the run has no views, pose cells or cognitive map.
        config: rates and map settings (the same as the tap's).
        clock: ``"log"`` throttles on the items' log times, ``"wall"`` on the wall clock.
        on_time: called with each published scan's log time (ns), e.g. to tell live viewers
            the current time.
    """

    def __init__(
        self,
        context: foxglove.Context,
        odometry_only: bool = False,
        config: RecorderConfig = RECORD_CONFIG,
        clock: Clock = "log",
        on_time: Any = None,
    ) -> None:
        self.context = context
        self.config = c = config
        self.clock = clock
        self.on_time = on_time
        self.scan = LaserScanChannel(tp.SCAN, context=context)
        self.tf = FrameTransformsChannel(tp.TF, context=context)
        self.odometry_pose = PoseInFrameChannel(tp.ODOMETRY_POSE, context=context)
        self.slam_pose = PoseInFrameChannel(tp.SLAM_POSE, context=context)
        self.match = _json_channel(
            tp.ODOMETRY_MATCH, "bioslam.OdometryMatch", msg.ODOMETRY_MATCH_FIELDS, context
        )
        self.grid = GridChannel(tp.MAP, context=context)
        self.log = LogChannel(tp.LOG, context=context)
        if not odometry_only:
            self.scene = SceneUpdateChannel(tp.COGNITIVE_MAP, context=context)
            self.view = _json_channel(
                tp.VIEW, "bioslam.ActiveView", msg.ACTIVE_VIEW_FIELDS, context
            )
            self.boundary = RawImageChannel(tp.BOUNDARY_CELLS, context=context)
            self.pose_cells_xy = RawImageChannel(tp.POSE_CELLS_XY, context=context)
            self.pose_cells_theta = RawImageChannel(tp.POSE_CELLS_THETA, context=context)
            self.pose_cell_state = _json_channel(
                tp.POSE_CELLS_STATE, "bioslam.PoseCellState", msg.POSE_CELL_FIELDS, context
            )
        self._throttles = {
            "pose": Throttle(c.pose_period),
            "match": Throttle(c.match_period),
            "map": Throttle(c.map_period, c.map_cells_per_second),
        }
        self.occupancy: OccupancyGrid | None = None
        #: (xmin, ymin, xmax, ymax) that the fused scans can have reached: what the map shows
        self._seen_extent: tuple[float, float, float, float] | None = None
        self._window: tuple[slice, slice] | None = None
        self._polar: tuple[NDArray[np.int64], NDArray[np.bool_]] | None = None
        self._ends: list[NDArray[np.int64]] = []
        self._loop: list[NDArray[np.bool_]] = []
        self._scene: tuple[int, NDArray[np.float64], int] | None = None
        self._degenerate_since: float | None = None
        self._degenerate_last = 0.0
        self._last_ns: int | None = None
        #: messages handed to the context, per topic
        self.counts: dict[str, int] = {}
        self._handlers = {
            "scan": self._on_scan, "fuse": self._on_fuse, "look": self._on_look,
            "neurons": self._on_neurons, "scene": self._on_scene, "log": self._on_log,
            "finish": self._on_finish,
        }  # fmt: skip

    def handle(self, items: list[Item]) -> None:
        """Publish what a batch of items carries, in order."""
        for item in items:
            self._handlers[item[0]](*item[1:])

    def _now(self, ns: int) -> float:
        return ns / 1e9 if self.clock == "log" else time.monotonic()

    def _count(self, topic: str) -> None:
        self.counts[topic] = self.counts.get(topic, 0) + 1

    # --- every scan ---------------------------------------------------------------------------

    def _on_scan(
        self, ns: int, ranges: NDArray[np.floating], start: float, end: float,
        range_min: float, range_max: float, odometry_pose: tuple, slam_pose: tuple,
        report: tuple,
    ) -> None:  # fmt: skip
        self._last_ns = ns
        now = self._now(ns)
        if self.scan.has_sinks():
            valid = msg.scan_ranges(ranges, range_min, range_max)
            self.scan.log(msg.laser_scan(ns, valid, start, end), log_time=ns)
            self._count(tp.SCAN)
        if self.tf.has_sinks():
            self.tf.log(msg.odometry_transform(ns, odometry_pose), log_time=ns)
            self._count(tp.TF)
        if self.on_time is not None:
            self.on_time(ns)
        if self._throttles["pose"].ready(now):
            self._publish_poses(ns, slam_pose, odometry_pose)
        self._odometry_events(ns, report)
        if self._throttles["match"].ready(now) and self.match.has_sinks():
            self.match.log(msg.odometry_match_json(*report), log_time=ns)
            self._count(tp.ODOMETRY_MATCH)
        if self.occupancy is not None and self._throttles["map"].ready(now, self._map_cells):
            self.publish_map(ns)

    def _publish_poses(self, ns: int, slam_pose: tuple, odometry_pose: tuple) -> None:
        """The two poses, and the ``map -> odom`` transform between them."""
        if self.tf.has_sinks():
            self.tf.log(msg.correction_transform(ns, slam_pose, odometry_pose), log_time=ns)
            self._count(tp.TF)
        if self.odometry_pose.has_sinks():
            pose = msg.pose_in_frame(ns, tp.ODOM_FRAME, odometry_pose)
            self.odometry_pose.log(pose, log_time=ns)
            self._count(tp.ODOMETRY_POSE)
        if self.slam_pose.has_sinks():
            self.slam_pose.log(msg.pose_in_frame(ns, tp.MAP_FRAME, slam_pose), log_time=ns)
            self._count(tp.SLAM_POSE)

    def _odometry_events(self, ns: int, report: tuple) -> None:
        score, _, points, condition, degenerate, recovered, predicted_only = report
        if recovered:
            self._log(ns, "Warning", f"odometry: the scan match failed and a search found a "
                      f"better one (score {score:.2f})", "odometry")
        if predicted_only:
            self._log(ns, "Warning", f"odometry: {points} usable points, too few to match; "
                      "the pose is predicted", "odometry")
        else:
            self._degeneracy(ns, degenerate, condition)

    def _degeneracy(self, ns: int, degenerate: bool, condition: float) -> None:
        """A degenerate stretch (a corridor the scan does not pin down along its length) is
        logged when it starts and when it ends; a scan or two that flicker in and out of it
        within :data:`DEGENERACY_HOLD` seconds continue the stretch rather than start one."""
        t = ns / 1e9
        if degenerate:
            if self._degenerate_since is None:
                self._log(ns, "Warning", "odometry: degenerate matches start (a direction the "
                          f"scan does not constrain, condition {condition:.3f})", "odometry")
                self._degenerate_since = t
            self._degenerate_last = t
        elif self._degenerate_since is not None and t - self._degenerate_last > DEGENERACY_HOLD:
            self._log(ns, "Info", "odometry: degenerate matches ended after "
                      f"{self._degenerate_last - self._degenerate_since:.1f} s", "odometry")
            self._degenerate_since = None

    # --- the occupancy map -------------------------------------------------------------------

    def _on_fuse(
        self, ns: int, pose: tuple, points: NDArray[np.floating], max_range: float
    ) -> None:
        c = self.config
        points = np.asarray(points, dtype=np.float64)
        if self.occupancy is None:
            size = 2.0 * float(np.max(np.abs(points))) + 1.0
            origin = (pose[0] - 0.5 * size, pose[1] - 0.5 * size)
            self.occupancy = OccupancyGrid(c.map_resolution, size, origin, auto_grow=True)
        self.occupancy.insert_scan(pose, points, max_range)
        reach = min(float(np.max(np.abs(points), initial=0.0)) * math.sqrt(2.0), max_range)
        seen = (pose[0] - reach, pose[1] - reach, pose[0] + reach, pose[1] + reach)
        b = self._seen_extent or seen
        self._seen_extent = (min(b[0], seen[0]), min(b[1], seen[1]),
                             max(b[2], seen[2]), max(b[3], seen[3]))  # fmt: skip
        self._window = None

    def _map_window(self) -> tuple[slice, slice]:
        """Rows and columns of the grid that the fused scans can have reached (the grid
        itself grows by whole blocks, mostly empty)."""
        if self._window is None:
            grid, extent = self.occupancy, self._seen_extent
            assert grid is not None and extent is not None
            rows, cols = grid.shape
            (r0, c0), (r1, c1) = grid.world_to_cell(np.array([extent[:2], extent[2:]]))
            self._window = (slice(max(r0, 0), min(r1 + 1, rows)),
                            slice(max(c0, 0), min(c1 + 1, cols)))  # fmt: skip
        return self._window

    def _map_cells(self) -> int:
        rows, cols = self._map_window()
        return (rows.stop - rows.start) * (cols.stop - cols.start)

    def publish_map(self, ns: int) -> None:
        grid = self.occupancy
        if grid is None or not self.grid.has_sinks():
            return
        rows, cols = self._map_window()
        origin = grid.origin + grid.resolution * np.array([cols.start, rows.start])
        known = grid.known_mask()[rows, cols]
        message = msg.occupancy_grid(ns, grid.logodds[rows, cols], known, origin, grid.resolution)
        self.grid.log(message, log_time=ns)
        self._count(tp.MAP)

    # --- views, neurons, cognitive map, events ------------------------------------------------

    def _on_look(self, ns: int, *fields: Any) -> None:
        if self.view.has_sinks():
            self.view.log(msg.active_view_json(*fields), log_time=ns)
            self._count(tp.VIEW)

    def _on_neurons(
        self, ns: int, boundary: NDArray[np.float64], rings: tuple, cells_per_ring: int,
        pc_xy: NDArray[np.float64], pc_theta: NDArray[np.float64], centre: tuple,
        active_cells: int, collapses: int,
    ) -> None:  # fmt: skip
        if self.boundary.has_sinks():
            if self._polar is None:
                self._polar = msg.polar_lookup(rings, cells_per_ring, self.config.boundary_pixels)
            self.boundary.log(msg.boundary_image(ns, boundary, *self._polar), log_time=ns)
            self._count(tp.BOUNDARY_CELLS)
        if self.pose_cells_xy.has_sinks() or self.pose_cells_theta.has_sinks():
            xy, theta = msg.pose_cell_images(ns, pc_xy, pc_theta)
            self.pose_cells_xy.log(xy, log_time=ns)
            self.pose_cells_theta.log(theta, log_time=ns)
            self._count(tp.POSE_CELLS_XY)
            self._count(tp.POSE_CELLS_THETA)
        if self.pose_cell_state.has_sinks():
            state = msg.pose_cell_json(centre, active_cells, collapses)
            self.pose_cell_state.log(state, log_time=ns)
            self._count(tp.POSE_CELLS_STATE)

    def _on_scene(
        self, ns: int, poses: NDArray[np.float64], ends: NDArray[np.int64],
        loop: NDArray[np.bool_], current: int,
    ) -> None:  # fmt: skip
        self._ends.append(ends)
        self._loop.append(loop)
        self._scene = (ns, poses, current)
        self.publish_scene()

    def publish_scene(self, trajectory: NDArray[np.float64] | None = None) -> None:
        if self._scene is None or not self.scene.has_sinks():
            return
        ns, poses, current = self._scene
        ends = np.concatenate(self._ends) if self._ends else np.zeros((0, 2), np.int64)
        loop = np.concatenate(self._loop) if self._loop else np.zeros(0, bool)
        self._ends, self._loop = [ends], [loop]
        scene = msg.cognitive_map_scene(ns, poses, ends, loop, current, trajectory)
        self.scene.log(scene, log_time=ns)
        self._count(tp.COGNITIVE_MAP)

    def _on_log(self, ns: int, level: str, text: str, name: str) -> None:
        self._log(ns, level, text, name)

    def _log(self, ns: int, level: str, text: str, name: str) -> None:
        if self.log.has_sinks():
            self.log.log(msg.log_message(ns, level, text, name), log_time=ns)
            self._count(tp.LOG)

    def _on_finish(
        self, ns: int, scans: int, scene: Item | None, trajectory: NDArray[np.float64] | None
    ) -> None:
        """After the run: the final map, and the relaxed cognitive map with the corrected
        trajectory, at the last scan's time."""
        self.publish_map(ns)
        if scene is not None:
            _, _, poses, ends, loop, current = scene
            self._ends.append(ends)
            self._loop.append(loop)
            self._scene = (ns, poses, current)
            self.publish_scene(trajectory)
        self._log(ns, "Info", f"run finished after {scans} scans", "bioslam")
