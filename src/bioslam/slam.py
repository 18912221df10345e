"""BioSLAM: the paper's system, one LiDAR scan in, one pose out (Fig. 1's data flow).

::

    LaserScan -> LidarOdometry -dp-> PoseCellNetwork -centre-> CognitiveMap -> pose
        '-----> BoundaryCells -B-> ViewCells -V---^

No file or terminal I/O here: :mod:`bioslam.pipeline` owns progress, timing and results.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Callable, Iterator, MutableSequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, overload

import numpy as np
from numpy.typing import NDArray

from bioslam.boundary import BoundaryCells
from bioslam.closure import (
    BreakRun,
    Candidate,
    Check,
    ClosureConsensus,
    SeenArea,
    SlideReturns,
    Submap,
    SubmapCache,
    Verdict,
    break_departure,
    break_extent,
    break_thresholds,
    clear_of_rivals,
    first_marked_experience,
    implausible,
    judged_shape,
    jumped,
    link_extent,
    motion_over,
    nearest_experience,
    odometry_broke,
    odometry_doubted,
    pass_neighbours,
    place_covariance,
    polish_on_lines,
    score_plateau,
    settle_weak_direction,
    submap_anchor,
    submap_span,
    thin_points,
    turned_after_break,
    unbroken,
    verify,
    weak_modes,
    within,
)
from bioslam.cognitive_map import (
    ISOTROPIC,
    CognitiveMap,
    Experience,
    Measurement,
    configured_noise,
    link_terms,
    modelled_heading_var,
    registration_shape,
    untaught_noise,
)
from bioslam.config import SLAMConfig
from bioslam.consistency import SharpnessComparison
from bioslam.geometry import Pose2D, between, compose, inverse, rotation
from bioslam.growing import GrowingArray, RowsFactory
from bioslam.link_noise import LinkNoise, LinkNoiseEstimator
from bioslam.matching.point_to_line import LineFit
from bioslam.occupancy_grid import NORMAL_MAX_GAP, NORMAL_RADIUS, scan_normals, subsample_by_spacing
from bioslam.odometry import LidarOdometry, MatchReport
from bioslam.pose_cells import PoseCellNetwork
from bioslam.scan import LaserScan
from bioslam.trajectory import Trajectory
from bioslam.views import ViewCells

FloatArray = NDArray[np.float64]

#: How far (as a share of the robot's speed) a step may land from its steady motion driven
#: back and still count as the robot backing up along its path (:meth:`SelfMotion._reversed`)
REVERSAL_MISMATCH = 0.25

__all__ = ["BioSLAM", "SelfMotion", "StepRecord", "StepRecords", "thin_points"]


@dataclass(frozen=True)
class StepRecord:
    """What one look (a scan that reached the view cells) did, for figures and summaries."""

    stamp: float
    view_id: int
    view_is_new: bool
    event: str
    experience_id: int


@dataclass(frozen=True)
class _CheckPlan:
    """How a loop-closure check to one place runs (:meth:`BioSLAM._plan_check`): the submap
    that verifies it (``anchor``'s frame, ``members``' scans); whether the odometry vouches
    for the map's prediction (``trusted``, ``chained`` through earlier links); the breaks'
    summed extent since (m, rad; ``broken``, None for none); the drift bound (``bound``) and
    the window searched, the bound widened by the breaks (``window``); ``broke``: one of the
    breaks departed from the motion beyond any search, and the check is refused."""

    anchor: int
    members: list[int]
    trusted: bool
    chained: bool
    broken: FloatArray | None
    bound: tuple[float, float]
    window: tuple[float, float]
    broke: bool


class _ScanGeometry:
    """A checked scan's geometry, each part computed at most once and only where read: its
    normals, its constraint shape (:func:`bioslam.cognitive_map.registration_shape`, which
    weighs the closure) and the weak modes of what the registration at ``pose`` (in the
    submap anchor's frame, before the settle took a weak correction back) matched where the
    submap looked (``seen``, :func:`bioslam.closure.judged_shape`: which of its
    corrections must earn their score)."""

    def __init__(
        self, points: FloatArray, ratio: float, pose: FloatArray, seen: SeenArea
    ) -> None:
        self.points = points
        self.pose = pose
        self._ratio = ratio
        self._seen = seen

    @functools.cached_property
    def normals(self) -> FloatArray:
        return scan_normals(self.points, NORMAL_RADIUS, NORMAL_MAX_GAP)

    @functools.cached_property
    def shape(self) -> FloatArray:
        return registration_shape(self.points, self.normals, self._ratio)

    @functools.cached_property
    def modes(self) -> FloatArray:
        matched = judged_shape(self.points, self.normals, self.pose, self._seen, self._ratio)
        return weak_modes(matched)


@dataclass(frozen=True)
class _Registration:
    """A check as registered (:meth:`BioSLAM._registered`): its ``verdict``, in the checked
    experience's frame; the map's ``predicted`` pose of the robot there; the check's
    ``plan``; the ``submap`` it was registered against, whose anchor is at
    ``anchor_in_experience`` in the experience's frame; the pose as registered in the
    anchor's frame after the settle (``registered``; before it, ``geometry.pose``); and the
    scan's ``geometry``."""

    verdict: Verdict
    predicted: FloatArray
    plan: _CheckPlan
    submap: Submap
    anchor_in_experience: FloatArray
    registered: FloatArray
    geometry: _ScanGeometry


def _scan_payload(points: FloatArray, spacing: float) -> NDArray[np.float32]:
    """The scan kept with a place for registration: its endpoints at least ``spacing`` apart
    along the scan (computed at every look, so cheaper than :func:`thin_points`)."""
    return points[subsample_by_spacing(points, spacing)].astype(np.float32)


class StepRecords:
    """Every look's :class:`StepRecord`, kept as columns (one a look for the whole run: as
    objects about 250 bytes each, 8 MB an hour at 40 Hz; as columns 26). A sequence of
    ``StepRecord``; the columns themselves for figures."""

    EVENTS = ("none", "new", "link", "loop")

    def __init__(self) -> None:
        self.stamps = GrowingArray(np.float64)
        self.view_ids = GrowingArray(np.int64)
        self.new_views = GrowingArray(np.bool_)
        self._events = GrowingArray(np.int8)
        self.experience_ids = GrowingArray(np.int64)

    def append(self, record: StepRecord) -> None:
        self.stamps.append(record.stamp)
        self.view_ids.append(record.view_id)
        self.new_views.append(record.view_is_new)
        self._events.append(self.EVENTS.index(record.event))
        self.experience_ids.append(record.experience_id)

    def __len__(self) -> int:
        return len(self.stamps)

    @overload
    def __getitem__(self, index: int) -> StepRecord: ...

    @overload
    def __getitem__(self, index: slice) -> list[StepRecord]: ...

    def __getitem__(self, index: int | slice) -> StepRecord | list[StepRecord]:
        if isinstance(index, slice):
            return [self[k] for k in range(len(self))[index]]
        k = range(len(self))[index]  # IndexError, negative indices
        return StepRecord(
            float(self.stamps[k]), int(self.view_ids[k]), bool(self.new_views[k]),
            self.EVENTS[int(self._events[k])], int(self.experience_ids[k]),
        )  # fmt: skip

    def __iter__(self) -> Iterator[StepRecord]:
        return (self[k] for k in range(len(self)))


def row_stores(rows: RowsFactory | None, capacity: int = 1024) -> RowsFactory:
    """``rows``, or when None a maker of growing arrays of ``capacity`` rows in memory."""
    if rows is not None:
        return rows

    def in_memory(dtype: Any, width: int) -> GrowingArray:
        return GrowingArray(dtype, width, capacity=capacity)

    return in_memory


def scan_columns(rows: RowsFactory | None, capacity: int = 1024) -> tuple[Any, Any, Any, Any]:
    """Empty stores (:func:`row_stores`) of each scan's stamp, anchor experience, offset
    from it and odometry pose."""
    make = row_stores(rows, capacity)
    return make(np.float64, 0), make(np.int64, 0), make(np.float64, 3), make(np.float64, 3)


class MatchUncertainty:
    """Each scan's odometry covariance and doubts (:attr:`MatchReport.covariance`, flags), in
    25 bytes a scan: the covariance's upper triangle as float32, the flags in one byte."""

    _UPPER = np.triu_indices(3)  # (np.triu_indices costs 15 µs a call)

    def __init__(self, capacity: int = 1024, rows: RowsFactory | None = None) -> None:
        """``rows``: where the columns are kept (growing arrays of ``capacity`` when None)."""
        make = row_stores(rows, capacity)
        self._covariances, self._flags = make(np.float32, 6), make(np.int8, 0)

    def append(self, report: MatchReport) -> None:
        self._covariances.append(report.covariance[self._UPPER])
        self._flags.append(report.degenerate | report.ambiguous << 1 | report.predicted_only << 2)

    def arrays(self, n: int | None = None) -> tuple[FloatArray, NDArray[np.int8]]:
        """The covariances (N, 6: xx, xy, xθ, yy, yθ, θθ) and flags (bit 0 degenerate, bit 1
        ambiguous, bit 2 predicted only) of the first ``n`` scans (all when None)."""
        return self._covariances.array()[:n].astype(np.float64), self._flags.array()[:n]


class SelfMotion:
    """The self-motion cue: the LiDAR odometry's step per scan, integrated into a pose.

    ``heading_bias`` (rad/s) adds an artificial gyro-like drift to every step, for ablations.
    """

    def __init__(self, config: SLAMConfig) -> None:
        self.odometry = LidarOdometry(config.odometry)
        self.heading_bias = config.heading_bias
        self.closure = config.loop_closure
        self.pose = np.zeros(3)
        self._last_stamp: float | None = None
        self._last_step = np.zeros(3)
        self._last_dt = 0.0
        #: steps so far that broke the odometry's chain (:func:`bioslam.closure.odometry_broke`)
        self.breaks = 0
        #: the breaks so far and, with ``distrust_jumps``, the other steps no robot can make
        #: (:func:`bioslam.closure.jumped`: a slide the odometry tracked without a search):
        #: across either the odometry's relative poses are no random walk
        self.jumps = 0
        #: steps so far whose match the odometry itself doubted (blind along some direction,
        #: among look-alikes, or no match): a closure across one needs a second to confirm it
        self.doubts = 0
        #: the summed (m, rad) by which those breaks may have put the robot off
        #: (:func:`bioslam.closure.break_extent`)
        self.break_extent = np.zeros(2)
        #: each break's departure (m, rad) from the robot's motion
        #: (:func:`bioslam.closure.break_departure`), in the order they came
        self.break_departures: list[tuple[float, float]] = []
        #: the same summed (m, rad) over the breaks that came at the scanner's rate
        #: (:meth:`bioslam.odometry.LidarOdometry.at_scanner_rate`) and, after gaps or on a
        #: thinned log's steps, over the runs of breaks that began with one more than a
        #: robot can change its motion by (:meth:`_count_run`): how far the breaks may have
        #: slid the odometry, against what a closure's check searches
        self.summed_departure = np.zeros(2)
        # the run of breaks under way after gaps or on a thinned log's steps
        self._run: BreakRun | None = None
        #: the same summed over the breaks and every other step no robot can make
        #: (:func:`bioslam.closure.jumped`: a slide, and the return to the robot's motion
        #: after it), each at most what a closure can measure
        #: (:func:`bioslam.closure.link_extent`): how far the odometry may be off along each
        #: of the map's links
        self.jump_extent = np.zeros(2)
        #: the heading variance (rad²) of every step so far, summed, as the odometry's matches
        #: measured it (:attr:`MatchReport.covariance`; the model's, from
        #: ``cognitive_map.odometry_heading_var_per_m`` and ``_per_rad``, for a scan without
        #: a match): the map's odometry links are weighted by it
        self.heading_var = 0.0
        #: the position variance (m²) of every step whose match the scan left unconstrained
        #: along a direction (:attr:`MatchReport.degenerate`), summed, as its match measured
        #: it: how far the odometry may have slid where its scans could not hold it (0 unless
        #: ``cognitive_map.weak_step_variance``)
        self.weak_var = 0.0
        self._map_config = config.cognitive_map
        #: metres travelled by the odometry so far
        self.travelled = 0.0
        tolerance = config.loop_closure.return_tolerance
        self.slides = SlideReturns(
            (tolerance * self.closure.break_distance, tolerance * self.closure.break_angle),
            self.closure.return_reach,
        )
        #: what the last step did to a slide of the odometry (:meth:`SlideReturns.jump`):
        #: '' (none, or it goes on), 'opened' or 'returned'
        self.slide = ""
        self._steady = np.zeros(3)
        self._steady_dt = 0.0
        #: scans since the last break (:func:`bioslam.closure.turned_after_break`)
        self._since_break: float = math.inf

    def step(self, scan: LaserScan) -> FloatArray:
        """The motion since the previous scan, in the previous robot frame."""
        dp = np.asarray(self.odometry.update(scan), dtype=np.float64).copy()
        self.slide = ""
        dt = 0.0 if self._last_stamp is None else max(scan.stamp - self._last_stamp, 0.0)
        if self._last_stamp is not None:
            if self._last_dt > 0.0:  # the velocity of the step before is known
                expected = motion_over(self._last_step, self._last_dt, dt)
                report = self.odometry.last_report
                self.doubts += int(odometry_doubted(report))
                self._since_break += 1
                broke = odometry_broke(
                    report, dp, expected, dt, self.closure, self.odometry.config.max_speed,
                    self._last_step,
                ) or turned_after_break(
                    report, dp, expected, self._since_break, self.closure,
                    self.odometry.config.break_turn,
                )  # fmt: skip
                # a step no robot can make, short of a break, counts where it is weighed or
                # distrusted, and so does one that carries such a slide on
                weighed = self.closure.weigh_jumps or self.closure.distrust_jumps
                departed = self._track_slide(dp, dt) and self.closure.distrust_slides
                if broke or (weighed and (departed or self._jumped(dp, expected, dt))):
                    self._note_jump(dp, expected, dt, broke)
                if not broke:
                    self._run = None
            self._last_step, self._last_dt = dp.copy(), dt
            if self.heading_bias:
                dp[2] += self.heading_bias * dt
        self._last_stamp = scan.stamp
        self.heading_var += self._step_heading_var(dp)
        self.weak_var += self._step_weak_var(dt)
        self.travelled += math.hypot(dp[0], dp[1])
        self.slides.travel(self.travelled)
        self.pose = compose(self.pose, dp)
        return dp

    def _note_jump(self, dp: FloatArray, expected: FloatArray, dt: float, broke: bool) -> None:
        """Count a step that broke the odometry's chain (``broke``) or that no robot can make
        (:func:`bioslam.closure.jumped`), with how far it may have put the robot
        (:func:`bioslam.closure.break_extent`): a break always, a jump as the settings say
        (``distrust_jumps``, ``weigh_jumps``)."""
        extent = break_extent(dp, expected, dt, self.closure)
        if broke:
            self._since_break = 0
            self.breaks += 1
            self.break_extent += extent
            departure = break_departure(dp, expected, self._last_step)
            self.break_departures.append(departure)
            if self.odometry.at_scanner_rate(dt):
                self.summed_departure += departure
                self._run = None
            else:
                self._count_run(dp, expected, dt, departure)
        self.jumps += int(broke or self.closure.distrust_jumps)
        if broke or self.closure.weigh_jumps:
            self.jump_extent += link_extent(extent, self.closure)

    def _count_run(
        self, dp: FloatArray, expected: FloatArray, dt: float, departure: tuple[float, float]
    ) -> None:
        """Add a break after a gap or on a thinned log's step to ``summed_departure``: the
        run of breaks in a row it begins or goes on, by how far the run has now moved the
        odometry's position from the motion before it (:class:`bioslam.closure.BreakRun`;
        turns count by single breaks, :meth:`BioSLAM._jumped_beyond_search`). A run begins
        only with a break whose ``departure`` from the motion is farther than a robot can
        change its motion by in ``dt`` seconds (:func:`bioslam.closure.break_thresholds`); a
        nearer one may be the robot's own change of motion over seconds (intel: true
        closures across breaks summing to 3.6 m), and so may one that drives the last step
        back (``expected``, the last step's motion over ``dt``: :meth:`_mirrors`; a
        simulated robot reverses within a scan, 0.6 m from its motion in 0.6 s, and its
        odometry's search follows it there)."""
        if self._run is None:
            if departure[0] <= break_thresholds(dt, self.closure)[0] or self._mirrors(
                dp, expected, dt
            ):
                return
            self._run = BreakRun(self._last_step, self._last_dt)
        before = self._run.moved
        self.summed_departure[0] += self._run.step(dp, dt) - before

    def _track_slide(self, dp: FloatArray, dt: float) -> bool:
        """Note whether ``dp`` opens or undoes a slide (:class:`bioslam.closure.SlideReturns`):
        its departure from the robot's steady motion, the last step that departed from the
        one before by no more than a robot can change its motion, or that drove it back
        (:meth:`_reversed`: a robot backing up). (Against the step just
        before, the first ordinary step after a slide departs from the slide's own motion
        as much as the slide did, and would pass for its undoing.) Returns whether ``dp``
        departs from the steady motion both as scaled by the stamps and as it was, as
        :func:`bioslam.closure.jumped` judges a step against the last one (where the stamps
        jitter, freiburg-079, the scaled one alone overshoots a steady step)."""
        if self._steady_dt <= 0.0:
            self._steady, self._steady_dt = dp.copy(), dt
            return False
        steady = motion_over(self._steady, self._steady_dt, dt)
        if not implausible(dp, steady, dt, self.closure) or self._reversed(dp, steady, dt):
            self._steady, self._steady_dt = dp.copy(), dt
            return False
        c, s = math.cos(self.pose[2]), math.sin(self.pose[2])
        dx, dy = dp[0] - steady[0], dp[1] - steady[1]
        departure = (c * dx - s * dy, s * dx + c * dy, dp[2] - steady[2])
        self.slide = self.slides.jump(departure, self.travelled)
        return implausible(dp, self._steady, dt, self.closure)

    def _jumped(self, dp: FloatArray, expected: FloatArray, dt: float) -> bool:
        """Whether ``dp`` departs from the last step (:func:`bioslam.closure.jumped`) other
        than by driving it back (:meth:`_reversed`)."""
        return jumped(dp, self._last_step, expected, dt, self.closure) and not self._reversed(
            dp, self._last_step, dt
        )

    def _reversed(self, dp: FloatArray, steady: FloatArray, dt: float) -> bool:
        """Whether ``dp`` is the ``steady`` motion driven back (its translation negated to
        within ``REVERSAL_MISMATCH`` of its speed, its turn within what a robot can change
        in ``dt``), matched from the motion model's start and not among look-alikes: a
        robot that backs up along its path. Held to the motion before, every step of the
        way back departed from it and weakened its link (a thinned SICK backing up through
        a garage of pillars: 140 of its 157 jumps, every one right to 1 cm; ATE 19.7 cm
        against its odometry's 3.3). A slide back at another speed is no such mirror
        (within the break thresholds alone, at 10 Hz any step back of a robot driving 5 cm
        a scan would pass for one)."""
        report = self.odometry.last_report
        if report.predicted_only or report.ambiguous or report.recovered:
            return False
        return self._mirrors(dp, steady, dt)

    def _mirrors(self, dp: FloatArray, steady: FloatArray, dt: float) -> bool:
        """Whether ``dp`` is the ``steady`` motion driven back, its translation negated to
        within ``REVERSAL_MISMATCH`` of its speed and its turn within what a robot can
        change in ``dt``, however the odometry matched it."""
        speed = math.hypot(steady[0], steady[1])
        mismatch = math.hypot(dp[0] + steady[0], dp[1] + steady[1])
        return mismatch <= REVERSAL_MISMATCH * speed and not implausible(
            dp, -steady, dt, self.closure
        )

    def _step_heading_var(self, dp: FloatArray) -> float:
        """The heading variance (rad²) of the last step: its match's, or the model's where
        the scan was not matched."""
        var = float(self.odometry.last_report.covariance[2, 2])
        if math.isfinite(var):
            return max(var, 0.0)
        return modelled_heading_var(math.hypot(dp[0], dp[1]), abs(dp[2]), self._map_config)

    def _step_weak_var(self, dt: float) -> float:
        """The position variance (m²) the last step may have slid by where its match was
        degenerate: its covariance's trace, which the unconstrained direction dominates,
        less the motion prior's share of the curvature there (where the prior held the
        match the scan's own covariance overstates it: on the simulated pillar hall with a
        3.5 m scanner, a pillar or two in view, some ran to 10⁵ m²), and at most the
        square of the most a robot's motion changes in ``dt`` (a step off by more is a jump,
        weighed as one). 0 for a step the scan held on every axis: a well-held scan's
        covariance is not the odometry's drift (each scan is matched to a map the others
        hold too; summed over a run of a 10 Hz SICK it bent the rooms' loops by more than
        the closures' error, ATE 0.71 cm against 0.30), a slide along a corridor is. 0
        also when the map does not take it (``cognitive_map.weak_step_variance``)."""
        report = self.odometry.last_report
        if not (self._map_config.weak_step_variance and report.degenerate):
            return 0.0
        var = float(report.covariance[0, 0] + report.covariance[1, 1])
        if not math.isfinite(var):
            return 0.0
        var *= 1.0 - report.prior_share
        return min(max(var, 0.0), break_thresholds(dt, self.closure)[0] ** 2)


def _p_value(test: SharpnessComparison | None) -> float | None:
    return None if test is None else test.p_second_sharper


class BioSLAM:
    """The LiDAR-based biologically-inspired SLAM system (Sec. III)."""

    def __init__(
        self, config: SLAMConfig | None = None, scan_store: MutableSequence[Any] | None = None,
        rows: RowsFactory | None = None, view_dir: str | Path | None = None,
    ) -> None:  # fmt: skip
        """``scan_store``: an empty store for the scans kept with the experiences (a list
        when None; :class:`bioslam.io.spill.SpilledScans` keeps them on disk). ``rows``:
        makes the stores of the per-scan columns, read only for the outputs (growing arrays
        in memory when None; :class:`bioslam.io.spill.SpilledRows` keeps them on disk).
        ``view_dir``: keep the learned views' cells in a file there, of which memory holds
        those recently compared (:mod:`bioslam.view_store`); in memory when None."""
        self.config = config or SLAMConfig()
        self._rows = rows
        cfg = self.config
        self.self_motion = SelfMotion(cfg)
        self.boundary_cells = BoundaryCells(cfg.boundary)
        self.view_cells = ViewCells(
            cfg.views, cells_per_ring=cfg.boundary.cells_per_ring, spill_dir=view_dir
        )
        self.pose_cells = PoseCellNetwork(cfg.pose_cells)
        self.cognitive_map = CognitiveMap.from_pose_cells(
            cfg.cognitive_map, cfg.pose_cells, scan_store
        )
        # one row per scan for the whole run, so kept as arrays (bioslam.growing)
        self._new_scan_columns()
        self.records = StepRecords()
        self._travelled = 0.0
        # odometry distance at which each experience was made, by id (a doubling buffer:
        # the closure cues search it at every look)
        self._made_at = np.empty(1024)
        # odometry breaks so far (:func:`bioslam.closure.odometry_broke`), and when each
        # experience was made: a closure is measured only against a place the odometry
        # relates to the robot without a break
        self._breaks_at = np.empty(1024, dtype=np.int64)
        # ... and of its breaks and jumps (:attr:`SelfMotion.jumps`)
        self._jumps_at = np.empty(1024, dtype=np.int64)
        self._extent_at = np.empty((1024, 2))
        self._summed_at = np.empty((1024, 2))
        # the odometry's pose when each experience was made: the old pass's chain of
        # relative poses for the closures' pairwise test (:class:`bioslam.closure.Candidate`)
        self._odometry_at = np.empty((1024, 3))
        self._doubts_at = np.empty(1024, dtype=np.int64)
        # whether each experience keeps a scan to register against (the proximity cue
        # proposes only those)
        self._verifiable = np.empty(1024, dtype=np.bool_)
        # the travel (m) at each place's last check refused as ambiguous, for the places no
        # loop has joined to the robot since (inf for the others), which the proximity cue
        # goes back to first (:meth:`_refused_return`)
        self._refused_at = np.empty(1024)
        # the travel (m) at each place's last check refused as ambiguous, for those within
        # ``ambiguity_memory`` of the robot's travel
        self._ambiguous_at: dict[int, float] = {}
        self.consensus = ClosureConsensus(self.config.loop_closure)
        # the odometry's summed heading variance when each experience was made, and the
        # closures' residuals against the odometry that refine the links' noise model
        self._heading_var_at = np.empty(1024)
        map_config = self.config.cognitive_map
        self.link_noise = LinkNoiseEstimator(
            configured_noise(map_config), map_config.noise_prior_decades,
            map_config.noise_min_closures,
        )  # fmt: skip
        self._confirmed_earlier = False
        #: closures held back and entered later, when another confirmed them (each makes a
        #: loop link without a look of its own)
        self.confirmed_later = 0
        self._extent_at_look = np.zeros(2)
        self._doubts_at_look = 0
        self._heading_var_at_look = 0.0
        self._weak_var_at_look = 0.0
        self._last_registration = -np.inf
        self._travelled_at_entry = 0.0
        self._pending = np.zeros(3)
        #: every loop-closure verification's outcome, in order (for benchmarks and figures)
        self.checks: list[Check] = []
        self._proposed: int | None = None
        self._stamp = 0.0
        self.submaps = SubmapCache()
        self._scans_since_look = 0
        self._last_forced = -np.inf
        # the proximity cue found no place near the robot at this scan (:meth:`_due`)
        self._cue_silent = False
        # a relaxation after a closure, left for a later scan (``SLAMConfig.defer_relaxation``),
        # and the scans it has waited for a look or one the odometry fuses
        self._relax_due = False
        self._relax_waited = 0
        self._scans_waited = 0
        self._far_before = False
        # the last chain test of the proximity cue (:meth:`_nearby`) and its map state
        self._chain_key: tuple[int, int, int, int] | None = None
        self._chained = False
        self._released: dict[str, int] | None = None
        # where an open slide of the odometry began (:meth:`_note_slide`), and one it undid,
        # to be bridged at the next look
        self._slide_start: tuple | None = None
        self._bridge_due: tuple | None = None
        # experiences made while a slide was under way: displaced by it, no end for a bridge
        self._made_in_slide: set[int] = set()
        #: odometry links that bridge a slide the odometry undid (``bridge_returns``)
        self.bridges = 0
        #: what the finished map's scans said of the settings' link noise against the one
        #: the closures taught, and of holding the odometry's jumps
        #: (:meth:`bioslam.cognitive_map.CognitiveMap.adopt_if_sharper`); None where there
        #: was nothing to choose
        self.settings_test: SharpnessComparison | None = None
        self.jump_test: SharpnessComparison | None = None
        #: of holding the jumps the map bent by a small share of their allowance, against
        #: the map as it was (:meth:`bioslam.cognitive_map.CognitiveMap.hold_unbent_jumps`)
        self.unbent_test: SharpnessComparison | None = None
        #: how many jumps' links that test held
        self.unbent_held = 0
        #: of the run's own model where too few closures taught it to be taken unasked
        self.few_taught_test: SharpnessComparison | None = None
        #: and of the map with its loop links weighing nothing (the odometry's chain)
        self.closures_test: SharpnessComparison | None = None

    # --- the per-scan update ---------------------------------------------------------------

    def process(self, scan: LaserScan) -> Pose2D:
        """Feed one scan; return the robot's current pose in the cognitive map's frame."""
        before = (self._pending, self.self_motion.pose)
        asked = self.submaps.requests
        self._cue_silent = False
        dp = self.self_motion.step(scan)
        if self.self_motion.slide:
            self._note_slide(*before)
        self._pending = compose(self._pending, dp)
        self._scans_since_look += 1
        self._relax_if_due()
        looked = self._due(dp)
        if looked:
            # the scan as the odometry matched it: the robot's own body left out
            seen = self.self_motion.odometry.last_scan
            self._perceive(scan if seen is None else seen, self._pending)
            self._pending = np.zeros(3)
            self._scans_since_look = self._scans_waited = 0
        self._record(scan.stamp)
        if self.submaps.requests == asked:  # no check registered this scan
            self._prefetch_submap(dp, looked)
        return Pose2D(*compose(self.cognitive_map.pose(), self._pending))

    def _note_slide(self, pending: FloatArray, odometry: FloatArray) -> None:
        """The step just taken opened a slide of the odometry or undid one
        (:attr:`SelfMotion.slide`); ``pending`` and ``odometry``: the motion since the last
        look and the odometry's pose before the step. Where a slide began, the robot's pose
        in the map (its anchor and offset) is kept; once it is undone, the map gets an
        odometry link across it at the next look (:meth:`_bridge`)."""
        motion = self.self_motion
        if motion.slide == "opened":
            self._slide_start = None  # (the start of one that was never undone)
            base, offset = self.cognitive_map.anchor()
            if base in self._made_in_slide:
                return  # the pose it hangs off is displaced by the slide before
            self._slide_start = (
                base, compose(offset, pending), odometry, motion.travelled, motion.heading_var
            )
        elif self._slide_start is not None and self.config.loop_closure.bridge_returns:
            self._bridge_due, self._slide_start = self._slide_start, None

    def _bridge(self) -> None:
        """An odometry link from the experience the robot's pose hung off where a slide
        began to the one it hangs off now the slide is undone, measuring the odometry
        across it (:attr:`bioslam.config.LoopClosureConfig.bridge_returns`)."""
        start, self._bridge_due = self._bridge_due, None
        assert start is not None
        source, offset, odometry, travelled, heading_var = start
        cmap, motion = self.cognitive_map, self.self_motion
        target, now = cmap.anchor()
        if source < 0 or source == target or motion.slides.open:
            return  # (another slide began since: the robot's pose is displaced by it)
        across = between(odometry, motion.pose)
        dp = compose(compose(offset, across), inverse(now))
        terms = link_terms(
            motion.travelled - travelled, abs(float(across[2])), 0, cmap.config,
            heading_var=motion.heading_var - heading_var,
        )  # fmt: skip
        if cmap.add_odometry_link(source, target, dp, self._stamp, terms):
            self._relax_due = True
        self.bridges += 1

    def _relax_if_due(self) -> None:
        """The relaxation a closure left for a later scan (``defer_relaxation``): the next
        look's (:meth:`_perceive` runs it, as anything that reads the map does, through
        :meth:`_relax_now`) within ``relax_wait`` scans; failing one, the next scan the
        odometry fuses into its map, which is slow already, or the ``view_wait``-th after."""
        if not self._relax_due:
            return
        cfg = self.config
        self._relax_waited += 1
        if self._relax_waited <= cfg.relax_wait:
            return
        if not self._fused() and self._relax_waited <= cfg.relax_wait + cfg.view_wait:
            return
        self._relax_now()

    def _fused(self) -> bool:
        """The odometry fused this scan into its local map: a scan slow already, on which
        deferred work (a relaxation, a submap built ahead) adds least to the median."""
        return self.odometry.last_report.inserted

    def _relax_now(self) -> None:
        """The relaxation left for later, before anything reads the map's poses (a look, the
        proximity cue): what they see, and so the closures and the final trajectory, are
        as if it had run on the scan after the closure."""
        if self._relax_due:
            self._relax_due = False
            self._relax_waited = 0
            self.cognitive_map.relax()

    def _due(self, step: FloatArray) -> bool:
        """Whether to look again: the robot has moved or turned enough since the last look
        (and ``view_min_scans`` scans have passed), or the map puts it near an old
        experience while a registration is due (so that the path-integration cue is checked
        as often as registrations are allowed, however sparse the looks). Between two looks
        only the odometry runs; its motion reaches the pose cells and the map at the next
        look (path integration takes steps of any size). A look that the scan count held
        back (the robot moved far enough scans ago: a slow scanner), and one the cue
        forces on a slow scanner (:meth:`_held_by_count`), waits up to ``view_wait`` scans
        more for one the odometry fuses into its map (:meth:`_waits`): on freiburg-079 the
        forced looks (a check each) fell on 256 scans the odometry did not fuse, of 295."""
        cfg = self.config
        if len(self.cognitive_map) == 0:
            return True
        moved = float(np.hypot(self._pending[0], self._pending[1]))
        far = moved >= cfg.view_distance or abs(self._pending[2]) >= cfg.view_angle
        # far already at the scan before: the scan count, not the motion, held the look
        held, self._far_before = self._far_before, far
        if far and self._scans_since_look >= cfg.view_min_scans:
            if held and self._waits(step):
                return False
            self._far_before = False
            return True
        if self._travelled + moved - self._last_forced < cfg.loop_closure.registration_interval:
            return False  # a candidate forces one look per registration interval at most
        if self._nearby(self._travelled + moved, self._pending) is None:
            self._cue_silent = True
            return False
        if self._held_by_count(step) and self._waits(step):
            return False  # the cue holds over a scan or two: check on the fused scan
        self._last_forced = self._travelled + moved
        return True

    def _held_by_count(self, step: FloatArray) -> bool:
        """Whether steps like ``step`` make a look due by motion sooner than the scan count
        allows (a slow scanner): its looks are then set by the count, and one forced by the
        proximity cue may as well wait for a fused scan. A fast scanner's looks stay where
        the motion puts them."""
        cfg = self.config
        n = cfg.view_min_scans
        return bool(
            math.hypot(step[0], step[1]) * n >= cfg.view_distance
            or abs(step[2]) * n >= cfg.view_angle
        )

    def _waits(self, step: FloatArray) -> bool:
        """Whether a look due now waits for the scan the odometry fuses into its map next,
        which steps like ``step`` reach within the scans the look may still wait
        (``view_wait``). A fused scan costs the odometry about twice a matched one; a look
        on another scan made a third slow scan of every three with a 10 Hz scanner."""
        odometry = self.self_motion.odometry
        if odometry.last_report.inserted or self._scans_waited >= self.config.view_wait:
            return False
        if odometry.steps_to_insert(step) > self.config.view_wait - self._scans_waited:
            return False
        self._scans_waited += 1
        return True

    def _prefetch_submap(self, step: FloatArray, looked: bool) -> None:
        """On a scan that ran no closure check, fuse the submap of the check the next look
        will make (:meth:`bioslam.closure.SubmapCache.prefetch`): the place the proximity
        cue will propose where steps like ``step`` put the robot at that look (the next
        scan, or the fused one a slow scanner's look waits for, :meth:`_waits`), when a
        registration will be due there. Only on a scan above the median's cost already (the
        odometry fused it into its map, or a look ran: ``looked``), so that the median scan
        stays as it was: built on any scan without a check, the simulated maze's RPLIDAR
        route moved 7 % of its scans above the median, and the median rose by 15 %. Not
        while a relaxation is due (it moves the pass the submap is fused along before the
        look). Only the time moves: the check adopts the submap only as it would have built
        it, so the run's results are the same."""
        cfg = self.config.loop_closure
        if not cfg.prefetch_submaps or self._relax_due:
            return
        if not (self._fused() or looked):
            return
        if self._travelled - self._last_registration < cfg.registration_interval:
            return  # (the look's check reads this travel too: none is due before it)
        if self._cue_silent:
            return  # no place near the robot now: none a step on either, as a rule
        pending = self._pending
        for _ in range(self._scans_to_look(step)):
            pending = compose(pending, step)
        found = self._nearby(self._travelled, pending)
        if found is None:
            return
        cmap = self.cognitive_map
        poses = cmap.experience_poses_view
        plan = self._plan_check(found, between(poses[found], compose(cmap.pose(), pending)))
        if plan is not None and not plan.broke:
            self.submaps.prefetch(poses, cmap.payloads, plan.anchor, plan.members, cfg)

    def _scans_to_look(self, step: FloatArray) -> int:
        """How many scans like ``step`` from now the next look falls on: the next, or where
        a slow scanner's look waits for the scan the odometry fuses (:meth:`_waits`), that
        one."""
        if not self._held_by_count(step):
            return 1
        steps = self.odometry.steps_to_insert(step)  # (inf for no motion)
        left = self.config.view_wait - self._scans_waited
        return math.ceil(steps) if 1.0 < steps <= left + 1 else 1

    def _payload(self, scan: LaserScan, points: FloatArray) -> NDArray[np.float32] | None:
        """The scan kept with an experience made now, for the closures to it; None for the
        run's first scan where the scanner sweeps (``time_increment`` > 0): the odometry
        knew no velocity yet to de-skew it, so that scan, and the odometry's first step
        matched against it, carry the motion during the sweep. A closure to it measures the
        place well and then bends the whole loop by the first step's error (simulated hall,
        SICK scanner: 3.5 cm / 0.68 deg; one closure to it doubled the ATE, 1.42 ->
        2.86 cm, with the closure given the truth as well). None too for a scan bent by its
        sweep (:meth:`_bent`)."""
        first = len(self.cognitive_map) == 0 and self.self_motion.odometry.num_scans <= 1
        cfg = self.config
        skewed = scan.time_increment > 0.0 and cfg.odometry.deskew
        if first and skewed and not cfg.loop_closure.close_to_first_scan:
            return None
        if self._bent():
            return None
        return _scan_payload(points, cfg.loop_closure.payload_spacing)

    def _bent(self) -> bool:
        """Whether the scan just matched is bent by its sweep beyond what a closure takes
        (``loop_closure.max_scan_bend``): it neither checks one nor is kept for one."""
        bend = self.self_motion.odometry.last_report.bend
        return bend > self.config.loop_closure.max_scan_bend

    def _perceive(self, scan: LaserScan, dp: FloatArray) -> None:
        """The view cells, pose cells and cognitive map for one scan, after motion ``dp``."""
        self._relax_now()
        # the odometry's endpoints: de-skewed, and already computed
        points = self.self_motion.odometry.last_points
        # Egocentric views of corridors running in different directions look alike; the map
        # heading lets the view cells compare only views learned facing the same way.
        heading = self.cognitive_map.pose()[2] + dp[2] if len(self.cognitive_map) else dp[2]
        match = self.view_cells.observe(
            self.boundary_cells.activity(scan),
            heading=heading,
            coverage=self.boundary_cells.coverage(scan),
            turned=lambda turn: self.boundary_cells.activity(scan, turn),
        )
        self.pose_cells.path_integrate(dp)
        self.pose_cells.inject_view(match.view_id, match.activity, match.is_new)
        self.pose_cells.step()
        # the breaks and jumps of the odometry since the last look weaken the link that
        # carries them
        broken = self.self_motion.jump_extent - self._extent_at_look
        self._extent_at_look = self.self_motion.jump_extent.copy()
        doubted = self.self_motion.doubts > self._doubts_at_look
        self._doubts_at_look = self.self_motion.doubts
        heading_var = self.self_motion.heading_var - self._heading_var_at_look
        self._heading_var_at_look = self.self_motion.heading_var
        weak_var = self.self_motion.weak_var - self._weak_var_at_look
        self._weak_var_at_look = self.self_motion.weak_var
        self.cognitive_map.integrate_odometry(
            dp, scan.stamp, broken, doubted,
            heading_var if self.config.cognitive_map.scan_heading_variance else None, weak_var,
        )  # fmt: skip
        self._stamp = scan.stamp
        self._proposed = self._nearby(self._travelled)
        known = len(self.cognitive_map)
        payload = self._payload(scan, points)
        event = self.cognitive_map.update(
            match.view_id,
            match.is_new,
            self.pose_cells.centre(),
            scan.stamp,
            payload=payload,
            refine=self._refiner(points) if self.config.loop_closure.refine else None,
            nearby=self._proposed,
        )
        if self._bridge_due is not None:
            self._bridge()
        if event.kind == "loop" or self._confirmed_earlier:
            if self.config.defer_relaxation:
                self._relax_due = True  # not on the scan that paid for the registration
            else:
                self.cognitive_map.relax()
        self._confirmed_earlier = False
        self._travelled += float(np.hypot(dp[0], dp[1]))
        # every experience this look made (a closure also makes one of the robot's pose)
        for experience_id in range(known, len(self.cognitive_map)):
            self._note_made(experience_id, payload is not None)
            if self.self_motion.slides.open:
                self._made_in_slide.add(experience_id)
        if event.kind != "none":
            self._travelled_at_entry = self._travelled
        self.records.append(
            StepRecord(scan.stamp, match.view_id, match.is_new, event.kind, event.experience)
        )

    def _note_made(self, experience_id: int, verifiable: bool = True) -> None:
        if experience_id >= self._made_at.size:
            for name in (
                "_made_at", "_breaks_at", "_jumps_at", "_extent_at", "_summed_at",
                "_odometry_at", "_doubts_at", "_heading_var_at", "_verifiable", "_refused_at",
            ):  # fmt: skip
                column = getattr(self, name)
                setattr(self, name, np.concatenate([column, np.empty_like(column)]))
        self._made_at[experience_id] = self._travelled
        self._odometry_at[experience_id] = self.self_motion.pose
        self._heading_var_at[experience_id] = self.self_motion.heading_var
        self._doubts_at[experience_id] = self.self_motion.doubts
        self._breaks_at[experience_id] = self.self_motion.breaks
        self._jumps_at[experience_id] = self.self_motion.jumps
        self._extent_at[experience_id] = self.self_motion.break_extent
        self._summed_at[experience_id] = self.self_motion.summed_departure
        self._verifiable[experience_id] = verifiable
        self._refused_at[experience_id] = np.inf

    def _nearby(self, travelled: float, pending: FloatArray | None = None) -> int | None:
        """The path-integration cue: the experience nearest the robot's map pose (the map's,
        then ``pending`` motion not yet integrated, after ``travelled`` metres of odometry),
        made long enough ago to be a loop and not already joined to the current one by a
        short chain of links (:func:`bioslam.closure.nearest_experience`), or before it a
        place found ambiguous (:meth:`_refused_return`); None while no
        registration is due. It reads the map as it is: at a look relaxed already
        (:meth:`_perceive`), between looks as the last look left it (a relaxation left for
        later waits for the next look; one the cue forces asks the cue again, relaxed)."""
        cfg = self.config.loop_closure
        cmap = self.cognitive_map
        if not (cfg.proximity and cfg.refine) or len(cmap) < 2:
            return None
        if travelled - self._last_registration < cfg.registration_interval:
            return None
        pose = cmap.pose() if pending is None else compose(cmap.pose(), pending)
        drift, _ = self._drift_bound(travelled, False)
        radius = min(cfg.recognition_radius, drift)
        refused = self._refused_return(pose, travelled, radius)
        if refused is not None:
            return refused
        found = nearest_experience(
            cmap.experience_poses_view, self._made_at[: len(cmap)], pose, travelled,
            radius, cfg.min_loop_travel, self._verifiable[: len(cmap)],
        )  # fmt: skip
        if found is None or found == cmap.current:
            return None
        return None if self._joined(found) else found

    def _joined(self, experience_id: int) -> bool:
        """Whether a short chain of links (``chain_distance``) joins the current experience
        to ``experience_id``: a place the map relates to the robot already, no loop. Between
        looks the map does not change, and the cue is probed at every scan while a
        registration is due: the chain search (0.09 ms on freiburg-079, a third of a matched
        scan) runs once per map state and candidate."""
        cmap = self.cognitive_map
        key = (cmap.current, experience_id, cmap.num_links, len(cmap))
        if key != self._chain_key:
            distance = self.config.loop_closure.chain_distance
            chained = cmap.link_distance(cmap.current, experience_id, distance) is not None
            self._chain_key, self._chained = key, chained
        return self._chained

    def _refused_return(self, pose: FloatArray, travelled: float, radius: float) -> int | None:
        """The oldest place within ``radius`` of the map pose ``pose`` whose check was
        refused as ambiguous at least ``min_loop_travel`` metres of travel ago, with no
        break or jump of the odometry since it was made, and not joined to the robot by a
        short chain of links; None if none. Once a return was refused, the robot maps the
        area anew, and the nearest place is the new copy from then on (hospital floor, SICK
        reversing, heading drift injected: 5.72 -> 0.87 cm). A check a few scans on sees
        what the refused one saw (the ring floor's SICK 361-beam tour, retrying at once,
        lost the check that closed its loop round the floor: 2.92 -> 27.84 cm). Across a
        break, a lost odometry's map pose may sit on a look-alike of the old place (ring
        floor, URG-04LX thinned: a closure 3 m off), and the nearest place stands. A place
        found joined has its loop, and is no longer marked. Only while the map's link noise
        says the heading drifts (:meth:`_heading_drifts`): where it holds, the copy lies on
        the first pass, and a check to it serves as well."""
        cfg = self.config.loop_closure
        cmap = self.cognitive_map
        if not (cfg.revisit_refused and self._heading_drifts()):
            return None
        count = len(cmap)
        # every break counts as a jump too (:meth:`SelfMotion._note_jump`), and the count only
        # grows: the places made since the last jump are a suffix
        start = int(np.searchsorted(self._jumps_at[:count], self.self_motion.jumps))
        while True:
            found = first_marked_experience(
                cmap.experience_poses_view, self._made_at[:count], pose, travelled, radius,
                cfg.min_loop_travel, self._refused_at[:count], start,
            )  # fmt: skip
            if found is None or not self._joined(found):
                return found
            self._refused_at[found] = np.inf

    def _refiner(
        self, points: FloatArray
    ) -> Callable[[Experience], Measurement | FloatArray | None]:
        """A callable for the cognitive map that refines a move to a recognised experience."""
        return functools.partial(self._refine, points=points)

    def _refine(
        self, experience: Experience, points: FloatArray
    ) -> Measurement | FloatArray | None:
        """The robot's pose in ``experience``'s frame, from registering this scan against the
        scan stored with it, with the shape of its information (the scan's geometry,
        :func:`bioslam.cognitive_map.registration_shape`), or None to reject the
        recognition: the check registered (:meth:`_registered`), judged
        (:meth:`_accepted`), made a measurement (:meth:`_measurement`) and confirmed
        (:meth:`_confirmed`)."""
        check = self._registered(experience, points)
        if check is None:
            return None
        verdict = self._accepted(experience, check)
        if not verdict.accepted:
            return None
        measured = self._measurement(check, verdict)
        # a correction only the breaks' widening of the window let in: checks that matched
        # the same old scans share its error, and cannot vouch for one another
        beyond = not within(between(check.predicted, verdict.pose), *check.plan.bound)
        read = frozenset((*check.plan.members, check.plan.anchor)) if beyond else frozenset()
        alone = self._alone(check.plan) and not verdict.needs_partner
        if not self._confirmed(experience, measured, alone, read):
            return None
        if self.config.cognitive_map.learn_noise and not measured.partial:
            unsettled = compose(check.anchor_in_experience, check.geometry.pose)
            self._learn_noise(experience.id, unsettled, check.geometry.modes[:2, 2])
        return measured

    def _registered(self, experience: Experience, points: FloatArray) -> _Registration | None:
        """This scan (``points``) registered against the submap around ``experience``
        (:func:`bioslam.closure.verify`), polished on its lines and settled along what the
        scan pins least (:meth:`_settled`), the verdict in the experience's frame; None
        where no check runs (no scan to check against, a registration not yet due, the map
        putting the robot beyond any check's reach, no submap), and a check refused before
        its registration (the odometry broke beyond the search) is recorded so."""
        cfg = self.config.loop_closure
        if experience.payload is None or points.shape[0] < 3 or self._bent():
            return None
        if self._travelled - self._last_registration < cfg.registration_interval:
            return None
        predicted = between(experience.pose, self.cognitive_map.pose())
        plan = self._plan_check(experience.id, predicted)
        if plan is None:
            return None
        if plan.broke:
            # a break since departed from the robot's motion by more than the verification
            # searches: a look-alike the odometry jumped to, which a check could only confirm
            self._last_registration = self._travelled
            self._refuse(experience, predicted, "odometry broke")
            return None
        cmap = self.cognitive_map
        poses = cmap.experience_poses_view
        submap = self.submaps.get(poses, cmap.payloads, plan.anchor, plan.members, cfg)
        if submap.pyramid is None:
            return None
        self._last_registration = self._travelled
        # registered in the submap anchor's frame, reported in the experience's
        anchor_in_experience = between(experience.pose, poses[submap.anchor])
        # Across a step the odometry doubted (blind along a corridor, a look-alike match) it
        # may have slid farther than the drift bound says: an accepted pose is challenged by
        # the best fits over the whole search window, so that a look-alike the map's error
        # put inside the bound is not taken for the place unchallenged (maze, SICK scanner:
        # a closure 0.98 m off, the true place outside a 0.4 m window).
        mapped = between(poses[submap.anchor], cmap.pose())
        drift, drift_angle = plan.window
        rival = None if plan.trusted else self._rival_window(drift, drift_angle, plan.broken)
        # (a slide's rivals across it only across breaks: a doubted step slides along; the
        # serpentine's 20 min drift route, its partial checks challenged 3 m across without a
        # break: recall 0.42, ATE 6.33 cm; across breaks only, 0.52 and 5.34)
        verdict = verify(
            submap.points, points, mapped, (drift, drift_angle), cfg, submap.seen,
            submap.pyramid, rival, None if plan.broken is None else rival,
        )  # fmt: skip
        pts = np.ascontiguousarray(points, dtype=np.float64)
        lines = None
        if verdict.accepted and cfg.polish:
            polished, lines = polish_on_lines(submap.lines(), verdict.pose, pts, submap.seen, cfg)
            verdict = dataclasses.replace(verdict, pose=polished)
        # the scan's own constraint shape, which weighs the closure, and the weak modes of
        # what the registration matched, which say which of its corrections must earn their
        # score, from the pose as registered, before a correction along what the scan barely
        # pins is taken back (the link weighed by the matched points' shape instead took
        # intel from 8.26 to 8.84 cm against the odometry's 8.25)
        geometry = _ScanGeometry(
            pts, self.config.cognitive_map.closure_shape_ratio, verdict.pose, submap.seen
        )  # fmt: skip
        verdict = self._settled(verdict, mapped, geometry, submap, lines)
        registered = verdict.pose  # in the submap anchor's frame
        verdict = dataclasses.replace(
            verdict, pose=compose(anchor_in_experience, verdict.pose),
            free=None if verdict.free is None else rotation(anchor_in_experience[2]) @ verdict.free,
        )  # fmt: skip
        return _Registration(
            verdict, predicted, plan, submap, anchor_in_experience, registered, geometry
        )  # fmt: skip

    def _heading_drifts(self) -> bool:
        """Whether the map's link noise says the odometry's heading drifts: the heading
        variance the closures make likeliest, over what the odometry's scan matches measured
        (:attr:`bioslam.link_noise.LinkNoise.likeliest_heading_scale`), at least
        ``drift_scale`` (the settings' model, 1, until a closure teaches one)."""
        scale = self.cognitive_map.noise.likeliest_heading_scale
        return scale >= self.config.loop_closure.drift_scale

    def _settled(
        self, verdict: Verdict, mapped: FloatArray, geometry: _ScanGeometry, submap: Submap,
        lines: LineFit | None = None,
    ) -> Verdict:
        """An accepted ``verdict`` with its correction of the map's prediction (``mapped``,
        in the submap anchor's frame) along what the scan barely pins taken back unless it
        earns its score (:func:`bioslam.closure.settle_weak_direction`) or, while the
        heading drifts (:meth:`_heading_drifts`), the polish's ``lines`` measured it; refused
        as ambiguous where the prediction fits about as well farther off than a rival may be
        (``refuse_far_settle``)."""
        cfg = self.config.loop_closure
        if not (verdict.accepted and cfg.weak_margin > 0.0):
            return verdict
        grids = submap.pyramid.grids  # type: ignore[union-attr]
        if not self._heading_drifts():
            lines = None  # (the map's prediction holds along the scan's weak direction)
        settled = settle_weak_direction(
            grids[min(cfg.registration.score_level, len(grids) - 1)], verdict.pose, mapped,
            geometry.points, geometry.modes, cfg, submap.seen, lines,
        )  # fmt: skip
        if (
            cfg.refuse_far_settle
            and not verdict.partial  # which claims nothing along the free direction
            and not within(between(verdict.pose, settled), cfg.rival_distance, cfg.rival_angle)
        ):
            # the map's prediction fits about as well as the registration, farther from it
            # than a rival may be: the scan cannot say which is the place (a pillar hall
            # seen to 3.5 m: both 0.8-1 m apart scored 0.99, the prediction the wrong one)
            return dataclasses.replace(verdict, accepted=False, reason="ambiguous")
        return dataclasses.replace(verdict, pose=settled)

    def _alone(self, plan: _CheckPlan) -> bool:
        """Whether a check may stand without a partner's agreement: the odometry vouches for
        the map's prediction (``plan.trusted``) and partners are sought at all."""
        return plan.trusted and self.config.loop_closure.consistency

    def _accepted(self, experience: Experience, check: _Registration) -> Verdict:
        """The registered check's verdict after the rules no registration alone decides,
        recorded (:meth:`_note_check`): a fit only a partner may confirm where the odometry
        cannot vouch for the prediction either, a partial one below ``min_score``, and one to
        a place recently found ambiguous, unless it clears that doubt (:meth:`_clears_doubt`),
        are refused."""
        verdict = check.verdict
        if verdict.accepted and verdict.needs_partner and not self._alone(check.plan):
            # a registration that fits less well than a place alone must, where the
            # odometry cannot vouch for the prediction either (or no partner is sought):
            # nothing says it is the place and not a look-alike the odometry's own error
            # put there (a thinned RPLIDAR lost 8.4 m and 180 degrees: two such closures
            # agreed, each as far off)
            verdict = dataclasses.replace(verdict, accepted=False, reason="score")
        if verdict.accepted and verdict.partial and verdict.needs_partner:
            # a slide's pose along the corridor is the map's prediction: nothing a partner
            # could check it against, so it must fit well enough to close alone
            verdict = dataclasses.replace(verdict, accepted=False, reason="degenerate")
        doubted = self._recently_ambiguous(experience.id) if verdict.accepted else None
        if doubted is not None and self._clears_doubt(check):
            doubted = None
        if doubted is not None:
            verdict = dataclasses.replace(verdict, accepted=False, reason="ambiguous")
        # a doubt taken from a place beside is not found here: it does not arm the memory for
        # the places beyond (each refusal would arm the next, the doubt moving with the robot)
        self._note_check(experience, verdict, remember=doubted != "beside")
        return verdict

    def _clears_doubt(self, check: _Registration) -> bool:
        """Whether an accepted check stands at a place found ambiguous moments before
        (:meth:`_recently_ambiguous`): the odometry vouches for the map's prediction, the
        check fits well enough to close alone and claims every direction, and no distinct
        pose in its window fits within ``clear_ambiguity`` of it
        (:func:`bioslam.closure.clear_of_rivals`; a window narrower than the rival distance,
        from a short chain of links, holds none)."""
        cfg = self.config.loop_closure
        verdict = check.verdict
        if cfg.clear_ambiguity >= cfg.max_ambiguity:
            return False
        if not check.plan.trusted or verdict.needs_partner or verdict.partial:
            return False
        mapped = between(check.anchor_in_experience, check.predicted)  # in the anchor's frame
        pyramid = check.submap.pyramid  # (a check registers only on a submap with one)
        return clear_of_rivals(
            pyramid, check.geometry.points, mapped, check.plan.window, cfg  # type: ignore[arg-type]
        )  # fmt: skip

    def _measurement(self, check: _Registration, verdict: Verdict) -> Measurement:
        """The accepted ``verdict`` as the loop link's measurement: within the dead band of
        the map's prediction, the prediction itself; else the registered pose, its
        information shaped by the scan and capped along what its score pins
        (:meth:`_pinned_shape`), with the registration's covariance where the map weighs by
        it."""
        cfg = self.config.loop_closure
        partial = verdict.partial
        # the slide in the robot's frame, as the shapes are; along it the pose is the map's
        # prediction, which joins the places by a chain only where the odometry vouched for it
        free = None if not partial else rotation(-verdict.pose[2]) @ verdict.free
        vouched = check.plan.trusted or not partial
        chained = check.plan.chained
        if within(between(check.predicted, verdict.pose), cfg.deadband, cfg.deadband_angle):
            # The map already agrees with the registration to within the registration's own
            # error: keep the map's estimate rather than inject that error into the map.
            return Measurement(
                np.asarray(check.predicted, dtype=np.float64),
                check.geometry.shape if partial else ISOTROPIC.copy(), chained,
                partial=partial, vouched=vouched, free=free,
            )  # fmt: skip
        shape = self._pinned_shape(
            check.geometry.shape, check.registered, check.geometry.points, check.submap
        )  # fmt: skip
        covariance = (
            place_covariance(verdict.covariance, check.registered, check.anchor_in_experience)
            if self.config.cognitive_map.registration_covariance and not partial
            else None  # (only that weighting reads it; a slide's says nothing)
        )
        return Measurement(verdict.pose, shape, chained, covariance, partial, vouched, free)

    def _plan_check(self, experience_id: int, predicted: FloatArray) -> _CheckPlan | None:
        """How a check to ``experience_id``, with the robot predicted at ``predicted`` in its
        frame, is to run (:class:`_CheckPlan`), or None when the map puts the robot beyond
        any check's reach. Reads the map and the odometry's record; changes nothing."""
        cfg = self.config.loop_closure
        if self._beyond_any_check(experience_id, predicted):
            return None
        linked, since = self._odometry_relation(experience_id)
        anchor, members = self._submap_members(experience_id)
        trusted, since, by_chain = self._trust(min(anchor, experience_id), since, anchor)
        chained = by_chain is not None
        drift, drift_angle = self._drift_bound(since, linked or chained)
        bound = (drift, drift_angle)
        # a trusted relation has no break; one trusted only through the chain none on it
        broken = None if trusted else self._break_since(min(anchor, experience_id))
        if broken is not None:
            # The map relates the robot to the place through a break of the odometry (a
            # jump to a look-alike, a match it could not tell from one, a step it could not
            # match): its prediction may be off by as much as the breaks since, so the
            # window covers that too (a registration within the drift bound alone would
            # only confirm the break: a corridor seen along its axis fits anywhere along
            # it, and the look-alike the odometry jumped to fits where the map puts it).
            drift, drift_angle = drift + broken[0], drift_angle + broken[1]
        if np.hypot(predicted[0], predicted[1]) > cfg.recognition_radius + drift:
            return None
        broke = broken is not None and self._jumped_beyond_search(min(anchor, experience_id))
        return _CheckPlan(
            anchor, members, trusted, chained, broken, bound, (drift, drift_angle), broke
        )

    def _learn_noise(self, experience_id: int, registered: FloatArray, pinned: FloatArray) -> None:
        """Refine the map's link noise model (:mod:`bioslam.link_noise`) by an accepted
        closure to a place the odometry relates to the robot without a break or a jump
        (:attr:`SelfMotion.jumps`): where the registration put the robot in the place's frame
        (``registered``, before any correction was taken back to the map's prediction, which
        would measure the map, not the registration) against where the odometry alone does,
        over the distance and the heading variance between. The position is compared along
        the direction the scan pins best (``pinned``, a unit vector in the robot's frame),
        the one the loop link's ``closure_sigma_m`` stands for
        (:func:`bioslam.cognitive_map.registration_shape`): along a corridor a registration
        slides, and its weaker directions are weighed down from that one."""
        if self.self_motion.jumps != self._jumps_at[experience_id]:
            return  # a break or a jump is no random walk: its links carry it apart
        odometry = between(self._odometry_at[experience_id], self.self_motion.pose)
        residual = between(odometry, registered)
        noise = self.link_noise.add(
            self._travelled - float(self._made_at[experience_id]),
            float(residual[:2] @ pinned), float(residual[2]),
            self.self_motion.heading_var - float(self._heading_var_at[experience_id]),
        )  # fmt: skip
        self.cognitive_map.set_noise(noise)

    def _pinned_shape(
        self, shape: FloatArray, pose: FloatArray, points: FloatArray, submap: Submap
    ) -> FloatArray:
        """The closure's position information ``shape`` (the scan's geometry,
        :func:`bioslam.cognitive_map.registration_shape`) with its weakest direction capped
        at what the registration's score pins there (:func:`bioslam.closure.score_plateau`
        around the registered ``pose`` in ``submap``'s frame): a closure whose score is as
        good 16 cm along a corridor does not pull the map along it as one pinned to 2 cm
        does (``closure_sigma_m``), however its scan's points lie."""
        cfg = self.config.loop_closure
        if cfg.plateau_reach <= 0.0 or submap.pyramid is None:
            return shape
        grids = submap.pyramid.grids
        grid = grids[min(cfg.registration.score_level, len(grids) - 1)]
        info = np.array([[shape[0], shape[1]], [shape[1], shape[2]]])
        w, v = np.linalg.eigh(info)
        extent = score_plateau(grid, pose, points, v[:, 0], cfg, submap.seen)
        sigma = self.config.cognitive_map.closure_sigma_m
        floor = 1.0 / self.config.cognitive_map.closure_shape_ratio
        w[0] = max(min(w[0], (sigma / max(extent, sigma)) ** 2), floor)
        pinned = (v * w) @ v.T
        return np.array([pinned[0, 0], pinned[0, 1], pinned[1, 1]])

    def _confirmed(
        self, experience: Experience, measured: Measurement, alone: bool, read: frozenset[int]
    ) -> bool:
        """Whether a verified closure enters the map now: at once without the pairwise
        test, or when it may stand ``alone`` (the odometry relates the robot to the place
        without a step it doubted, :func:`bioslam.closure.odometry_doubted`, or a break, and
        the registration scored ``min_score``); else once another closure agrees with it
        (:class:`bioslam.closure.ClosureConsensus`). The waiting closures a closure
        confirms enter the map here, their checks then counting as accepted; one left
        waiting is recorded as refused ('unconfirmed') until then. ``read``: the experiences
        whose scans the registration matched, where their shared errors would tell (empty
        where not)."""
        if not self.config.loop_closure.consistency or measured.partial:
            # (a partial closure's pose along its free direction is the map's own: agreeing
            # with another there would vouch for nothing)
            return True
        cmap, eid = self.cognitive_map, experience.id
        candidate = Candidate(
            self._stamp, eid, np.asarray(measured.pose, dtype=np.float64),
            self.self_motion.pose.copy(), self._odometry_at[eid].copy(), self._travelled,
            float(self._made_at[eid]), self.self_motion.jumps, int(self._jumps_at[eid]),
            link=cmap.loop_link(eid, measured, self._stamp), check=len(self.checks) - 1,
            read=read,
        )  # fmt: skip
        confirmed = self.consensus.offer(candidate, alone)
        check = self.checks[candidate.check]
        if not confirmed:
            waiting = dataclasses.replace(check.verdict, accepted=False, reason="unconfirmed")
            self.checks[candidate.check] = dataclasses.replace(check, verdict=waiting)
            return False
        for earlier in confirmed[:-1]:
            cmap.add_loop_link(earlier.link)  # type: ignore[arg-type]
            self.confirmed_later += 1
            old = self.checks[earlier.check]
            accepted = dataclasses.replace(old.verdict, accepted=True, reason="")
            self.checks[earlier.check] = dataclasses.replace(old, verdict=accepted)
            self._confirmed_earlier = True
        return True

    def _trust(
        self, experience_id: int, since: float, anchor: int
    ) -> tuple[bool, float, FloatArray | None]:
        """Whether the drift bound bounds the error of the robot's predicted pose relative
        to ``experience_id``, the odometry distance (m) it is to be drawn from (``since``:
        the shortest chain's, :meth:`_odometry_relation`), and the prediction (the robot in
        ``anchor``'s frame) when it is not the map's. Trusted when the odometry since the
        place was made has neither doubted a step (:func:`bioslam.closure.odometry_doubted`)
        nor broken nor made a step no robot can make (:attr:`SelfMotion.jumps`: a slide it
        tracked; the maze's UTM-30LX thinned to every tenth scan, weaving, seed 0, slid 1.75 m
        back along a corridor in 2 s without a break, and a closure 3.5 s later, trusted,
        confirmed the slide), or when a chain of links the odometry never doubted (through earlier
        closures: a weaving route back to a corridor it closed at a loop ago) joins the
        robot to it; the bound is then that chain's, which may be longer than the shortest,
        and the prediction the chain's measurements composed
        (:meth:`CognitiveMap.chain_pose`): the relaxed map between the two places may have
        been pulled by a loop across doubted steps (maze, SICK tour: 0.3 m along a corridor
        over a chain of a few metres). A 180°
        scanner doubts a step every few metres (maze, SICK tour: 106 of 3000), so across a
        whole loop nearly every place was doubted; its closures to a pass it was joined to
        by an undoubted chain a few metres long were challenged over the whole search window
        and refused for the next corridor door 1.2-1.5 m away (27 of them, all within 0.1 m
        of the truth)."""
        if (
            self.self_motion.doubts == self._doubts_at[experience_id]
            and self.self_motion.jumps == self._jumps_at[experience_id]
        ):
            return True, since, None
        cmap = self.cognitive_map
        base, offset = cmap.anchor()
        if cmap.doubted_since_entry or base < 0:
            return False, since, None
        cfg = self.config.loop_closure
        since_entry = self._travelled - self._travelled_at_entry
        # no longer than a chain whose window from the link floor stays within a fresh
        # place's (the drift floor): over 24-44 m of chain the window reached 0.5-0.9 m, and
        # registrations that slid 0.3-0.5 m along corridors from a prediction 1-3 cm from
        # the truth were accepted (maze, SICK tour, seed 3)
        horizon = (cfg.drift_floor - cfg.link_floor) / max(cfg.drift_per_metre, 1e-9)
        limit = horizon - since_entry
        reach = cmap.link_distance(base, experience_id, limit, undoubted=True)
        chain = cmap.chain_pose(anchor, base, limit, undoubted=True)
        if reach is None or chain is None:
            return False, since, None
        span = max(since, since_entry + reach, since_entry + chain[0])
        predicted = compose(chain[1], offset)
        mapped = between(cmap.experience_poses_view[anchor], cmap.pose())
        if not within(between(mapped, predicted), cfg.link_floor, cfg.link_angle_floor):
            return False, since, None
        return True, span, predicted

    def _beyond_any_check(self, experience_id: int, predicted: FloatArray) -> bool:
        """Whether the map puts the robot (``predicted``, in ``experience_id``'s frame)
        farther from the place than any check to it may look: the recognition radius, the
        drift bound's cap and the breaks since the earliest experience its submap may be
        anchored at (:meth:`_submap_members`). The check's own bound (below, in
        :meth:`_refine`) is never wider, so this decides as it would, before the chain
        searches that make it: a view recognised across the building (the rooms' UTM-30LX
        tour: 1098 of 1154 recognitions past the registration interval, 4 m or more away)."""
        cfg = self.config.loop_closure
        made_at = self._made_at[: len(self.cognitive_map)]
        earliest = min(submap_anchor(made_at, experience_id, cfg.submap_step), experience_id)
        reach = cfg.recognition_radius + cfg.max_drift
        broken = self._break_since(earliest)
        if broken is not None:
            reach += float(broken[0])
        return math.hypot(predicted[0], predicted[1]) > reach

    def _jumped_beyond_search(self, experience_id: int) -> bool:
        """Whether the breaks since ``experience_id`` was made departed from the robot's
        motion (:func:`bioslam.closure.break_departure`) by more than the verification's
        search window, one of them or, at the scanner's rate, all of them summed: the
        odometry may have slid farther than a check searches, and a look-alike there fits
        with no rival in reach (simulated library, a 360° scanner of 3.5 m among tables 4 m
        apart: the odometry slid back by one table in breaks of 0.1-0.9 m, each within the
        window, and four closures 4.0 m off confirmed it). Summed as magnitudes: a stall and
        the step that resumes the motion depart from the motion each way, and as vectors
        they cancel where the slide they leave does not. After gaps or on a thinned log's
        steps, whose departures may be the robot's own changes of motion over seconds (intel
        with a heading drift injected: summed, they refused the closures that take it out,
        0.87 m left of the odometry's 1.44), only the runs of breaks that began with one no
        robot can make are summed, each by where it put the odometry
        (:meth:`SelfMotion._count_run`: a cubicles floor's 3.5 m scanner kept every third
        scan jumped back 4.0 m, one cubicle, in two breaks, and 25 closures confirmed the
        cubicle it jumped to). Departures, not the breaks'
        extents: after a gap of seconds a break's extent is what a robot could have done
        meanwhile, and one gap refused every later closure to the places before it (intel:
        165-210 of its 245-287 checks, its 23 breaks all true steps)."""
        cfg = self.config.loop_closure
        since = self.self_motion.break_departures[int(self._breaks_at[experience_id]) :]
        if any(m > cfg.search_distance or a > cfg.search_angle for m, a in since):
            return True
        moved, turned = self.self_motion.summed_departure - self._summed_at[experience_id]
        return bool(moved > cfg.search_distance or turned > cfg.search_angle)

    def _rival_window(
        self, drift: float, drift_angle: float, broken: FloatArray | None
    ) -> tuple[float, float]:
        """How far (m, rad) from the map's prediction an untrusted check's accepted pose is
        challenged (:func:`bioslam.closure.outside_rival`): the search window, and across
        breaks the window they widened (``drift``, ``drift_angle``; capped at
        ``outside_rival_distance``, ``outside_rival_angle``). The breaks may have left the
        true place outside the search window, where only a wider search finds that it fits
        as well as a look-alike inside."""
        cfg = self.config.loop_closure
        if broken is None:
            return cfg.search_distance, cfg.search_angle
        return max(drift, cfg.search_distance), max(drift_angle, cfg.search_angle)

    def _break_since(self, experience_id: int) -> FloatArray | None:
        """The summed extent (m, rad) of the odometry breaks since ``experience_id`` was
        made (:func:`bioslam.closure.break_extent`), or None when there was none or the
        loop-closure settings trust the odometry across breaks."""
        if not self.config.loop_closure.refuse_broken_odometry:
            return None
        if self.self_motion.breaks == self._breaks_at[experience_id]:
            return None
        return self.self_motion.break_extent - self._extent_at[experience_id]

    def _submap_members(self, candidate: int) -> tuple[int, list[int]]:
        """The experiences whose scans verify ``candidate``: those around it on its own pass,
        in the frame of the pass's experience nearest a whole ``submap_step`` of travel (the
        anchor, shared by the checks near one old place, :class:`bioslam.closure.SubmapCache`);
        the last ``submap_reach`` metres of travel, which the current scan would match
        trivially, are left out, and so is every scan the odometry relates to the anchor
        only across a break or a jump (:func:`bioslam.closure.unbroken`,
        :attr:`SelfMotion.jumps`): fused at a broken relative pose, it would put a wall where
        the place has none. Nor is the anchor one the odometry relates to the candidate only
        across one: the candidate is then its own anchor. (The same route at seed 4 made a
        place while the odometry had slid 0.75 m back, three steps before the jump that
        undid it; fused with the scans from before the slide, its submap put the robot
        0.73 m off, four times, each closure confirming the others.)"""
        cfg = self.config.loop_closure
        made_at = self._made_at[: len(self.cognitive_map)]
        anchor = submap_anchor(made_at, candidate, cfg.submap_step)
        if cfg.refuse_broken_odometry and self._jumps_at[anchor] != self._jumps_at[candidate]:
            anchor = candidate  # the anchor's map pose is off from the candidate's by the jump
        reach, step = submap_span(
            made_at, anchor, cfg.submap_reach, cfg.submap_step, cfg.submap_max_reach
        )
        members = pass_neighbours(made_at, anchor, reach, step, self._travelled - reach)
        if cfg.refuse_broken_odometry:
            members = unbroken(self._jumps_at, anchor, members)
        return anchor, members

    def _refuse(self, experience: Experience, predicted: FloatArray, reason: str) -> None:
        """Record a check refused before its registration ran."""
        verdict = Verdict(False, np.asarray(predicted, dtype=np.float64), float("nan"), 0.0, reason)
        self._note_check(experience, verdict)

    def _recently_ambiguous(self, experience_id: int) -> str | None:
        """Whether a check to ``experience_id`` ("place"), or else to a place within
        ``ambiguity_radius`` of it on the map ("beside"), was refused as ambiguous within the
        last ``ambiguity_memory`` metres of travel; None if neither."""
        cfg = self.config.loop_closure
        if cfg.ambiguity_memory <= 0.0:
            return None
        for place, when in list(self._ambiguous_at.items()):
            if self._travelled - when > cfg.ambiguity_memory:
                del self._ambiguous_at[place]  # forgotten: the robot has moved on
        if experience_id in self._ambiguous_at:
            return "place"
        if cfg.ambiguity_radius <= 0.0 or not self._ambiguous_at:
            return None
        poses = self.cognitive_map.experience_poses_view
        places = np.fromiter(self._ambiguous_at, dtype=np.int64)
        offsets = poses[places, :2] - poses[experience_id, :2]
        near = np.hypot(offsets[:, 0], offsets[:, 1]) <= cfg.ambiguity_radius
        return "beside" if near.any() else None

    def _note_check(self, experience: Experience, verdict: Verdict, remember: bool = True) -> None:
        """Record a verification's outcome, with the cue that proposed the experience; an
        ambiguity found (``remember``) arms :meth:`_recently_ambiguous`."""
        # Only an ambiguity is worth a later visit (:meth:`_refused_return`): one from
        # elsewhere may see what tells the place from its look-alikes, while a place refused
        # for its score or as degenerate meets the same walls again (every refusal marked:
        # 85 runs without drift, 12 worse and 8 better; the serpentine floor's thinned SICK
        # 6.35 -> 7.49 cm)
        if verdict.reason == "ambiguous":
            self._refused_at[experience.id] = self._travelled
            if remember:
                self._ambiguous_at[experience.id] = self._travelled
        cue = "proximity" if experience.id == self._proposed else "view"
        self.checks.append(Check(self._stamp, experience.id, experience.stamp, cue, verdict))

    def _odometry_relation(self, experience_id: int) -> tuple[bool, float]:
        """Whether a short chain of links joins the current experience to
        ``experience_id``, and the distance over which the odometry alone relates the robot
        to it: since entering the current experience plus the chain's length when they are
        joined, else since the experience was made. (A place two experiences back, passed
        again, is related by a few centimetres of odometry however long ago it was made: a
        registration sliding 25 cm along a corridor there must not pass as a loop.)"""
        cmap = self.cognitive_map
        since_entry = self._travelled - self._travelled_at_entry
        chain = cmap.link_distance(
            cmap.current, experience_id, self.config.loop_closure.chain_distance
        )
        if chain is not None:
            return True, since_entry + chain
        since = self._travelled - float(self._made_at[experience_id])
        # Earlier closures may join the two places by a shorter chain of links than the
        # travel since the place was made: the map's error between them is then that
        # chain's odometry's (a weaving route back to a place it closed at a loop ago)
        cfg = self.config.loop_closure
        horizon = min(since, (cfg.max_drift - cfg.drift_floor) / max(cfg.drift_per_metre, 1e-9))
        graph = cmap.link_distance(cmap.current, experience_id, horizon - since_entry)
        return False, since if graph is None else min(since, since_entry + graph)

    def _drift_bound(self, travelled: float, linked: bool) -> tuple[float, float]:
        """How far (m, rad) the map's prediction may be off after ``travelled`` metres of
        odometry: a known link leaves only the registration's own error as a floor."""
        cfg = self.config.loop_closure
        floor, angle_floor = (
            (cfg.link_floor, cfg.link_angle_floor)
            if linked
            else (cfg.drift_floor, cfg.drift_angle_floor)
        )
        return (
            min(floor + cfg.drift_per_metre * travelled, cfg.max_drift),
            min(angle_floor + cfg.drift_angle_per_metre * travelled, cfg.max_drift_angle),
        )

    def _record(self, stamp: float) -> None:
        exp_id, offset = self.cognitive_map.anchor()
        self._anchor_ids.append(exp_id)
        self._anchor_offsets.append(compose(offset, self._pending))
        self._odometry_poses.append(self.self_motion.pose)
        self._uncertainty.append(self.odometry.last_report)
        # last: a scan counts once its stamp is in (:attr:`num_scans`), so that a signal
        # between these appends leaves the read-outs one scan short, not of unequal lengths
        self._stamps.append(stamp)

    def finish(self) -> None:
        """Settle the cognitive map after the last scan (the final trajectory is re-derived
        from it), its links weighed by the drift the closures make likeliest rather than the
        largest they do not rule out (:meth:`bioslam.link_noise.LinkNoise.likely`): while the
        run goes on, the map must be able to follow a slide the odometry did not notice, so
        that its predictions of where the robot is hold; the finished map is the one the
        evidence makes likeliest. Where the closures show no drift, the largest they could
        not rule out let their registrations' millimetres bend an odometry better than them
        (the rooms' SICK weaving route: 0.35 cm against the odometry's 0.30; 0.31 so). Taught
        by fewer than ``noise_min_closures_finished`` closures, the model is the untaught
        one (:meth:`_finished_noise`). Then the map's own scans judge the alternatives
        (:meth:`bioslam.cognitive_map.CognitiveMap.adopt_if_sharper`): the odometry's jumps
        held as any other step where the model lets them bend (where they stay free, those
        the map bent by a small share of their allowance held unless the scans say
        otherwise: :meth:`bioslam.cognitive_map.CognitiveMap.hold_unbent_jumps`), the run's
        own model where the untaught one stood in for it, the settings' weighing instead of
        the taught one, and last the map without its closures' weight
        (:meth:`~bioslam.cognitive_map.CognitiveMap.drop_closures_if_sharper`)."""
        self._relax_now()
        cmap = self.cognitive_map
        reweighed = few = False
        taught = cmap.noise
        if self.config.cognitive_map.learn_noise and cmap.loop_closures:
            cmap.set_noise(self._finished_noise())
            reweighed = cmap.noise != taught
            few = len(self.link_noise) < self.config.cognitive_map.noise_min_closures_finished
        if reweighed or not cmap.converged:
            # after a re-weighing the whole map: the weights changed everywhere
            cmap.solve(window=None if reweighed else -1)
            cmap.relax()
        # the jumps first, and the settings' weighing then tried with the jumps as decided:
        # held or not, they change the map's shape where the weighing only spreads a
        # correction (the other way round, a settings' model 0.01 mm sharper took the maze
        # SICK reversing s72's jumps out of the test)
        each = self.config.cognitive_map.scan_test_significance / 3.0
        self.jump_test = cmap.hold_jumps_if_sharper(each)
        free = int(cmap.jump_links().sum())
        self.unbent_test = cmap.hold_unbent_jumps(self.config.cognitive_map.hold_unbent_jumps, each)
        self.unbent_held = free - int(cmap.jump_links().sum())
        jumps = cmap.noise.jump_scale
        settings = dataclasses.replace(configured_noise(cmap.config), jump_scale=jumps)
        likeliest = dataclasses.replace(taught.likely(), jump_scale=jumps)
        if few and likeliest != settings:  # (untaught, the run's model is the settings')
            # the untaught model stands in for the few closures' fit unless the scans say
            # otherwise: a drift the run's closures followed (intel with 0.0005 rad/s of
            # heading drift injected: 9 taught, the run's map 0.25 m off, the untaught 3.64)
            self.few_taught_test = cmap.adopt_if_sharper(likeliest, each)
        self.settings_test = cmap.adopt_if_sharper(settings, each)
        # last, the map as weighed against none of its closures
        self.closures_test = cmap.drop_closures_if_sharper(each)
        tests = (
            self.jump_test, self.unbent_test, self.few_taught_test, self.settings_test,
            self.closures_test,
        )  # fmt: skip
        if any(t is not None for t in tests):
            cmap.relax()

    def _finished_noise(self) -> LinkNoise:
        """The link noise the finished map is solved with: the drift the closures make
        likeliest, once ``noise_min_closures_finished`` closures have taught the model; the
        untaught model before (:func:`bioslam.cognitive_map.untaught_noise`: a fit from a few
        closures, those that happened to cross no break or jump, is no measure of the rest,
        and the settings, the run's cautious prior, let the closures bend the odometry at
        its routine jumps)."""
        config = self.config.cognitive_map
        if len(self.link_noise) < config.noise_min_closures_finished:
            return untaught_noise(config)
        return self.cognitive_map.noise.likely()

    # --- read-outs ---------------------------------------------------------------------------

    @property
    def odometry(self) -> LidarOdometry:
        return self.self_motion.odometry

    @property
    def num_scans(self) -> int:
        return len(self._stamps)

    def trajectory(self, experience_poses: FloatArray | None = None) -> Trajectory:
        """Every scan's pose: its experience's relaxed pose composed with the odometry since,
        so that the whole trajectory follows each correction of the map. With
        ``experience_poses`` ((N, 3), e.g. :meth:`CognitiveMap.solved`) instead of the map's."""
        n = self.num_scans
        if not n:
            return Trajectory.empty()
        poses = self.cognitive_map.poses_of(
            self._anchor_ids.view()[:n], self._anchor_offsets.view()[:n], experience_poses
        )
        return Trajectory(self._stamps.array(), poses)

    def odometry_trajectory(self) -> Trajectory:
        """The self-motion cue alone (as the pose cells received it), one pose per scan."""
        n = self.num_scans
        if not n:
            return Trajectory.empty()
        return Trajectory(self._stamps.array(), self._odometry_poses.array()[:n])

    def odometry_uncertainty(self) -> tuple[FloatArray, FloatArray, NDArray[np.int8]]:
        """Each scan's stamp, its odometry match's covariance (the upper triangle xx, xy,
        xθ, yy, yθ, θθ) and flags (:meth:`MatchUncertainty.arrays`), for
        :func:`bioslam.io.uncertainty.write_uncertainty`."""
        return (self._stamps.array(), *self._uncertainty.arrays(self.num_scans))

    def release_scans(self) -> None:
        """Once the trajectories are made (:func:`bioslam.pipeline.write_results` with
        ``release``): drop the per-scan columns they are made from (97 bytes a scan, 14 MB
        after an hour at 40 Hz), so that the figures are drawn without them.
        :meth:`trajectory` and :meth:`odometry_trajectory` are empty after."""
        self._new_scan_columns(capacity=1)

    def _new_scan_columns(self, capacity: int = 1024) -> None:
        """Empty per-scan columns: each scan's stamp, the experience its pose hangs off
        with the offset from it, and its odometry pose (in the stores ``rows`` makes, but
        in memory once released: ``capacity`` 1)."""
        self._stamps, self._anchor_ids, self._anchor_offsets, self._odometry_poses = (
            scan_columns(self._rows if capacity > 1 else None, capacity)
        )
        self._uncertainty = MatchUncertainty(capacity, self._rows if capacity > 1 else None)

    def _check_counts(self) -> dict[str, int]:
        """Loop-closure verifications by cue, refusals by reason (``closure.verify``), the
        accepted that scored under ``min_score`` and entered with a partner, and the
        accepted that were partial (a slide along a corridor left free)."""
        out = {"closure_checks_view": 0, "closure_checks_proximity": 0}
        for reason in (
            "score", "degenerate", "ambiguous", "slid", "beyond_drift", "odometry_broke",
            "unconfirmed",
        ):
            out[f"closure_refused_{reason}"] = 0
        out["closures_partnered"] = out["closures_partial"] = 0
        for check in self.checks:
            out[f"closure_checks_{check.cue}"] += 1
            if check.verdict.reason:
                out[f"closure_refused_{check.verdict.reason.replace(' ', '_')}"] += 1
            else:
                out["closures_partnered"] += check.verdict.needs_partner
                out["closures_partial"] += check.verdict.partial
        return out

    def release(self) -> None:
        """After the last scan: drop what only the per-scan update uses (the odometry's local
        map, the view cells' stored views, the pose cells, the loop closures' cached submaps;
        about 70 MB after 600 s at 40 Hz), so that the outputs are written and drawn without
        it. The trajectories, the cognitive map, the records and the summary stay;
        :meth:`process` no longer works."""
        if self._released is None:
            self._released = self.summary()
        self.self_motion.odometry = None  # type: ignore[assignment]
        self.view_cells = self.pose_cells = self.boundary_cells = None  # type: ignore[assignment]
        self.submaps = SubmapCache(size=0)

    def summary(self) -> dict[str, Any]:
        if self._released is not None:
            return dict(self._released)
        cmap = self.cognitive_map
        noise = cmap.noise
        return {
            "views": self.view_cells.num_views,
            "experiences": len(cmap),
            "loop_closures": cmap.loop_closures,
            "loop_closures_rejected": cmap.rejected_closures,
            **self._check_counts(),
            **self.odometry.summary(),
            # the link noise model the closures refined (bioslam.link_noise)
            "link_noise_closures": len(self.link_noise),
            "link_noise_odometry_var_per_m": noise.odometry_var_per_m,
            "link_noise_closure_sigma_m": math.sqrt(noise.closure_var),
            "link_noise_heading_scale": noise.heading_scale,
            "link_noise_closure_sigma_rad": math.sqrt(noise.closure_heading_var),
            # 0 where the finished map held the odometry's jumps (untaught_noise, or its
            # scans agreed better so: jumps_held_p below that significance)
            "link_noise_jump_scale": noise.jump_scale,
            # the scans' tests of the finished map (None: nothing to choose)
            "settings_noise_p": _p_value(self.settings_test),
            "jumps_held_p": _p_value(self.jump_test),
            # the jumps the map bent little held, unless its scans agreed better with them
            # free (this p below the test's significance)
            "unbent_jumps_held": self.unbent_held,
            "unbent_jumps_free_p": _p_value(self.unbent_test),
            # the run's own model against the untaught one, where too few closures taught it
            "few_taught_noise_p": _p_value(self.few_taught_test),
            # the map the odometry's chain, its closures weighing nothing (the test's p below
            # a third of cognitive_map.scan_test_significance)
            "closures_dropped": cmap.closures_dropped,
            "closures_dropped_p": _p_value(self.closures_test),
        }
