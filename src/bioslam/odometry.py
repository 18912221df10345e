"""LiDAR odometry (paper Sec. III-A, Eq. 1-4): scan-to-local-map matching, the state machine.

Follows Hector SLAM (Kohlbrecher et al. 2011), the method the paper cites: every scan is
matched against a local log-odds occupancy grid by maximising the summed map function M* at the
scan endpoints (Eq. 3), coarse to fine over a map pyramid, starting from a constant-velocity
prediction. The map is a window that scrolls with the robot, so memory is constant however long
the run. The matching itself lives in :mod:`bioslam.matching` (Gauss-Newton, the searches,
de-skewing, pairwise registration) and its settings in :mod:`bioslam.odometry_config`; this
module decides, scan by scan, where to start, when a match has failed, what to search and what
to keep.

Frames: the sensor frame is taken as the robot frame (no extrinsic offset). The pose of a scan
is the pose at ``scan.stamp`` (the first beam, as in ROS); with per-beam timing the endpoints
are de-skewed to that instant with the current constant-velocity estimate.

No file or terminal I/O here.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable
from dataclasses import replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from bioslam.geometry import (
    between,
    compose,
    inverse,
    separation,
    transform_points,
    wrap_angle,
)
from bioslam.matching.branch_and_bound import WideBasinConfig, WideBasinMatcher
from bioslam.matching.deskew import deskew_points, se2_exp, se2_log, usable_endpoints
from bioslam.matching.gauss_newton import (
    NO_FACING,
    FloatArray,
    MatchReport,
    facing_normals,
    geometric_conditioning,
    geometric_information,
    grid_args,
    in_map_frame,
    kept_rows,
    levels_up_to,
    mapped_conditioning,
    match_scan_to_map,
    matched_normals,
    points_per_level,
    pose_costs,
    summed_map,
)
from bioslam.matching.registration import (
    RegistrationConfig,
    RegistrationQuality,
    densify_scan,
    densify_with_mask,
    register_scans,
)
from bioslam.motion_model import ConstantVelocityModel, translation_part
from bioslam.occupancy_grid import (
    NORMAL_MAX_GAP,
    MapPyramid,
    OccupancyGrid,
    subsample_by_spacing,
    thinned_normals,
)
from bioslam.odometry_config import OdometryConfig
from bioslam.scan import LaserScan
from bioslam.step_prior import StepPrior

__all__ = [
    "LidarOdometry",
    "MatchReport",
    "OdometryConfig",
    "RegistrationConfig",
    "RegistrationQuality",
    "densify_scan",
    "deskew_points",
    "geometric_conditioning",
    "match_scan_to_map",
    "register_scans",
    "se2_exp",
    "se2_log",
]


def turned_windows(half_width: float) -> list[tuple[float, ...]]:
    """The centres (radians, from the last heading) of the search windows of ``half_width``
    that, beside the one around the prediction, cover every heading, in rings ``2 *
    half_width`` apart either way, nearest first (one window where the two sides meet at
    180°). A log thinned by distance alone keeps no scan while the robot turns on the spot:
    freiburg-079 at a scan per metre turns more than 135° between 5 of its 401 scans, up to
    179°. The odometry searches the first ring while every match so far sees through walls
    or none is credible, and one beyond it only while none is credible
    (:meth:`LidarOdometry._credible`): a room looks much like itself turned round, and
    where the true step's match only fitted too little of a scan seeing new ground, the room
    turned round outscored it (6 of the rooms world's 12 routes thinned to a scan per metre
    and 0.6 rad were lost with the far rings searched as the near ones)."""
    step = 2.0 * half_width
    rings: list[tuple[float, ...]] = []
    for k in range(1, math.ceil((math.pi - half_width) / step - 1e-9) + 1):
        angle = min(k * step, math.pi)
        rings.append((-angle,) if angle >= math.pi else (-angle, angle))
    return rings


def _match_quality(report: MatchReport) -> float:
    """Mean M* over the matched endpoints, less the fraction of them in known free space
    (negative evidence: the map saw through where the match puts a wall) and the fraction of
    beams that pass through a known wall (the scan saw through where the map has one)."""
    return report.score - report.free_fraction - report.through_fraction


def _contradicted_where_constrained(report: MatchReport) -> bool:
    """A match on a scan that constrains every direction that puts endpoints in known free
    space (along a direction the scan does not constrain, the motion prior's match is
    judged by :meth:`LidarOdometry._unless_contradicted` instead)."""
    return not report.degenerate and report.free_fraction > 0.0


def _off_line(
    pose: FloatArray, origin: FloatArray, direction: FloatArray, length_scale: float
) -> float:
    """How far ``pose`` lies from the line through ``origin`` along ``direction`` (unit,
    (x, y, theta * length_scale), as ``MatchReport.degenerate_direction``)."""
    offset = np.array([
        pose[0] - origin[0], pose[1] - origin[1], length_scale * wrap_angle(pose[2] - origin[2])
    ])  # fmt: skip
    return float(np.linalg.norm(offset - (offset @ direction) * direction))


class LidarOdometry:
    """Pose change from consecutive LiDAR scans alone (paper Sec. III-A).

    ``update(scan)`` returns Δp, the motion since the previous scan in the previous robot
    frame (``geometry.between(prev_pose, pose)``); ``pose`` is the pose in the odometry frame
    (the first scan's pose is ``initial_pose``); ``last_report`` says how the match went and
    ``last_points`` holds the scan's usable endpoints (sensor frame, de-skewed to its stamp).
    """

    def __init__(self, config: OdometryConfig | None = None, initial_pose: ArrayLike = (0, 0, 0)):
        self.config = config or OdometryConfig()
        c = self.config
        self.pose = np.asarray(initial_pose, dtype=np.float64).reshape(3).copy()
        self.pyramid = self._new_pyramid()
        self.last_report = MatchReport()
        self.last_points: FloatArray = np.zeros((0, 2))
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
        # (pose, endpoints, the straight_angle they were densified with)
        self._first_fused: tuple[FloatArray, FloatArray, float] | None = None
        self._step_prior = StepPrior(c.step_prior)
        # the poses of the last scans fused, whose beam patterns a sparse map echoes
        self._fused_poses: deque[FloatArray] = deque(maxlen=max(c.echo_scans, 1))
        self._searched: deque[bool] = deque(maxlen=c.score_window)
        self._num_searched = 0  # of those in _searched
        self._directions: tuple[FloatArray, FloatArray, FloatArray] | None = None
        # on sparse scans, the map being built to replace the one matched against
        # (:meth:`_turn_submaps`), the distance travelled while each was fused into, and
        # whether a step was ambiguous or broken since the last turn
        self._young: MapPyramid | None = None
        self._travel = [0.0, 0.0]
        self._doubts = 0
        self._conflict = False  # and the maps disagreed since (:meth:`_maps_disagree`)
        self._matched_levels: tuple[list[FloatArray], FloatArray, list[FloatArray]] | None = None
        self.num_submaps = 0

    # -- steps of one update ------------------------------------------------------------------

    def _time_step(self, stamp: float) -> float:
        if self._last_stamp is None:
            return 0.0
        dt = stamp - self._last_stamp
        return dt if dt > 0 else 0.0

    def _sensor_points(self, scan: LaserScan) -> FloatArray:
        c = self.config
        lo = max(c.min_range, scan.range_min, np.nextafter(0.0, 1.0))
        hi = self._usable_range(scan)
        increment = scan.time_increment if c.deskew else 0.0
        vx, vy, w = self._motion.twist
        cos_a, sin_a = self._beam_directions(scan.angles)
        return usable_endpoints(scan.ranges, cos_a, sin_a, lo, hi, increment, vx, vy, w)

    def _usable_range(self, scan: LaserScan) -> float:
        return min(self.config.max_range, scan.range_max)

    def _matched(
        self, pts: FloatArray, keep: NDArray[np.bool_], scan: LaserScan
    ) -> tuple[FloatArray, NDArray[np.bool_]]:
        """The endpoints (and the kept ones among them) that are matched: those at least
        :attr:`OdometryConfig.matched_range_margin` short of the usable range. The map holds
        a wall only as far as earlier scans reached; moved on since the last fusion, the
        scan's farthest endpoints on a wall ahead fall past the map's end, whose edge pulls
        them, and the pose, back. Along a corridor longer than the range nothing else
        fixes the pose, and that pull stalled it (simulated URG-04LX, 5.6 m). All endpoints
        are still fused into the map."""
        limit = self._usable_range(scan) - self.config.matched_range_margin
        near = pts[:, 0] ** 2 + pts[:, 1] ** 2 <= limit * limit
        if near.all():
            return pts, keep
        pts = kept_rows(pts, near)
        return pts, subsample_by_spacing(pts, self.config.point_spacing)

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

    def _should_insert(self) -> bool:
        if self._last_inserted is None:
            return True
        d = between(self._last_inserted, self.pose)
        c = self.config
        return bool(math.hypot(d[0], d[1]) >= c.insert_distance or abs(d[2]) >= c.insert_angle)

    def _insert(self, pts: FloatArray, normals: FloatArray) -> None:
        c = self.config
        self._turn_submaps()
        centre = self.pyramid.finest.origin + 0.5 * c.map_size
        if np.max(np.abs(self.pose[:2] - centre)) > c.recenter_distance:
            for pyramid in self._maps():
                pyramid.recenter(self.pose[0], self.pose[1])
        if self._last_inserted is None:
            self._first_fused = (self.pose.copy(), pts, self._fill_angle())
        # densified along its surfaces: a scanner's beam pattern fused as measured makes
        # standing still score best
        at_rate = self._at_scanner_rate()
        tolerance = c.densify_tolerance if at_rate else None
        angle = c.dense_straight_angle if at_rate else c.straight_angle
        dense = densify_scan(pts, c.resolution, NORMAL_MAX_GAP, angle, tolerance)
        if dense.shape[0] != pts.shape[0]:
            pts, normals = dense, thinned_normals(dense)
        self._fuse(self.pose, pts, normals)
        self._last_inserted = self.pose.copy()
        self._fused_poses.append(self._last_inserted)

    def _fill_angle(self) -> float:
        """The ``straight_angle`` a scan is densified with when fused: ``dense_straight_angle``
        at the scanner's rate (:meth:`_at_scanner_rate`), else ``straight_angle`` (the first
        scan: :meth:`_densify_first` adds the rest once the second tells how far apart the
        scans are; fused with straight runs filled at once, a thinned corridor's second scan
        was placed 0.9 m off)."""
        c = self.config
        return c.dense_straight_angle if self._at_scanner_rate() else c.straight_angle

    def _at_scanner_rate(self) -> bool:
        """Something was fused and the scans are not sparse (:meth:`_sparse`,
        :meth:`_sparse_so_far`): the map is many scans of each wall, and a gap that cuts a
        corner is not needed to hold it (``densify_tolerance``). A thinned log's map is a
        few scans, where a door's edge seen by two beams, or a recess's corner, is all that
        fixes a step a metre on (a corridor with doors, a scan per metre: filled only where
        lines continue, the second scan stood still)."""
        return not (self._last_inserted is None or self._as_sparse())

    def _fuse(self, pose: FloatArray, pts: FloatArray, normals: FloatArray) -> None:
        static = self._not_in_known_free_space(pose, pts)
        for pyramid in self._maps():
            pyramid.insert_scan(pose, pts[static], self.config.max_range, normals[static])

    def _maps(self) -> list[MapPyramid]:
        """The map matched against and, on sparse scans, the one that will replace it."""
        return [self.pyramid] if self._young is None else [self.pyramid, self._young]

    def _turn_submaps(self) -> None:
        """On sparse scans, once the map holds walls twice, match against the scans of the
        last ``submap_travel`` metres only. Two maps are fused into (Cartographer's
        submaps): the older, matched against, and a younger one begun when the older has
        seen half of ``submap_travel``; once the older has seen all of it, the younger
        replaces it if a step was in doubt and the two maps disagreed on a scan since the
        last turn (:meth:`_maps_disagree`), and is begun anew otherwise. A wrong step puts
        the walls the map already holds a second time, a look-alike's length off, and later
        scans then jump between the two copies (the SICK maze thinned to a scan per metre:
        one wrong turn, then wrong steps on every revisit); a map made only of the scans
        since (or shortly before) it holds one copy.
        Otherwise the older map keeps everything: a thinned log tracked well gains from its
        revisits (freiburg-079 thinned to a scan per metre: RPE over 1 m 4.9 -> 5.6 cm
        when every map was replaced). Off unless ``submap_travel`` is set."""
        c = self.config
        if c.submap_travel <= 0 or self._last_inserted is None:
            return
        d = between(self._last_inserted, self.pose)
        moved = math.hypot(d[0], d[1])
        self._travel = [t + moved for t in self._travel]
        if not self._sparse():
            self._young = None
            return
        if self._young is None and self._travel[0] >= 0.5 * c.submap_travel:
            self._young, self._travel[1] = self._new_pyramid(), 0.0
            return
        grown = self._young is not None and self._travel[1] >= 0.25 * c.submap_travel
        if grown and self._doubts >= c.submap_doubts and not self._conflict:
            self._conflict = self._maps_disagree()
        if self._young is not None and self._travel[0] >= c.submap_travel:
            if self._conflict:
                self.pyramid = self._young
                self.num_submaps += 1
            self._travel = [self._travel[1], 0.0]
            self._young, self._doubts, self._conflict = self._new_pyramid(), 0, False

    def _maps_disagree(self) -> bool:
        """The last scan matched (Gauss-Newton, Eq. 3) on the younger map alone from the pose
        it was given lands farther than ``submap_conflict`` metres (or that at
        ``length_scale`` in heading) from it: the older map holds walls the recent scans put
        elsewhere."""
        c = self.config
        if c.submap_conflict <= 0:
            return True
        if self._young is None or self._matched_levels is None:
            return False
        level_pts, normals, facing = self._matched_levels
        pose, _ = match_scan_to_map(
            self._young, level_pts, self.pose, c.max_iterations, c.step_tolerance,
            c.length_scale, c.degeneracy_ratio, c.subcell_sigma, normals, c.search_prior_weight,
            facing=facing,
        )  # fmt: skip
        d = between(self.pose, pose)
        return bool(
            math.hypot(d[0], d[1]) > c.submap_conflict
            or abs(d[2]) * c.length_scale > c.submap_conflict
        )

    def _new_pyramid(self) -> MapPyramid:
        """An empty local map centred on the pose."""
        c = self.config
        pyramid = MapPyramid(c.resolution, c.map_size, c.levels, c.log_odds, origin=None)
        pyramid.recenter(self.pose[0], self.pose[1])
        return pyramid

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

    def _densify_first(self, dt: float) -> None:
        """The first scan, fused before anything told how far apart the scans are, gets the
        points densifying adds to those it was fused with (:func:`densify_scan`): with
        ``first_straight_angle`` if the second came after a gap (``gap_time``, a thinned
        log's seconds), else with ``dense_straight_angle``, as every later scan at the
        scanner's rate. Left as dots, the first scan is the whole map for the next ones,
        whose beams land on its dots only when placed back at the start: a SICK in a
        pillared hall, its walls 7-15 m away, stood still while the robot drove 15 m."""
        pose, pts, filled = self._first_fused
        self._first_fused = None
        c = self.config
        angle = c.dense_straight_angle if dt <= c.gap_time else c.first_straight_angle
        dense, added = densify_with_mask(pts, c.resolution, NORMAL_MAX_GAP, angle, filled)
        if added.any():
            self._fuse(pose, dense[added], thinned_normals(dense)[added])

    def _not_in_known_free_space(self, pose: FloatArray, pts: FloatArray) -> NDArray[np.bool_]:
        """Endpoints whose cell and its 8 neighbours several earlier scans saw free are taken
        for moving objects (a person) and not fused: fused, they leave a trail in the map
        that the next scans' points on the same person are pulled towards. (The neighbours
        keep the noisy endpoints in front of a wall, whose own cell the rays have freed.)"""
        world = transform_points(pose, pts)
        return self.pyramid.finest.above_near(world, self.config.free_logodds)

    # -- public -------------------------------------------------------------------------------

    def update(self, scan: LaserScan) -> FloatArray:
        """Match one scan and return Δp (3,) since the previous scan (zeros on the first)."""
        c = self.config
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
            matched, matched_keep = self._matched(pts, keep, scan)
            level_pts = points_per_level(matched, c.point_spacing, c.levels, matched_keep)
            if self._first_fused is not None:
                self._densify_first(dt)
            start = self._best_start(level_pts[-1], previous, predicted)
            normals = matched_normals(level_pts)
            self._matched_levels = (level_pts, normals, facing_normals(level_pts, normals))
            self.pose, self.last_report = self._match(
                level_pts, start, previous, normals, dt, predicted
            )
            if dt <= c.gap_time and not self.last_report.overruled:
                # after a gap the velocity is measured afresh, and where the map overruled
                # the motion prior, the scan measured it
                constraint = (
                    *self._mapped_constraint(level_pts[0], normals), self._axis_offset()
                )
            self.num_recovered += self.last_report.recovered
            self.num_degenerate += self.last_report.degenerate
            self.num_ambiguous += self.last_report.ambiguous
            self.num_broken += self.last_report.broken
            self._doubts += self.last_report.ambiguous or self.last_report.broken
        if not self.last_report.predicted_only and self._should_insert():
            # every endpoint is fused, each with the normal of the kept one before it
            self._insert(pts, thinned_normals(pts, keep))
            self.last_report.inserted = True
        if self.last_report.inserted and not self._scores:
            self._remember_score(self._score_at(self.pose, kept_rows(pts, keep)))
        self._motion.update(scan.stamp, self.pose, *(constraint or (1.0, None, None)))
        self._last_stamp = scan.stamp
        self._last_delta = between(previous, self.pose)
        return self._last_delta.copy()

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
        the odometry cannot vouch for (``MatchReport.broken``)."""
        return {
            "odometry_scans": self.num_scans,
            "odometry_recovered": self.num_recovered,
            "odometry_degenerate": self.num_degenerate,
            "odometry_predicted_only": self.num_predicted_only,
            "odometry_ambiguous": self.num_ambiguous,
            "odometry_broken": self.num_broken,
        }

    def _match(
        self, level_pts: list[FloatArray], start: FloatArray, previous: FloatArray,
        normals: FloatArray, dt: float, predicted: FloatArray,
    ) -> tuple[FloatArray, MatchReport]:
        """Eq. 3 from ``start`` (the motion model's prior, :meth:`_best_start`); when that
        cannot be trusted (:meth:`_untrusted`), also from the wide-basin search's winner and
        its rival and from the other motion hypotheses (the constant-velocity prediction,
        the last step repeated, the typical step straight on: after a turn on the spot in
        a log thinned to a scan per metre the first two say "turning", the last "a metre
        on"; on sparse scans also the step prior's typical steps, the searches' seeds and the
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
        gapless = dt <= c.gap_time  # the start is then a trusted prediction
        # the prior pulls towards the motion model's prediction, never a standstill it did not
        # predict (:meth:`_prior_target`)
        target = self._prior_target(start, previous, predicted, gapless)
        weight = self._prior_weight(dt)
        information = self._motion.prior_information(dt) if gapless else None
        self._axis_prior = (start if target is None else target, information)
        held = information if c.weak_axis_prior else None
        options = [self._option(level_pts, start, normals, weight, target, gapless, held)]
        if gapless:
            options[0] = self._unless_slipped(options[0], level_pts, start, normals, weight,
                                              target, held)  # fmt: skip
            if not np.array_equal(start, predicted):
                options[0] = self._unless_astray(options[0], level_pts, predicted, normals,
                                                 weight, target, held)  # fmt: skip
            options[0] = self._unless_reversed(options[0], level_pts, previous, normals)
        if weight > c.search_prior_weight:
            options[0] = self._unless_contradicted(
                options[0], level_pts, start, normals, gapless, dt
            )
        motion: tuple[FloatArray, ...] = (start,)  # only compared when the search ran
        jump = self._jump_limits()
        # a trusted prediction's match that jumped is searched as an untrusted one is: in a
        # spin its Gauss-Newton can slide into a look-alike basin tens of centimetres off
        searched = c.search_distance > 0 and (
            self._untrusted(options[0][2], dt, previous, start)
            or self._is_jump(options[0][0], start, jump)
        )
        if len(self._searched) == self._searched.maxlen:
            self._num_searched -= self._searched[0]
        self._searched.append(searched)
        self._num_searched += searched
        as_sparse = self._as_sparse()
        if searched:
            forward = compose(previous, np.array([self._typical_step, 0.0, 0.0]))
            motion = (start, predicted, compose(previous, self._last_delta), forward)
            if self._sparse():
                modes = self._step_prior.modes(c.step_modes)
                motion += tuple(compose(previous, m) for m in modes)
            # the next level's endpoints (twice as far apart) on the search level's grid
            points = level_pts[min(c.search_level + 1, c.levels - 1)]
            centre, distance, angle = self._search_window(start, (previous, *motion[1:]))
            # the typical step's window (:meth:`_typical_seeds`) searches the same pooled map
            typical = self._typical_window(forward, distance, angle) if as_sparse else ()
            seeds = self._search_seeds(
                points, centre, distance, angle, options[0][0],
                pooled_for=((centre, distance, angle), *typical),
            )  # fmt: skip
            lone = len(seeds) == 1
            seeds += self._typical_seeds(points, typical, seeds)
            options += self._weighed(level_pts, seeds, normals)
            settled = as_sparse and lone and self._settles(
                options[1], previous, level_pts[0], normals
            )
            if not settled:
                hypotheses = self._distinct_hypotheses(motion)
                seeds += hypotheses
                options += self._weighed(level_pts, hypotheses, normals)
            finer = self._finer_basins(level_pts, normals, seeds, options) if as_sparse else []
            self._weigh_walls([options[0], *finer], level_pts[0])
            options += finer
            if as_sparse:
                slid = self._slid(options, forward, level_pts[0], normals)
                options += self._weighed(level_pts, slid, normals, held=not self._step_prior.flat)
            for k, ring in enumerate(turned_windows(c.search_angle)):
                if (k > 0 or not all(self._hopeless(o, previous) for o in options)) and any(
                    self._credible(o, previous) for o in options
                ):
                    break  # a match that only failed its score: a room turned round fits better
                turns = [compose(previous, np.array([0.0, 0.0, a])) for a in ring]
                both = tuple((turn, c.search_distance, c.search_angle) for turn in turns)
                for turn in turns:  # the two windows of a ring share one pooled map
                    seeds = self._search_seeds(
                        points, turn, c.search_distance, c.search_angle, pooled_for=both
                    )
                    options += self._weighed(level_pts, seeds, normals)
        reach = (jump[0] + c.max_speed * dt, jump[1] + c.max_turn_rate * dt)
        if as_sparse and len(options) > 1:
            pose, report = self._choose_sparse(options, previous, reach, gapless)
        else:
            pose, report = self._choose(options, motion, previous, reach, jump, gapless)
        step = between(previous, pose)
        self._remember_miss(between(start, pose), step)
        if searched:  # the steps where the prediction was not trusted, as on sparse scans
            self._step_prior.add(step)

        report.iterations = sum(option[1].iterations for option in options)
        self._remember_score(report.score, report.free_fraction)
        return pose, report

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

    def _unless_slipped(
        self, option: tuple[FloatArray, MatchReport, bool], level_pts: list[FloatArray],
        start: FloatArray, normals: FloatArray, weight: float, target: FloatArray | None,
        held: float | None,
    ) -> tuple[FloatArray, MatchReport, bool]:
        """The match from a trusted prediction, unless the pyramid's descent carried it more
        than a finest cell away on a scan that constrains every direction, and put endpoints
        in known free space there: then the finest level's descent from the prediction
        alone, if it did not fail, ended in another basin with fewer endpoints in free
        space, and beside it the pyramid's match is not plausible
        (:meth:`_plausible_beside`). A scan that sees new ground through a door fits the
        coarse levels better a cell back, where its new walls land on walls seen before, and
        its cost was lower there on the finest level too (URG-04LX, simulated rooms, 10 Hz:
        a slip of 15-20 cm back each time the robot passed the same door of the repeating
        rooms, ATE 30 cm); the endpoints the slip puts where the map saw through tell the
        two apart. Along a direction the scan does not constrain :meth:`_unless_contradicted`
        decides (exp1, a corridor: a poor fit either way, and the finest level's descent
        there doubled the loop gap)."""
        pose, report, _ = option
        if not _contradicted_where_constrained(report) or not self._different_start(start, pose):
            return option
        iterations = levels_up_to(self.config.max_iterations, 0)
        alt_pose, alt = self._match_from(
            level_pts, start, normals, weight, target, False, held, iterations
        )
        return self._less_contradicted(option, (alt_pose, alt, self._failed(alt)), level_pts)

    def _unless_astray(
        self, option: tuple[FloatArray, MatchReport, bool], level_pts: list[FloatArray],
        predicted: FloatArray, normals: FloatArray, weight: float,
        target: FloatArray | None, held: float | None,
    ) -> tuple[FloatArray, MatchReport, bool]:
        """The match from a start :meth:`_best_start` preferred to the constant-velocity
        prediction (standing still, or the last step repeated: logged stamps jitter), unless
        it put endpoints in known free space on a scan that constrains every direction:
        then the match from the prediction where it is less contradicted
        (:meth:`_less_contradicted`). A robot that drives on at a steady 1.2 m/s in a
        corridor of the maze (SICK, 361 beams at 5 Hz) had its standstill fit the coarsest
        level better than the true step 24 cm on (the map holds the last scans' walls where
        their beams fell), and the match from there stayed: 15 % of its endpoints in free
        space, and the odometry stalled for good."""
        if not _contradicted_where_constrained(option[1]):
            return option
        alternative = self._option(level_pts, predicted, normals, weight, target, True, held)
        return self._less_contradicted(option, alternative, level_pts)

    def _unless_reversed(
        self, option: tuple[FloatArray, MatchReport, bool], level_pts: list[FloatArray],
        previous: FloatArray, normals: FloatArray,
    ) -> tuple[FloatArray, MatchReport, bool]:
        """The match from a trusted prediction on a scan that constrains every direction,
        unless it is contradicted (:meth:`_contradicted`): then the match from the last step
        undone where it is less contradicted (:meth:`_less_contradicted`). A robot that
        backs up is predicted on at its speed while it drives back, two steps from the
        truth, and Gauss-Newton's basin can be narrower than that (simulated hall of
        pillars, SICK 361 beams at 5 Hz, reversing at 0.5 m/s: the match stayed 0.2 m on,
        and the run was lost)."""
        if option[1].degenerate or not self._contradicted(option[1]):
            return option
        alternative = self._option(level_pts, compose(previous, inverse(self._last_delta)), normals)
        return self._less_contradicted(option, alternative, level_pts)

    def _less_contradicted(
        self, option: tuple[FloatArray, MatchReport, bool],
        alternative: tuple[FloatArray, MatchReport, bool], level_pts: list[FloatArray],
    ) -> tuple[FloatArray, MatchReport, bool]:
        """``alternative`` instead of ``option`` where it did not fail, ended in another
        basin with fewer endpoints in known free space, and beside it ``option`` is not
        plausible (:meth:`_plausible_beside`); else ``option``."""
        report, alt = option[1], alternative[1]
        if alternative[2] or alt.free_fraction >= report.free_fraction:
            return option
        if not self._different_start(alternative[0], option[0]):
            return option
        # weighed on a copy: the match kept stays as the rest of the step would see it
        weighed = (option[0], replace(report), option[2])
        self._weigh_walls([weighed, alternative], level_pts[0])
        if self._plausible_beside(weighed[1], alt):
            return option
        alt.restarted = True
        alt.iterations += report.iterations
        return alternative

    def _unless_contradicted(
        self, option: tuple[FloatArray, MatchReport, bool], level_pts: list[FloatArray],
        start: FloatArray, normals: FloatArray, restart: bool, dt: float,
    ) -> tuple[FloatArray, MatchReport, bool]:
        """The match held by the motion prior along a direction the scan hardly constrains,
        unless the map contradicts it: where it leaves endpoints in known free space, the
        match is repeated with the weak prior of a search's seed, and if the prior's match is
        not plausible beside it (``plausible_ratio`` of its quality) or that match explains
        the contradiction away (:meth:`_contradiction_explained`), the scan's evidence along
        that direction wins (``MatchReport.overruled``). Where the weak prior's match stays
        with the prior (on a plateau Gauss-Newton does not move), the match from the pose
        along the weak direction that leaves the fewest endpoints in free space
        (:meth:`_slid_out_of_free_space`) is weighed instead."""
        report = option[1]
        if not report.degenerate or report.free_fraction <= 0.0:
            return option
        free = self._option(level_pts, start, normals, restart=restart)
        if self._plausible_beside(report, free[1]) and not self._contradiction_explained(
            option, free
        ):
            free = self._slid_out_of_free_space(option, level_pts, normals, dt)
            if free is None or not self._contradiction_explained(option, free):
                return option
        free[1].overruled = True
        free[1].iterations += report.iterations
        return free

    def _slid_out_of_free_space(
        self, option: tuple[FloatArray, MatchReport, bool], level_pts: list[FloatArray],
        normals: FloatArray, dt: float,
    ) -> tuple[FloatArray, MatchReport, bool] | None:
        """Gauss-Newton from the pose along the contradicted match's weak direction, within
        what the robot can have moved against the prediction since the last scan (its
        speed plus ``max_speed``, times ``dt``; finest cells apart), whose endpoints fit best
        less their share in known free space; None where that is the match's own pose or
        the match is not contradicted (:meth:`_contradicted`). Along an aisle longer than
        the range the map function is flat where the prior put the pose, and a descent from
        there stays: the robot backing up at 0.5 m/s while the prior carried it forward
        (simulated warehouse, SICK) was 19 cm ahead when its endpoints first fell where the
        map saw through, and the weak prior's match stayed with it from the next scan on,
        10 cm a scan farther each time (2.2 m off after 3 s). Searched over the whole
        window instead, a pillared hall's look-alike 1.4 m back won (URG-04LX)."""
        c = self.config
        pose, report, _ = option
        if not self._contradicted(report):
            return None
        along = translation_part(report.degenerate_direction)
        if along is None:
            return None
        speed = math.hypot(self._motion.twist[0], self._motion.twist[1])
        reach = min((c.max_speed + speed) * dt, c.search_distance)
        cells = max(int(reach / c.resolution), 1)
        offsets = np.arange(-cells, cells + 1) * c.resolution
        poses = pose + offsets[:, None] * along
        points = level_pts[0]
        grid = self.pyramid.finest
        quality = np.array([
            self._score_at(p, points) - grid.fraction_not_above_near(p, points, c.free_logodds)
            for p in poses
        ])  # fmt: skip
        # among equals the offset nearest the prior's match
        best = int(np.argmax(quality - 1e-9 * np.abs(offsets)))
        if offsets[best] == 0.0:
            return None
        return self._option(level_pts, poses[best], normals)

    def _contradicted(self, report: MatchReport) -> bool:
        """The match put at least ``contradiction_factor`` times the run's typical share of
        its endpoints in known free space (and some)."""
        factor = self.config.contradiction_factor
        return factor > 0.0 and report.free_fraction > 0.0 and (
            report.free_fraction >= factor * self._typical_free
        )

    def _contradiction_explained(
        self, option: tuple[FloatArray, MatchReport, bool],
        alternative: tuple[FloatArray, MatchReport, bool],
    ) -> bool:
        """Whether ``alternative`` explains away a contradiction of the motion prior along
        the scan's weak direction: the prior's ``option`` is contradicted
        (:meth:`_contradicted`), and ``alternative`` did not fail, fitted better
        (:func:`_match_quality`) and put no more of its endpoints in known free space than
        is typical. A robot that reversed along an aisle longer than the range (simulated
        warehouse, SICK scanner: backing up at 0.5 m/s while the prior carried it forward)
        left 4.3 % of its prior's endpoints where the map saw through (2.2 % typical), the
        weak prior's match 19 cm back 2.2 % and a better fit, yet plausible beside it the
        prior's match was kept."""
        report, alt = option[1], alternative[1]
        return (
            not alternative[2]
            and self._contradicted(report)
            and alt.free_fraction <= self._typical_free
            and _match_quality(alt) > _match_quality(report)
        )

    def _plausible_beside(self, report: MatchReport, other: MatchReport) -> bool:
        """A match whose quality (:func:`_match_quality`) falls short of ``other``'s by at
        most ``1 - plausible_ratio`` of its size."""
        return _match_quality(report) >= self._plausible_floor(_match_quality(other))

    def _plausible_floor(self, quality: float) -> float:
        """The least quality plausible beside ``quality``: short of it by at most
        ``1 - plausible_ratio`` of its size (a quality can be negative)."""
        return quality - (1.0 - self.config.plausible_ratio) * abs(quality)

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
        without)."""
        c = self.config
        return c.prior_weight if dt <= c.gap_time else c.search_prior_weight

    def _weigh_walls(
        self, options: list[tuple[FloatArray, MatchReport, bool]], points: FloatArray
    ) -> None:
        """Each match's fraction of beams through known walls, the evidence that tells a pose
        a metre off along a corridor from the true one."""
        c = self.config
        for pose, report, _ in options:
            report.through_fraction = self.pyramid.finest.fraction_through_walls(
                pose, points, c.wall_logodds, c.through_margin
            )

    def _sparse(self) -> bool:
        """The wide-basin search ran for at least ``sparse_share`` of the recent scans (and
        of at least ``sparse_scans``): a thinned log or a low scan rate, where the motion
        model's prediction is no better than a guess."""
        c = self.config
        return self._num_searched >= c.sparse_share * max(len(self._searched), c.sparse_scans)

    def _hopeless(self, option: tuple[FloatArray, MatchReport, bool], previous: FloatArray) -> bool:
        """A match failed or rejected by the map, or, on sparse scans, a step unlike the
        recent ones (the step prior's density below ``implausible_density``)."""
        if option[2] or self._rejected(option[1]):
            return True
        return self._sparse() and self._implausible(between(previous, option[0]))

    def _credible(self, option: tuple[FloatArray, MatchReport, bool], previous: FloatArray) -> bool:
        """A match that may yet be the true step: not rejected by the map, its quality above
        what the step prior charges for its step (on sparse scans, where the prior weighs the
        matches; above none on dense ones), and not both failed and a step unlike the recent
        ones. A step like the recent ones that merely fits too little of a scan seeing new
        ground is credible. Not credible: a failed match 2.5 m and 60° off the typical step
        (freiburg-079 thinned to a scan per metre of path, a 147° turn between two scans: at
        quality 0.13 it kept the far ring unsearched and the run was lost), nor one that
        barely fits (quality 0.01) a step 1.4 m back and 39° off that the prior charges 0.22
        for (the warehouse's tour thinned by distance alone, seed 4: a turn of 50° out of the
        ±45° window, the turned windows never searched and the route lost)."""
        report = option[1]
        sparse = self._sparse()
        cost = self._step_cost(previous, option[0]) if sparse else 0.0
        if self._rejected(report) or _match_quality(report) - cost <= 0.0:
            return False
        implausible = sparse and self._implausible(between(previous, option[0]))
        return not (option[2] and implausible)

    def _implausible(self, step: FloatArray) -> bool:
        """The step prior's density of ``step`` is below ``implausible_density``: a step
        unlike the recent ones."""
        return self._step_prior.cost(step) > -math.log(self.config.implausible_density)

    def _choose_sparse(
        self, options: list[tuple[FloatArray, MatchReport, bool]],
        previous: FloatArray, reach: tuple[float, float], gapless: bool = False,
    ) -> tuple[FloatArray, MatchReport]:
        """On sparse scans: the match not rejected by the map with the best quality less
        ``step_prior_weight`` times the step prior's cost of its step. Where the scan cannot
        tell places apart, the step like the robot's recent ones wins; where it can, the
        scan does (the prior costs at most ``-log(step_prior.floor)`` times its weight).
        When every match the map does not reject has failed, all compete the same way: a
        match that slid off the map meets no evidence against it, but none for it either
        (intel from its 5th scan: a 19.8 m step was so kept). A match farther than the robot
        can have moved since the last scan (``reach``) falls back on the first, as in
        :meth:`_choose`, unless the first is rejected and it is clean and did not fail, and
        it turned no farther than the robot can have since the last scan or the scan came
        after a gap (not ``gapless``). A pose lost along a corridor is so found again, but
        a look-alike turned round is no recovery: scans at the scanner's rate match as
        sparse ones where the search ran for most of them, as on a revisit of a map a
        drift put a decimetre off, whose free space then rejects the true step, and a
        look-alike turned 180° in a tenth of a second was kept there (simulated warehouse,
        SICK, from the origin, seed 31).
        Where the scan leaves a direction free, the step prior picks among the matches along
        it that fit nearly as well (:meth:`_typical_on_plateau`).
        Flags the report ambiguous when a distinct match is plausible (``plausible_ratio``
        of the quality), recovered when it is not the first match."""
        c = self.config
        first = options[0]
        pool = [o for o in options if not self._rejected(o[1])]
        if all(o[2] for o in pool):  # no match both fits and is consistent with the map
            pool = options
        quality = {id(o): _match_quality(o[1]) for o in options}
        costs: dict[int, float] = {}  # the plateau and the broken-turn check ask again

        def cost(option: tuple[FloatArray, MatchReport, bool]) -> float:
            key = id(option)
            if key not in costs:
                costs[key] = self._step_cost(previous, option[0])
            return costs[key]

        def merit(option: tuple[FloatArray, MatchReport, bool]) -> float:
            return quality[id(option)] - cost(option)

        chosen = self._typical_on_plateau(max(pool, key=merit), pool, quality, cost)
        if chosen is not first and self._beyond(chosen[0], previous, reach) and (
            (gapless and abs(between(previous, chosen[0])[2]) > reach[1])  # turned beyond
            or not (self._rejected(first[1]) and self._clean(chosen[1]) and not chosen[2])
        ):
            chosen = first
        floor = self._plausible_floor(quality[id(chosen)])
        report = chosen[1]
        report.recovered = chosen is not first
        report.ambiguous = any(
            quality[id(o)] >= floor and self._distinct(o[0], chosen[0]) for o in pool
        )
        report.broken = report.score < c.break_score_ratio * self._typical_score or any(
            abs(between(chosen[0], o[0])[2]) > c.break_turn
            and merit(o) > merit(chosen) - c.break_margin
            for o in pool
            if not self._rejected(o[1])
        )
        return chosen[0], report

    def _typical_on_plateau(
        self, chosen: tuple[FloatArray, MatchReport, bool],
        pool: list[tuple[FloatArray, MatchReport, bool]], quality: dict[int, float],
        cost: Callable[[tuple[FloatArray, MatchReport, bool]], float],
    ) -> tuple[FloatArray, MatchReport, bool]:
        """Where the scan of the ``chosen`` match leaves a direction free (degenerate: a
        corridor whose ends are out of range), the match of ``pool`` along that direction
        from it whose step the step prior finds most typical (least ``cost``), among those
        within two finest cells of the line, not distinct from ``chosen`` (one place, not a
        look-alike a rack further on), neither failed nor rejected, and fitting nearly as
        well: a quality at least ``plausible_ratio`` of its, and less by at most
        ``plateau_slope`` per metre between them. Along such a plateau the fit varies by
        what the walls' sampling leaves, not by where the robot is: a 240° URG-04LX (5.6 m)
        thinned to a scan per metre took steps 0.1-0.5 m short down the maze's corridors,
        each fitting 0.01-0.03 better than the typical step, until the map held its walls
        twice (ATE 5.8 m, maze tour, seed 6). A SICK that sees corners within its range
        fits 0.6 less a metre off along the corridor, and its choice stands. While the
        step prior is flat it cannot tell the plateau's points apart."""
        report = chosen[1]
        if not report.degenerate or chosen[2] or self._step_prior.flat:
            return chosen
        c = self.config
        q = quality[id(chosen)]
        floor = self._plausible_floor(q)

        def on_plateau(option: tuple[FloatArray, MatchReport, bool]) -> bool:
            pose, found, failed = option
            if failed or self._rejected(found) or quality[id(option)] < floor:
                return False
            if self._distinct(pose, chosen[0]):
                return False
            drop = q - quality[id(option)]
            return drop <= c.plateau_slope * separation(pose, chosen[0])[0] and _off_line(
                pose, chosen[0], report.degenerate_direction, c.length_scale
            ) <= 2.0 * c.resolution

        plateau = [chosen, *(o for o in pool if o is not chosen and on_plateau(o))]
        return min(plateau, key=cost)

    def _step_cost(self, previous: FloatArray, pose: FloatArray) -> float:
        """The step prior's cost of the step from ``previous`` to ``pose``, weighed by
        ``step_prior_weight``; at an echo of a fused scan (:meth:`_echoes`) by
        ``echo_prior_weight``, and in full from the first steps (the prior's floor not
        raised while it knows few, :class:`bioslam.step_prior.StepPriorConfig`)."""
        c = self.config
        step = between(previous, pose)
        if c.echo_prior_weight is not None and self._echoes(pose):
            return c.echo_prior_weight * self._step_prior.cost(step, young=False)
        return c.step_prior_weight * self._step_prior.cost(step)

    def _echoes(self, pose: FloatArray) -> bool:
        """``pose`` is within a finest cell (and that at ``length_scale`` in heading) of a
        pose where one of the last ``echo_scans`` scans was fused: a scan placed there puts
        its beams where that scan's hit, and on a sparse map (a wall held only where the
        last scans' beams hit it) scores better for it than the true step does."""
        return any(not self._different_start(pose, f) for f in self._fused_poses)

    def _rejected(self, report: MatchReport) -> bool:
        """More endpoints in known free space than ``recovery_free_fraction``, or more
        beams through known walls than ``recovery_through_fraction``: a wrong pose,
        whatever its score."""
        c = self.config
        return (
            report.free_fraction > c.recovery_free_fraction
            or report.through_fraction > c.recovery_through_fraction
        )

    def _clean(self, report: MatchReport) -> bool:
        """Little negative evidence of either kind: at most ``recovery_free_fraction`` of
        endpoints in free space and beams through walls together."""
        c = self.config
        return report.free_fraction + report.through_fraction <= c.recovery_free_fraction

    def _untrusted(self, failed: bool, dt: float, previous: FloatArray, start: FloatArray) -> bool:
        """The match failed, the scan came after a gap, the predicted step is large, or this
        is the first match: the motion model knows no velocity yet and predicts standing
        still, which a log cut from a longer recording does not start with (a SICK at 5 Hz,
        1.2 m/s through a pillared hall: read as standing still from the first step)."""
        c = self.config
        step = between(previous, start)
        large = math.hypot(step[0], step[1]) > c.large_step or abs(step[2]) > c.large_turn
        return failed or dt > c.gap_time or large or self.num_scans == 2

    def _search_window(
        self, start: FloatArray, hold: tuple[FloatArray, ...]
    ) -> tuple[FloatArray, float, float]:
        """Centre and half-widths (metres, radians) of a window around ``start`` grown to
        hold the last pose (the first of ``hold``), and grown again for any other pose of
        ``hold`` (the motion hypotheses) outside it or in the outer fifth of its width: a
        log thinned to a scan per 1.5 m steps 2 m on, beyond a window around the last
        pose, and the typical step forward is then inside. (Grown for every hypothesis,
        the larger windows found look-alikes on logs whose steps they already held:
        intel from scan 7, RPE over 1 m 4.3 -> 5.9 cm.)"""
        c = self.config
        # in plain floats: up to twelve poses a scan, each a few array operations otherwise
        last = between(start, hold[0]).tolist()
        low, high = [min(0.0, v) for v in last], [max(0.0, v) for v in last]
        spare = [0.8 * c.search_distance, 0.8 * c.search_distance, 0.8 * c.search_angle]
        for h in hold[1:]:
            d = between(start, h).tolist()
            bounds = zip(d, low, high, spare, strict=True)
            if any(v < lo - m or v > hi + m for v, lo, hi, m in bounds):
                low = [min(lo, v) for lo, v in zip(low, d, strict=True)]
                high = [max(hi, v) for hi, v in zip(high, d, strict=True)]
        mid = np.array([0.5 * (lo + hi) for lo, hi in zip(low, high, strict=True)])
        half = [0.5 * (hi - lo) for lo, hi in zip(low, high, strict=True)]
        return compose(start, mid), c.search_distance + max(half[0], half[1]), (
            c.search_angle + half[2]
        )

    def _search_seeds(
        self, points: FloatArray, centre: FloatArray, distance: float, angle: float,
        hint: FloatArray | None = None,
        pooled_for: tuple[tuple[FloatArray, float, float], ...] = (),
    ) -> list[FloatArray]:
        """The wide-basin search's winner and, if it scores nearly as well, its rival, in
        the window of half-widths ``distance``, ``angle`` around ``centre`` (``hint``, the
        match from the prediction, only speeds the search up). The map is pooled for the
        windows ``pooled_for`` (centre, distance, angle; this one among them, or it alone
        when empty), so that later searches of this scan in the others find it pooled."""
        c = self.config
        window = WideBasinConfig(
            distance=distance,
            angle=angle,
            min_rival_ratio=c.rival_ratio,
            angular_cells=c.search_angular_cells,
            depth=c.search_depth,
        )
        if self._searcher.config != window:
            self._searcher.config = window
        grid = self.pyramid.grids[c.search_level]
        windows = list(pooled_for) or [(centre, distance, angle)]
        self._pool(grid, self._searcher.reach_box(points, windows, grid.resolution))
        found = self._searcher.search(points, centre, hint)
        seeds = [found.pose]
        if found.rival_pose is not None:
            seeds.append(found.rival_pose)
        return seeds

    def _pool(self, grid: OccupancyGrid, box: tuple[float, float, float, float]) -> None:
        """The searcher's pooled map of ``box`` of ``grid``, pooled again only when the grid,
        its content (:attr:`~bioslam.occupancy_grid.OccupancyGrid.insertions`), its origin or
        size, the box or the pooling depth changed: the two windows turned either way from
        the last pose share their box, and the pooling (0.7 ms on intel) ran twice on the
        scans that were slow already."""
        depth = self._searcher.depth_for(grid.resolution)
        key = (grid.insertions, *grid.origin.tolist(), *grid.shape, *box, depth)
        if self._pooled is not None and self._pooled[0] is grid and self._pooled[1] == key:
            return
        self._searcher.set_map(grid, box)
        self._pooled = (grid, key)

    def _typical_window(
        self, forward: FloatArray, distance: float, angle: float
    ) -> tuple[tuple[FloatArray, float, float], ...]:
        """The window (centre, distance, angle) around the typical step ``forward`` that
        :meth:`_typical_seeds` searches, beside a wide one of half-widths ``distance`` and
        ``angle``: ``typical_search_distance`` but no wider, the wide one's angle; none
        when the typical search is off."""
        c = self.config
        if c.typical_search_distance <= 0.0:
            return ()
        return ((forward, min(c.typical_search_distance, distance), angle),)

    def _typical_seeds(
        self, points: FloatArray, typical: tuple[tuple[FloatArray, float, float], ...],
        seeds: list[FloatArray],
    ) -> list[FloatArray]:
        """On sparse scans, the best lattice pose within the ``typical`` window
        (:meth:`_typical_window`, none: nothing) around the typical step forward, when every
        seed of the wide search is distinct from that step. The wide window's winner is the
        best fit on the search level; where a 180° scanner turns into a corridor it never
        saw, a look-alike a metre or more sideways fits as well as the true step, and the
        step prior, which tells them apart, can only weigh the matches it is shown
        (simulated maze, SICK, thinned to a scan per metre: a metre on with a 20° turn
        placed 1.6 m sideways, the true step never a candidate though it scored 0.35 as the
        look-alike did and cost less under the prior). The wide search pooled the map for
        this window too."""
        if not typical:
            return []
        forward, distance, _ = typical[0]
        if not all(self._distinct(s, forward) for s in seeds):
            return []
        wide = self._searcher.config
        depth = self._searcher.depth_for(self._searcher.resolution)
        # no rival: the seed is the prior's candidate, the wide search judged ambiguity
        self._searcher.config = replace(wide, distance=distance, min_rival_ratio=1.0)
        if self._searcher.depth_for(self._searcher.resolution) != depth:
            self._searcher.config = wide  # pooled for another depth: leave it to the wide
            return []
        found = self._searcher.search(points, forward).pose
        self._searcher.config = wide
        return [found] if all(self._distinct(found, s) for s in seeds) else []

    def _weighed(
        self, level_pts: list[FloatArray], seeds: list[FloatArray], normals: FloatArray,
        held: bool = False,
    ) -> list[tuple[FloatArray, MatchReport, bool]]:
        """Gauss-Newton from each of ``seeds`` (:meth:`_option`), each match's beams through
        known walls counted (:meth:`_weigh_walls`). ``held``: each is held where its seed
        put it along a direction its scan leaves free (:meth:`_held`, for the seeds
        :meth:`_slid` along such a direction)."""
        match = self._held if held else self._option
        found = [match(level_pts, seed, normals) for seed in seeds]
        self._weigh_walls(found, level_pts[0])
        return found

    def _held(
        self, level_pts: list[FloatArray], seed: FloatArray, normals: FloatArray
    ) -> tuple[FloatArray, MatchReport, bool]:
        """Gauss-Newton from ``seed`` held there along the direction its scan leaves free
        (:func:`~bioslam.matching.gauss_newton.match_scan_to_map` with no prior weight):
        (pose, report, failed). Let loose, a seed slid along a corridor to the typical step
        slid back to where the walls' sampling fits best, tens of centimetres short
        (:meth:`_typical_on_plateau`)."""
        pose, report = self._match_from(level_pts, seed, normals, None)
        return pose, report, self._failed(report)

    def _settles(
        self, option: tuple[FloatArray, MatchReport, bool], previous: FloatArray,
        points: FloatArray, normals: FloatArray,
    ) -> bool:
        """The wide search's winner (weighed, :meth:`_weighed`), found without a rival,
        settles the step on its own: it
        fits as well as the recent matches (its score at least ``plausible_ratio`` of their
        median), contradicts the map little (:meth:`_clean`), neither its scan nor the walls
        the map holds leave a direction free (:meth:`_free_direction`), and the step prior,
        once it has learnt something, finds its step like the recent ones (the learned
        density at least ``implausible_density``). The motion hypotheses and their finer
        basins are for the scans where the winner may be a look-alike, one point of a
        plateau, or a basin next to the true one; matched from every sparse scan, they made
        most of the Gauss-Newton runs on a thinned log (intel: 7 hypotheses a scan, 18 runs
        in all, half of them on the finer levels alone). A winner that merely was not
        rejected settled too often:
        a match 0.17 m ahead fitting 0.42 where a hypothesis's fitted 0.79 (the rooms'
        tour, SICK, thinned to a scan per metre, seed 2)."""
        c = self.config
        pose, report, failed = option
        typical = c.plausible_ratio * self._typical_score
        if failed or self._step_prior.flat or report.score < typical:
            return False
        return (
            self._clean(report)
            and self._step_prior.density(between(previous, pose)) >= c.implausible_density
            and self._free_direction(pose, report, points, normals) is None
        )

    def _finer_basins(
        self, level_pts: list[FloatArray], normals: FloatArray, seeds: list[FloatArray],
        options: list[tuple[FloatArray, MatchReport, bool]],
    ) -> list[tuple[FloatArray, MatchReport, bool]]:
        """Gauss-Newton from each of the searches' and the motion hypotheses' ``seeds`` on
        the levels up to the search level only, where it ends apart from every match in
        ``options``. A lattice pose of the search lies within a cell of the search level's
        best fit; the coarsest level's blur pulled it 0.2-0.25 m into a basin of the finer
        levels that fitted worse, and the pose then sat 0.2 m off for tens of scans (SICK,
        thinned to a scan per metre, rooms and maze, turns of 15-40°). A motion hypothesis
        (the typical step, the last one repeated) is as often such a start, and a pull of
        less than a search-level cell as often leaves the finer basin it started in (the
        rule before, only the searches' seeds pulled farther than a cell, did worse on 10 of
        48 thinned routes: benchmarks README, "The finer levels for every seed"). None while
        the step prior is flat: a further candidate is only as safe as the prior that
        weighs it against look-alikes (the warehouse of identical aisles, 5th scan: a finer
        basin 2 m back fitted 0.01 better than the true step a metre on, and four steps
        known could not tell the two apart)."""
        c = self.config
        if self._step_prior.flat:
            return []
        iterations = levels_up_to(c.max_iterations, c.search_level)
        found: list[tuple[FloatArray, MatchReport, bool]] = []
        for seed in seeds:
            pose, report = self._match_from(
                level_pts, seed, normals, c.search_prior_weight, iterations=iterations
            )
            if all(self._different_start(pose, o[0]) for o in options + found):
                found.append((pose, report, self._failed(report)))
        return found

    def _slid(
        self, options: list[tuple[FloatArray, MatchReport, bool]], forward: FloatArray,
        points: FloatArray, normals: FloatArray,
    ) -> list[FloatArray]:
        """Seeds: each sound match that its scan, or the walls of it the map holds, leave
        free along a direction (a corridor whose ends are out of sight, or not yet mapped),
        slid along it to the point nearest the typical step forward. On such a plateau the
        search's lattice winner is any of its points, and Gauss-Newton from there stays
        where it starts; the step prior, which can tell the plateau's points apart, weighs
        only the matches it is shown (simulated maze, SICK, thinned to a scan per metre,
        seed 4: a turn of 36° into a corridor placed 1.8 m along it, the plateau's point
        0.15 m from the truth fitting better and never a candidate). A 180° scanner that
        turns into a corridor sees its far end, which the map does not hold yet: the scan's
        geometry is sound, the map's pins nothing along the corridor
        (:func:`~bioslam.matching.gauss_newton.mapped_conditioning` below
        ``degeneracy_ratio``; seed 6: matches 0.5-2 m along it, the route lost, 6.4 m ATE).
        The Gauss-Newton normal matrix does not show it: the walls' texture, mapped from
        ranges with a centimetre of noise, curves the fit along them at 40-70 % of across
        them (measured on the corridor of ``tests/test_map_held_direction.py``)."""
        known = [option[0] for option in options]
        seeds: list[FloatArray] = []
        for pose, report, failed in options:
            if failed or self._rejected(report):
                continue
            free = translation_part(self._free_direction(pose, report, points, normals))
            if free is None:
                continue
            along = float(free[0] * (forward[0] - pose[0]) + free[1] * (forward[1] - pose[1]))
            seed = pose + along * free
            if all(self._different_start(seed, k) for k in known):
                seeds.append(seed)
                known.append(seed)
        return seeds

    def _free_direction(
        self, pose: FloatArray, report: MatchReport, points: FloatArray, normals: FloatArray
    ) -> FloatArray | None:
        """The direction (unit, (x, y, theta * length_scale), map frame) the scan leaves
        free (its degenerate one), or else the one the walls the map holds leave free at
        ``pose`` (:meth:`_slid`); None where both are constrained."""
        c = self.config
        if report.degenerate:
            return report.degenerate_direction
        level = 0.0 if c.mapped_logodds is None else c.mapped_logodds
        condition, weakest = mapped_conditioning(
            self.pyramid.finest, points, normals, pose, level, c.length_scale
        )
        return None if condition >= c.degeneracy_ratio else in_map_frame(weakest, pose[2])

    def _choose(
        self, options: list[tuple[FloatArray, MatchReport, bool]],
        motion: tuple[FloatArray, ...], previous: FloatArray, reach: tuple[float, float],
        jump: tuple[float, float], gapless: bool = False,
    ) -> tuple[FloatArray, MatchReport]:
        """The plausible match nearest the motion model's prior (``plausible_ratio``; the
        first of ``motion``, the start Gauss-Newton ran from), then the best of those in its
        basin; a jump (far from every motion hypothesis: the start, the constant-velocity
        prediction, the last step repeated) from the prediction's own match (the first option)
        must be overwhelming (``overwhelming_ratio``), and one farther than the robot can
        have moved since the last scan (``reach``) falls back on the first. Only after a
        gap (not ``gapless``: logged stamps jitter) may a clean match beyond reach replace
        a first match the map rejects; between scans at the scanner's rate the stamps hold,
        and on a revisit whose map an earlier pass put a few decimetres off, the rejected
        prediction was so replaced by a look-alike 1.4 m along a corridor, or turned 90
        degrees, in a tenth of a second (simulated URG-04LX, maze, 600 s, seeds 0 and 3).
        Flags the report ambiguous when a plausible match lies elsewhere, recovered when it
        is not the first match."""
        c = self.config
        first = options[0]
        if len(options) == 1:
            return first[0], first[1]
        quality = {id(o): _match_quality(o[1]) for o in options}
        pool = (
            [o for o in options if not (o[2] or self._rejected(o[1]))]
            or [o for o in options if not self._rejected(o[1])]
            or options
        )
        floor = self._plausible_floor(max(quality[id(o)] for o in pool))
        plausible = [o for o in pool if quality[id(o)] >= floor]
        nearest = min(plausible, key=lambda o: self._pose_distance(o[0], motion[0]))
        basin = [o for o in plausible if not self._distinct(o[0], nearest[0])]
        chosen = max(basin, key=lambda o: quality[id(o)])
        ambiguous = len(basin) < len(plausible)
        if chosen is not first and all(self._is_jump(chosen[0], m, jump) for m in motion):
            q_first = quality[id(first)]
            if not first[2] and q_first > c.overwhelming_ratio * quality[id(chosen)]:
                chosen, ambiguous = first, True  # a look-alike, not overwhelming evidence
            elif self._beyond(chosen[0], previous, reach) and (
                gapless or not (self._rejected(first[1]) and self._clean(chosen[1]))
            ):
                # farther than the robot can have moved since the last scan (after a gap,
                # logged stamps jitter: a clean match wins over a prediction the map rejects)
                chosen, ambiguous = first, True
        pose, report = chosen[0], chosen[1]
        report.recovered = chosen is not first
        report.ambiguous = ambiguous
        return pose, report

    def _distinct_hypotheses(self, motion: tuple[FloatArray, ...]) -> list[FloatArray]:
        """The motion hypotheses after the first (the start, already matched from) that
        are not the same start as it or each other (farther apart than a finest cell, or
        than a finest cell at ``length_scale`` in heading): Gauss-Newton starts from each
        too. Starts closer than the search's rival distance are not one start: on a
        sparse map the coarse levels slide a start a few decimetres off into a
        neighbouring basin while one 40 cm on stays in the true one (intel: the typical
        step forward, dropped as "not distinct" from a prediction 0.4 m short, was the
        right match; RPE over 1 m from scans 0-9 median 9.1 -> 7.4 cm with this alone)."""
        kept = [motion[0]]
        for m in motion[1:]:
            if all(self._different_start(m, k) for k in kept):
                kept.append(m)
        return kept[1:]

    def _different_start(self, a: FloatArray, b: FloatArray) -> bool:
        """Farther apart than a finest cell (or its width at ``length_scale`` in heading):
        Gauss-Newton from each may end in different places."""
        distance, turn = separation(a, b)
        c = self.config
        return distance > c.resolution or turn > c.resolution / c.length_scale

    def _pose_distance(self, a: FloatArray, b: FloatArray) -> float:
        distance, turn = separation(a, b)
        return distance + self.config.length_scale * turn

    def _distinct(self, a: FloatArray, b: FloatArray) -> bool:
        """Farther apart than the search's rival distance or angle: different places."""
        distance, turn = separation(a, b)
        cfg = self._searcher.config
        return distance > cfg.rival_distance or turn > cfg.rival_angle

    @staticmethod
    def _beyond(pose: FloatArray, previous: FloatArray, reach: tuple[float, float]) -> bool:
        d = between(previous, pose)
        return math.hypot(d[0], d[1]) > reach[0] or abs(d[2]) > reach[1]

    @staticmethod
    def _is_jump(pose: FloatArray, prior: FloatArray, jump: tuple[float, float]) -> bool:
        """Farther from a motion hypothesis ``prior`` than ``jump`` (metres, radians)."""
        d = between(prior, pose)
        return math.hypot(d[0], d[1]) > jump[0] or abs(d[2]) > jump[1]

    def _jump_limits(self) -> tuple[float, float]:
        """How far from the motion model a match may lie before it counts as a jump:
        ``jump_distance`` / ``jump_angle``, or ``jump_factor`` times the motion model's
        typical error over the last scans if that is larger (a log thinned to a scan per
        metre is predicted to within tens of centimetres and degrees at best; a 40 Hz
        scanner's to within millimetres, where the fixed limits hold)."""
        c = self.config
        return (
            max(c.jump_distance, c.jump_factor * self._typical_miss[0]),
            max(c.jump_angle, c.jump_factor * self._typical_miss[1]),
        )

    def _failed(self, report: MatchReport) -> bool:
        """Endpoints in known free space, or a score far below that of recent matches."""
        c = self.config
        if report.free_fraction > c.recovery_free_fraction:
            return True
        return report.score < c.recovery_score_ratio * self._typical_score

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

    def _score_at(self, pose: FloatArray, points: FloatArray) -> float:
        """Mean M* of ``points`` at ``pose`` on the finest level (the first scan's score on
        the map made from it is the reference until matches have been made)."""
        grid = grid_args(self.pyramid.finest, self.config.subcell_sigma)
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
        candidates = np.array([predicted, compose(previous, self._last_delta), previous])
        grid = grid_args(self.pyramid.grids[-1], self.config.subcell_sigma)
        facing = self._facing_of(coarse_pts)
        costs = pose_costs(grid, coarse_pts, facing, candidates)
        best = int(np.argmin(costs))
        if costs[best] < (1.0 - self.config.start_margin) * costs[0]:
            return candidates[best]
        return predicted

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
