"""The LiDAR odometry's state machine (paper Sec. III-A): one update per scan, from the
prediction through the match kept to the motion model's and the scores' bookkeeping. The
concepts it composes each have their module in :mod:`bioslam.odometry`.

No file or terminal I/O here.
"""

from __future__ import annotations

import itertools
import math
from collections import deque
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from bioslam.geometry import between, compose
from bioslam.matching.branch_and_bound import WideBasinMatcher
from bioslam.matching.deskew import usable_endpoints
from bioslam.matching.gauss_newton import (
    NO_FACING,
    FloatArray,
    MatchReport,
    facing_normals,
    geometric_information,
    grid_args,
    kept_rows,
    mapped_conditioning,
    match_scan_to_map,
    matched_normals,
    points_per_level,
    pose_costs,
    summed_map,
)
from bioslam.matching.registration import grazing_endpoints
from bioslam.motion_model import ConstantVelocityModel, translation_part
from bioslam.occupancy_grid import MapPyramid, OccupancyGrid, subsample_by_spacing, thinned_normals
from bioslam.odometry.body_hits import BodyHits
from bioslam.odometry.choice import MatchChoice, match_quality
from bioslam.odometry.guards import PredictionGuards
from bioslam.odometry.local_map import Fusion, LocalMap
from bioslam.odometry.search import WideSearch
from bioslam.odometry.sweep import SweepMotion, sweep_bend
from bioslam.odometry_config import OdometryConfig
from bioslam.scan import LaserScan, farthest_return
from bioslam.step_prior import StepPrior


@dataclass
class ScanMatch:
    """One scan's match: the pose kept and its report, the start it was matched from, whether
    the prediction was searched beyond, and the endpoints (sensor frame; ``keep``: the kept
    ones) with the levels and normals it was matched on."""

    pose: FloatArray
    report: MatchReport
    start: FloatArray
    searched: bool
    points: FloatArray
    keep: NDArray[np.bool_]
    levels: list[FloatArray]
    normals: FloatArray


def within_range(points: FloatArray, limit: float) -> NDArray[np.bool_]:
    """Endpoints (sensor frame) no farther than ``limit`` metres from the scanner."""
    return points[:, 0] ** 2 + points[:, 1] ** 2 <= limit * limit


class LidarOdometry(LocalMap, PredictionGuards, WideSearch, MatchChoice, SweepMotion):
    """Pose change from consecutive LiDAR scans alone (paper Sec. III-A).

    ``update(scan)`` returns Δp, the motion since the previous scan in the previous robot
    frame (``geometry.between(prev_pose, pose)``); ``pose`` is the pose in the odometry frame
    (the first scan's pose is ``initial_pose``); ``last_report`` says how the match went and
    ``last_points`` holds the scan's usable endpoints (sensor frame, de-skewed to its stamp).

    One update's steps are here; the concepts they call on are mixed in from their modules:
    the local map fused into and matched against (:class:`~.local_map.LocalMap`), the trusted
    prediction's match checked against it (:class:`~.guards.PredictionGuards`), the starts
    searched when the prediction is not trusted (:class:`~.search.WideSearch`), the
    choice among the matches (:class:`~.choice.MatchChoice`) and, after a gap or on a
    thinned log, the turn during the scan's sweep (:class:`~.sweep.SweepMotion`).
    """

    def __init__(self, config: OdometryConfig | None = None, initial_pose: ArrayLike = (0, 0, 0)):
        self.config = config or OdometryConfig()
        c = self.config
        self.pose = np.asarray(initial_pose, dtype=np.float64).reshape(3).copy()
        self.pyramid = self._new_pyramid()
        self.last_report = MatchReport()
        self.last_points: FloatArray = np.zeros((0, 2))
        #: the last scan as matched: the directions the robot's own body blocks left out
        self.last_scan: LaserScan | None = None
        self._body = BodyHits(c.body_reach, c.body_turn)
        self._heading = 0.0  # turns counted: the body's directions are learned as it turns
        self.num_scans = 0
        self.num_predicted_only = 0
        self.num_recovered = 0
        self.num_degenerate = 0
        self.num_ambiguous = 0
        self.num_broken = 0
        self._searcher = WideBasinMatcher()
        self._pooled: tuple[OccupancyGrid, tuple] | None = None  # what the searcher pooled
        # the endpoints and normals last matched, and their geometric information
        self._geometry: tuple[FloatArray, FloatArray, tuple] | None = None
        self._motion = ConstantVelocityModel(
            c.velocity_window, c.velocity_scans, c.length_scale, c.degeneracy_ratio,
            c.constrained_ratio, c.accel_noise, c.velocity_noise, c.velocity_spread,
            sideways_noise=c.sideways_noise, point_noise=c.weak_point_noise,
        )
        # the motion prior's pose and its information along the weak direction
        self._axis_prior: tuple[FloatArray, float | None] | None = None
        self._last_delta = np.zeros(3)
        self._last_stamp: float | None = None
        self._last_dt = 0.0  # the interval before the last scan (0 before the second)
        self._scores: deque[float] = deque(maxlen=self.config.score_window)
        self._misses: deque[tuple[float, float, float]] = deque(maxlen=self.config.score_window)
        self._typical_miss = (0.0, 0.0)
        self._typical_step = 0.0
        self._typical_score = 0.0
        # the matches' shares of endpoints in known free space, and their median
        self._frees: deque[float] = deque(maxlen=self.config.score_window)
        self._typical_free = 0.0
        self._num_scores = 0
        self._last_inserted: FloatArray | None = None
        # where the scan being matched is predicted, at the scanner's rate: the frame the
        # places of the last fusions are seen from (``fused_reach_scans``); None otherwise
        self._fusion_frame: FloatArray | None = None
        # (pose, endpoints, the straight_angle they were densified with)
        self._first_fused: tuple[FloatArray, FloatArray, float] | None = None
        # the first scan's finest map with its walls on both sides of the cell edges they run
        # along, while a thinned log's second scan is matched (:meth:`_densify_first`)
        self._first_twinned: OccupancyGrid | None = None
        self._step_prior = StepPrior(c.step_prior)
        # the last scans fused: those whose beam patterns a sparse map echoes
        # (``echo_scans``), whose beams mapped what is near the end of the range
        # (``fused_reach_scans``), and that a map in conflict with the scans is rebuilt
        # from (``rebuild_scans``)
        self._fusions: deque[Fusion] = deque(
            maxlen=max(c.echo_scans, c.fused_reach_scans, c.rebuild_scans, 1)
        )
        self._searched: deque[bool] = deque(maxlen=c.score_window)
        self._num_searched = 0  # of those in _searched
        self._counted_scan = 0  # the scan last counted in _searched
        self._directions: tuple[FloatArray, FloatArray, FloatArray] | None = None
        # on sparse scans, the map being built to replace the one matched against
        # (:meth:`_turn_submaps`), the distance travelled while each was fused into, and
        # whether a step was ambiguous or broken since the last turn
        self._young: MapPyramid | None = None
        # at the scanner's rate, the stamps and centres of the objects the last scans saw
        self._object_track: deque[tuple[float, FloatArray]] = deque(maxlen=64)
        self._travel = [0.0, 0.0]
        self._doubts = 0
        self._conflict = False  # and the maps disagreed since (:meth:`_maps_disagree`)
        self._matched_levels: tuple[list[FloatArray], FloatArray, list[FloatArray]] | None = None
        self.num_submaps = 0
        self.num_rebuilds = 0

    # -- steps of one update ------------------------------------------------------------------

    def _time_step(self, stamp: float) -> float:
        if self._last_stamp is None:
            return 0.0
        dt = stamp - self._last_stamp
        return dt if dt > 0 else 0.0

    def _sensor_points(
        self, scan: LaserScan, twist: tuple[float, float, float] | None = None
    ) -> FloatArray:
        """The scan's usable endpoints de-skewed with ``twist`` (body frame; default the
        motion model's)."""
        c = self.config
        lo = max(c.min_range, scan.range_min, np.nextafter(0.0, 1.0))
        hi = self._usable_range(scan)
        increment = scan.time_increment if c.deskew else 0.0
        vx, vy, w = self._motion.twist if twist is None else twist
        cos_a, sin_a = self._beam_directions(scan.angles)
        return usable_endpoints(scan.ranges, cos_a, sin_a, lo, hi, increment, vx, vy, w)

    def _usable_range(self, scan: LaserScan) -> float:
        return min(self.config.max_range, farthest_return(scan.range_max))

    def _matched(
        self, pts: FloatArray, keep: NDArray[np.bool_], scan: LaserScan
    ) -> tuple[FloatArray, NDArray[np.bool_]]:
        """The endpoints (and the kept ones among them) that are matched: those at least
        :attr:`OdometryConfig.matched_range_margin` short of the usable range, from the scan's
        pose or from where one of the last scans was fused (:meth:`_within_fused_reach`), and
        along a corridor none on a wall the beams graze (:meth:`_weakly_pinned`). The map holds
        a wall only as far as earlier scans reached; moved on since the last fusion, the
        scan's farthest endpoints on a wall ahead fall past the map's end, whose edge pulls
        them, and the pose, back. Along a corridor longer than the range nothing else
        fixes the pose, and that pull stalled it (simulated URG-04LX, 5.6 m). All endpoints
        are still fused into the map."""
        c = self.config
        limit = self._matched_range(scan)
        matched = within_range(pts, limit)
        if not matched.all():
            matched |= self._within_fused_reach(pts, limit)
        if c.grazing_ratio is not None and self._weakly_pinned():
            matched &= ~grazing_endpoints(pts, c.grazing_ratio, c.grazing_gap)
        if matched.all():
            return pts, keep
        pts = kept_rows(pts, matched)
        return pts, subsample_by_spacing(pts, c.point_spacing)

    def _matched_range(self, scan: LaserScan) -> float:
        """How far from the scan's pose its endpoints are matched on their own:
        ``matched_range_margin`` short of the usable range."""
        return self._usable_range(scan) - self.config.matched_range_margin

    def _own_reach(self, points: FloatArray) -> NDArray[np.bool_]:
        """The current scan's endpoints ``points`` (sensor frame) within its own matched
        range (:meth:`_matched_range`)."""
        return within_range(points, self._matched_range(self.last_scan))

    def _last_fused(self, count: int) -> list[FloatArray]:
        """The poses the last ``count`` scans were fused at (fewer at the start)."""
        return [fusion.pose for fusion in itertools.islice(reversed(self._fusions), count)]

    def _within_fused_reach(self, pts: FloatArray, limit: float) -> NDArray[np.bool_]:
        """The endpoints ``pts`` within ``limit`` metres of where one of the last
        ``fused_reach_scans`` scans was fused, seen from the scan's predicted pose: inside
        what that scan's beams mapped. None on sparse scans (``_fusion_frame`` None): a
        thinned log's prediction is a guess and its fusions lie metres back; with the rule
        there, a URG-04LX thinned to a scan per metre down the maze's corridors (seed 6)
        took two steps 0.3 m off, where it had taken none."""
        recent = self._last_fused(self.config.fused_reach_scans)
        if self._fusion_frame is None or not recent:
            return np.zeros(pts.shape[0], dtype=bool)
        origins = between(self._fusion_frame, np.array(recent))[:, :2]
        apart = pts[:, None, :2] - origins[None, :, :]
        return np.any(np.einsum("ijk,ijk->ij", apart, apart) <= limit * limit, axis=1)

    def _weakly_pinned(self) -> bool:
        """At the scanner's rate, the last match's conditioning was below
        ``grazing_condition``: a corridor, where a grazed wall's dots decide the pose along
        it (``grazing_ratio``)."""
        weak = self.last_report.condition < self.config.grazing_condition
        return weak and self._at_scanner_rate()

    def _beam_directions(self, angles: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Cosines and sines of the beam angles, kept while the scans' angles stay the same."""
        known = self._directions
        same = known is not None and (
            known[0] is angles
            or (known[0].shape == angles.shape and np.array_equal(known[0], angles))
        )
        if not same:
            self._directions = known = (angles, np.cos(angles), np.sin(angles))
        return known[1], known[2]

    def _count_searched(self, searched: bool) -> None:
        """Remember whether this scan was searched, for :meth:`_sparse` (once a scan: a scan
        matched again replaces its entry)."""
        if self._counted_scan == self.num_scans:
            self._num_searched -= self._searched.pop()
        self._counted_scan = self.num_scans
        if len(self._searched) == self._searched.maxlen:
            self._num_searched -= self._searched[0]
        self._searched.append(searched)
        self._num_searched += searched

    def _sparse(self) -> bool:
        """The wide-basin search ran for at least ``sparse_share`` of the recent scans (and
        of at least ``sparse_scans``): a thinned log or a low scan rate, where the motion
        model's prediction is no better than a guess."""
        c = self.config
        return self._num_searched >= c.sparse_share * max(len(self._searched), c.sparse_scans)

    def _sparse_so_far(self) -> bool:
        """Fewer than ``sparse_scans`` matched, and the search ran for every one: a thinned
        log before :meth:`_sparse` can tell. Its map is then the first one or two scans,
        densest where they were taken, and, fused as measured, a pose moved back there
        (standing still) outscored the true step a metre on."""
        n = len(self._searched)
        return 0 < n < self.config.sparse_scans and self._num_searched == n

    def _as_sparse(self) -> bool:
        """Matched as sparse scans: :meth:`_sparse`, or :meth:`_sparse_so_far` before it can
        tell."""
        return self._sparse() or self._sparse_so_far()

    # -- public -------------------------------------------------------------------------------

    def update(self, scan: LaserScan) -> FloatArray:
        """Match one scan and return Δp (3,) since the previous scan (zeros on the first)."""
        c = self.config
        measured, scan = scan, self._body.without(scan)
        self.last_scan = scan
        dt = self._time_step(scan.stamp)
        previous = self.pose.copy()
        predicted = self._motion.predict(previous, dt) if self.num_scans else previous
        pts = self.last_points = self._sensor_points(scan)
        keep = subsample_by_spacing(pts, c.point_spacing)
        first = self._last_inserted is None  # nothing to match against yet
        constraint: tuple[float, FloatArray] | None = None
        self.num_scans += 1
        if pts.shape[0] < c.min_points:
            self.pose = predicted
            self.num_predicted_only += 1
            self.last_report = MatchReport(predicted_only=True, num_points=int(pts.shape[0]))
        elif first:
            self.last_report = MatchReport(num_points=int(pts.shape[0]))
        else:
            if self._first_fused is not None:
                self._densify_first(dt)
            self._fusion_frame = predicted if self._at_scanner_rate() else None
            found = self._match_scan(pts, keep, scan, previous, predicted, dt)
            if self._sweep_unknown(scan, dt):
                found = self._with_sweep_settled(scan, previous, predicted, dt, found)
            pts, keep = found.points, found.keep
            self.last_points = pts
            self.pose, self.last_report = found.pose, found.report
            self._note_match(found, previous)
            self._rebuild_on_conflict(dt)
            self._first_twinned = None  # the first match is made
            if self._gapless(dt) and not self.last_report.overruled:
                # after a gap the velocity is measured afresh, and where the map overruled
                # the motion prior, the scan measured it
                constraint = (
                    *self._mapped_constraint(found.levels[0], found.normals),
                    self._axis_offset(),
                )
            self.num_recovered += self.last_report.recovered
            self.num_degenerate += self.last_report.degenerate
            self.num_ambiguous += self.last_report.ambiguous
            self.num_broken += self.last_report.broken
            self._doubts += self.last_report.ambiguous or self.last_report.broken
        if not self.last_report.predicted_only:
            self._track_objects(scan.stamp, self.pose, pts)
        if not self.last_report.predicted_only and self._should_insert():
            # every endpoint is fused, each with the normal of the kept one before it
            self._insert(pts, thinned_normals(pts, keep))
            self.last_report.inserted = True
        if self.last_report.inserted and not self._scores:
            self._remember_score(self._score_at(self.pose, kept_rows(pts, keep)))
        self._last_delta = between(previous, self.pose)
        self._note_bend(scan, float(self._last_delta[2]), dt)
        self._motion.update(scan.stamp, self.pose, *(constraint or (1.0, None, None)))
        self._last_stamp = scan.stamp
        self._last_dt = dt
        self._heading += float(self._last_delta[2])
        self._body.observe(measured, self._heading)
        return self._last_delta.copy()

    def _note_bend(self, scan: LaserScan, turned: float, dt: float) -> None:
        """The report's ``bend``: how far the scan's sweep, de-skewed with the motion model's
        twist (before the step updates it), is bent against the turn rate of the step just
        matched (``turned`` radians in ``dt`` seconds). As a turn begins or
        ends the twist, a mean over its window, lags the rate: a 360° scanner's sweep is
        then bent by up to 2.5° (simulated maze, RPLIDAR), and the match of the bent scan,
        and the pose it gives, by as much. Left at 0 where the steps are a gap or a thinned
        log's (:meth:`_gapless`, :meth:`_sparse`): a step's mean rate over seconds says
        nothing of the turn through a sweep (a 360° scanner's is then measured on the scan,
        :meth:`_sweep_unknown`)."""
        report = self.last_report
        if self.at_scanner_rate(dt) and self.config.deskew and not report.predicted_only:
            report.bend = sweep_bend(float(self._motion.twist[2]), turned / dt, scan)

    def at_scanner_rate(self, dt: float) -> bool:
        """Whether a step ``dt`` seconds after the scan before is one at the scanner's rate:
        no gap (:meth:`_gapless`), and the scans not a thinned log's (:meth:`_sparse`), where
        the motion between two scans is seconds of driving."""
        return dt > 0.0 and self._gapless(dt) and not self._sparse()

    def steps_to_insert(self, step: ArrayLike) -> float:
        """How many more steps like ``step`` (the last one, in the robot's frame) until the
        pose is ``insert_distance`` / ``insert_angle`` from the last scan fused into the map
        and the next is fused: 0 when one is due now, inf when the step does not move."""
        if self._last_inserted is None:
            return 0.0
        c = self.config
        d = between(self._last_inserted, self.pose)
        left = (c.insert_distance - math.hypot(d[0], d[1]), c.insert_angle - abs(d[2]))
        if min(left) <= 0.0:
            return 0.0
        s = np.asarray(step, dtype=np.float64).reshape(3)
        rates = (math.hypot(s[0], s[1]), abs(s[2]))
        return min((lo / r for lo, r in zip(left, rates, strict=True) if r > 0.0), default=math.inf)

    def summary(self) -> dict[str, int]:
        """Counts over the run: scans, matches recovered by a search, scans with an
        unconstrained direction, scans with too few points (prediction only), scans whose
        search found a look-alike as plausible as the match kept, sparse scans whose match
        the odometry cannot vouch for (``MatchReport.broken``), the directions of the scan
        (a degree each) learned as blocked by the robot's own body at the end
        (:mod:`~bioslam.odometry.body_hits`), and the times the local map was rebuilt from
        the recent scans (``OdometryConfig.rebuild_scans``)."""
        return {
            "odometry_scans": self.num_scans,
            "odometry_recovered": self.num_recovered,
            "odometry_degenerate": self.num_degenerate,
            "odometry_predicted_only": self.num_predicted_only,
            "odometry_ambiguous": self.num_ambiguous,
            "odometry_broken": self.num_broken,
            "odometry_body_directions": int(np.count_nonzero(self._body.blocked)),
            "odometry_map_rebuilds": self.num_rebuilds,
        }

    def _match_scan(
        self, pts: FloatArray, keep: NDArray[np.bool_], scan: LaserScan, previous: FloatArray,
        predicted: FloatArray, dt: float,
    ) -> ScanMatch:
        """The scan's endpoints ``pts`` (``keep``: the kept ones) matched from the motion
        model's best start (:meth:`_best_start`, :meth:`_match`)."""
        level_pts, normals = self._levels(pts, keep, scan)
        start = self._best_start(level_pts[-1], previous, predicted)
        self._matched_levels = (level_pts, normals, facing_normals(level_pts, normals))
        pose, report, searched = self._match(level_pts, start, previous, normals, dt, predicted)
        return ScanMatch(pose, report, start, searched, pts, keep, level_pts, normals)

    def _levels(
        self, pts: FloatArray, keep: NDArray[np.bool_], scan: LaserScan
    ) -> tuple[list[FloatArray], FloatArray]:
        """The matched endpoints of ``pts`` (:meth:`_matched`) on each pyramid level, finest
        first, and the finest level's surface normals."""
        c = self.config
        matched, matched_keep = self._matched(pts, keep, scan)
        level_pts = points_per_level(matched, c.point_spacing, c.levels, matched_keep)
        return level_pts, matched_normals(level_pts)

    def _with_sweep_settled(
        self, scan: LaserScan, previous: FloatArray, predicted: FloatArray, dt: float,
        found: ScanMatch,
    ) -> ScanMatch:
        """``found`` with the scan de-skewed by the turn rate measured on it
        (:meth:`~.sweep.SweepMotion._settle_sweep`): the settled match where that rate bends
        the scan by less than ``sweep_rematch`` against the one it was matched with, else
        the scan matched afresh as de-skewed (a robot spinning on the spot through a 360°
        sweep bends the scan by 6°, and the match chosen for the bent scan may be a
        look-alike a metre off). At the scanner's pace (:meth:`at_scanner_rate`, steps of
        several sweeps, :meth:`~.sweep.SweepMotion._steps_span_sweeps`) the motion prior
        holds the match, which the settled match's search prior lets slide along a corridor
        (simulated maze, 3.5 m LDS-01 every 2nd scan: 15-35 cm a step): ``found`` stays
        unless the rate bends the scan by ``sweep_min_skew``, and is then matched afresh; a
        match that failed either way is tried with the robot stopped or reversed
        (:meth:`_unless_failed_by_twist`)."""
        settled = self._settle_sweep(scan, previous, found.pose, dt)
        if settled is None:
            return found
        bend = sweep_bend(float(self._motion.twist[2]), settled.rate, scan)
        if self.at_scanner_rate(dt):
            if bend >= self.config.sweep_min_skew:
                found = self._match_scan(
                    settled.points, settled.keep, scan, previous, predicted, dt
                )
            return self._unless_failed_by_twist(found, scan, previous, predicted, dt)
        if bend >= self.config.sweep_rematch:
            return self._match_scan(settled.points, settled.keep, scan, previous, predicted, dt)
        return replace(
            found, pose=settled.pose, points=settled.points, keep=settled.keep,
            levels=settled.levels, normals=settled.normals,
        )  # fmt: skip

    def _unless_failed_by_twist(
        self, found: ScanMatch, scan: LaserScan, previous: FloatArray, predicted: FloatArray,
        dt: float,
    ) -> ScanMatch:
        """``found``, or where it failed (:meth:`_failed`), the scan de-skewed as if the robot
        had stopped, or had reversed its motion and its turn, and matched afresh, whichever of
        those did not fail and fits best. At the scanner's pace of a log thinned by count a
        robot that reverses between two scans reverses its turn through the sweep too: the
        motion model's twist then bends the scan by twice the turn (13° at 0.8 rad/s through a
        RPLIDAR's sweep), no pose fits it, and the rate measured from the failed pose says
        nothing (simulated maze, RPLIDAR every 3rd scan reversing s502: lost, 9 m, at the
        reversal; found with the reversed twist)."""
        if not self._failed(found.report):
            return found
        best, fit = found, match_quality(found.report)
        vx, vy, w = (float(v) for v in self._motion.twist)
        for twist in ((0.0, 0.0, 0.0), (-vx, -vy, -w)):
            deskewed = self._deskewed(scan, twist)
            if deskewed is None:
                continue
            match = self._match_scan(*deskewed, scan, previous, predicted, dt)
            quality = match_quality(match.report)
            if not self._failed(match.report) and quality > fit:
                best, fit = match, quality
        return best

    def _note_match(self, found: ScanMatch, previous: FloatArray) -> None:
        """Remember the match kept: the motion model's miss, the step (for the step prior,
        where the prediction was not trusted, as on sparse scans) and the score."""
        step = between(previous, found.pose)
        self._remember_miss(between(found.start, found.pose), step)
        if found.searched:
            self._step_prior.add(step)
        self._remember_score(found.report.score, found.report.free_fraction)

    def _match(
        self, level_pts: list[FloatArray], start: FloatArray, previous: FloatArray,
        normals: FloatArray, dt: float, predicted: FloatArray,
    ) -> tuple[FloatArray, MatchReport, bool]:
        """Eq. 3 from ``start`` (the motion model's prior, :meth:`_best_start`); when that
        cannot be trusted (:meth:`_untrusted`), also from the wide-basin search's winner and
        its rival and from the other motion hypotheses (the constant-velocity prediction,
        the last step repeated, the typical step straight on: after a turn on the spot in
        a log thinned to a scan per metre the first two say "turning", the last "a metre
        on"; on sparse scans also the step prior's typical steps, the arc to the winner's
        heading, :meth:`_arc_seeds`, the searches' seeds and the
        hypotheses on the finer levels alone, :meth:`_finer_basins`, and each match its
        scan leaves free along a corridor slid there, :meth:`_slid`; the motion hypotheses not
        where the search's lone winner settles the step, :meth:`_settles`), keeping the plausible
        match nearest ``start`` (:meth:`_choose`), or on sparse scans and while every scan
        so far came after a gap (:meth:`_sparse_so_far`: standing still is then no motion
        prior) the best one (:meth:`_choose_sparse`). When
        every match so found sees through walls, or none is credible (:meth:`_credible`),
        the search is repeated for a turn of about ``2 * search_angle`` either way from
        ``previous`` (thinned logs turn up to 80° between scans), and on round the circle
        while none is credible (:func:`turned_windows`)."""
        c = self.config
        gapless = self._gapless(dt)
        prior = self._motion_prior(start, previous, predicted, dt)
        options = [self._guarded_option(level_pts, start, previous, normals, dt, predicted, prior)]
        motion: tuple[FloatArray, ...] = (start,)  # only compared when the search ran
        jump = self._jump_limits()
        # a trusted prediction's match that jumped is searched as an untrusted one is: in a
        # spin its Gauss-Newton can slide into a look-alike basin tens of centimetres off;
        # so is one the walls contradict, lagging along a corridor behind a robot that sped up
        searched = c.search_distance > 0 and (
            self._untrusted(options[0][2], dt, previous, start)
            or self._is_jump(options[0][0], start, jump)
            or self._walls_contradict(options[0][0], options[0][1], level_pts[0])
        )
        self._count_searched(searched)
        as_sparse = self._as_sparse()
        if searched:
            motion = self._searched_options(
                options, level_pts, normals, start, previous, predicted, as_sparse
            )
        reach = self._reach(jump, dt)
        if as_sparse and len(options) > 1:
            pose, report = self._choose_sparse(options, previous, reach, gapless)
        else:
            pose, report = self._choose(options, motion, previous, reach, jump, gapless)
        report.iterations = sum(option[1].iterations for option in options)
        return pose, report, searched

    def _reach(self, jump: tuple[float, float], dt: float) -> tuple[float, float]:
        """How far (m, rad) a match may lie from the previous pose: what the robot moves in
        ``dt`` (``max_speed``, ``max_turn_rate``) plus the jump limits, the previous pose's
        own error. The first match's previous pose is the first scan's, exact by
        definition: there the robot's motion alone (the garage's pillars seen by a URG-04LX,
        14 endpoints, from a standstill: a match 0.22 m and 4° on in a tenth of a second,
        0.67 against the standstill's 0.65, was taken, and the motion model carried its
        2.2 m/s through 20 s of degenerate scans, 6 m)."""
        c = self.config
        motion = (c.max_speed * dt, c.max_turn_rate * dt)
        if self._first_match():
            return motion
        return jump[0] + motion[0], jump[1] + motion[1]

    def _first_match(self) -> bool:
        """The scan being matched is the second of the run (:attr:`num_scans` counts it): the
        first matched against a map, from the first scan's pose."""
        return self.num_scans == 2

    def _gapless(self, dt: float) -> bool:
        """The scan came no later than ``gap_time`` after the last: its prediction is a
        trusted motion prior."""
        return dt <= self.config.gap_time

    def _motion_prior(
        self, start: FloatArray, previous: FloatArray, predicted: FloatArray, dt: float
    ) -> tuple[FloatArray | None, float, float | None]:
        """The motion prior of the match from ``start``: where it pulls (None: the start,
        :meth:`_prior_target`), its weight (:meth:`_prior_weight`) and the information it
        holds along the weak direction (with ``weak_axis_prior``). Notes its pose and its
        predicted information there for the motion model's filter (:meth:`_axis_offset`)."""
        gapless = self._gapless(dt)
        # the prior pulls towards the motion model's prediction, never a standstill it did not
        # predict (:meth:`_prior_target`)
        target = self._prior_target(start, previous, predicted, gapless)
        information = self._motion.prior_information(dt) if gapless else None
        self._axis_prior = (start if target is None else target, information)
        held = information if self.config.weak_axis_prior else None
        return target, self._prior_weight(dt), held

    def _prior_target(
        self, start: FloatArray, previous: FloatArray, predicted: FloatArray, gapless: bool
    ) -> FloatArray | None:
        """Where the motion prior pulls along a direction the scan does not constrain: the
        constant-velocity prediction when :meth:`_best_start` chose to start from the last
        pose (standing still scored better on the coarse level), else the start itself
        (None). Pulled towards that standstill start, the pose stood still along an aisle
        for seconds while the robot drove on, its slid scans were fused, and the map then
        held it there (simulated warehouse, UTM-30LX, adversarial route: 2.3 m behind
        after 1 s of degenerate scans). With ``sideways_noise`` the prediction also when
        the start is the last step repeated: its turn is a better start in a spin, but its
        slide along the corridor is no motion the model predicts. After a gap the
        prediction is no prior."""
        if not gapless or np.array_equal(start, predicted):
            return None
        if self.config.sideways_noise > 0.0 or np.array_equal(start, previous):
            return predicted
        return None

    def _prior_weight(self, dt: float) -> float:
        """``prior_weight`` for a scan that came without a gap, ``search_prior_weight``
        after one: the constant-velocity prediction across a gap (a thinned log's second)
        is no better than the last pose (intel: RPE 52 cm with the full weight, 44 cm
        without). Nor is it before any scan measured the velocity along its weakest
        direction (:attr:`~bioslam.motion_model.ConstantVelocityModel.weak_measured`): a
        run that starts in a corridor carries the start's standstill along it, and held
        there by the full weight, the pose stood while the robot drove off (a 180°
        scanner facing backwards, its corridor's far end 12 m behind: 5.1 m short after
        8 s, the far wall's 22 endpoints outweighed)."""
        c = self.config
        trusted = self._gapless(dt) and self._motion.weak_measured
        return c.prior_weight if trusted else c.search_prior_weight

    def _option(
        self, level_pts: list[FloatArray], start: FloatArray, normals: FloatArray,
        prior_weight: float | None = None, prior_pose: FloatArray | None = None,
        restart: bool = False, prior_information: float | None = None,
    ) -> tuple[FloatArray, MatchReport, bool]:
        """Gauss-Newton from ``start``: (pose, report, failed). The motion prior pulls
        towards ``prior_pose`` (default ``start``) with ``prior_weight``, by default
        ``search_prior_weight`` (a search's seed is no motion prior); ``restart``: see
        :func:`bioslam.matching.gauss_newton.match_scan_to_map`."""
        weight = self.config.search_prior_weight if prior_weight is None else prior_weight
        pose, report = self._match_from(
            level_pts, start, normals, weight, prior_pose, restart, prior_information
        )
        return pose, report, self._failed(report)

    def _remember_score(self, score: float, free_fraction: float = 0.0) -> None:
        """Keep the last ``score_window`` scores and shares of endpoints in known free space.
        Their medians are refreshed on each of the first tenth of a window, then every tenth
        (per scan it cost more than the rest of the failure test)."""
        self._scores.append(score)
        self._frees.append(free_fraction)
        self._num_scores += 1
        if self._refresh_due():
            self._typical_score = float(np.median(self._scores))
            self._typical_free = float(np.median(self._frees))

    def _refresh_due(self) -> bool:
        step = max(self.config.score_window // 10, 1)
        return self._num_scores <= step or self._num_scores % step == 0

    def _remember_miss(self, miss: FloatArray, step: FloatArray) -> None:
        """Keep the last ``score_window`` differences between the motion model's start and
        the match kept (metres, radians), and steps: the misses' ``miss_percentile``-th
        percentiles are the motion model's typical error, the median of the steps longer
        than half that percentile of the step lengths the typical step forward (a thinned
        log keeps a scan per metre or per tens of degrees of turn: its steps are about a
        metre or about none). Refreshed as the scores' median is."""
        self._misses.append((math.hypot(miss[0], miss[1]), abs(miss[2]), math.hypot(*step[:2])))
        if self._refresh_due():
            record = np.array(self._misses)
            misses = np.percentile(record, self.config.miss_percentile, axis=0)
            self._typical_miss = (float(misses[0]), float(misses[1]))
            lengths = record[:, 2]
            self._typical_step = float(np.median(lengths[lengths >= 0.5 * misses[2]]))

    def _score_at(
        self, pose: FloatArray, points: FloatArray, on: OccupancyGrid | None = None
    ) -> float:
        """Mean M* of ``points`` at ``pose`` on the finest level, or on the grid ``on`` (the
        first scan's score on the map made from it is the reference until matches have been
        made)."""
        grid = grid_args(self.pyramid.finest if on is None else on, self.config.subcell_sigma)
        c, s = math.cos(pose[2]), math.sin(pose[2])
        total = summed_map(grid, points, self._facing_of(points), c, s, pose[0], pose[1], False)
        return total / max(len(points), 1)

    def _facing(self, level_pts: list[FloatArray]) -> list[FloatArray] | None:
        """The scan's :func:`~bioslam.matching.gauss_newton.facing_normals` per level, for
        ``level_pts`` the scan's own endpoints (none for others)."""
        held = self._matched_levels
        return held[2] if held is not None and held[0] is level_pts else None

    def _facing_of(self, points: FloatArray) -> FloatArray:
        """The surface normals of ``points`` when they are one level of the scan's
        endpoints, else none (:data:`~bioslam.matching.gauss_newton.NO_FACING`)."""
        held = self._matched_levels
        if held is not None:
            for level, facing in zip(held[0], held[2], strict=True):
                if level is points:
                    return facing
        return NO_FACING

    def _match_from(
        self, level_pts: list[FloatArray], start: FloatArray, normals: FloatArray,
        prior_weight: float | None, prior_pose: FloatArray | None = None,
        restart: bool = False, prior_information: float | None = None,
        iterations: tuple[int, ...] | None = None,
    ) -> tuple[FloatArray, MatchReport]:
        """Gauss-Newton from ``start`` (:func:`~bioslam.matching.gauss_newton.match_scan_to_map`;
        ``prior_weight`` None holds the pose at ``start`` along a direction the scan leaves
        free), the share of its endpoints in known free space counted."""
        c = self.config
        pose, report = match_scan_to_map(
            self.pyramid, level_pts, start, iterations or c.max_iterations, c.step_tolerance,
            c.length_scale, c.degeneracy_ratio, c.subcell_sigma, normals, prior_weight,
            prior_pose, restart, prior_information, self._scan_geometry(level_pts[0], normals),
            self._facing(level_pts),
        )  # fmt: skip
        report.free_fraction = self.pyramid.finest.fraction_not_above_near(
            pose, level_pts[0], c.free_logodds
        )
        return pose, report

    def _scan_geometry(self, points: FloatArray, normals: FloatArray) -> tuple:
        """:func:`~bioslam.matching.gauss_newton.geometric_information` of the scan's
        endpoints, once a scan: Gauss-Newton runs from up to twenty starts on sparse scans."""
        held = self._geometry
        if held is None or held[0] is not points or held[1] is not normals:
            info = geometric_information(points, normals, self.config.length_scale)
            self._geometry = held = (points, normals, info)
        return held[2]

    def _best_start(
        self, coarse_pts: FloatArray, previous: FloatArray, predicted: FloatArray
    ) -> FloatArray:
        """The initial pose with the lowest cost on the coarsest level among: the
        constant-velocity prediction, the previous scan's motion repeated, and no motion.
        Logged timestamps often jitter (CARMEN logs stamp scans when written, not when
        measured): a robot turning at a steady rate per scan then gets a prediction off by
        tens of degrees from the time-based model alone. An alternative must beat the
        prediction clearly (``start_margin``), so that where the scan cannot tell the
        candidates apart (a featureless corridor) the prediction is kept."""
        candidates = np.array([predicted, self._step_repeated(previous), previous])
        grid = grid_args(self.pyramid.grids[-1], self.config.subcell_sigma)
        facing = self._facing_of(coarse_pts)
        costs = pose_costs(grid, coarse_pts, facing, candidates)
        best = int(np.argmin(costs))
        if costs[best] < (1.0 - self.config.start_margin) * costs[0]:
            return candidates[best]
        return predicted

    def _step_repeated(self, previous: FloatArray) -> FloatArray:
        """The last step repeated from ``previous``: a motion hypothesis that, unlike the
        time-based prediction, survives jittered stamps and a turn that just stopped."""
        return compose(previous, self._last_delta)

    def _axis_offset(self) -> tuple[FloatArray | None, float]:
        """For the motion model's filter along the weak direction
        (:meth:`bioslam.motion_model.ConstantVelocityModel.update`): the match's offset from
        the motion prior (robot frame) along the direction the prior held (None unless the
        prior held one, weighed by
        :meth:`~bioslam.motion_model.ConstantVelocityModel.prior_information`), and the
        scan's information along it in endpoints (its conditioning times the largest
        eigenvalue of its point-to-line information)."""
        report = self.last_report
        information = report.condition * report.information
        prior = self._axis_prior
        if prior is None or prior[1] is None or report.recovered or not report.degenerate:
            return None, information
        u = translation_part(report.weakest_direction)
        if u is None:
            return None, information
        # where the scan alone put the pose: the prior held back ``prior_share`` of it
        d = between(prior[0], self.pose)
        scale = 1.0 / max(1.0 - report.prior_share, 1e-3)
        return u[:2] * (scale * float(u[0] * d[0] + u[1] * d[1])), information

    def _mapped_constraint(
        self, points: FloatArray, normals: FloatArray
    ) -> tuple[float, FloatArray | None]:
        """The conditioning and weakest direction (sensor frame) of the scan's endpoints that
        the matched pose puts on walls the map holds (a finest cell or one of its neighbours
        above ``mapped_logodds``): what the motion model may learn its velocity from
        (:mod:`bioslam.motion_model`). A surface the scan sees for the first time (a
        corridor's end coming into range) does not fix the pose against the map; counted,
        it hid that along the corridor the pose was held by nothing but the map's edge
        ahead. Direction None when ``mapped_logodds`` is None: the velocity is then the
        plain measurement."""
        c = self.config
        if c.mapped_logodds is None:
            return 1.0, None
        # every other endpoint: the conditioning is a ratio, and this runs on every scan
        return mapped_conditioning(
            self.pyramid.finest, points[::2], normals[::2], self.pose, c.mapped_logodds,
            c.length_scale,
        )
