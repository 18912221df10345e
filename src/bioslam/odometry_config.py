"""The LiDAR odometry's settings (:class:`OdometryConfig`), each with what it is for and the
measurements behind its default; the odometry itself is :mod:`bioslam.odometry`.

No file or terminal I/O here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from bioslam.occupancy_grid import LogOddsConfig
from bioslam.step_prior import StepPriorConfig

__all__ = ["OdometryConfig"]


@dataclass
class OdometryConfig:
    """Parameters of :class:`LidarOdometry` (defaults and where they come from).

    Attributes:
        resolution: finest map cell, metres. Hector SLAM's default ``map_resolution`` (0.05 m).
        levels: map pyramid levels, each twice as coarse. Hector's ``map_multi_res_levels``
            (3); the coarsest cell (0.2 m) sets the capture range of the matcher.
        map_size: side of the square local window, metres. Larger than the usable range of
            most indoor 2D LiDARs (Hector's 1024 cells x 0.05 m = 51 m is of the same order).
        recenter_distance: the window scrolls when the robot is this far from its centre,
            metres; a quarter of the window keeps at least ``map_size / 4`` of map around it.
        max_range: endpoints farther than this are not used, metres (beyond it a 0.25° beam
            spacing leaves gaps of more than a finest cell; also bounded by the window).
        min_range: endpoints closer than this are dropped (the robot's own body), metres.
        body_reach, body_turn: directions of the scan that the robot's own body blocks are
            learned and dropped (:mod:`bioslam.odometry.body_hits`): a range shorter than
            ``body_reach`` metres that stays the same while the robot turns ``body_turn``
            radians, half of it each way. ``body_reach`` 0 learns none.
        insert_distance, insert_angle: a scan is fused into the map when the pose has moved
            this far (metres, radians) from the last fused pose. Hector fuses at 0.4 m / 0.9
            rad; we fuse more often because a small field of view needs the map refreshed
            when turning (measured in ``benchmarks/bench_odometry.py``).
        point_spacing: matching uses endpoints at least this far apart along the scan, per
            level multiplied by the level's coarseness (2^k); keeps the cost bounded for dense
            scans at no measurable accuracy cost (benchmark). Metres.
        max_iterations: Gauss-Newton iterations per level, finest first (Hector runs a few
            per level; more are cheap because a converged level stops early).
        step_tolerance: stop a level when the step is below this fraction of the level's
            cell (and that divided by ``length_scale``, radians): a coarse level only has to
            bring the pose into the next level's basin. At 0.05 (2.5 mm at the finest level)
            the maze's RPE is that of 0.002 with a third fewer iterations (benchmark).
        length_scale: metres that make a radian commensurate with a metre when judging how
            well-conditioned the problem is (a typical indoor endpoint distance).
        degeneracy_ratio: a direction whose curvature is below this fraction of the strongest
            is weakly constrained (a corridor): the report flags it, and a motion prior
            pulls the pose along it towards the prediction, with a weight of ``prior_weight``
            times the scan's mean curvature times how far below the ratio it is
            (:func:`bioslam.matching.gauss_newton.match_scan_to_map`): in a featureless
            corridor the pose follows the prediction, in a warehouse aisle the uprights
            still count (a hard hold there: ATE 5.9 m; the prior: 2.6 cm, SICK 600 s).
            ``prior_weight`` 0.2: with 0.0005 the pull of the map's edge ahead beat the prior
            along a corridor longer than a 5.6 m range and the pose stalled; 1.0 overrode a
            warehouse aisle's uprights (ATE 41 cm on 300 s; 1.4 cm at 0.2). 0.05 since the
            prior pulls towards the prediction rather than a standstill start
            (:meth:`LidarOdometry._prior_target`): at 0.2, twenty times what an aisle's
            uprights pull, the pose lagged a robot speeding up along an aisle by up to 2.8 m
            and locked onto the uprights a bay back (warehouse, UTM-30LX, adversarial route,
            3600 s: ATE 64.5 cm; 0.37 cm at 0.05; SICK tour 600 s 5.4 -> 0.75 cm).
            ``search_prior_weight`` replaces it for a match from a search's seed and after a
            gap (``gap_time``), where the start is no motion prediction worth the name.
        mapped_logodds: the motion model learns its velocity along a direction from the
            endpoints the matched pose puts on walls the map holds (a finest cell or one of
            its 8 neighbours above this log-odds: hit more often than seen through) only: a
            corridor's end just come into range is not in the map yet and fixes nothing
            against it. None: from every endpoint.
        matched_range_margin: endpoints within this many metres of the usable range (the
            smaller of ``max_range`` and the scanner's) are fused into the map but not
            matched: the map holds a wall only as far as earlier scans reached, and the
            farthest endpoints of a scan taken since fall past that end, whose edge pulls the
            pose back. At least ``insert_distance`` plus the coarsest level's kernel (two of
            its cells): 0.4 m still stalled in the simulated maze with a 5.6 m scanner.
        fused_reach_scans: ... unless they lie as far short of the range of a pose one of the
            last ``fused_reach_scans`` scans was fused at (0: the current pose alone): that
            scan's beams mapped the place, and the margin leaves the coarsest kernel and the
            prediction's error. Behind and beside a robot that moved on lie the walls it saw
            from nearer. A 3.5 m scanner (ROBOTIS LDS-01) otherwise matched only its nearest
            2.9 m, and turning at the end of a lane between pillars 5 m apart it matched
            nothing (simulated hall, tour, seed 0: lost by 11.4 m). Eight fusions are 1.6 m
            of travel at ``insert_distance``. A margin of 0.4 m from those poses held the
            lanes as well but lost a SICK backing up along an aisle (2.8 m; 0.5 m held it):
            endpoints that near the map's edge feel its pull. Off on sparse scans.
        grazing_ratio, grazing_gap, grazing_condition: at the scanner's rate, while the
            last match's conditioning was below ``grazing_condition`` (a corridor pinned
            along its axis by a few endpoints at its doors: 0.002-0.05 where the pose
            stalled), an endpoint whose gaps to both neighbours continue one line and are
            longer than ``grazing_gap`` metres and than ``grazing_ratio`` times the arc its
            beams span there (a beam meeting a wall within 9.6° of grazing at 6:
            :func:`bioslam.matching.registration.grazing_endpoints`) is fused into the map
            but not matched. Such beams sample a wall ahead metres apart, and the map holds
            the wall as the dots the last fused scans' beams left, since the robot moves on
            by less than their spacing between fusions; matched, the few of them pull the
            pose back to where those scans were taken, the speed carried decays with it,
            and along a corridor longer than the range the pose stops (a 2 m corridor with
            a door niche every 4 m, a 181-beam 180° scanner: 4.4 m behind after 40 m; a
            ring of 100 m corridors, SICK: 18 m ATE). Where the scan pins every direction
            better they are matched: their pull along the wall is outweighed there, and
            their lever arm holds the heading (left out on every scan at a ratio of 4 and
            from 0.5 m, the maze's UTM-30LX weaving route at 40 Hz turned up to 0.15° a
            scan more: ATE 0.7 -> 2.5 cm; up to a conditioning of 0.1, a 360° scanner
            driving the maze's junctions at 1.2 m/s jumped 42 cm back). Not on sparse
            scans: each is fused, a metre or more from the last, and its far endpoints are
            what its searches and the step chooser weigh (thinned intel: ATE 8.25 -> 13.0
            cm with them left out there). ``grazing_gap`` is far beyond the reach of the
            coarsest level's kernels (0.2 m cells), and a real scan's clutter is sampled
            closer (left out from 0.1 m, freiburg-079 7.03 -> 7.55 cm). Fewer left out
            than this (a gap from 0.5 m, a ratio of 4) and the simulated maze and
            warehouse runs took other turns, a test route among them each time (a SICK
            among people walking: 4.2 m off at worst; backing up an aisle: 2.8 m). None:
            every endpoint is matched.
        constrained_ratio, accel_noise, velocity_noise, velocity_spread: the motion model's
            velocity along a scan's weakest direction (:mod:`bioslam.motion_model`): taken
            from the scan as measured at or above ``constrained_ratio`` conditioning, carried
            on at or below ``degeneracy_ratio``, Kalman-filtered between (its variance grows
            by ``accel_noise`` m/s² per second up to ``velocity_spread`` m/s squared, a
            measurement's is ``velocity_noise`` m/s squared over the scan's gain); a slip of
            the pose along a corridor then no longer stops the prediction, and a carried
            velocity that more scans in a row contradict than slips can explain gives way
            to theirs (:meth:`~bioslam.motion_model.ConstantVelocityModel.update`).
        sideways_noise: when positive, the motion model also takes it that a wheeled robot
            does not slip sideways (lateral velocity 0, this many m/s standard deviation,
            :func:`bioslam.motion_model.sideways_along`), and the prior along a degenerate
            direction pulls towards the motion model's prediction whatever start
            :meth:`LidarOdometry._best_start` chose (the last step repeated starts a spin
            well, but carries its slide along the corridor on). In a corridor longer than
            the range a robot that stops, then turns on the spot, is then seen to stand
            still: carried on, its speed slid the pose along the corridor for the whole
            turn. Off by default (0): it tells nothing driving along the corridor, and on
            the simulated routes it helped as often as it hurt (``benchmarks/README.md``,
            "Along the weak direction"). A scanner mounted off the axle moves sideways in a
            turn: this noise must cover the turn rate times the offset.
        weak_point_noise, weak_axis_prior: when ``weak_point_noise`` (metres, an endpoint's
            standard deviation along its normal) is positive, the velocity along a
            degenerate direction is a position-and-velocity Kalman filter's
            (:meth:`bioslam.motion_model.ConstantVelocityModel.prior_information`): each
            degenerate match's offset from the prior, scaled back to where the scan alone
            put the pose (``MatchReport.prior_share``), is a position measurement of
            ``weak_point_noise``² over the scan's information along that direction (its
            conditioning times the largest eigenvalue of its point-to-line information, in
            endpoints), and moves the speed by the filter's covariance; with
            ``weak_axis_prior`` the Gauss-Newton prior there is weighed by the filter's
            predicted information instead of ``prior_weight`` times the scan's whole
            curvature. Off by default: on the simulated routes they helped as often as they
            hurt (``benchmarks/README.md``, "Along the weak direction").
        subcell_sigma: width of the sub-cell map function's kernels in cells of each level
            (:func:`bioslam.occupancy_grid.subcell_point`); ``None`` uses Hector's bilinear
            M*, which biases the match towards cell centres (benchmark: more drift).
        start_margin: the repeated-motion or standstill start replaces the prediction only if
            its coarse-level cost is lower by this fraction (ours; see ``_best_start``).
        velocity_window: seconds of past poses the constant-velocity estimate (prediction and
            de-skew) is taken over; ours, about the time constant of a robot's acceleration,
            and several scans of a 40 Hz scanner.
        velocity_scans: ... and over at least this many scan intervals: a 360° scanner
            sweeps during the whole scan period, so a velocity error de-skews the next scan
            wrongly by up to a period's worth of motion; averaging 3 intervals keeps that
            loop stable (measured: the 7 Hz low-cost preset diverges with 1, drifts 0.5 %
            with 3).
        free_logodds: endpoints falling where the cell and its neighbours are all at or below
            this log-odds (free, seen so by about four scans with the default miss update) are
            not fused into the map (moving objects; ours).
        object_size, object_gap, object_lag, object_still, object_reach: at the scanner's
            rate, a run of endpoints standing apart from the walls the map holds (each within
            ``object_gap`` metres of the next, its ends at most ``object_size`` apart) is an
            object, and one whose nearest object ``object_lag`` seconds before lies more than
            ``object_still`` but at most ``object_reach`` metres away moved, and is not fused
            (:meth:`bioslam.odometry.local_map.LocalMap._moving_objects`; ``object_size`` 0:
            every endpoint fused). Ours.
        object_near: an object within this many metres of the scanner that was not seen
            standing still ``object_lag`` seconds before is not fused either: a person
            walking up beside the robot is seen there for the first time, where anything
            that stands still was seen from farther away first. Fused at first sight, a
            person walking on ahead along a corridor the scan leaves free was the only thing
            fixing the pose along it, and the odometry followed them (UTM-30LX, three people
            walking the robot's own route: 1.6 m back in 3 s). 0: none.
        deskew: correct per-beam motion when ``scan.time_increment > 0``.
        sweep_turn_rate: after a gap or on sparse scans, where the motion model's twist is a
            mean over seconds, the turn rate a 360° scan is de-skewed with is measured on the
            scan (:mod:`bioslam.odometry.sweep`) among rates within this many rad/s either
            way (a robot's turns; 0: never measured). RPLIDAR thinned to a scan per metre /
            0.6 rad, 48 simulated routes: 14 lost without, none with.
        sweep_min_skew: ... on scans whose sweep at ``sweep_turn_rate`` turns at least this
            much (rad; 1°: a 360° scanner at 7 Hz turns 12°).
        sweep_rates, sweep_refinements: the rates tried: this many evenly spaced, then the
            two rates half the last spacing either side of the best, this many times.
        sweep_iterations: Gauss-Newton iterations per level, finest first, of each rate's
            match (levels not given: none).
        sweep_rematch: where the measured rate bends the scan by at least this much (rad)
            against the one it was matched with, the scan is matched afresh, its match
            chosen again (a spin on the spot: the bent scan's choice may be a look-alike).
        sweep_thinned: the rate is measured too where the scans are neither after a gap nor
            sparse but each step spans more than this many sweeps (a 360° scanner's log
            thinned by count, a topic recorded throttled): the motion model's twist is then a
            mean over the last steps, each several sweeps long, and lags a turn's onset and end
            by a step (cubicles floor, RPLIDAR every 3rd scan, 2.3 Hz, spins at 1.5 rad/s:
            heading errors of 3.3° a step at the 90th percentile, 12° at the 99th). Such a scan
            keeps its match unless the measured rate bends it by ``sweep_min_skew`` or more
            against the twist, and is then matched afresh as de-skewed, the motion prior
            holding it as any scan's; where its match failed, it is matched again de-skewed
            as if the robot had stopped or reversed its motion and turn. 0: never.
        min_points: fewer valid endpoints than this give a prediction-only update.
        recovery_free_fraction: a match that leaves more than this fraction of the matched
            endpoints in cells the map knows to be free has probably failed (a good match
            leaves almost none there: 1 % median, 4 % at the 90th percentile on freiburg-079,
            0 on the maze). (A person close to the sensor also puts endpoints in free space;
            the search then costs time but finds nothing better.)
        recovery_score_ratio, score_window: a match has also failed if its score (mean
            M*) is below this fraction of the median score of the last ``score_window``
            matches (of the first scan on its own map before that): early in a run, or in a
            log whose scans are far apart, few cells are yet known free, and a failed match
            is told by its points landing on nothing (intel: 0.02 for a failed match of the
            second scan, against 0.6 for the first scan on its own map; the lowest accepted
            scores on our logs and simulations are 0.24-0.5 of the median).
        search_distance, search_angle: half-widths (metres, radians) of the wide-basin
            search (:mod:`bioslam.matching.branch_and_bound`) run when the prediction cannot
            be trusted: the match failed, the scan came after ``gap_time``, or the predicted
            step is longer than ``large_step`` / ``large_turn``. The window is centred on
            the prediction, widened to hold the previous pose as well (a robot that turned
            on the spot may stop turning; a thinned log has up to 80° between scans).
            When every match so found has failed or is rejected, the search is repeated in
            windows turned ``2 * search_angle`` either way from the previous pose (intel's
            60° turns in place). 0 disables the search.
        search_level: the map pyramid level searched (1: 10 cm cells; Gauss-Newton refines
            the winner from there).
        gap_time: after this many seconds without a scan the search runs even if the first
            match looks fine: the constant-velocity prediction is then no better than the
            previous pose (freiburg-079 drops a scan in a turn; thinned logs such as intel
            have scans 0.5-1 m and up to 80 degrees apart), and a match in the wrong basin
            of a corridor can look fine.
        large_step, large_turn: a predicted step longer than this (metres, radians) is not
            trusted either (a scanner at a low rate on a fast robot).
        plausible_ratio: after Gauss-Newton from the prediction, the search's winner and its
            rival, every match whose quality (mean M* less the fraction in free space) is
            at least this fraction of the best is plausible, and the plausible match nearest
            the prediction is kept: where the scan cannot tell places apart (identical
            aisles, a corridor along its axis) the motion prior decides, never a look-alike.
            A plausible match elsewhere is reported (``MatchReport.ambiguous``).
        contradiction_factor: along a direction the scan does not constrain, a match
            that leaves no more than the run's typical share of endpoints in known free
            space and fits better also wins where the prior's is plausible beside it but put
            this many times the typical share there: the weak prior's match, or the match
            from the pose along that direction the free space favours within a scan's
            reach (``LidarOdometry._contradiction_explained``); 0 never.
        contradiction_points: ... and at least this many endpoints in known free space (a
            match with fewer explains a contradiction away if it leaves at most half the
            prior's there): a beam grazing a wall's end falls where the map saw through as
            often as not, and in a clean world (the typical share 0) one such endpoint moved
            the pose 0.1-0.25 m back along a corridor and the speed measured from it turned
            the robot round (URG-04LX, maze, 10 Hz, tour: every such overrule on three of six
            seeds, ATE 0.7-3.4 m; ``benchmarks/README.md``, "Stray endpoints"). The price:
            a robot backing up along a corridor is noticed later, when more endpoints say so.
        search_contradicted, search_free_fraction: a trusted prediction's match on a scan
            that constrains every direction is searched, as a jump is, when it is contradicted
            (as above) with at least ``search_free_fraction`` of its endpoints in known free
            space, the endpoints of moving objects left out
            (``LidarOdometry._walls_contradict``). Such a match lags or leads along a
            corridor, its endpoints in free space step after step, until the run is lost
            (the maze's weaving route kept at every 20th scan, UTM-30LX at 2 Hz: a robot
            speeding up out of a spin from 0.1 to 0.6 m a step, 11-19 % of the endpoints
            in free space, lost 5.9 m; searched, 0.9 cm). People walking put endpoints
            where the map saw free space at the right pose too: searched, the match followed
            a look-alike (the maze's weaving route, SICK, three people: 4.4 m off). Good
            matches leave 1 % there on freiburg-079 at the median and 4 % at the 90th
            percentile: searched from 3 endpoints and 1.8 times the typical share on, with no
            such floor, its matches were replaced by a search's 432 times (30 without the
            search of contradicted matches, 120 with the floor).
        search_score_drop: a trusted prediction's match on a scan that constrains every
            direction whose score (mean M*) falls below this fraction of the recent matches'
            median, though no endpoint lands in known free space, is matched again from the
            last step undone, and that match replaces it where its own score did not drop,
            it puts no more endpoints in free space and beside it the first is not plausible
            (``PredictionGuards._unless_reversed``; 0: never). Along a corridor whose walls
            pin the pose across it alone, a robot that backs up is carried on by the
            prediction: the walls still fit, the doors and corners along it less with every
            scan (the twin-room floor's corridor, SICK kept at every 4th scan, 2.5 Hz: scores
            0.85 -> 0.77 -> 0.70 -> 0.65 -> 0.61, the pose 2.5 m on before the reversal was
            noticed; now found at 0.70). The search instead (run on such a drop as on a
            contradiction) found the reversal too but, on the 3.5 m LDS-01, took look-alikes
            along the aisles where a short scan's score is noisy (benchmarks README, "A drop
            in the score").
        rival_ratio: the search's rival is matched only if it scores at least this fraction
            of the winner on the search's grid.
        jump_distance, jump_angle, overwhelming_ratio: a match farther than this from the
            motion model's prediction (metres, radians) is a jump; it is accepted only if the
            prediction's own match failed or scores below ``overwhelming_ratio`` of it (intel:
            RPE 62 cm with this guard, 78 cm with a limit grown by 2 m/s and 2 rad/s of
            motion between the scans instead).
        max_speed, max_turn_rate: ... and never if it lies farther from the previous pose
            than ``jump_distance + max_speed * dt`` metres or ``jump_angle + max_turn_rate *
            dt`` radians, more than a robot moves between two scans ``dt`` seconds apart
            (freiburg-079: a failed match in clutter 0.14 s after the last scan was
            replaced by a look-alike 0.95 m away).
        jump_factor, miss_percentile: the jump limits grow to ``jump_factor`` times the
            ``miss_percentile``-th percentile of the motion model's misses (its start against
            the match kept) over the last ``score_window`` scans: a log thinned to a scan per
            metre is predicted to within tens of centimetres and degrees at best, and there a
            fixed 0.5 m limit turns every correct step into a "jump" (intel: RPE 75 -> 46 cm
            with the through-wall evidence below); a 40 Hz scanner's misses are millimetres
            and the fixed limits hold.
        wall_logodds, through_margin, recovery_through_fraction: where the odometry
            compares matches (the search ran), each is also charged the fraction of its
            beams that cross a cell above ``wall_logodds`` (hit more often than missed)
            before ``through_margin`` metres short of their endpoint (range noise, beams
            grazing the endpoint's own wall): a scan placed a metre off along a corridor
            sees through the walls around a side door or past the corridor's end, while its
            endpoints still score as well as at the true pose
            (:meth:`bioslam.occupancy_grid.OccupancyGrid.fraction_through_walls`). More than
            ``recovery_through_fraction`` rejects a match as endpoints in free space do (at
            the reference poses: median 0.05-0.09, 99th percentile 0.34 on freiburg-079
            thinned to 0.5 m; wrong matches on intel 0.3-0.9).
        sparse_share, sparse_scans: the scans are *sparse* (a thinned log, a scanner at a low
            rate on a moving robot) when the wide-basin search ran for at least
            ``sparse_share`` of the last ``score_window`` scans (and of at least
            ``sparse_scans``): the prediction is then no better than a guess. Sparse scans
            get three things dense ones never do. Their matches are chosen by
            ``step_prior_weight`` (:meth:`LidarOdometry._choose_sparse`), and Gauss-Newton
            also starts from the ``step_modes`` most typical recent steps, instead of the
            jump limits, which grow with the motion model's misses until
            they stop nothing. When every match is an implausible step (the step prior's
            density below ``implausible_density``), the turn searches run as they do when
            every match fails (intel: a 61° turn plus a metre, beyond the first window, was
            otherwise placed 2.8 m sideways). (Every fused scan, sparse or not, is densified
            along its surfaces first, :func:`bioslam.matching.registration.densify_scan`:
            the map of a 1° scanner holds a wall only where the fused scans' beams hit it, a
            metre apart along a wall seen 10 m ahead, and a pose that reproduces a fused
            scan's own beam pattern, standing still, then scores best in a corridor. Intel:
            RPE 1 m 22 -> 8 cm with the other two; SICK in a warehouse aisle, dense: the
            pose stood still while the robot drove off, :meth:`LidarOdometry._unless_contradicted`.)
            The first scan, fused before anything was known, gets the points of
            ``first_straight_angle`` if the second came after ``gap_time``
            (:meth:`LidarOdometry._densify_first`): a thinned log's map is at first one or
            two scans, densest where they were taken, and a pose moved back there (standing
            still) outscored the true step a metre on (SICK in the warehouse thinned to a
            scan per metre, seed 1: lost from its first steps).
        straight_angle: when positive, densifying also fills a gap longer than
            ``NORMAL_MAX_GAP`` between neighbouring endpoints that continues a straight run
            of them (the gaps either side turn by at most this many radians,
            :func:`bioslam.matching.registration.straight_gaps`): a 1° scanner hits a wall
            it looks along a metre apart at 10 m, and such a wall left as dots is matched
            by the dots' pattern, not the wall. Off by default: at 0.05 the SICK maze
            thinned to a scan per metre went from RPE 1 m 72 / 131 cm to 32 / 84 cm (seeds
            0 / 1, lost at its corners either way) and intel from ten starts kept its median
            (6.1 cm), but freiburg-079 thinned to 1 m went from 4.2 to 5.2 cm.
        dense_straight_angle: ``straight_angle`` for the scans fused while the scans are not
            sparse (a scanner at its own rate): a map made of many scans of a wall, each
            dotted a metre apart where a 1° scanner looks along it, still holds the dots'
            pattern, and a pose that lags the robot along an aisle reproduces the last fused
            scans' pattern as well as the true one matches (simulated warehouse, SICK,
            adversarial route, 3600 s, seed 3: the pose moved at half the robot's speed
            along an aisle for 4 s with endpoints in known free space; ATE 95 -> 4.2 cm).
            The first scan gets it too once the second shows the scanner's rate
            (:meth:`LidarOdometry._densify_first`; SICK, hall, tour, seed 57: the pose stood
            at the start for 31 s, ATE 269 -> 1.0 cm).
        first_straight_angle: ``straight_angle`` for the first scan of a thinned log, when
            it gets its densified points (:meth:`LidarOdometry._densify_first`): the map is
            then that one scan, and the next scan's 1° beams, placed back where it was taken,
            land on its beam pattern exactly along a corridor's walls, so that standing
            still outscored the true step a metre on (a corridor with doors, a scan per
            metre: five steps stood still, RPE over 1 m 84 cm; 0.9 cm with its walls filled
            as lines and, while every scan so far came after a gap, the best match kept as
            on sparse scans, :meth:`LidarOdometry._choose_sparse`). Later scans keep
            ``straight_angle``: the first few filled so too cost intel thinned to 1.5 m
            from its first scan 34 -> 101 cm.
        densify_tolerance: at the scanner's rate (:meth:`LidarOdometry._at_scanner_rate`)
            a gap up to ``NORMAL_MAX_GAP`` is densified only where it continues a surface:
            the endpoint before it or the one after (joined to it by such a gap) lies within
            this many metres of the line through its two, or, with neither joined, the gap
            lies more across the beams than along them (a post's face;
            :func:`bioslam.matching.registration.straight_gaps`). Filled regardless, the gaps
            around door jambs' corners and down depth steps put points off every wall, on the
            edges that fix a pose along a corridor (simulated SICK, adversarial routes: 0.6-3 %
            of the points those gaps added lay over 2 cm farther off the walls than their
            endpoints; 52-92 % of those are dropped, 91-95 % of the rest kept; rooms 900 s
            seed 5: ATE 1.31 -> 0.31 cm, the pose 20 cm off along the corridor in spins on
            the spot before). A thinned log keeps every gap: a few scans make its map, and a
            door's edge seen by two beams, or a recess's corner cut, can be all that fixes a
            step a metre on. None (the default) fills every gap: on the real logs 0.03 made
            the odometry worse (exp1's loop gap 0.330 m / 4.1° -> 0.533 m / 11.1°,
            freiburg-079 ATE 7.12 -> 7.47 cm, RPE over 1 m 4.49 -> 4.70 cm; real walls are
            not the simulator's straight lines), and on unseen simulated routes it won as
            often as it lost (maze SICK 600 s seed 4: 0.47 -> 24.3 cm with a 1.5 m jump).
        break_score_ratio, break_turn, break_margin: on sparse scans the odometry reports a
            step as a break (``MatchReport.broken``, a break of its chain of relative poses
            for loop closure, :func:`bioslam.closure.odometry_broke`) when the match kept
            scores below ``break_score_ratio`` times the recent matches' median (it fits
            nowhere: a hard turn into space the map has not seen), or a match turned by
            more than ``break_turn`` radians from it, not rejected by the map, comes within
            ``break_margin`` of its merit (:meth:`LidarOdometry._choose_sparse`: the scan
            cannot tell which way the robot turned). A break's extent after a gap of seconds
            is the motion a robot can change in that time, so a thinned log's steps never
            broke before, and a map turned by 90-180 degrees went unreported. Intel thinned
            to a scan per 1.5 m / 45 degrees: 20 of its 29 steps with more than 30 degrees
            of heading error from scan 10 are flagged, and 13 of 349 right steps; intel as
            logged 3 of 903 right steps (16-18 breaks by the motion thresholds), freiburg-079
            thinned to 1 m from scan 1 one of its two wrong turns and one of 478 right steps.
        step_prior, step_prior_weight: the density of the recent steps for which the search
            ran, mixed with the heading cones a wheeled robot moves in
            (:class:`bioslam.step_prior.StepPrior`; a run that turns sparse halfway is not
            then held to the millimetre steps of its dense part, and dense scans pay nothing
            for it) and the weight of its cost (``-log``, at most ``-log(step_prior.floor *
            step_prior.cone_floor)``) against a match's quality (mean M* less the negative
            evidence, :func:`bioslam.odometry.choice.match_quality`). The prior never keeps
            a match the walls contradict over one that explains the contradiction away
            (:meth:`bioslam.odometry.choice.MatchChoice._unless_explained_away`).
        step_modes: on sparse scans, Gauss-Newton also starts from this many typical recent
            steps (:meth:`bioslam.step_prior.StepPrior.modes`: a metre on, a turn either way
            on the spot, an arc), taken from the previous pose. The motion model's
            hypotheses say what the robot did last (turning, say), and on a sparse map a
            match slides only a few decimetres from its start; intel's wrong steps on
            revisits were mostly starts that never came near the true step (a turn plus a
            metre on after turns on the spot; freiburg-079 thinned to 1 m: a turn reversed).
            Only the scan and the step prior choose among the matches: a distance from the
            motion hypotheses, weighed in as well, favoured the last step repeated (intel,
            RPE over 1 m from scans 0-9: median 8.0 cm and 8 of 10 starts at most 10 cm
            with it, 6.1 cm and 10 of 10 without). Eight, not four, since the first scan of
            a thinned log is densified with straight runs filled: intel from scans 0-9
            median 5.5 -> 5.35 cm and 9 -> 10 of 10 at most 10 cm, from scans 10 / 17 / 19
            7.9 / 14.9 / 13.2 -> 8.0 / 10.3 / 13.3 cm, at the same time per scan; the SICK
            maze thinned to 1 m stays lost either way (38 / 131 -> 42 / 125 cm).
        implausible_density: see ``sparse_share``.
        submap_travel, submap_doubts, submap_conflict: on sparse scans the map matched
            against can be replaced by one of only the scans of the last ``submap_travel``
            to half that many metres when it holds walls twice
            (:meth:`LidarOdometry._turn_submaps`): a wrong step, fused, leaves the walls in
            two frames, and later scans jumped between them. It is replaced when, since the
            last turn, at least ``submap_doubts`` steps were ambiguous or broken and a scan
            matched on the recent scans' map alone landed more than ``submap_conflict``
            metres (or that at ``length_scale`` in heading) from the pose the map gave it
            (a conflict of 0 replaces on doubts alone). Off by default (0 travel): at 30 m
            the SICK maze thinned to a scan per metre went from RPE over 1 m 59.6 to 30.2
            cm (seed 0; seed 1 unchanged, 125 cm) but seed 2, tracked at 4.4 cm, was lost
            (80 cm) after a replacement the conflict test let through; at a 0.3 m conflict
            nothing is replaced, and on doubts alone the thinned Intel log lost the revisits
            that keep it precise (its first 200 scans from ten starts: median 5.3 -> 10.6
            cm). ``benchmarks/README.md``, "Submaps on sparse scans".
        rebuild_scans: on scans without a gap (not a thinned log), once the typical match
            (the median over ``score_window``) leaves more than ``recovery_free_fraction`` of
            its endpoints in known free space, the local map is rebuilt from those of the
            last ``rebuild_scans`` scans fused whose own match did not
            (:meth:`LidarOdometry._rebuild_on_conflict`; 0: never). Endpoints in known free
            space are never fused (they are taken for people), so a map whose earlier pass
            disagrees with the scans for good never learns what they see: pallets set down
            along an aisle while the robot was at its far end (a 3.5 m 360° scanner: steps
            0.8-0.9 m wrong on the way back without the rebuild, within 3 cm with it,
            ``tests/test_odometry_rebuild.py``), or an aisle come back to after the heading
            drifted 7° (the simulated warehouse, ``benchmarks/README.md``, "A map that
            disagrees with the scans for good"). Half the window must be in conflict, so a
            conflict the matches resolve (the map of an earlier pass pulling a drifted pose
            back onto it, over tens of scans) keeps the map that resolves it.
        echo_prior_weight, echo_scans: on sparse scans a match within a finest cell of a
            pose where one of the last ``echo_scans`` scans was fused (an *echo*: standing
            still, or a step back onto an earlier scan's pose) has its step prior cost
            weighed by ``echo_prior_weight`` instead of ``step_prior_weight``, and counted
            in full from the first steps (``StepPriorConfig.floor_steps`` does not raise its
            floor there). A scan placed where an earlier one was taken puts its beams where
            that scan's hit, and a sparse map, which holds a wall only where the last scans'
            beams hit it, scores it above the true step (the SICK warehouse thinned to
            1.5 m, seed 0: standing still 0.584 against 0.541 for the true 1.5 m on its 5th
            step). Elsewhere the prior keeps its weight: raised everywhere (0.2 with
            ``floor_steps`` 1), it tracked that warehouse but outweighed intel's first metre
            on after eight turns on the spot, which the scan clearly preferred (RPE over 1 m
            from scans 0 / 3 / 7 6.4 / 5.1 / 4.9 -> 9.7 / 35 / 6.1 cm). None: off.
            ``benchmarks/README.md``, "Echoes of fused scans".
        typical_search_distance: on sparse scans, when none of the wide-basin search's
            seeds is near the typical step forward, a second search of this half-width
            (metres; the full ``search_angle``) around that step adds its best pose as a
            seed (:meth:`LidarOdometry._typical_seeds`), so that the step prior can weigh
            the match nearest the robot's usual step against the wide window's winner, a
            look-alike sideways where a 180° scanner turns into an unseen corridor
            (simulated maze, SICK, adversarial route thinned to a scan per metre, seeds
            2 / 3: ATE 81.8 / 125.6 -> 0.91 / 3.14 cm; freiburg-079 thinned to 1 m, RPE
            over 1 m 4.88 -> 4.19 cm). 0: off. ``benchmarks/README.md``, "The typical
            step searched".
        plateau_slope: on sparse scans, where the scan of the match chosen leaves a
            direction free, a match along it that fits less by at most this much quality
            per metre between them is a point of the same plateau, and the step prior
            picks among them (:meth:`LidarOdometry._typical_on_plateau`; the seeds slid
            along it to the typical step are matched held there). Measured slopes: 0.05-0.2
            per metre for a URG-04LX's steps down corridors longer than its range, 0.6 for a
            SICK's that sees corners down them. 0: only a match fitting as well is (the
            choice is then the merit's). ``benchmarks/README.md``, "Down a corridor the scan
            cannot pin".
        place_logodds: on sparse scans, the place a match is at (among distinct ones) is
            judged by the share of its endpoints within a cell of a wall, a cell or one of
            its neighbours above this log-odds, rather than by the mean map value, which
            favours the walls the map has seen most (:meth:`LidarOdometry._at_place`); the
            mean map value then picks among the matches at that place. The thinned battery
            (346 simulated routes) lost 65 -> 56, none newly lost. None: the mean map value
            alone. ``benchmarks/README.md``, "Where the map is surest".
        log_odds: hit/miss increments of the map cells.
    """

    resolution: float = 0.05
    levels: int = 3
    map_size: float = 48.0
    recenter_distance: float = 10.0
    max_range: float = 30.0
    min_range: float = 0.05
    body_reach: float = 1.0
    body_turn: float = math.pi
    insert_distance: float = 0.2
    insert_angle: float = 0.15
    point_spacing: float = 0.05
    max_iterations: tuple[int, ...] = (10, 10, 15)
    step_tolerance: float = 0.05
    length_scale: float = 3.0
    degeneracy_ratio: float = 0.01
    prior_weight: float = 0.05
    search_prior_weight: float = 0.0005
    velocity_window: float = 0.1
    velocity_scans: int = 3
    constrained_ratio: float = 0.1
    accel_noise: float = 0.5
    velocity_noise: float = 0.05
    velocity_spread: float = 0.1
    sideways_noise: float = 0.0
    weak_point_noise: float = 0.0
    weak_axis_prior: bool = False
    mapped_logodds: float | None = 0.0
    matched_range_margin: float = 0.6
    fused_reach_scans: int = 8
    grazing_ratio: float | None = 6.0
    grazing_gap: float = 1.0
    grazing_condition: float = 0.05
    start_margin: float = 0.1
    subcell_sigma: float | None = 1.0
    free_logodds: float = -1.5
    object_size: float = 0.7
    object_gap: float = 0.15
    object_lag: float = 0.2
    object_still: float = 0.1
    object_reach: float = 1.0
    object_near: float = 1.0
    deskew: bool = True
    sweep_turn_rate: float = 1.5
    sweep_min_skew: float = math.radians(1.0)
    sweep_rates: int = 5
    sweep_refinements: int = 2
    sweep_iterations: tuple[int, ...] = (10, 10)
    sweep_rematch: float = math.radians(4.0)
    sweep_thinned: float = 1.5
    min_points: int = 20
    recovery_free_fraction: float = 0.2
    recovery_score_ratio: float = 0.5
    search_distance: float = 1.5
    search_angle: float = math.pi / 4
    search_level: int = 1
    search_angular_cells: float = 2.0
    search_depth: int | None = 4
    gap_time: float = 0.5
    large_step: float = 0.3
    large_turn: float = 0.3
    plausible_ratio: float = 0.9
    contradiction_factor: float = 1.8
    contradiction_points: int = 3
    search_contradicted: bool = True
    search_free_fraction: float = 0.05
    search_score_drop: float = 0.9
    rival_ratio: float = 0.8
    jump_distance: float = 0.5
    jump_angle: float = 0.35
    max_speed: float = 2.0
    max_turn_rate: float = 3.0
    overwhelming_ratio: float = 0.7
    jump_factor: float = 2.0
    miss_percentile: float = 90.0
    wall_logodds: float = 3.0
    through_margin: float = 0.5
    recovery_through_fraction: float = 0.4
    score_window: int = 100
    sparse_share: float = 0.5
    sparse_scans: int = 5
    step_prior: StepPriorConfig = field(default_factory=StepPriorConfig)
    step_prior_weight: float = 0.1
    step_modes: int = 8
    implausible_density: float = 0.1
    straight_angle: float = 0.0
    dense_straight_angle: float = 0.05
    first_straight_angle: float = 0.05
    densify_tolerance: float | None = None
    break_score_ratio: float = 0.4
    break_turn: float = math.radians(25.0)
    break_margin: float = 0.1
    submap_travel: float = 0.0
    submap_doubts: int = 1
    submap_conflict: float = 0.1
    rebuild_scans: int = 50
    echo_prior_weight: float | None = 0.2
    echo_scans: int = 8
    typical_search_distance: float = 0.5
    plateau_slope: float = 0.3
    place_logodds: float | None = 0.0
    log_odds: LogOddsConfig = field(default_factory=LogOddsConfig)

    def __post_init__(self) -> None:
        if self.levels < 1 or len(self.max_iterations) != self.levels:
            raise ValueError(
                f"max_iterations needs one entry per level ({self.levels}), "
                f"got {self.max_iterations}"
            )
        if not (self.resolution > 0 and self.map_size > 4 * self.recenter_distance > 0):
            raise ValueError("need resolution > 0 and map_size > 4 * recenter_distance > 0")
        objects = (
            self.object_size, self.object_gap, self.object_lag, self.object_still,
            self.object_near,
        )  # fmt: skip
        _require(
            min(objects) >= 0 and self.object_reach >= self.object_still,
            "object_size, object_gap, object_lag, object_still and object_near must be "
            "non-negative and object_reach at least object_still, "
            f"got {(*objects, self.object_reach)}",
        )
        _require(
            (self.grazing_ratio is None or self.grazing_ratio > 1.0)
            and min(self.grazing_gap, self.grazing_condition) >= 0,
            "grazing_ratio must be None or above 1, grazing_gap and grazing_condition "
            f"non-negative, got {(self.grazing_ratio, self.grazing_gap, self.grazing_condition)}",
        )
        _require(
            min(self.fused_reach_scans, self.rebuild_scans) >= 0,
            "fused_reach_scans and rebuild_scans must be non-negative, got "
            f"{(self.fused_reach_scans, self.rebuild_scans)}",
        )
        sweep = (self.sweep_turn_rate, self.sweep_refinements, self.sweep_thinned)
        _require(
            min(sweep) >= 0 and self.sweep_rates >= 1,
            "sweep_turn_rate, sweep_refinements and sweep_thinned must be non-negative and "
            f"sweep_rates positive, got {(*sweep, self.sweep_rates)}",
        )
        if self.score_window < 1:
            raise ValueError(f"score_window must be at least 1, got {self.score_window}")
        if not (0.0 < self.sparse_share <= 1.0 and 0.0 < self.implausible_density <= 1.0):
            raise ValueError(
                f"sparse_share and implausible_density must be in (0, 1], got "
                f"{self.sparse_share}, {self.implausible_density}"
            )
        if self.step_prior_weight < 0 or self.step_modes < 0 or self.plateau_slope < 0:
            raise ValueError(
                f"step_prior_weight, step_modes and plateau_slope must be non-negative, got "
                f"{self.step_prior_weight}, {self.step_modes}, {self.plateau_slope}"
            )
        if (self.echo_prior_weight is not None and self.echo_prior_weight < 0) or (
            self.echo_scans < 1
        ):
            raise ValueError(
                f"echo_prior_weight must be None or non-negative and echo_scans positive, "
                f"got {self.echo_prior_weight}, {self.echo_scans}"
            )
        _require(
            self.place_logodds is None or math.isfinite(self.place_logodds),
            f"place_logodds must be None or finite, got {self.place_logodds}",
        )
        if not 0 <= self.search_level < self.levels:
            raise ValueError(
                f"search_level must name a pyramid level (0..{self.levels - 1}), "
                f"got {self.search_level}"
            )


def _require(condition: bool, message: str) -> None:
    """Refuse a setting: ``ValueError(message)`` unless ``condition``."""
    if not condition:
        raise ValueError(message)
