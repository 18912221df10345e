"""Which match a scan keeps: the plausible match nearest the motion model's prior on dense
scans, the best fit less the step prior's cost on sparse ones, a jump only on overwhelming
evidence, and the tests of a match every caller shares (failed, rejected by the map, distinct
from another).

A mixin of :class:`bioslam.odometry.LidarOdometry`. No file or terminal I/O here.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from bioslam.geometry import between, separation, wrap_angle
from bioslam.matching.gauss_newton import FloatArray, MatchReport, in_map_frame
from bioslam.motion_model import ConstantVelocityModel
from bioslam.occupancy_grid import MapPyramid, OccupancyGrid
from bioslam.odometry_config import OdometryConfig


def match_quality(report: MatchReport) -> float:
    """Mean M* over the matched endpoints, less the fraction of them in known free space
    (negative evidence: the map saw through where the match puts a wall) and the fraction of
    beams that pass through a known wall (the scan saw through where the map has one)."""
    return quality_with_score(report, report.score)


def quality_with_score(report: MatchReport, score: float) -> float:
    """:func:`match_quality` of ``report`` with ``score`` for its mean M* (the fit measured
    another way or on another map)."""
    return score - report.free_fraction - report.through_fraction


def off_line(
    pose: FloatArray, origin: FloatArray, direction: FloatArray, length_scale: float
) -> float:
    """How far ``pose`` lies from the line through ``origin`` along ``direction`` (unit,
    (x, y, theta * length_scale), as ``MatchReport.degenerate_direction``)."""
    offset = np.array([
        pose[0] - origin[0], pose[1] - origin[1], length_scale * wrap_angle(pose[2] - origin[2])
    ])  # fmt: skip
    return float(np.linalg.norm(offset - (offset @ direction) * direction))


class MatchChoice:
    """The match kept among those a scan's starts led to."""

    config: OdometryConfig
    pyramid: MapPyramid
    _first_twinned: OccupancyGrid | None
    _motion: ConstantVelocityModel
    _matched_levels: tuple[list[FloatArray], FloatArray, list[FloatArray]] | None

    def _failed(self, report: MatchReport) -> bool:
        """Endpoints in known free space, or a score far below that of recent matches."""
        c = self.config
        if report.free_fraction > c.recovery_free_fraction:
            return True
        return report.score < c.recovery_score_ratio * self._typical_score

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
        if self._rejected(report) or match_quality(report) - cost <= 0.0:
            return False
        implausible = sparse and self._implausible(between(previous, option[0]))
        return not (option[2] and implausible)

    def _implausible(self, step: FloatArray) -> bool:
        """The step prior's density of ``step`` is below ``implausible_density``: a step
        unlike the recent ones."""
        return self._step_prior.cost(step) > -math.log(self.config.implausible_density)

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
        fused = self._last_fused(self.config.echo_scans)
        return any(not self._different_start(pose, f) for f in fused)

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
        There a jump by a match that failed too is no evidence either, and the first is
        kept (freiburg-079 at 898.3 s, every contradicted match searched: two scans with
        42 % of their endpoints in known free space wherever matched, a match 0.68 m on
        that scored 0.28 where 0.7 is typical kept, then undone). Flags the report
        ambiguous when a plausible match lies elsewhere, recovered when it is not the first
        match."""
        c = self.config
        first = options[0]
        if len(options) == 1:
            return first[0], first[1]
        quality = {id(o): match_quality(o[1]) for o in options}
        pool = (
            [o for o in options if not (o[2] or self._rejected(o[1]))]
            or [o for o in options if not self._rejected(o[1])]
            or options
        )
        chosen, ambiguous = self._nearest_plausible(pool, motion[0], quality)
        if (
            chosen is not first
            and all(self._is_jump(chosen[0], m, jump) for m in motion)
            and not self._undoes_slide(first, chosen)
        ):
            q_first = quality[id(first)]
            if not first[2] and q_first > c.overwhelming_ratio * quality[id(chosen)]:
                chosen, ambiguous = first, True  # a look-alike, not overwhelming evidence
            elif chosen[2] and gapless:
                chosen, ambiguous = first, True  # a failed match is no evidence of a jump
            elif self._beyond(chosen[0], previous, reach) and (
                gapless or not (self._rejected(first[1]) and self._clean(chosen[1]))
            ):
                # farther than the robot can have moved since the last scan (after a gap,
                # logged stamps jitter: a clean match wins over a prediction the map rejects)
                chosen = self._kept_within_reach(
                    first, pool, previous, reach,
                    lambda near: self._nearest_plausible(near, motion[0], quality)[0],
                )  # fmt: skip
                ambiguous = True
        pose, report = chosen[0], chosen[1]
        report.recovered = chosen is not first
        report.ambiguous = ambiguous
        return pose, report

    def _nearest_plausible(
        self, pool: list[tuple[FloatArray, MatchReport, bool]], prior: FloatArray,
        quality: dict[int, float],
    ) -> tuple[tuple[FloatArray, MatchReport, bool], bool]:
        """Of ``pool``, the plausible match (``plausible_ratio`` of the best ``quality``, keyed
        by ``id``) nearest ``prior``, then the best in its basin; and whether a plausible
        one lies elsewhere."""
        floor = self._plausible_floor(max(quality[id(o)] for o in pool))
        plausible = [o for o in pool if quality[id(o)] >= floor]
        nearest = min(plausible, key=lambda o: self._pose_distance(o[0], prior))
        basin = [o for o in plausible if not self._distinct(o[0], nearest[0])]
        return max(basin, key=lambda o: quality[id(o)]), len(basin) < len(plausible)

    def _kept_within_reach(
        self, first: tuple[FloatArray, MatchReport, bool],
        pool: list[tuple[FloatArray, MatchReport, bool]], previous: FloatArray,
        reach: tuple[float, float],
        pick: Callable[
            [list[tuple[FloatArray, MatchReport, bool]]], tuple[FloatArray, MatchReport, bool]
        ],
    ) -> tuple[FloatArray, MatchReport, bool]:
        """The match kept where the chosen one lies beyond ``reach``: the prior's own
        (``first``), unless it failed or the map rejects it and ``pool`` holds matches within
        reach that did neither, then the one of those that ``pick`` picks, as the chooser
        would have among them. A look-alike beyond reach outscoring the true step must not
        hand the pose to a failed match: in a pillar hall a 180° scanner turning on the spot
        (7.7° a scan) was matched from the standstill the motion model predicted with 0.035
        of its endpoints on the map and 38 % in free space, the turn found within 2.9 cm at
        0.66, and a look-alike 1.65 m off at 0.86 set the floor that left only itself
        plausible; the standstill kept, the odometry lost 63° over the turn."""
        if not (first[2] or self._rejected(first[1])):
            return first
        near = [
            o for o in pool
            if not (o[2] or self._rejected(o[1]) or self._beyond(o[0], previous, reach))
        ]  # fmt: skip
        return pick(near) if near else first

    def _undoes_slide(
        self, first: tuple[FloatArray, MatchReport, bool],
        chosen: tuple[FloatArray, MatchReport, bool],
    ) -> bool:
        """Whether ``chosen`` takes back a slide that the prior's match ``first`` shows: the
        walls contradict ``first`` (at least ``search_free_fraction`` of its endpoints in
        known free space, :meth:`_contradicted`), ``chosen`` explains that away
        (:meth:`_contradiction_explained`), neither failed, and ``chosen`` lies along the
        direction ``first``'s scan pins least, within two finest cells of that line. While a
        corridor's ends were out of sight the pose could not follow the robot along it, so
        where the walls come back into view the pose may be off along it by more than the
        robot moves in a scan, and the match that finds it again is no jump. A robot that
        turned on the spot into a library's aisle and drove off along it (URG-04LX, 5.6 m)
        was left 0.8 m behind; the search found the true pose with no endpoint in free space
        against the prior's 7 %, and the jump rule put it back, the pose lagging 0.8 m with
        10 % of its endpoints in free space for nine scans more."""
        c = self.config
        report = first[1]
        # (the explanation asks that ``chosen`` did not fail and the walls contradict ``first``)
        if first[2] or report.free_fraction < c.search_free_fraction:
            return False
        if not self._contradiction_explained(first, chosen):
            return False
        weak = in_map_frame(report.weakest_direction, float(first[0][2]))
        return off_line(chosen[0], first[0], weak, c.length_scale) <= 2.0 * c.resolution

    def _choose_sparse(
        self, options: list[tuple[FloatArray, MatchReport, bool]],
        previous: FloatArray, reach: tuple[float, float], gapless: bool = False,
    ) -> tuple[FloatArray, MatchReport]:
        """:meth:`_sparse_choice` by :func:`match_quality`; while the map is a thinned log's
        first scan alone, the choice by :meth:`_quality_on` its twinned map where it lands
        elsewhere (farther apart than a finest cell, :meth:`_different_start`)."""
        first_map = self._first_twinned
        if first_map is not None:
            twinned = self._sparse_choice(
                options, previous, reach, gapless, lambda o: self._quality_on(first_map, o)
            )
            plain = self._sparse_choice(options, previous, reach, gapless)
            return twinned if self._different_start(twinned[0], plain[0]) else plain
        return self._sparse_choice(options, previous, reach, gapless)

    def _sparse_choice(
        self, options: list[tuple[FloatArray, MatchReport, bool]],
        previous: FloatArray, reach: tuple[float, float], gapless: bool = False,
        quality_of: Callable[[tuple[FloatArray, MatchReport, bool]], float] | None = None,
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
        it turned no farther than the robot can have since the last scan and lies within
        that reach across the robot's motion (:meth:`_beyond_motion`), or the scan came after a
        gap (not ``gapless``). A pose lost along a corridor is so found again, but
        a look-alike turned round is no recovery: scans at the scanner's rate match as
        sparse ones where the search ran for most of them, as on a revisit of a map a
        drift put a decimetre off, whose free space then rejects the true step, and a
        look-alike turned 180° in a tenth of a second was kept there (simulated warehouse,
        SICK, from the origin, seed 31). Nor is the parallel corridor of a maze 1.4 m to the
        side, which a URG-04LX among four people took in a tenth of a second (adversarial
        route, seed 64: two such jumps, full ATE 66.7 cm; 33.7 without them).
        Where the scan leaves a direction free, the step prior picks among the matches along
        it that fit nearly as well (:meth:`_typical_on_plateau`). A match the walls contradict
        gives way to one that explains the contradiction away
        (:meth:`_unless_explained_away`).
        Flags the report ambiguous when a distinct match is plausible (``plausible_ratio``
        of the quality), recovered when it is not the first match. ``quality_of``: a match's
        quality (default :func:`match_quality` of its report)."""
        c = self.config
        first = options[0]
        pool = [o for o in options if not self._rejected(o[1])]
        if all(o[2] for o in pool):  # no match both fits and is consistent with the map
            pool = options
        # the place by the walls' extent, unless the caller judges on a map of its own
        place_quality = self._place_quality() if quality_of is None else None
        quality_of = quality_of or (lambda o: match_quality(o[1]))
        quality = {id(o): quality_of(o) for o in options}
        costs: dict[int, float] = {}  # the plateau and the broken-turn check ask again

        def cost(option: tuple[FloatArray, MatchReport, bool]) -> float:
            key = id(option)
            if key not in costs:
                costs[key] = self._step_cost(previous, option[0])
            return costs[key]

        def merit(option: tuple[FloatArray, MatchReport, bool]) -> float:
            return quality[id(option)] - cost(option)

        best = self._at_place(pool, merit, cost, place_quality)
        chosen = self._typical_on_plateau(best, pool, quality, cost, previous)
        chosen = self._unless_explained_away(chosen, pool, merit)
        if chosen is not first and self._beyond(chosen[0], previous, reach) and (
            (gapless and self._beyond_motion(previous, chosen[0], reach))
            or not (self._rejected(first[1]) and self._clean(chosen[1]) and not chosen[2])
        ):
            chosen = self._kept_within_reach(
                first, pool, previous, reach, lambda near: max(near, key=merit)
            )
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
        report.vetoed = any(
            abs(between(chosen[0], o[0])[2]) > c.break_turn and merit(o) > merit(chosen)
            for o in options
            if self._rejected(o[1])
        )
        return chosen[0], report

    def _unless_explained_away(
        self, chosen: tuple[FloatArray, MatchReport, bool],
        pool: list[tuple[FloatArray, MatchReport, bool]],
        merit: Callable[[tuple[FloatArray, MatchReport, bool]], float],
    ) -> tuple[FloatArray, MatchReport, bool]:
        """``chosen``, unless the walls contradict it and a match of ``pool`` explains that
        away (:meth:`_contradiction_explained`: a better fit without the endpoints in known
        free space); then the best of those by ``merit``. The step prior is there to choose
        among matches the scan cannot tell apart, and these it can: down a street of
        identical blocks, a robot that sped off from 0.5 to 1.1 m/s after 208 s had its first
        fast step (0.88 m, no endpoint in free space, quality 0.72) lose to a match 0.41 m
        on, like the 0.4 m steps the prior knew, with 6 % of its endpoints where the map saw
        through (0.56); every scan after was matched half a step short until the pose was a
        block's pitch behind (360° SICK thinned to 1.25 Hz, held-out seed 464). Where the
        map around the robot has drifted, the true step is the contradicted one, and a
        look-alike can explain it away: the hall's URG-04LX weaving route thinned to a scan
        per metre (seed 3), 0.38 m off along the hall, was lost so. Of 572 odometry
        benchmark routes two tracked ones were lost and two lost ones found again; eight
        tracked ones came out better, two worse (``benchmarks/README.md``)."""
        if not self._contradicted(chosen[1]):
            return chosen  # most scans: nothing to explain
        explained = [
            o for o in pool if o is not chosen and self._contradiction_explained(chosen, o)
        ]
        return max(explained, key=merit) if explained else chosen

    def _place_quality(self) -> Callable[[tuple[FloatArray, MatchReport, bool]], float] | None:
        """:func:`match_quality` of a match with, for its mean map value, the share of its
        endpoints within a cell of a wall (the cell or one of its eight neighbours above
        ``place_logodds``); None when ``place_logodds`` is None or no scan is being
        matched."""
        level = self.config.place_logodds
        if level is None or self._matched_levels is None:
            return None
        grid, points = self.pyramid.finest, self._matched_levels[0][0]

        def quality(option: tuple[FloatArray, MatchReport, bool]) -> float:
            near = 1.0 - grid.fraction_not_above_near(option[0], points, level)
            return quality_with_score(option[1], near)

        return quality

    def _at_place(
        self, pool: list[tuple[FloatArray, MatchReport, bool]],
        merit: Callable[[tuple[FloatArray, MatchReport, bool]], float],
        cost: Callable[[tuple[FloatArray, MatchReport, bool]], float],
        place_quality: Callable[[tuple[FloatArray, MatchReport, bool]], float] | None,
    ) -> tuple[FloatArray, MatchReport, bool]:
        """The match of ``pool`` of best ``merit`` (quality less step cost) among those at
        the place where ``place_quality`` less the step cost is best (not distinct from
        that match); the best by ``merit`` when ``place_quality`` is None.

        The mean map value says how sure the map is of the walls a match puts its
        endpoints on, and a map is surest where the robot has been: walls fused from near
        and often. A corridor's walls ahead, seen from its mouth at a grazing angle, are
        held by few hits between the misses of beams passing along them. Turning into a
        corridor on a log thinned to a scan per metre, a match 0.7 m short put the scan's
        walls on the part fused from near and fitted 0.746 against the true step's 0.602,
        and the route was lost there (a ring corridor's diagonal, SICK, seed 131: 4 m at
        worst), while the share of endpoints within a cell of a wall was the same for both
        (0.928 against 0.934). That share says where the scan's walls are, not how often
        they were seen: it picks the place. Within it, the mean map value's finer slope
        picks the match (by the share alone, the routes held lost a few centimetres
        each, 2.6 -> 2.8 cm median over the thinned battery)."""
        if place_quality is None:
            return max(pool, key=merit)
        place = max(pool, key=lambda o: place_quality(o) - cost(o))
        return max((o for o in pool if not self._distinct(o[0], place[0])), key=merit)

    def _quality_on(
        self, grid: OccupancyGrid, option: tuple[FloatArray, MatchReport, bool]
    ) -> float:
        """:func:`match_quality` of a match with its score measured on ``grid``: a thinned
        log's first scan's map with the walls on both sides of the cell edges they run along
        (``_first_twinned``, :meth:`~bioslam.odometry.LidarOdometry._densify_first`). One
        scan holds a wall that runs along a cell edge on one side of it or the other, where
        each of its beams landed; the second scan, placed back where the first was taken,
        lands its beams on the same cells, and standing still outscored the true step a
        metre on (the maze's top corridor, a scan per metre and 0.6 rad, seed 51: 0.573
        against 0.570 on the tour, 0.501 against 0.470 turning 7° on the weaving route;
        lost from the start). Only the choice is made so: the matches themselves, and the
        map, are as before."""
        points = self._matched_levels[0][0]
        return quality_with_score(option[1], self._score_at(option[0], points, grid))

    def _typical_on_plateau(
        self, chosen: tuple[FloatArray, MatchReport, bool],
        pool: list[tuple[FloatArray, MatchReport, bool]], quality: dict[int, float],
        cost: Callable[[tuple[FloatArray, MatchReport, bool]], float], previous: FloatArray,
    ) -> tuple[FloatArray, MatchReport, bool]:
        """Where the scan of the ``chosen`` match leaves a direction free (degenerate: a
        corridor whose ends are out of range), the match of ``pool`` along that direction
        from it whose step the step prior finds most typical (least ``cost``, plus
        ``step_prior_weight`` times its length's cost for its turn,
        :meth:`~bioslam.step_prior.StepPrior.length_cost`), among those
        within two finest cells of the line, not distinct from ``chosen`` (one place, not a
        look-alike a rack further on), neither failed nor rejected, and fitting nearly as
        well: a quality at least ``plausible_ratio`` of its, and less by at most
        ``plateau_slope`` per metre between them. Along such a plateau the fit varies by
        what the walls' sampling leaves, not by where the robot is: a 240° URG-04LX (5.6 m)
        thinned to a scan per metre took steps 0.1-0.5 m short down the maze's corridors,
        each fitting 0.01-0.03 better than the typical step, until the map held its walls
        twice (ATE 5.8 m, maze tour, seed 6). A SICK that sees corners within its range
        fits 0.6 less a metre off along the corridor, and its choice stands. While the
        step prior is flat it cannot tell the plateau's points apart. Where the step turns
        unlike every recent one, its cost is the floor's all along the plateau, and how far
        the recent steps that turned as far went decides: a SICK thinned to a scan per
        metre and 0.6 rad turned 27° into a corridor it had not seen, and the match 0.6 m
        short (0.644) was taken for the true step (0.639) by a cost 0.002 lower (maze
        tour, seed 6: lost, 4.7 m; at most 0.48 m off with the lengths)."""
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
            return drop <= c.plateau_slope * separation(pose, chosen[0])[0] and off_line(
                pose, chosen[0], report.degenerate_direction, c.length_scale
            ) <= 2.0 * c.resolution

        plateau = [chosen, *(o for o in pool if o is not chosen and on_plateau(o))]
        if len(plateau) == 1:
            return chosen
        lengths = self._step_prior.length_cost
        weight = c.step_prior_weight
        return min(plateau, key=lambda o: cost(o) + weight * lengths(between(previous, o[0])))

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

    def _beyond_motion(
        self, previous: FloatArray, pose: FloatArray, reach: tuple[float, float]
    ) -> bool:
        """Whether the step from ``previous`` to ``pose`` turned farther than ``reach`` or lies
        farther than it across the direction the robot was moving in (the motion model's
        velocity; any way for a robot that stood still). A pose the odometry lost slides
        along that direction, where a corridor's ends are out of sight: the search may find
        it again farther than the robot moves between two scans. Across it the walls held
        every step, and a match there beyond reach is a look-alike, as is one turned
        round."""
        step = between(previous, pose)
        if abs(step[2]) > reach[1]:
            return True
        vx, vy = float(self._motion.twist[0]), float(self._motion.twist[1])
        speed = math.hypot(vx, vy)
        if speed < 1e-6:
            return math.hypot(step[0], step[1]) > reach[0]
        along = np.array([vx / speed, vy / speed, 0.0])
        return off_line(step, np.zeros(3), along, 0.0) > reach[0]

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
