"""Where to look when the prediction cannot be trusted (a gap in time, a large step, a failed
match, a thinned log): the wide-basin search's winner and rival in a window grown to hold the
motion hypotheses, the typical step's own window, the matches slid along a corridor, the
finer levels' basins, and the windows turned round the circle.

A mixin of :class:`bioslam.odometry.LidarOdometry` (Gauss-Newton from a start, and the match
choice's tests, :mod:`.choice`). No file or terminal I/O here.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from bioslam.geometry import between, compose, wrap_angle
from bioslam.matching.branch_and_bound import WideBasinConfig
from bioslam.matching.deskew import se2_exp
from bioslam.matching.gauss_newton import (
    FloatArray,
    MatchReport,
    in_map_frame,
    levels_up_to,
    mapped_conditioning,
)
from bioslam.motion_model import translation_part
from bioslam.occupancy_grid import MapPyramid, OccupancyGrid
from bioslam.odometry_config import OdometryConfig
from bioslam.step_prior import along_axis


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


class WideSearch:
    """The starts, beyond the prediction, that Gauss-Newton runs from on an untrusted scan."""

    config: OdometryConfig
    pyramid: MapPyramid
    _last_dt: float

    def _searched_options(
        self, options: list[tuple[FloatArray, MatchReport, bool]], level_pts: list[FloatArray],
        normals: FloatArray, start: FloatArray, previous: FloatArray, predicted: FloatArray,
        as_sparse: bool,
    ) -> tuple[FloatArray, ...]:
        """Add to ``options`` (the prediction's match first) the matches from the wide-basin
        search's winner and rival, the typical step's window and the arc to the winner's
        heading (on sparse scans, :meth:`_arc_seeds`), the motion
        hypotheses unless the lone winner settles the step, the finer levels' basins and the
        matches slid along a free direction (on sparse scans), and the turned windows'
        (:meth:`_turned_options`). Returns the motion hypotheses: the start, the
        constant-velocity prediction, the last step repeated, the typical step forward and
        on sparse scans the step prior's typical steps."""
        c = self.config
        forward = compose(previous, self._typical_straight_on(self._typical_step, 0.0))
        motion = (start, predicted, self._step_repeated(previous), forward)
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
        if as_sparse:
            seeds += self._arc_seeds(seeds[0], previous, (*seeds, *motion))
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
        self._turned_options(options, points, level_pts, normals, previous)
        return motion

    def _turned_options(
        self, options: list[tuple[FloatArray, MatchReport, bool]], points: FloatArray,
        level_pts: list[FloatArray], normals: FloatArray, previous: FloatArray,
    ) -> None:
        """Add to ``options`` the matches from the windows turned about ``2 * search_angle``
        either way from ``previous`` while every match so far is hopeless or none credible,
        and then from the rings further round the circle while none is credible
        (:func:`turned_windows`); on sparse scans also from the arc to each window's winner's
        heading (:meth:`_arc_seeds`)."""
        c = self.config
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
                if self._as_sparse():
                    known = (*seeds, *(o[0] for o in options))
                    seeds += self._arc_seeds(seeds[0], previous, known)
                options += self._weighed(level_pts, seeds, normals)

    def _untrusted(self, failed: bool, dt: float, previous: FloatArray, start: FloatArray) -> bool:
        """The match failed, the scan came after a gap, the predicted step is large, this
        is the first match (the motion model knows no velocity yet and predicts standing
        still, which a log cut from a longer recording does not start with: a SICK at 5 Hz,
        1.2 m/s through a pillared hall was read as standing still from the first step), or
        on sparse scans (:meth:`_as_sparse`) the last interval was a gap: the velocity
        predicted with is then a thinned log's last step over its seconds, no prediction,
        however soon this scan came. Half a second after a step of 0.85 m in two seconds, a
        robot that spun 40° on the spot was predicted 0.2 m on, and Gauss-Newton from there
        slid 50° the other way, into a junction's look-alike that nothing searched
        (simulated maze, SICK with 5 % of beams lost, three people, weaving route thinned
        to a scan per metre and 0.6 rad, seed 52: lost, 3.8 m). (Every sparse scan
        searched kept a dense log sparse for good: its first scans are searched.)"""
        c = self.config
        step = between(previous, start)
        large = math.hypot(step[0], step[1]) > c.large_step or abs(step[2]) > c.large_turn
        first = self._first_match()
        after_gap = not self._gapless(self._last_dt) and self._as_sparse()
        return failed or not self._gapless(dt) or large or first or after_gap

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

    def _arc_seeds(
        self, seed: FloatArray, previous: FloatArray, known: tuple[FloatArray, ...]
    ) -> list[FloatArray]:
        """The end of the circular arc of the typical step's length from ``previous`` to
        the heading of the search's winner ``seed``: where a wheeled robot that drives while
        it turns (:meth:`~bioslam.step_prior.StepPrior.turning_length` at least half the
        typical step, or no such turn known yet) ends a step with that turn. Where a thinned
        log's robot turns a corner into a corridor, the search finds the new heading, but a
        scan looking down the corridor places itself as well a metre or two back along it,
        where the map holds the walls it saw, as at the true step; those look-alikes leave
        endpoints in known free space and the step prior prices their steps, but they win
        when Gauss-Newton never started near the true step (simulated maze, SICK, thinned
        by distance alone, seed 5: ATE 8.1 m -> 0.6 cm).

        None where the arc ends in the same place as the typical step straight on
        (:meth:`_distinct`: a motion hypothesis already), nor where one of ``known`` is the
        same start (:meth:`_different_start`), nor for a robot that turns on the spot. The
        small turns' arcs added points a metre along a corridor that the step prior then
        preferred to a shorter true step fitting better (maze, adversarial route, SICK,
        thinned to a scan per metre and 0.6 rad, seeds 2 and 7: ATE 1.1 -> 4.3 and 4.0 ->
        9.4 cm); arcs for a robot that turns on the spot are steps it does not take (intel,
        200 scans from each of its first ten scans: 10 steps off by more than 20 cm, 19 with
        them). Thinned battery (``benchmarks/README.md``, "A corner's arc"): 39 of 218
        routes lost, 37 with the arcs.
        """
        length = self._typical_step
        if length <= 0.0:
            return []
        turn = wrap_angle(float(seed[2] - previous[2]))
        arc = compose(previous, self._typical_straight_on(length, turn))
        if not self._distinct(arc, compose(previous, self._typical_straight_on(length, 0.0))):
            return []  # the cheap test first: it rules out most scans' arcs
        turning = self._step_prior.turning_length(turn)
        if turning is not None and turning < 0.5 * length:
            return []
        return [arc] if all(self._different_start(arc, k) for k in known) else []

    def _typical_straight_on(self, length: float, turn: float) -> FloatArray:
        """The step of a robot that drives ``length`` metres along the circular arc that
        turns it by ``turn`` radians, in the scan's frame: along the driving axis the step
        prior learnt (:attr:`~bioslam.step_prior.StepPrior.axis`, a scanner mounted facing
        backwards sees the robot drive away from its forward axis)."""
        return along_axis(se2_exp((length, 0.0, turn)), self._step_prior.axis)

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
