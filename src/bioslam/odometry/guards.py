"""The match from a trusted prediction, checked against the map before it is kept: where it
slipped into a neighbouring basin, strayed from the constant-velocity prediction, missed a
reversal, or was held by the motion prior where the map contradicts it, a match from another
start that the map contradicts less replaces it.

A mixin of :class:`bioslam.odometry.LidarOdometry` (Gauss-Newton from a start,
``_option`` / ``_match_from``, and the match choice's tests, :mod:`.choice`). No file or
terminal I/O here.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from bioslam.geometry import compose, inverse
from bioslam.matching.gauss_newton import FloatArray, MatchReport, levels_up_to
from bioslam.motion_model import translation_part
from bioslam.occupancy_grid import MapPyramid
from bioslam.odometry.choice import match_quality, off_line
from bioslam.odometry_config import OdometryConfig


def _contradicted_where_constrained(report: MatchReport) -> bool:
    """A match on a scan that constrains every direction that puts endpoints in known free
    space (along a direction the scan does not constrain, the motion prior's match is
    judged by :meth:`LidarOdometry._unless_contradicted` instead)."""
    return not report.degenerate and report.free_fraction > 0.0


class PredictionGuards:
    """The trusted prediction's match, unless the map says it is wrong."""

    config: OdometryConfig
    pyramid: MapPyramid
    _typical_score: float

    def _guarded_option(
        self, level_pts: list[FloatArray], start: FloatArray, previous: FloatArray,
        normals: FloatArray, dt: float, predicted: FloatArray,
        prior: tuple[FloatArray | None, float, float | None],
    ) -> tuple[FloatArray, MatchReport, bool]:
        """Gauss-Newton from ``start`` with the motion ``prior`` (its target, weight and held
        information, :meth:`_motion_prior`), (pose, report, failed); after no gap (a trusted
        prediction) unless it slipped, strayed from the prediction or missed a reversal, and
        with the prior's full weight unless the map contradicts it along the scan's weak
        direction (the ``_unless_*`` checks)."""
        target, weight, held = prior
        gapless = self._gapless(dt)
        option = self._option(level_pts, start, normals, weight, target, gapless, held)
        if gapless:
            option = self._unless_slipped(option, level_pts, start, normals, weight, target,
                                          held)  # fmt: skip
            if not np.array_equal(start, predicted):
                option = self._unless_astray(option, level_pts, start, previous, predicted,
                                             normals, weight, target, held)  # fmt: skip
            option = self._unless_reversed(option, level_pts, previous, normals)
        if weight > self.config.search_prior_weight:
            option = self._unless_contradicted(option, level_pts, start, normals, gapless, dt)
        return option

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
        start: FloatArray, previous: FloatArray, predicted: FloatArray, normals: FloatArray,
        weight: float, target: FloatArray | None, held: float | None,
    ) -> tuple[FloatArray, MatchReport, bool]:
        """The match from a start :meth:`_best_start` preferred to the constant-velocity
        prediction (standing still, or the last step repeated: logged stamps jitter), unless
        it put endpoints in known free space on a scan that constrains every direction:
        then the match from the prediction, and from the last step repeated, where it is
        less contradicted (:meth:`_less_contradicted`). A robot that drives on at a steady
        1.2 m/s in a corridor of the maze (SICK, 361 beams at 5 Hz) had its standstill fit
        the coarsest level better than the true step 24 cm on (the map holds the last scans'
        walls where their beams fell), and the match from there stayed: 15 % of its
        endpoints in free space, and the odometry stalled for good. The prediction alone
        fails where the robot has just stopped turning: it turns on (a UTM-30LX log kept at
        every 20th scan, 2 Hz, out of a corner of the maze: 14° too far), and its match was
        no better, while the last step repeated is the step the robot made (the odometry
        stood still for two steps, 0.5 m behind, and the places made there were that far
        off for the closures)."""
        if not _contradicted_where_constrained(option[1]):
            return option
        for other in (predicted, self._step_repeated(previous)):
            if np.array_equal(other, start):
                continue
            alternative = self._option(level_pts, other, normals, weight, target, True, held)
            option = self._less_contradicted(option, alternative, level_pts)
        return option

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
        and the run was lost). Where the map says nothing of free space (a corridor's walls
        fit both ways), a score that dropped (:meth:`_score_dropped`) asks the same, and
        the match from the last step undone wins only where its own score did not drop
        (on a short-range scanner's noisy scores, a match a metre back that fitted a little
        better, 0.69 against 0.59 where 0.84 is typical, was a look-alike)."""
        if option[1].degenerate:
            return option
        contradicted = self._contradicted(option[1])
        if not (contradicted or self._score_dropped(option[1])):
            return option
        alternative = self._option(level_pts, compose(previous, inverse(self._last_delta)), normals)
        if not contradicted and self._score_dropped(alternative[1]):
            return option  # the step undone fits no better than the drop
        return self._less_contradicted(option, alternative, level_pts, strictly=contradicted)

    def _less_contradicted(
        self, option: tuple[FloatArray, MatchReport, bool],
        alternative: tuple[FloatArray, MatchReport, bool], level_pts: list[FloatArray],
        strictly: bool = True,
    ) -> tuple[FloatArray, MatchReport, bool]:
        """``alternative`` instead of ``option`` where it did not fail, ended in another
        basin with fewer endpoints in known free space (not ``strictly``: no more), and
        beside it ``option`` is not plausible (:meth:`_plausible_beside`); else ``option``."""
        report, alt = option[1], alternative[1]
        if alternative[2] or alt.free_fraction > report.free_fraction:
            return option
        if strictly and alt.free_fraction == report.free_fraction:
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
        unless the map contradicts it: where it leaves endpoints within the scan's own range
        in known free space (:meth:`_free_in_own_reach`: the match is judged by those), the
        match is repeated with the weak prior of a search's seed, and if the prior's match is
        not plausible beside it (``plausible_ratio`` of its quality) or that match explains
        the contradiction away (:meth:`_contradiction_explained`), the scan's evidence along
        that direction wins (``MatchReport.overruled``), as far as the robot can have moved
        against the prediction since the last scan (:meth:`_overrules`). Where the weak
        prior's match stays with the prior (on a plateau Gauss-Newton does not move) or went
        beyond that reach, the match from the pose along the weak direction that leaves the
        fewest endpoints in free space (:meth:`_slid_out_of_free_space`) is weighed
        instead."""
        report = option[1]
        if not report.degenerate or report.free_fraction <= 0.0:
            return option
        points = level_pts[0]
        own = self._free_in_own_reach(option[0], report, points)
        if own == 0:
            return option
        # the prior's match judged by the endpoints within the scan's own range alone
        judged = (option[0], replace(report, free_fraction=own / points.shape[0]), option[2])
        free = self._option(level_pts, start, normals, restart=restart)
        if not self._overrules(judged, free, dt, unless_plausible=True):
            free = self._slid_out_of_free_space(judged, level_pts, normals, dt)
            if free is None or not self._overrules(judged, free, dt):
                return option
        free[1].overruled = True
        free[1].iterations += report.iterations
        return free

    def _free_in_own_reach(self, pose: FloatArray, report: MatchReport, points: FloatArray) -> int:
        """How many of the scan's endpoints ``points`` (sensor frame, those ``report``'s
        ``free_fraction`` counted at ``pose``) within its own matched range
        (:meth:`_own_reach`) lie in known free space there: the report's count less the
        endpoints beyond that range it counted, the only ones looked up again. Those matched beyond
        it because one of the last fusions mapped their place are fitted, but lie where that
        scan's beams ended or grazed, at the edge of what it swept: a cell freed there says
        little against the motion prior. Five such endpoints 4.9-5.1 m behind a URG-04LX
        (5.6 m) driving down a corridor of the maze overruled the prior 0.16 m forward, the
        speed so measured was twice the robot's, and the corridor carried it on (ATE 2.15 m;
        7.1 cm where neither they nor stray endpoints at the reach's edge overrule it,
        :meth:`_contradiction_explained`; the maze's odometry before the fused reach 4.4)."""
        free = round(report.free_fraction * points.shape[0])
        beyond = ~self._own_reach(points)
        if not beyond.any():
            return free
        seen = self._not_in_known_free_space(pose, points[beyond])
        return free - int(np.count_nonzero(~seen))

    def _overrules(
        self, option: tuple[FloatArray, MatchReport, bool],
        alternative: tuple[FloatArray, MatchReport, bool], dt: float,
        unless_plausible: bool = False,
    ) -> bool:
        """Whether ``alternative`` replaces the motion prior's contradicted ``option``: it lies
        within a scan's reach of it (:meth:`_within_reach`), along the direction the scan does
        not constrain (within a finest cell of that line: the scan's evidence wins there only;
        an overrule 0.25 m back and 2.3° round, whose speed the corridor carried, lost the
        URG-04LX maze tour seed 12, ATE 99.6 -> 35.2 cm), and explains the contradiction away
        (:meth:`_contradiction_explained`), or, ``unless_plausible``, the prior's match is not
        plausible beside it."""
        if not self._within_reach(option[0], alternative[0], dt):
            return False
        direction = option[1].degenerate_direction
        c = self.config
        if off_line(alternative[0], option[0], direction, c.length_scale) > c.resolution:
            return False
        if unless_plausible and not self._plausible_beside(option[1], alternative[1]):
            return True
        return self._contradiction_explained(
            option, alternative, clipped=self._at_reach_edge(option[0], alternative[0], dt)
        )

    def _slid_out_of_free_space(
        self, option: tuple[FloatArray, MatchReport, bool], level_pts: list[FloatArray],
        normals: FloatArray, dt: float,
    ) -> tuple[FloatArray, MatchReport, bool] | None:
        """Gauss-Newton from the pose along the contradicted match's weak direction, within
        what the robot can have moved against the prediction since the last scan
        (:meth:`_weak_reach`; finest cells apart), whose endpoints fit best
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
        cells = max(int(self._weak_reach(dt) / c.resolution), 1)
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

    def _weak_reach(self, dt: float) -> float:
        """How far the robot can have moved against the motion model's prediction in ``dt``
        seconds (its speed plus ``max_speed``; at most ``search_distance``)."""
        c = self.config
        speed = math.hypot(self._motion.twist[0], self._motion.twist[1])
        return min((c.max_speed + speed) * dt, c.search_distance)

    def _at_reach_edge(self, pose: FloatArray, other: FloatArray, dt: float) -> bool:
        """``other`` lies within a finest cell of the edge of :meth:`_weak_reach` from
        ``pose``: where the reach, not the scan's evidence, stopped the match."""
        apart = math.hypot(other[0] - pose[0], other[1] - pose[1])
        return apart > self._weak_reach(dt) - self.config.resolution

    def _within_reach(self, pose: FloatArray, other: FloatArray, dt: float) -> bool:
        """``other`` lies within :meth:`_weak_reach` of ``pose``: where the scan's evidence
        may move the prior's match along a direction it hardly constrains. Beyond it, a
        weak prior's match took a few endpoints at a corridor's end for 5.8 m/s of speed
        (URG-04LX, maze, 10 Hz: 0.58 m in a scan, and the speed so measured carried the
        pose 0.24 m a scan on)."""
        return math.hypot(other[0] - pose[0], other[1] - pose[1]) <= self._weak_reach(dt)

    def _stray(self, report: MatchReport) -> bool:
        """Fewer than ``contradiction_points`` of the match's endpoints in known free space:
        as many as a beam grazing a wall's end puts there."""
        return round(report.free_fraction * report.num_points) < self.config.contradiction_points

    def _contradicted(self, report: MatchReport) -> bool:
        """The match put at least ``contradiction_factor`` times the run's typical share of
        its endpoints in known free space, and at least ``contradiction_points`` of them."""
        c = self.config
        return c.contradiction_factor > 0.0 and report.free_fraction > 0.0 and (
            report.free_fraction >= c.contradiction_factor * self._typical_free
            and not self._stray(report)
        )

    def _walls_contradict(self, pose: FloatArray, report: MatchReport, points: FloatArray) -> bool:
        """With ``search_contradicted``, the match at ``pose`` of a scan that constrains every
        direction is contradicted (:meth:`_contradicted`), with at least
        ``search_free_fraction`` of its endpoints in known free space, even without the
        endpoints (``points``, the finest level's) of the objects that moved
        (:meth:`_moving_objects`): people walking put endpoints where the map saw free
        space at the right pose too, a wrong match puts walls there."""
        c = self.config
        # the share counted without the moving objects is at most the report's: most
        # contradictions end here, before the objects are looked for
        if (
            not c.search_contradicted
            or report.degenerate
            or report.free_fraction < c.search_free_fraction
            or not self._contradicted(report)
        ):
            return False
        free = ~self._not_in_known_free_space(pose, points)
        free &= ~self._moving_objects(pose, points)
        share = float(np.mean(free))
        return share >= c.search_free_fraction and self._contradicted(
            replace(report, free_fraction=share)
        )

    def _score_dropped(self, report: MatchReport) -> bool:
        """Whether a match on a scan that constrains every direction scores below
        ``search_score_drop`` of the recent matches' median: it fits what the scan shares
        with the map (a corridor's walls) and misses the rest (its doors and corners, where
        the prediction carried the pose on past a reversal)."""
        drop = self.config.search_score_drop
        return drop > 0.0 and not report.degenerate and report.score < drop * self._typical_score

    def _contradiction_explained(
        self, option: tuple[FloatArray, MatchReport, bool],
        alternative: tuple[FloatArray, MatchReport, bool], clipped: bool = False,
    ) -> bool:
        """Whether ``alternative`` explains away a contradiction of the motion prior along
        the scan's weak direction: the prior's ``option`` is contradicted
        (:meth:`_contradicted`), and ``alternative`` did not fail, fitted better
        (:func:`.match_quality`) and put no more of its endpoints in known free space than
        is typical, or fewer than ``contradiction_points`` and at most half the prior's where
        the reach did not stop it (not ``clipped``, :meth:`_at_reach_edge`). In a clean world
        none is typical: a robot speeding up from 0.65 to 1.2 m/s along an aisle, the weak
        prior's match right with 1-2 stray endpoints against the prior's 5-16, was never let
        overrule it, and the run was lost; a 3.5 m scanner's match 0.10 m on, 1 against 3,
        took back a lag of 8 cm (simulated parking deck). But stray endpoints at the reach's
        edge are evidence that would carry the pose farther than the robot can have gone: a
        match 0.25 m back, the whole reach, left 1 against the true pose's 3 (a wall 4.5-4.9
        m off that an earlier pass along the maze's corridor mapped a little elsewhere) and
        taught a URG-04LX's motion model -0.3 m/s against a true 0.5, which the corridor
        carried on. A robot that reversed along an aisle longer than the range (simulated
        warehouse, SICK scanner: backing up at 0.5 m/s while the prior carried it forward)
        left 4.3 % of its prior's endpoints where the map saw through (2.2 % typical), the
        weak prior's match 19 cm back 2.2 % and a better fit, yet plausible beside it the
        prior's match was kept."""
        report, alt = option[1], alternative[1]
        return (
            not alternative[2]
            and self._contradicted(report)
            and (
                alt.free_fraction <= self._typical_free
                or (
                    not clipped
                    and self._stray(alt)
                    and 2.0 * alt.free_fraction <= report.free_fraction
                )
            )
            and match_quality(alt) > match_quality(report)
        )

    def _plausible_beside(self, report: MatchReport, other: MatchReport) -> bool:
        """A match whose quality (:func:`.match_quality`) falls short of ``other``'s by at
        most ``1 - plausible_ratio`` of its size."""
        return match_quality(report) >= self._plausible_floor(match_quality(other))

    def _plausible_floor(self, quality: float) -> float:
        """The least quality plausible beside ``quality``: short of it by at most
        ``1 - plausible_ratio`` of its size (a quality can be negative)."""
        return quality - (1.0 - self.config.plausible_ratio) * abs(quality)
