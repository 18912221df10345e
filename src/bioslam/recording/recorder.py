"""What a recording or live view publishes, and when: the pipeline's per-scan observer.

Every scan, its poses and the transform tree go out at every scan (a recording keeps them all);
the maps and the neurons are throttled, by a period on the recorder's clock and, for the maps,
by their size (a map twice as large goes out half as often), so that a long run in a large
building costs a bounded share of the run time and of the file. A recording throttles on the
log's clock (reproducible: the same log gives the same file), a live view on the wall clock
(what a viewer can follow). Messages are built only for channels someone listens to, so a live
view nobody watches costs next to nothing.

The recorder reads the system through its public attributes only and never changes it.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Literal

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

from bioslam.geometry import Pose2D
from bioslam.occupancy_grid import OccupancyGrid
from bioslam.recording import messages as msg
from bioslam.recording import topics as tp
from bioslam.scan import LaserScan
from bioslam.slam import BioSLAM, thin_points

FloatArray = NDArray[np.float64]
PoseTuple = tuple[float, float, float]
Clock = Literal["log", "wall"]


@dataclass(frozen=True)
class RecorderConfig:
    """How often each kind of content goes out, and how the occupancy map is built.

    Periods are seconds on the recorder's clock (the log's for a recording, the wall's for a
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
    map_point_spacing: float = 0.05
    trajectory_points: int = 5000
    boundary_pixels: int = 96


#: A recording keeps every scan and throttles the rest on the log's clock.
RECORD_CONFIG = RecorderConfig()
#: A live view sends what a viewer can follow, on the wall clock.
LIVE_CONFIG = RecorderConfig(
    scan_period=0.05, pose_period=0.05, match_period=0.1, neuron_period=0.25, map_period=1.0,
    scene_period=1.0,
)


class Throttle:
    """Lets content through when ``period`` has passed since the last time, and longer for large
    content: ``size / per_second`` seconds for ``size`` items."""

    def __init__(self, period: float, per_second: float = math.inf) -> None:
        self.period = period
        self.per_second = per_second
        self._last = -math.inf

    #: stamps of a 10 Hz log are 0.1 s apart only to within rounding
    TOLERANCE = 1e-6

    def ready(self, now: float, size: int = 0) -> bool:
        wait = max(self.period, size / self.per_second)
        if now - self._last < wait - self.TOLERANCE:
            return False
        self._last = now
        return True


def _json_channel(topic: str, name: str, fields: dict[str, str], context: foxglove.Context):
    return foxglove.Channel(
        topic, schema=msg.json_schema(name, fields), message_encoding="json", context=context
    )


class Recorder:
    """Publishes a run's channels (:mod:`.topics`) on a Foxglove context, one scan at a time.

    Call it as the pipeline's observer, then :meth:`finish` with the system once the run is
    over (the final, relaxed cognitive map and the corrected trajectory). The sinks (an MCAP
    file, a WebSocket server) are attached to ``context`` by the caller.

    Args:
        context: the Foxglove context whose sinks receive the messages.
        odometry_only: the run has no views, pose cells or cognitive map.
        config: rates and map settings.
        clock: ``"log"`` throttles on the scans' stamps, ``"wall"`` on the wall clock.
        on_time: called with each published scan's log time (ns), e.g. to tell live viewers
            the current time.
    """

    def __init__(
        self,
        context: foxglove.Context,
        odometry_only: bool = False,
        config: RecorderConfig = RECORD_CONFIG,
        clock: Clock = "log",
        on_time: Callable[[int], None] | None = None,
    ) -> None:
        self.config = c = config
        # The context must outlive the channels: once it is garbage, they lose their sinks.
        self.context = context
        self.clock = clock
        self.on_time = on_time
        self.odometry_only = odometry_only
        self.scan = LaserScanChannel(tp.SCAN, context=context)
        self.tf = FrameTransformsChannel(tp.TF, context=context)
        self.odometry_pose = PoseInFrameChannel(tp.ODOMETRY_POSE, context=context)
        self.slam_pose = PoseInFrameChannel(tp.SLAM_POSE, context=context)
        self.match = _json_channel(
            tp.ODOMETRY_MATCH, "bioslam.OdometryMatch", msg.ODOMETRY_MATCH_FIELDS, context
        )
        self.grid = GridChannel(tp.MAP, context=context)
        self.log = LogChannel(tp.LOG, context=context)
        self._throttles = {
            "scan": Throttle(c.scan_period),
            "pose": Throttle(c.pose_period),
            "match": Throttle(c.match_period),
            "neurons": Throttle(c.neuron_period),
            "map": Throttle(c.map_period, c.map_cells_per_second),
            "scene": Throttle(c.scene_period, c.scene_items_per_second),
        }
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
        self.occupancy: OccupancyGrid | None = None
        self._last_fused: PoseTuple | None = None
        self._last_ns: int | None = None
        self._polar: tuple[NDArray[np.int64], NDArray[np.bool_]] | None = None
        self._links: list[tuple[int, int]] = []
        self._loop: list[bool] = []
        self._seen = {"records": 0, "recovered": 0, "rejected": 0, "collapses": 0}
        self._degenerate = False
        #: messages handed to the context, per topic (for summaries and tests)
        self.counts: dict[str, int] = {}
        #: seconds spent in the recorder (wall, and CPU of the calling thread)
        self.seconds = 0.0
        self.cpu_seconds = 0.0

    # --- the observer ----------------------------------------------------------------------

    def __call__(self, scan: LaserScan, pose: Pose2D, system: Any) -> None:
        started, cpu = time.perf_counter(), time.thread_time()
        ns = msg.log_time(scan.stamp)
        if self._last_ns is not None and ns < self._last_ns:
            raise ValueError(f"scan stamp {scan.stamp} s is earlier than the previous scan's")
        self._last_ns = ns
        now = scan.stamp if self.clock == "log" else time.monotonic()
        slam_pose = tuple(pose)
        odometry_pose = tuple(system.self_motion.pose.tolist())
        if self._throttles["scan"].ready(now):
            self._publish_scan(ns, scan, slam_pose, odometry_pose)
        if self._throttles["pose"].ready(now):
            self._publish_poses(ns, slam_pose, odometry_pose)
        self._publish_match(ns, now, system)
        self._fuse(slam_pose, system)
        if self._throttles["map"].ready(now, self._map_cells()):
            self.publish_map(ns)
        if isinstance(system, BioSLAM):
            self._publish_look(ns, now, scan, system)
            self._log_map_events(ns, system)
            cmap = system.cognitive_map
            if self._throttles["scene"].ready(now, len(cmap) + cmap.num_links):
                self.publish_scene(ns, system)
        self.seconds += time.perf_counter() - started
        self.cpu_seconds += time.thread_time() - cpu

    def finish(self, system: Any) -> None:
        """After the run: the final map, and the relaxed cognitive map with the corrected
        trajectory, at the last scan's time."""
        if self._last_ns is None:
            return
        ns = self._last_ns
        self.publish_map(ns)
        if isinstance(system, BioSLAM):
            trajectory = system.trajectory().poses
            step = max(1, len(trajectory) // max(1, self.config.trajectory_points))
            self.publish_scene(ns, system, trajectory[::step])
        self._log(ns, "Info", f"run finished after {system.num_scans} scans", "bioslam")

    # --- per channel ------------------------------------------------------------------------

    def _count(self, topic: str) -> None:
        self.counts[topic] = self.counts.get(topic, 0) + 1

    def _publish_scan(
        self, ns: int, scan: LaserScan, slam_pose: PoseTuple, odometry_pose: PoseTuple
    ) -> None:
        if self.scan.has_sinks():
            ranges = msg.scan_ranges(scan.ranges, scan.range_min, scan.range_max)
            angles = scan.angles
            start, end = (float(angles[0]), float(angles[-1])) if angles.size else (0.0, 0.0)
            self.scan.log(msg.laser_scan(ns, ranges, start, end), log_time=ns)
            self._count(tp.SCAN)
        if self.tf.has_sinks():
            self.tf.log(msg.odometry_transform(ns, odometry_pose), log_time=ns)
            self._count(tp.TF)
        if self.on_time is not None:
            self.on_time(ns)

    def _publish_poses(self, ns: int, slam_pose: PoseTuple, odometry_pose: PoseTuple) -> None:
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

    def _publish_match(self, ns: int, now: float, system: Any) -> None:
        odometry = system.odometry
        report = odometry.last_report
        if report.recovered:
            self._log(ns, "Warning", f"odometry: the scan match failed and a search found a "
                      f"better one (score {report.score:.2f})", "odometry")
        if report.predicted_only:
            self._log(ns, "Warning", f"odometry: {report.num_points} usable points, too few "
                      "to match; the pose is predicted", "odometry")
        if report.degenerate != self._degenerate and not report.predicted_only:
            self._degenerate = report.degenerate
            text = ("odometry: degenerate match (a direction the scan does not constrain, "
                    f"condition {report.condition:.3f})" if report.degenerate
                    else "odometry: the match is constrained again")
            self._log(ns, "Warning" if report.degenerate else "Info", text, "odometry")
        if self._throttles["match"].ready(now) and self.match.has_sinks():
            self.match.log({
                "score": float(report.score),
                "iterations": int(report.iterations),
                "points": int(report.num_points),
                "condition": float(report.condition),
                "degenerate": bool(report.degenerate),
                "recovered": bool(report.recovered),
                "predicted_only": bool(report.predicted_only),
            }, log_time=ns)
            self._count(tp.ODOMETRY_MATCH)

    def _fuse(self, slam_pose: PoseTuple, system: Any) -> None:
        """Fuse the scan into the occupancy map at the SLAM pose of the moment (the map as
        the system saw it; the corrected map is the run's ``map.pgm``)."""
        c = self.config
        last = self._last_fused
        if last is not None:
            moved = math.hypot(slam_pose[0] - last[0], slam_pose[1] - last[1])
            turned = abs(math.remainder(slam_pose[2] - last[2], 2.0 * math.pi))
            if moved < c.map_keyframe_distance and turned < c.map_keyframe_angle:
                return
        points = system.odometry.last_points
        if points.shape[0] == 0:
            return
        if self.occupancy is None:
            size = 2.0 * float(np.max(np.abs(points))) + 1.0
            origin = (slam_pose[0] - 0.5 * size, slam_pose[1] - 0.5 * size)
            self.occupancy = OccupancyGrid(c.map_resolution, size, origin, auto_grow=True)
        thinned = thin_points(points, c.map_point_spacing).astype(np.float64)
        self.occupancy.insert_scan(slam_pose, thinned, system.odometry.config.max_range)
        self._last_fused = slam_pose

    def _map_cells(self) -> int:
        return 0 if self.occupancy is None else self.occupancy.logodds.size

    def publish_map(self, ns: int) -> None:
        grid = self.occupancy
        if grid is None or not self.grid.has_sinks():
            return
        self.grid.log(
            msg.occupancy_grid(
                ns, grid.logodds, grid.known_mask(), grid.origin, grid.resolution
            ),
            log_time=ns,
        )
        self._count(tp.MAP)

    def _publish_look(self, ns: int, now: float, scan: LaserScan, system: BioSLAM) -> None:
        """The active view, and (throttled) the neurons, when the view cells looked."""
        records = system.records
        if len(records) == self._seen["records"]:
            return
        self._seen["records"] = len(records)
        record = records[-1]
        if self.view.has_sinks():
            ids, activity = system.view_cells.active_views()
            active = activity[ids == record.view_id]
            cmap = system.cognitive_map
            self.view.log({
                "view_id": int(record.view_id),
                "is_new": bool(record.view_is_new),
                "activity": float(active[0]) if active.size else 0.0,
                "event": record.event,
                "experience": int(record.experience_id),
                "views": int(system.view_cells.num_views),
                "experiences": len(cmap),
                "loop_closures": int(cmap.loop_closures),
            }, log_time=ns)
            self._count(tp.VIEW)
        if self._throttles["neurons"].ready(now):
            self._publish_neurons(ns, scan, system)

    def _publish_neurons(self, ns: int, scan: LaserScan, system: BioSLAM) -> None:
        if self.boundary.has_sinks():
            if self._polar is None:
                cfg = system.boundary_cells.config
                self._polar = msg.polar_lookup(
                    cfg.ring_distances, cfg.cells_per_ring, self.config.boundary_pixels
                )
            activity = system.boundary_cells.activity(scan)
            self.boundary.log(msg.boundary_image(ns, activity, *self._polar), log_time=ns)
            self._count(tp.BOUNDARY_CELLS)
        network = system.pose_cells
        if self.pose_cells_xy.has_sinks() or self.pose_cells_theta.has_sinks():
            xy, theta = msg.pose_cell_images(ns, network.activity)
            self.pose_cells_xy.log(xy, log_time=ns)
            self.pose_cells_theta.log(theta, log_time=ns)
            self._count(tp.POSE_CELLS_XY)
            self._count(tp.POSE_CELLS_THETA)
        if self.pose_cell_state.has_sinks():
            x, y, theta = (float(v) for v in network.centre())
            self.pose_cell_state.log({
                "x": x, "y": y, "theta": theta,
                "active_cells": int(network.active_count),
                "collapses": int(network.collapses),
            }, log_time=ns)
            self._count(tp.POSE_CELLS_STATE)

    def _new_links(self, system: BioSLAM) -> None:
        cmap = system.cognitive_map
        for index in range(len(self._links), cmap.num_links):
            link = cmap.link(index)
            self._links.append((link.source, link.target))
            self._loop.append(link.kind == "loop")

    def _log_map_events(self, ns: int, system: BioSLAM) -> None:
        cmap = system.cognitive_map
        closed = cmap.num_links > len(self._links)
        self._new_links(system)
        if closed and self._loop[-1]:
            source, target = self._links[-1]
            self._log(ns, "Info", f"loop closure accepted: experience {source} -> {target} "
                      f"({cmap.loop_closures} so far)", "cognitive_map")
        if cmap.rejected_closures > self._seen["rejected"]:
            self._seen["rejected"] = cmap.rejected_closures
            self._log(ns, "Warning", "loop closure rejected: the scan registration did not fit "
                      f"({cmap.rejected_closures} so far)", "cognitive_map")
        collapses = system.pose_cells.collapses
        if collapses > self._seen["collapses"]:
            self._seen["collapses"] = collapses
            self._log(ns, "Warning", "pose cells: the activity packet died out and was "
                      "re-seeded at its last centre", "pose_cells")

    def publish_scene(
        self, ns: int, system: BioSLAM, trajectory: FloatArray | None = None
    ) -> None:
        if not self.scene.has_sinks():
            return
        self._new_links(system)
        cmap = system.cognitive_map
        links = np.array(self._links, dtype=np.int64).reshape(-1, 2)
        scene = msg.cognitive_map_scene(
            ns, cmap.experience_poses, links, np.array(self._loop, dtype=bool),
            cmap.current, trajectory,
        )  # fmt: skip
        self.scene.log(scene, log_time=ns)
        self._count(tp.COGNITIVE_MAP)

    def _log(self, ns: int, level: str, text: str, name: str) -> None:
        if self.log.has_sinks():
            self.log.log(msg.log_message(ns, level, text, name), log_time=ns)
            self._count(tp.LOG)
