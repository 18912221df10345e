"""Running BioSLAM over a log and writing its results: progress, timing, files, figures.

The algorithm core (:mod:`bioslam.slam`) never touches files or the terminal; this module does,
and it does so defensively: a run interrupted (Ctrl-C) or failing half-way keeps what it had
computed and still writes it.
"""

from __future__ import annotations

import itertools
import math
import sys
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from tqdm import tqdm

from bioslam import signals
from bioslam.closure import slides
from bioslam.cognitive_map import CognitiveMap, configured_noise
from bioslam.config import SLAMConfig
from bioslam.evaluation import (
    evaluate,
    off_reference,
    position_errors,
    relative_pose_errors,
    relative_poses,
)
from bioslam.geometry import Pose2D, compose, inverse
from bioslam.growing import GrowingArray, Rows, RowsFactory
from bioslam.io.closures import write_closures
from bioslam.io.forked import ChildEndedError
from bioslam.io.jsonio import atomic_write_bytes, write_json, write_json_streamed
from bioslam.io.mapfile import OccupancyImage, write_map
from bioslam.io.outdir import OutputDir
from bioslam.io.spill import SpilledRows, SpilledScans
from bioslam.io.tum import write_tum
from bioslam.io.uncertainty import write_uncertainty
from bioslam.link_noise import LinkNoiseEstimator
from bioslam.memory import drop_file_pages, release_free_memory
from bioslam.occupancy_grid import OccupancyGrid
from bioslam.odometry import LidarOdometry, register_scans
from bioslam.plots import GROUND_TRUTH
from bioslam.scan import LaserScan
from bioslam.slam import (
    BioSLAM,
    MatchUncertainty,
    SelfMotion,
    StepRecords,
    row_stores,
    thin_points,
)
from bioslam.trajectory import Trajectory
from bioslam.views import ViewCells

if TYPE_CHECKING:
    from bioslam.plots.worker import FigureWorker, Job

FloatArray = NDArray[np.float64]

#: Called after each processed scan with the scan, the pose ``process`` returned and the
#: system (its public attributes give the odometry, views, pose cells and map): how a recorder
#: or live viewer watches a run without the run knowing about it.
ScanObserver = Callable[[LaserScan, Pose2D, "BioSLAM | OdometryOnly"], None]


@dataclass
class RunOptions:
    """How a run is carried out and what it keeps for its outputs.

    Attributes:
        odometry_only: run the LiDAR odometry alone (no views, pose cells or map).
        progress: show a progress bar on stderr.
        snapshot_times: seconds after the first scan at which to keep a copy of the cognitive
            map for the mapping-progress figure (the paper's Fig. 5 uses 200, 400 and 600 s).
        snapshot_tolerance: a snapshot time at most this many seconds past the last scan
            gets the final map.
        keyframe_distance, keyframe_angle: a scan is kept for rendering the output map when
            the robot has moved this far (m) or turned this much (rad) since the last kept one;
            this bounds memory on long logs while every place still gets drawn.
        keyframe_bytes: at most this many bytes of kept scan points; beyond, the two
            spacings double and the kept scans are thinned to them
            (:class:`KeyframeScans`).
        map_resolution: cell size of the output map, metres.
        map_point_spacing: the kept scans are thinned to one point per this many metres.
        warm_up: before the timed run, run a throwaway system on a second of simulated
            scans, so that Numba's compilation (first run after installing) or loading of
            its cache is not billed to the first scans of the log (``startup_s`` in the
            summary says what it took).
        release: :func:`write_results` first drops the system's per-scan working memory
            (``BioSLAM.release``) and, once the map is drawn, the kept scans, so that the
            outputs are made in that much less memory; for commands that are done with the
            system after writing.
        trim_every: every this many scans the allocator's free pages are handed back to the
            system (:func:`bioslam.memory.release_free_memory`, a millisecond or so, not
            billed to a scan): the blocks a scan's work frees between longer-lived ones
            would otherwise stay resident for the rest of the run. 0: never.
        scan_store_dir: keep the scans stored with the experiences in an unlinked temporary
            file in this directory instead of in memory (:mod:`bioslam.io.spill`: 4 kB an
            experience, the largest part of what a long run accumulates; the run is the same
            either way), and the per-scan columns read only for the outputs in files there
            too (:class:`bioslam.io.spill.SpilledRows`: 97 bytes a scan). None: in memory.
        drop_library_pages: once the warm-up has loaded every compiled kernel, drop the
            libraries' clean pages from the process (:func:`bioslam.memory.drop_file_pages`:
            84 MB, of which LLVM's 67 MB are needed again only to compile; what the run uses
            comes back at its first use); for a process of its own.
        figure_worker: draws the figures in a child process (:mod:`bioslam.plots.worker`,
            started by ``bioslam run`` with the command), beside the writing of the other
            outputs. None: drawn in this process.
        reference_label: what the figures call the trajectory the run is evaluated against:
            the ground truth (a simulation's, or ``--gt``), or a log's corrected poses,
            another SLAM system's estimate with errors of its own
            (:data:`bioslam.plots.LOG_REFERENCE`).
    """

    odometry_only: bool = False
    progress: bool = True
    snapshot_times: tuple[float, ...] = ()
    keyframe_distance: float = 0.1
    keyframe_angle: float = math.radians(5.0)
    keyframe_bytes: int = 8 * 2**20
    map_resolution: float = 0.05
    map_point_spacing: float = 0.025
    snapshot_tolerance: float = 1.0
    warm_up: bool = True
    release: bool = False
    trim_every: int = 2000
    scan_store_dir: Path | None = None
    drop_library_pages: bool = False
    figure_worker: FigureWorker | None = None
    reference_label: str = GROUND_TRUTH


class OdometryOnly:
    """The self-motion cue alone (Sec. III-A) behind the same interface as :class:`BioSLAM`."""

    def __init__(self, config: SLAMConfig, rows: RowsFactory | None = None) -> None:
        """``rows``: see :class:`BioSLAM`."""
        self.self_motion = SelfMotion(config)
        self._rows = rows
        self._new_scan_columns()
        self.records = StepRecords()
        self._released: dict[str, int] | None = None

    @property
    def odometry(self) -> LidarOdometry:
        return self.self_motion.odometry

    def process(self, scan: LaserScan) -> Pose2D:
        self.self_motion.step(scan)
        self._poses.append(self.self_motion.pose)
        self._uncertainty.append(self.odometry.last_report)
        self._stamps.append(scan.stamp)  # last, as in :meth:`BioSLAM._record`
        return Pose2D(*self.self_motion.pose)

    @property
    def num_scans(self) -> int:
        return len(self._stamps)

    def trajectory(self) -> Trajectory:
        n = self.num_scans
        if not n:
            return Trajectory.empty()
        return Trajectory(self._stamps.array(), self._poses.array()[:n])

    odometry_trajectory = trajectory

    def odometry_uncertainty(self) -> tuple[FloatArray, FloatArray, NDArray[np.int8]]:
        """See :meth:`BioSLAM.odometry_uncertainty`."""
        return (self._stamps.array(), *self._uncertainty.arrays(self.num_scans))

    def release_scans(self) -> None:
        """See :meth:`BioSLAM.release_scans`."""
        self._new_scan_columns(capacity=1)

    def _new_scan_columns(self, capacity: int = 1024) -> None:
        """Empty per-scan columns: each scan's stamp and odometry pose."""
        rows = self._rows if capacity > 1 else None
        make = row_stores(rows, capacity)
        self._stamps, self._poses = make(np.float64, 0), make(np.float64, 3)
        self._uncertainty = MatchUncertainty(capacity, rows)

    def finish(self) -> None:
        """Nothing to settle: the odometry is final as it goes."""

    def summary(self) -> dict[str, int]:
        if self._released is not None:
            return dict(self._released)
        return {"views": 0, "experiences": 0, "loop_closures": 0, **self.odometry.summary()}

    def release(self) -> None:
        """After the last scan: drop the odometry's local map (see :meth:`BioSLAM.release`)."""
        if self._released is None:
            self._released = self.summary()
        self.self_motion.odometry = None  # type: ignore[assignment]


class KeyframeScans:
    """The scans kept for the output map: their scan numbers, the odometry pose each was
    taken at and their thinned sensor-frame endpoints, all in growing arrays rather than one
    array per keyframe.

    A scan is kept when the robot has moved ``distance`` metres or turned ``angle`` radians
    since the last kept one (:meth:`wants`). They are kept for the whole run (the map is
    drawn at the final, corrected poses), so the endpoints within ``max_range`` (the only
    ones the map draws) are stored as 16-bit integers of ``quantum`` metres (1 mm for ranges
    up to 32 m: 4 bytes a point instead of 8); each keyframe's reach (the map's extent) is
    taken before, from the points as they came.

    At 40 Hz every 10 cm that is still 45 MB an hour: once the points pass ``max_bytes``
    the spacing doubles and the keyframes already kept are thinned to it (:meth:`thin`), so
    a run of any length keeps at most about ``max_bytes`` (a scanner sees metres around it:
    a map of walls drawn from every 20-40 cm of a long run differs little from every 10).
    """

    def __init__(
        self,
        max_range: float = 30.0,
        quantum: float = 0.001,
        distance: float = 0.1,
        angle: float = math.radians(5.0),
        max_bytes: int = 8 * 2**20,
    ) -> None:
        self.max_range = float(max_range)
        self.quantum = max(quantum, self.max_range / 32000.0)
        self.distance, self.angle = float(distance), float(angle)
        self.max_bytes = int(max_bytes)
        self._dtype = np.int16 if math.isfinite(self.quantum) else np.float32
        self._reset()

    def _reset(self, capacity: int = 1024, points: int = 1 << 16) -> None:
        self.index = GrowingArray(np.int64, capacity=capacity)
        self.reach = GrowingArray(np.float64, capacity=capacity)
        self.poses = GrowingArray(np.float64, 3, capacity=capacity)
        self._starts = GrowingArray(np.int64, capacity=capacity)
        self._points = GrowingArray(self._dtype, 2, capacity=points)

    def wants(self, pose: FloatArray) -> bool:
        """Whether a scan taken at odometry ``pose`` is to be kept: far enough from the
        last kept one (the first always is)."""
        if not len(self.index):
            return True
        return _apart(self.poses[-1], pose, self.distance, self.angle)

    def add(
        self, scan_index: int, points: NDArray[np.float32], pose: ArrayLike = (0.0, 0.0, 0.0)
    ) -> None:
        """Keep scan ``scan_index``'s ``points`` (taken at odometry ``pose``)."""
        pts = np.asarray(points, dtype=np.float32)
        self.index.append(scan_index)
        self.poses.append(pose)
        self.reach.append(np.max(np.abs(pts), initial=0.0))
        wide = pts.astype(np.float64)
        pts = pts[np.einsum("ij,ij->i", wide, wide) <= self.max_range * self.max_range]
        if self._dtype == np.int16:
            pts = np.rint(pts / np.float32(self.quantum))
        self._starts.append(len(self._points))
        self._points.extend(pts)
        if self._points.view().nbytes > self.max_bytes:
            self.thin()

    def thin(self) -> None:
        """Double the spacing and keep, of the keyframes so far, those it would have kept
        (moved forward in place: thinning takes no memory of its own)."""
        self.distance *= 2.0
        self.angle *= 2.0
        poses = self.poses.view()
        keep = [0]
        for k in range(1, len(self)):
            if _apart(poses[keep[-1]], poses[k], self.distance, self.angle):
                keep.append(k)
        data, starts = self._points.view(), self._starts.view()
        ends = np.append(starts[1:], len(self._points))
        filled = 0
        for k in keep:
            size = int(ends[k] - starts[k])
            data[filled : filled + size] = data[starts[k] : ends[k]]
            starts[k] = filled  # k only grows: no start still to be read is overwritten
            filled += size
        self._points.truncate(filled)
        for part in (self.index, self.reach, self.poses, self._starts):
            rows = part.view()
            rows[: len(keep)] = rows[keep]
            part.truncate(len(keep))

    def __len__(self) -> int:
        return len(self.index)

    def _stored(self, k: int) -> NDArray:  # type: ignore[type-arg]
        stop = self._starts[k + 1] if k + 1 < len(self) else len(self._points)
        return self._points.view()[self._starts[k] : stop]

    def points(self, k: int) -> FloatArray:
        """Keyframe ``k``'s endpoints (within ``max_range``), metres."""
        stored = self._stored(k).astype(np.float64)
        return stored * self.quantum if self._dtype == np.int16 else stored

    @property
    def nbytes(self) -> int:
        parts = (self.index, self.reach, self.poses, self._starts, self._points)
        return sum(part.nbytes for part in parts)


def _apart(a: FloatArray, b: FloatArray, distance: float, angle: float) -> bool:
    """Whether poses ``a`` and ``b`` are ``distance`` apart or turned ``angle`` (or more)."""
    moved = math.hypot(b[0] - a[0], b[1] - a[1])
    turned = abs(math.remainder(b[2] - a[2], 2.0 * math.pi))
    return moved >= distance or turned >= angle


@dataclass
class Snapshot:
    """The cognitive map as it stood at ``elapsed`` seconds into the run."""

    elapsed: float
    nodes_xy: FloatArray
    links: list[tuple[int, int, str]]


@dataclass
class RunResult:
    """Everything a run produced, complete or not."""

    system: BioSLAM | OdometryOnly
    # CPU seconds of this thread per ``process`` call: on a shared machine wall time also
    # counts the time other processes hold the core (measured: a wall mean 1.3-2.1 ms per
    # scan against a steady 1.2-1.3 ms CPU on the same demo run)
    scan_seconds: Rows = field(default_factory=lambda: GrowingArray(np.float64))
    wall_s: float = 0.0
    startup_s: float = 0.0
    snapshots: list[Snapshot] = field(default_factory=list)
    keyframes: KeyframeScans = field(default_factory=KeyframeScans)
    map_max_range: float = 30.0
    interrupted: bool = False
    error: str | None = None
    first_stamp: float | None = None
    last_stamp: float = 0.0


def cognitive_map_snapshot(system: BioSLAM, elapsed: float) -> Snapshot:
    """Experience positions and links as plain arrays (for figures and JSON)."""
    cmap = system.cognitive_map
    nodes = cmap.experience_poses_view[:, :2].copy()
    ends, kinds = cmap.link_table()
    links = [(a, b, str(kind)) for (a, b), kind in zip(ends.tolist(), kinds, strict=True)]
    return Snapshot(elapsed, nodes, links)


def warm_up(config: SLAMConfig, odometry_only: bool = False) -> float:
    """Run every compiled kernel once: the system on a second of the simulated maze, then
    what a loop closure adds; returns the seconds it took."""
    from bioslam.sim import LIDAR_PRESETS, maze_world, simulate_scans

    started = time.perf_counter()
    world = maze_world()
    scans = [scan for scan, _ in simulate_scans(world, LIDAR_PRESETS["utm30lx"], _drive(world))]
    system = OdometryOnly(config) if odometry_only else BioSLAM(config)
    try:
        for scan in scans:
            system.process(scan)
        if not odometry_only:
            # what a loop closure runs: a registration against a stored (float32) scan, the
            # map's solve and its relaxation sweeps
            stored = scans[0].endpoints().astype(np.float32)
            register_scans(stored, scans[-1].endpoints())
            _verify_a_revisit(config, [scan.endpoints() for scan in scans])
            _close_a_square(config)
            _learn_partial_views(config, system, scans[-1])
            _turn_for_views(config, system, scans[-1])
        _learn_steps_and_scroll(config, system)
    except Exception:
        pass  # a configuration the maze does not suit: the run then compiles as it goes
    return time.perf_counter() - started


def _drive(world: Any, seconds: float = 1.0, speed: float = 0.5) -> Any:
    """A straight drive along the first corridor of ``world``'s roadmap (a hand-made route:
    the route planner would import SciPy, which a run without loop closures never needs)."""
    from bioslam.sim import Route

    nodes = world.roadmap.nodes
    a, b = world.roadmap.edges[0]
    along = nodes[b] - nodes[a]
    heading = math.atan2(along[1], along[0])
    end = nodes[a] + along * min(1.0, speed * seconds / float(np.hypot(*along)))
    poses = np.array([[*nodes[a], heading], [*end, heading]])
    return Route(np.array([0.0, seconds]), poses)


def _verify_a_revisit(config: SLAMConfig, endpoints: list[FloatArray]) -> None:
    """What a loop-closure check runs on a candidate (:meth:`bioslam.slam.BioSLAM._refine`):
    a submap of stored scans and where they looked, the wide-basin search and the scores
    judged where the submap looked, the polish on the submap's lines."""
    from bioslam.closure import SeenArea, fuse_submap, polish_on_lines, verify
    from bioslam.matching.point_to_line import LineMap

    cfg = config.loop_closure
    payloads = [points.astype(np.float32) for points in (endpoints[0], endpoints[-1])]
    poses = np.zeros((len(payloads), 3))
    members = list(range(len(payloads)))
    submap = fuse_submap(poses, payloads, 0, members, cfg.submap_spacing)
    seen = SeenArea(poses, payloads, 0, members, cfg.registration.resolution)
    query = endpoints[len(endpoints) // 2]
    verdict = verify(submap, query, np.zeros(3), (0.3, 0.1), cfg, seen, None, (1.0, 0.5))
    polish_on_lines(LineMap.build(submap), verdict.pose, query, seen, cfg)


def _learn_steps_and_scroll(config: SLAMConfig, system: BioSLAM | OdometryOnly) -> None:
    """What a longer or thinned run reaches that a second of driving does not: the learned
    density of the odometry's steps and its typical steps (a thinned log's first scans
    stalled 0.6 and 3.6 s compiling them), and the local map scrolled as the robot leaves
    its centre."""
    from bioslam.step_prior import StepPrior

    prior = StepPrior(config.odometry.step_prior)
    for k in range(config.odometry.step_prior.window + 2):  # past a full window
        prior.add((0.5 + 0.01 * k, 0.001 * k, 0.005 * k))
    prior.density((0.6, 0.0, 0.1))
    prior.modes(2)
    odometry = system.self_motion.odometry
    odometry.pyramid.recenter(odometry.pose[0] + 20.0, odometry.pose[1] + 20.0)


def _learn_partial_views(config: SLAMConfig, system: BioSLAM, scan: LaserScan) -> None:
    """Views of a 180° scanner, more than the view cells compare in full: past that many,
    a partial view's candidates are the views of nearest ring keys (compiled)."""
    cells = system.view_cells
    activity = system.boundary_cells.activity(scan)
    cover = system.boundary_cells.coverage_span(-0.5 * math.pi, 0.5 * math.pi)
    rng = np.random.default_rng(0)
    for _ in range(config.views.partial_candidates + 2):
        cells.observe(activity * rng.uniform(0.0, 2.0, activity.shape), coverage=cover)


def _turn_for_views(config: SLAMConfig, system: BioSLAM, scan: LaserScan) -> None:
    """A 360° scanner's look that matches none of more views than it turns for: they are
    chosen by their ring sums (compiled), the scan turned for them."""
    boundary = system.boundary_cells
    cells = ViewCells(config.views, cells_per_ring=boundary.config.cells_per_ring)
    activity = boundary.activity(scan)
    rng = np.random.default_rng(0)
    for _ in range(4 * config.views.turn_candidates + 2):  # in one bucket of Eq. 6's hash
        cells.learn(activity * rng.uniform(0.95, 1.05, activity.shape), heading=0.0)
    # the rings mirrored: the same sum, a view matched at no shift
    mirrored = activity.reshape(-1, boundary.config.cells_per_ring)[:, ::-1].ravel()
    cells.observe(mirrored, heading=0.05, turned=lambda turn: boundary.activity(scan, turn))


def _close_a_square(config: SLAMConfig) -> None:
    """Four experiences around a square and a loop closure back onto the first."""
    cmap = CognitiveMap.from_pose_cells(config.cognitive_map, config.pose_cells)
    for k in range(5):
        cmap.integrate_odometry((1.0, 0.0, math.pi / 2), stamp=float(k))
        cmap.update(k % 4, k < 4, (1.0, 1.0, 0.0), float(k), refine=lambda e: np.full(3, 0.01))
    cmap.relax()
    cmap.mark_dirty()
    cmap.relax(iterations=2)
    cmap.link_distance(0, 2, 10.0)
    # and what refits the links' noise model after it (its compiled descent)
    estimator = LinkNoiseEstimator(configured_noise(config.cognitive_map))
    for k in range(estimator.min_samples + 1):
        estimator.add(10.0 + k, 0.01 * (k + 1), 0.001 * (k + 1), 1e-4)


def run_slam(
    scans: Iterable[LaserScan],
    config: SLAMConfig | None = None,
    options: RunOptions | None = None,
    total: int | None = None,
    observer: ScanObserver | None = None,
) -> RunResult:
    """Feed every scan to the system, timing each, keeping what the outputs need.

    ``observer`` (optional) sees every processed scan; its time is not in the per-scan times
    but is in ``wall_s``.

    Exceptions from the core end the run but not the result: ``RunResult.error`` says what
    happened and everything computed before is kept.
    """
    config = config or SLAMConfig()
    options = options or RunOptions()
    rows = _row_stores(options)
    system: BioSLAM | OdometryOnly = (
        OdometryOnly(config, rows) if options.odometry_only
        else BioSLAM(config, _scan_store(options), rows, options.scan_store_dir)
    )  # fmt: skip
    max_range = config.odometry.max_range
    keyframes = KeyframeScans(
        max_range, distance=options.keyframe_distance, angle=options.keyframe_angle,
        max_bytes=options.keyframe_bytes,
    )  # fmt: skip
    result = RunResult(system, map_max_range=max_range, keyframes=keyframes)
    if rows is not None:
        result.scan_seconds = rows(np.float64, 0)
    if options.warm_up:
        if options.progress:
            # on a first run the compiling takes up to a minute before the bar shows
            print(
                "warming up: the kernels compile on a first run (up to a minute), then load "
                "from the cache", file=sys.stderr, flush=True,
            )  # fmt: skip
        try:
            with signals.interruptible():
                result.startup_s = warm_up(config, options.odometry_only)
        except KeyboardInterrupt:
            result.interrupted = True
            return result
    if options.drop_library_pages:
        drop_file_pages()
    pending_snapshots = sorted(options.snapshot_times)
    bar = tqdm(total=total, unit="scan", disable=not options.progress, file=sys.stderr,
               dynamic_ncols=True, smoothing=0.05)
    started = time.perf_counter()
    try:
        with signals.interruptible():
            _feed(scans, system, result, options, pending_snapshots, bar, observer)
    except KeyboardInterrupt:
        result.interrupted = True
    except Exception as exc:  # the run's results must survive a failure half-way
        result.error = f"{type(exc).__name__}: {exc}"
    finally:
        bar.close()
        result.wall_s = time.perf_counter() - started
    system.finish()
    if isinstance(system, BioSLAM) and result.first_stamp is not None:
        # A snapshot asked for at the very end (600 s of a 600 s run) falls a scan period
        # after the last stamp: it is the final map.
        result.snapshots += [
            cognitive_map_snapshot(system, wanted)
            for wanted in pending_snapshots
            if wanted - (result.last_stamp - result.first_stamp) <= options.snapshot_tolerance
        ]
    return result


def _scan_store(options: RunOptions) -> SpilledScans | None:
    """The experiences' scan store :attr:`RunOptions.scan_store_dir` asks for (None: a list
    in memory, also when no temporary file can be made there)."""
    if options.scan_store_dir is None:
        return None
    try:
        return SpilledScans(options.scan_store_dir)
    except OSError:
        return None


def _row_stores(options: RunOptions) -> RowsFactory | None:
    """Where the per-scan columns are kept: in files beside the experiences' scans
    (:class:`SpilledRows`) when :attr:`RunOptions.scan_store_dir` is set, else in memory."""
    directory = options.scan_store_dir
    if directory is None:
        return None

    def rows(dtype: Any, width: int) -> SpilledRows:
        return SpilledRows(dtype, width, directory)

    return rows


def _feed(
    scans: Iterable[LaserScan],
    system: BioSLAM | OdometryOnly,
    result: RunResult,
    options: RunOptions,
    pending_snapshots: list[float],
    bar: tqdm,
    observer: ScanObserver | None,
) -> None:
    """The scan loop of :func:`run_slam`: process, time, keep keyframes and snapshots. A
    signal stops it between scans (:func:`bioslam.signals.atomic`), never inside one."""
    for scan in scans:
        with signals.atomic():
            pose = _step(scan, system, result, options, pending_snapshots)
        if observer is not None:
            observer(scan, pose, system)
        if options.trim_every > 0 and system.num_scans % options.trim_every == 0:
            release_free_memory()
        bar.update(1)


def _step(
    scan: LaserScan, system: BioSLAM | OdometryOnly, result: RunResult, options: RunOptions,
    pending_snapshots: list[float],
) -> Pose2D:
    """One scan of :func:`_feed`: processed and timed, its keyframe and snapshots kept."""
    t0 = time.thread_time()
    pose = system.process(scan)
    result.scan_seconds.append(time.thread_time() - t0)
    if result.first_stamp is None:
        result.first_stamp = scan.stamp
    result.last_stamp = scan.stamp
    odo_pose = system.self_motion.pose
    if result.keyframes.wants(odo_pose):
        points = thin_points(scan.endpoints(), options.map_point_spacing)
        result.keyframes.add(system.num_scans - 1, points, odo_pose)
    while pending_snapshots and scan.stamp - result.first_stamp >= pending_snapshots[0]:
        if isinstance(system, BioSLAM):
            result.snapshots.append(cognitive_map_snapshot(system, pending_snapshots[0]))
        pending_snapshots.pop(0)
    return pose


def render_map(
    result: RunResult, trajectory: Trajectory, resolution: float, max_cells: int = 4000
) -> OccupancyImage:
    """An occupancy map from the kept scans placed at their final (corrected) poses.

    The cell size grows beyond ``resolution`` when the map would be wider than ``max_cells``
    cells, so that a huge or diverged trajectory cannot exhaust memory.
    """
    keyframes = result.keyframes
    poses = trajectory.poses[keyframes.index.view()]
    reach = np.minimum(keyframes.reach.view(), result.map_max_range)
    lo = np.min(poses[:, :2] - reach[:, None], axis=0) - 1.0
    hi = np.max(poses[:, :2] + reach[:, None], axis=0) + 1.0
    cell = max(resolution, float(np.max(hi - lo)) / max_cells)
    # drawn only: log-odds and observation stamps, 8 bytes a cell instead of 30
    grid = OccupancyGrid.from_extent(cell, (lo[0], lo[1], hi[0], hi[1]), subcell=False)
    for k, pose in enumerate(poses):
        grid.insert_scan(pose, keyframes.points(k), result.map_max_range)
    probability = grid.probability(unknown=np.nan)
    return OccupancyImage(probability, grid.resolution, (*map(float, grid.origin), 0.0))


def timing_summary(result: RunResult, trajectory: Trajectory) -> dict[str, float]:
    ms = np.asarray(result.scan_seconds) * 1e3
    duration = float(trajectory.stamps[-1] - trajectory.stamps[0]) if len(trajectory) > 1 else 0.0
    compute_s = float(np.sum(np.asarray(result.scan_seconds)))
    return {
        "wall_s": round(result.wall_s, 3),
        "startup_s": round(result.startup_s, 3),
        "duration_s": round(duration, 3),
        "realtime_factor": round(duration / compute_s, 2) if compute_s > 0 else math.nan,
        "ms_per_scan_median": round(float(np.median(ms)), 4) if ms.size else math.nan,
        "ms_per_scan_p99": round(float(np.percentile(ms, 99)), 4) if ms.size else math.nan,
    }


def write_results(
    result: RunResult,
    out_dir: str | Path | OutputDir,
    gt: Trajectory | None = None,
    options: RunOptions | None = None,
    extra: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """Write trajectories, cognitive map, map, figures and ``summary.json``; return the summary.

    The trajectories, the cognitive map and the summary are written whole even when a signal
    arrives meanwhile; the map and the figures are abandoned on a signal (the summary then
    says ``"interrupted": true``). A file that cannot be written (a full disk) is listed in
    ``write_errors`` and the others are still written.
    """
    options = options or RunOptions()
    out = out_dir if isinstance(out_dir, OutputDir) else OutputDir(out_dir, marker=False)
    out.path.mkdir(parents=True, exist_ok=True)
    system = result.system
    if options.release:
        # before the outputs are made: the trajectories, the map's JSON and the figures
        # are built in the memory this frees (read-outs and summary stay)
        system.release()
        release_free_memory()
    with signals.protected():
        trajectory = system.trajectory()
        odometry = system.odometry_trajectory()
        uncertainty = system.odometry_uncertainty()
        summary: dict[str, Any] = {"scans": len(trajectory), **timing_summary(result, trajectory)}
        if options.release:
            system.release_scans()  # the trajectories are made: the figures go without them
        summary.update(system.summary())
        if gt is not None and len(trajectory) > 1:
            gt = _evaluate_into(summary, trajectory, odometry, gt)
        # the worker draws these while the files below and the map are written
        sent = _send_figures(options, result, trajectory, odometry, gt)
        out.save("trajectory.tum", write_tum, trajectory)
        out.save("odometry.tum", write_tum, odometry)
        out.save("odometry_uncertainty.csv", write_uncertainty, *uncertainty)
        if isinstance(system, BioSLAM):
            out.save("cognitive_map.json", write_json_streamed,
                     system.cognitive_map.json_fields())  # fmt: skip
            errors, odometry_errors = _closure_errors(system, odometry, gt, summary)
            out.save("closures.csv", write_closures, system.checks, errors, odometry_errors)
    if len(trajectory):
        _write_map_and_figures(result, out, trajectory, odometry, gt, options, summary, sent)
    if result.interrupted or signals.received() is not None:
        summary["interrupted"] = True
    if result.error:
        summary["error"] = result.error
    summary.update(extra or {})
    with signals.protected():
        if out.errors:
            summary["write_errors"] = list(out.errors)
        out.save("summary.json", write_json, summary)
    if out.errors:
        summary["write_errors"] = list(out.errors)
    return summary


def _closure_errors(
    system: BioSLAM, odometry: Trajectory, reference: Trajectory | None, summary: dict[str, Any]
) -> tuple[NDArray | None, NDArray | None]:
    """Each loop-closure check's measured pose against ``reference``
    (:func:`bioslam.evaluation.relative_pose_errors`), and the ``odometry``'s own relative
    pose between the check's two stamps judged the same way; (None, None) without a
    reference (or with one the trajectory could not be evaluated against: unsorted,
    non-finite). The accepted closures' count off it
    (:func:`bioslam.evaluation.off_reference`) and the two median errors go into
    ``summary``. Where the two medians are alike, the reference's own error at the revisits
    is what both measure: freiburg-079's closures are 3.2 cm from its corrected poses at the
    median, its odometry between the same stamps 3.3 cm."""
    if reference is None:
        return None, None
    checks = system.checks
    first, second = [c.experience_stamp for c in checks], [c.stamp for c in checks]
    free = slides(checks)
    errors = relative_pose_errors(
        first, second, [c.verdict.pose for c in checks], reference, free=free
    )  # fmt: skip
    own = relative_pose_errors(
        first, second, relative_poses(odometry, first, second), reference, free=free
    )  # fmt: skip
    accepted = np.array([c.verdict.accepted for c in checks], dtype=bool)
    judged = accepted & np.isfinite(errors[:, 0])
    summary["loop_closures_against_reference"] = int(judged.sum())
    summary["loop_closures_off_reference"] = int((off_reference(errors) & judged).sum())
    if judged.any():
        summary["loop_closure_reference_error_median_m"] = float(np.median(errors[judged, 0]))
    judged &= np.isfinite(own[:, 0])
    if judged.any():
        summary["loop_closure_odometry_reference_error_median_m"] = float(
            np.median(own[judged, 0])
        )
    return errors, own


def _evaluate_into(
    summary: dict[str, Any], trajectory: Trajectory, odometry: Trajectory, gt: Trajectory
) -> Trajectory | None:
    """Add the ``bioslam eval`` keys (and the odometry's) to ``summary``; a reference that
    cannot be evaluated against (too few matching stamps) is reported in
    ``evaluation_error`` instead, and ``None`` returned so that no figure uses it."""
    try:
        summary.update(evaluate(trajectory, gt))
        summary["odometry"] = evaluate(odometry, gt)
    except ValueError as exc:
        summary["evaluation_error"] = str(exc)
        return None
    return gt


def _write_map_and_figures(
    result: RunResult,
    out: OutputDir,
    trajectory: Trajectory,
    odometry: Trajectory,
    gt: Trajectory | None,
    options: RunOptions,
    summary: dict[str, Any],
    sent: _SentFigures | None = None,
) -> None:
    """The occupancy map and the figures: long to draw, so a signal abandons them (what was
    written stays), and a plotting failure is reported rather than losing the summary."""
    try:
        with signals.interruptible():
            image = render_map(result, trajectory, options.map_resolution)
            if options.release:
                result.keyframes = KeyframeScans(result.map_max_range)
                release_free_memory()
            out.write(["map.pgm", "map.yaml"], lambda: write_map(out.path, image))
            if sent is None or not _write_drawn(sent, out, image, trajectory, summary):
                label = options.reference_label
                _write_figures(result, out, trajectory, odometry, gt, image, label)
    except KeyboardInterrupt:
        result.interrupted = True
    except Exception as exc:  # a figure must not cost the summary
        summary["figures_error"] = f"{type(exc).__name__}: {exc}"


def _map_figure(image: OccupancyImage, trajectory: Trajectory) -> Job:
    return "map.png", "plot_occupancy", (image, trajectory.poses[:, :2])


def _other_figures(
    result: RunResult,
    trajectory: Trajectory,
    odometry: Trajectory,
    gt: Trajectory | None,
    label: str,
) -> Iterator[Job]:
    """The figures after the map's, in order, each made when asked for (an error in making
    one leaves those before it to draw); ``gt`` is called ``label`` in them."""
    system = result.system
    if not isinstance(system, BioSLAM):
        return
    final = cognitive_map_snapshot(system, float(trajectory.stamps[-1] - trajectory.stamps[0]))
    aligned_gt = _gt_in_map_frame(trajectory, gt) if gt is not None else None
    yield "cognitive_map.png", "plot_cognitive_map", (
        final.nodes_xy, final.links, aligned_gt, "Cognitive map", label)
    records = system.records
    stamps, view_ids = records.stamps.view(), records.view_ids.view()
    new_mask = records.new_views.view()
    yield "active_view.png", "plot_active_view", (stamps, view_ids, new_mask)
    if gt is None:
        return
    err_t, err = position_errors(trajectory, gt)
    odo_t, odo_err = position_errors(odometry, gt)
    yield "error.png", "plot_error_over_time", (err_t, err, (odo_t, odo_err), None, label)
    yield "views_and_error.png", "plot_views_and_errors", (
        stamps, view_ids, new_mask, err_t, err, (odo_t, odo_err), label)
    if result.snapshots:
        yield "mapping_progress.png", "plot_mapping_progress", (
            [(s.elapsed, s.nodes_xy, s.links) for s in result.snapshots], aligned_gt, label)


def _write_figures(
    result: RunResult,
    out: OutputDir,
    trajectory: Trajectory,
    odometry: Trajectory,
    gt: Trajectory | None,
    image: OccupancyImage,
    label: str,
) -> None:
    """Draw the figures in this process, in order (``gt`` called ``label``); the first failure
    ends them."""
    # matplotlib costs ~50 MB and a second to import: only once the run is over
    from bioslam.plots import figures

    jobs = _other_figures(result, trajectory, odometry, gt, label)
    for name, plot, args in itertools.chain([_map_figure(image, trajectory)], jobs):
        out.save(f"figures/{name}", getattr(figures, plot), *args)
        release_free_memory()  # the next figure is drawn on what this one left (module doc)


@dataclass
class _SentFigures:
    """Figures sent to a worker before the map was drawn: their names in order, and the
    error that ended their making (the figures after it are not sent), if any."""

    worker: FigureWorker
    names: list[str]
    failure: str | None


def _send_figures(
    options: RunOptions,
    result: RunResult,
    trajectory: Trajectory,
    odometry: Trajectory,
    gt: Trajectory | None,
) -> _SentFigures | None:
    """Send the figures that need no map to the options' figure worker; None: none, or the
    worker is gone (the figures are then drawn here)."""
    worker = options.figure_worker
    if worker is None or not len(trajectory):
        return None
    jobs: list[Job] = []
    failure = None
    try:
        jobs.extend(_other_figures(result, trajectory, odometry, gt, options.reference_label))
    except Exception as exc:  # reported after the figures before it, as when drawn here
        failure = f"{type(exc).__name__}: {exc}"
    try:
        worker.draw(jobs)
    except ChildEndedError:
        return None
    return _SentFigures(worker, [job[0] for job in jobs], failure)


def _write_drawn(
    sent: _SentFigures,
    out: OutputDir,
    image: OccupancyImage,
    trajectory: Trajectory,
    summary: dict[str, Any],
) -> bool:
    """Have the worker draw the map's figure too and write what it drew, in order, up to
    the first failure (then in ``figures_error``); False when the worker is gone."""
    try:
        sent.worker.draw([_map_figure(image, trajectory)])
        drawn = {name: (png, error) for name, png, error in sent.worker.drawn()}
    except ChildEndedError:
        return False
    for name in ["map.png", *sent.names]:
        png, error = drawn[name]
        if error is not None:
            summary["figures_error"] = error
            return True
        out.save(f"figures/{name}", atomic_write_bytes, png)
    if sent.failure is not None:
        summary["figures_error"] = sent.failure
    return True


def _gt_in_map_frame(trajectory: Trajectory, gt: Trajectory) -> FloatArray:
    """The ground-truth path expressed in the map frame (both start at the first scan), so
    that figures overlay it on the cognitive map without an alignment."""
    origin = gt.poses[int(np.argmin(np.abs(gt.stamps - trajectory.stamps[0])))]
    relative = compose(np.broadcast_to(inverse(origin), gt.poses.shape), gt.poses)
    return compose(np.broadcast_to(trajectory.poses[0], relative.shape), relative)[:, :2]
