"""The run's side of a recording: the pipeline's per-scan observer, which copies out what the
channels need as plain numbers and arrays ("items") and hands them on in batches.

What it sends, as tuples ``(kind, log_time_ns, ...)``:

* ``scan``: every scan (a live view: at most ``scan_period`` apart): ranges, angles, range
  limits, odometry and SLAM poses and the odometry's match report;
* ``fuse``: at keyframes, the scan's thinned endpoints and the SLAM pose, for the map;
* ``look``: at every look of the view cells, the active view and the map's event;
* ``neurons``: throttled, the boundary-cell activity and the pose-cell projections;
* ``scene``: throttled (longer as the map grows), the experiences and the new links;
* ``log``: events only the system knows (loop closures accepted and rejected, collapses);
* ``finish``: the relaxed map and the corrected trajectory after the run.

Building and writing the messages (:mod:`.recorder`) happens in a separate process
(:mod:`.session`), so the run pays only for these copies. The tap reads the system through its
public attributes and never changes it; it imports nothing of the Foxglove SDK.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from bioslam.geometry import Pose2D
from bioslam.recording.rates import (
    RECORD_CONFIG,
    Clock,
    Item,
    RecorderConfig,
    Throttle,
    log_time,
)
from bioslam.scan import LaserScan
from bioslam.slam import BioSLAM, thin_points


def _report(report: Any) -> tuple:
    """The odometry's :class:`~bioslam.odometry.MatchReport` as plain numbers."""
    return (float(report.score), int(report.iterations), int(report.num_points),
            float(report.condition), bool(report.degenerate), bool(report.recovered),
            bool(report.predicted_only))  # fmt: skip


class Tap:
    """The observer: call it with each processed scan, then :meth:`finish` with the system.

    Args:
        send: receives each batch (a list of items).
        config: rates and map settings.
        clock: ``"log"`` throttles on the scans' stamps, ``"wall"`` on the wall clock.
    """

    def __init__(
        self, send: Callable[[list[Item]], None], config: RecorderConfig = RECORD_CONFIG,
        clock: Clock = "log",
    ) -> None:  # fmt: skip
        self.send = send
        self.config = c = config
        self.clock = clock
        self._throttles = {
            "scan": Throttle(c.scan_period),
            "neurons": Throttle(c.neuron_period),
            "scene": Throttle(c.scene_period, c.scene_items_per_second),
        }
        self._batch: list[Item] = []
        self._last_ns: int | None = None
        self._last_fused: tuple[float, float, float] | None = None
        self._seen = {"records": 0, "links": 0, "rejected": 0, "collapses": 0}
        self._scene_links = 0
        #: wall and CPU seconds spent in the tap (the run's cost of recording)
        self.seconds = 0.0
        self.cpu_seconds = 0.0

    def __call__(self, scan: LaserScan, pose: Pose2D, system: Any) -> None:
        started, cpu = time.perf_counter(), time.thread_time()
        ns = log_time(scan.stamp)
        if self._last_ns is not None and ns < self._last_ns:
            raise ValueError(f"scan stamp {scan.stamp} s is earlier than the previous scan's")
        self._last_ns = ns
        now = scan.stamp if self.clock == "log" else time.monotonic()
        slam_pose = tuple(pose)
        odometry = system.odometry
        if self._throttles["scan"].ready(now):
            angles = scan.angles
            self._batch.append((
                "scan", ns, scan.ranges, float(angles[0]), float(angles[-1]), scan.range_min,
                scan.range_max, tuple(system.self_motion.pose.tolist()), slam_pose,
                _report(odometry.last_report),
            ))  # fmt: skip
        self._fuse(ns, slam_pose, odometry)
        if isinstance(system, BioSLAM) and len(system.records) != self._seen["records"]:
            self._seen["records"] = len(system.records)
            self._look(ns, now, scan, system)
        if isinstance(system, BioSLAM):
            cmap = system.cognitive_map
            if self._throttles["scene"].ready(now, lambda: len(cmap) + cmap.num_links):
                self._batch.append(self._scene(ns, system))
        if len(self._batch) >= self.config.batch:
            self.flush()
        self.seconds += time.perf_counter() - started
        self.cpu_seconds += time.thread_time() - cpu

    def flush(self) -> None:
        if self._batch:
            batch, self._batch = self._batch, []
            self.send(batch)

    def finish(self, system: Any) -> None:
        """After the run: the relaxed cognitive map and the corrected trajectory."""
        if self._last_ns is None:
            return
        trajectory = None
        scene = None
        if isinstance(system, BioSLAM):
            poses = system.trajectory().poses
            step = max(1, len(poses) // max(1, self.config.trajectory_points))
            trajectory = poses[::step, :2].astype(np.float64)
            scene = self._scene(self._last_ns, system)
        self._batch.append(("finish", self._last_ns, system.num_scans, scene, trajectory))
        self.flush()

    # --- what the system knows ----------------------------------------------------------------

    def _fuse(self, ns: int, slam_pose: tuple[float, float, float], odometry: Any) -> None:
        """At a keyframe, the scan's endpoints for the occupancy map (fused at the SLAM pose of
        the moment: the map as the system saw it; the corrected map is ``map.pgm``)."""
        c = self.config
        last = self._last_fused
        if last is not None:
            moved = math.hypot(slam_pose[0] - last[0], slam_pose[1] - last[1])
            turned = abs(math.remainder(slam_pose[2] - last[2], 2.0 * math.pi))
            if moved < c.map_keyframe_distance and turned < c.map_keyframe_angle:
                return
        points = odometry.last_points
        if points.shape[0] == 0:
            return
        self._last_fused = slam_pose
        thinned = thin_points(points, c.map_point_spacing)
        self._batch.append(("fuse", ns, slam_pose, thinned, float(odometry.config.max_range)))

    def _look(self, ns: int, now: float, scan: LaserScan, system: BioSLAM) -> None:
        """The active view and the map's events after a look of the view cells, and
        (throttled) the neurons."""
        record = system.records[-1]
        cmap = system.cognitive_map
        ids, activity = system.view_cells.active_views()
        active = activity[ids == record.view_id]
        self._batch.append((
            "look", ns, int(record.view_id), bool(record.view_is_new),
            float(active[0]) if active.size else 0.0, record.event, int(record.experience_id),
            system.view_cells.num_views, len(cmap), int(cmap.loop_closures),
        ))  # fmt: skip
        self._events(ns, system)
        if self._throttles["neurons"].ready(now):
            cells = system.boundary_cells
            network = system.pose_cells
            pc = network.activity
            self._batch.append((
                "neurons", ns, cells.activity(scan), tuple(cells.config.ring_distances),
                cells.config.cells_per_ring, pc.max(axis=2), pc.sum(axis=(0, 1)),
                tuple(float(v) for v in network.centre()), int(network.active_count),
                int(network.collapses),
            ))  # fmt: skip

    def _events(self, ns: int, system: BioSLAM) -> None:
        """A log message for each of the map's events since the last look: one look may bring
        several (a closure that confirms one held back enters both at once, :class:`bioslam.
        closure.ClosureConsensus`; two checks may be refused on one scan), and each counts."""
        cmap = system.cognitive_map
        loops = [
            link for link in (cmap.link(k) for k in range(self._seen["links"], cmap.num_links))
            if link.kind == "loop"
        ]
        self._seen["links"] = cmap.num_links
        first = cmap.loop_closures - len(loops) + 1
        for count, link in enumerate(loops, start=first):
            self._log(ns, "Info", f"loop closure accepted: experience {link.source} -> "
                      f"{link.target} ({count} so far)", "cognitive_map")
        for count in range(self._seen["rejected"] + 1, cmap.rejected_closures + 1):
            self._log(ns, "Warning", "loop closure rejected: the scan registration did not fit "
                      f"({count} so far)", "cognitive_map")
        self._seen["rejected"] = cmap.rejected_closures
        for _ in range(self._seen["collapses"], system.pose_cells.collapses):
            self._log(ns, "Warning", "pose cells: the activity packet died out and was "
                      "re-seeded at its last centre", "pose_cells")
        self._seen["collapses"] = system.pose_cells.collapses

    def _scene(self, ns: int, system: BioSLAM) -> Item:
        """The experiences' relaxed poses (all: relaxation moves them) and the links made since
        the last scene (links never change once made; the recorder keeps them)."""
        cmap = system.cognitive_map
        new = [cmap.link(i) for i in range(self._scene_links, cmap.num_links)]
        self._scene_links = cmap.num_links
        ends = np.array([(link.source, link.target) for link in new], dtype=np.int64)
        loop = np.array([link.kind == "loop" for link in new], dtype=bool)
        return ("scene", ns, cmap.experience_poses, ends.reshape(-1, 2), loop, cmap.current)

    def _log(self, ns: int, level: str, text: str, name: str) -> None:
        self._batch.append(("log", ns, level, text, name))
