"""The whole system's configuration: one dataclass per module, gathered in ``SLAMConfig``.

Each module documents its own defaults and their sources; this file only assembles them and
reads user overrides from a TOML or JSON file whose tables are named after the fields below,
e.g.::

    [odometry]
    resolution = 0.05

    [views]
    s_t = 0.4
"""

from __future__ import annotations

import dataclasses
import json
import math
import tomllib
import types
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from bioslam.boundary import BoundaryCellConfig
from bioslam.cognitive_map import CognitiveMapConfig
from bioslam.matching.registration import RegistrationConfig
from bioslam.odometry_config import OdometryConfig
from bioslam.pose_cells import PoseCellConfig
from bioslam.views import ViewCellConfig


@dataclass
class LoopClosureConfig:
    """How a recognised place becomes a loop-closure link.

    The paper links the current experience to the recognised one with the odometry alone (as
    RatSLAM does), which places the robot exactly on the old experience although a boundary view
    matches within tens of centimetres. We refine each closure by registering the current scan
    against the scan stored with the old experience and reject registrations that do not fit.

    Attributes:
        refine: register scans to refine loop closures (False = the paper's behaviour).
        min_score: smallest registration score (fraction of points landing on occupied cells)
            that accepts a closure. Correct registrations score above 0.9, wrong ones below
            0.6; on the 600 s demo maze 0.8 let through registrations ~10 cm off along
            corridors (max error 20 cm) where 0.9 gives 7 cm. Precision first: a missed
            closure costs little, a wrong one drags the map.
        partner_score: a registration that scores at least this but below ``min_score``
            is a closure only where the odometry vouches for the map's prediction (no
            doubted step nor break since the place) and once another closure agrees with it
            (:class:`bioslam.closure.ClosureConsensus`). Real scans of a cluttered room fit
            a correct registration less well than a simulated wall does (intel: 7 such
            closures, 1.2 cm median and 1.6 cm largest error against the reference, where
            0.9 had refused them; alone at 0.8, freiburg-079 took closures up to 27 cm
            off), and two at different places that agree to centimetres rarely do by chance.
            Where the odometry cannot vouch for the prediction either, nothing tells such a
            fit from a look-alike the odometry's own error put there. ``min_score`` (or 1)
            turns it off.
        reject_degenerate: refuse closures whose registration is unconstrained in some
            direction (a featureless corridor), since the along-corridor offset is then a guess.
            False: a registration that leaves the position free along one direction (a
            corridor seen along its axis, :func:`bioslam.closure.sliding`) is a partial
            closure: it measures the position across the corridor and the heading, takes the
            map's prediction along it, and its loop link weighs nothing there
            (:attr:`bioslam.cognitive_map.Measurement.partial`). Only at ``min_score``, never
            as a partner of another, and across the odometry's breaks only where no pose
            outside the window across the slide fits as well; one that leaves a turn free is
            refused either way.
        drift_floor, drift_per_metre: a closure may correct the map's estimate of where the
            robot stands relative to the recognised experience by at most
            ``drift_floor + drift_per_metre * d`` metres, ``d`` being the distance travelled
            since that experience was made, or the length of the shortest chain of links
            (odometry and earlier closures) joining it to the robot if shorter: a larger
            correction is more than the odometry can have drifted, so the recognition was of
            a look-alike place (repetitive corridors). The same bound is the verification's
            search window, so a chain through earlier closures also keeps rivals along a
            corridor out of it (maze weaving route: recall 0.59 -> 0.93).
            The defaults allow 2% drift, four times the worst the LiDAR odometry shows on
            its simulated benchmarks, so that real closures after long loops still pass.
            Real logs can drift more: exp1.dat's URG-04LX was 0.82 m off after 25 m, and
            its return's check stops at the bound (0.79 m; benchmarks README, "exp1's
            return to its start").
        max_drift, max_drift_angle: caps on those bounds (m, rad). Without them a place made
            hundreds of metres ago could be matched metres away from where the map puts it,
            which in repetitive corridors is a look-alike, not the same place.
        drift_angle_floor, drift_angle_per_metre: the same for the heading, radians.
        link_floor, link_angle_floor: the floors instead when the map already links the
            current experience to the recognised one (directly or by a chain of links up to
            ``chain_distance`` long), so that only the odometry since entering the current
            experience, along the chain, and the registration's error can be off; a
            registration sliding along a corridor is caught here.
        chain_distance: a recognised experience joined to the current one by a chain of
            links at most this long (m) counts as linked, with the chain's length added to
            the odometry the drift bound grows with.
        recognition_radius: how far (m) from a place its boundary view is still recognised;
            a candidate that the map puts farther than this plus the drift bound is rejected
            before any registration (the pose cells wrap, so their packet alone cannot tell
            two places a network-width apart).
        deadband, deadband_angle: a registration that corrects the map's prediction by less
            than this (m, rad) enters the map as that prediction instead of as measured. Off
            (0) by default: the prediction then becomes a loop link weighted as a
            registration, which holds the map at its drifted state (the maze tour's loop links
            were 1.2 cm off the truth with 3 cm / 0.006 rad against 0.7 cm without, their
            registrations 0.7 cm). Measured at a049569 with loop links weighted by their
            scan's geometry (``bioslam.cognitive_map.registration_shape``), 300 s per world,
            ATE full /
            odometry: without a dead band maze tour 0.59 / 0.49 cm, weaving 1.95 / 2.03,
            RPLIDAR weaving 2.62 / 2.80, rooms 3.60 / 3.45 (SICK) and 7.76 / 9.43, warehouse
            1.63 / 2.12 and 4.19 / 5.17, freiburg-079 6.67 / 7.21; with 3 cm / 0.006 rad
            (isotropic weights) 1.03, 2.21, 2.65, 4.13, 7.28, 1.61, 5.11 and 6.71.
        registration_interval: at most one registration per this many metres of travel;
            it bounds the cost of place recognition where views keep matching but
            registrations keep failing (noisy sensors, clutter): consecutive scans that
            close say the same thing anyway.
        payload_spacing: spacing (m) of the scan points kept with each experience.
        max_scan_bend: a scan whose sweep the odometry's de-skewing bent by more than this
            (rad; :attr:`bioslam.matching.gauss_newton.MatchReport.bend`) neither checks a
            closure nor is kept for one. As a turn begins or ends, a slow 360° scanner's
            scan is bent by the motion model's lagging twist, its match is off in heading
            by about the bend, and so is the pose of the experience made there: such a
            closure measured the bend, and one to such a place, even a true one, bent the
            map against its odometry links. Without them, on seven RPLIDAR and `lds01`
            routes (benchmarks README, "Bent scans neither close nor are closed to") the
            loop links' heading error at the 90th percentile went from 0.18-4.18° to
            0.17-0.78°, the trajectories by -0.40 to +0.23 cm. Scanners whose sweep is short
            (SICK, UTM-30LX) are bent by less than 0.2° at the 99th percentile at their
            rate; in a thinned log's turns a SICK's sweep reaches it too.
        proximity: also propose, as a loop candidate, the experience nearest the robot's map
            pose within the drift bound (the path-integration cue, :mod:`bioslam.closure`),
            not only the one its view cell recognises.
        revisit_refused: the proximity cue proposes first the oldest place within its reach
            whose check was refused as ambiguous at least ``min_loop_travel`` metres of
            travel ago, where the odometry neither broke nor jumped since the place was made
            (:meth:`bioslam.slam.BioSLAM._refused_return`): a return refused leaves the area
            mapped twice, and the nearest place is the new copy (hospital floor, SICK
            reversing, heading drift injected: 5.72 -> 0.87 cm; 23 drift runs, median 2.95
            -> 2.47 cm, 3 better and 4 worse). Everywhere, over 85 runs without drift, 4
            better and 7 worse, 27 above their odometry against 25, freiburg-079 7.29 ->
            7.44 cm (benchmarks README, "The cue back to a place found ambiguous"); hence
            only where the heading drifts (``drift_scale``). Off by default: of 12
            drift runs held out (seeds 820, 821) it made 4 better by 0.01-1.72 cm and 4
            worse, the warehouse's SICK weaving route 1.33 -> 8.48 cm; on 24 runs of seeds
            it had not seen, 6 better and 6 worse (median 4.01 -> 4.42 cm).
        drift_scale: ``revisit_refused`` and ``lines_pin`` act only while the map's link
            noise says the odometry's heading drifts: the heading variance the closures
            make likeliest, over what the odometry's scan matches measured
            (:attr:`bioslam.link_noise.LinkNoise.likeliest_heading_scale`), at least this
            (the settings' model, 1, until a closure teaches one). Where the heading holds,
            the new copy of an area lies on the first pass and a check to it serves as
            well. At the end of 59 simulated runs without drift the closures had taught at
            most 0.06 where the odometry held (freiburg-079 0.0003, intel 0.003), up to 0.29
            and 3.1 on lost ones; of 21 with a gyro-like drift of 0.0002 rad/s, 0.63-30 but
            0.08 on one (6 closures taught). With the gate, 23 drift runs gain as with the
            cue everywhere (median 2.95 -> 2.47 cm), and of 85 runs without drift 2 lose a
            little (the cue everywhere: 7) and freiburg-079 is unchanged (benchmarks README,
            "The cue back, where the heading drifts"). 0: whatever the drift.
        min_loop_travel: metres of travel since an experience was made before the proximity
            cue proposes it (a place just left is not a loop).
        submap_reach: the verification submap fuses the scans of the experiences made within
            this many metres of travel of the candidate, on its own pass (m).
        submap_step: the submap takes one scan per this many metres of travel (m).
        submap_max_reach: where the pass made its experiences sparser than ``submap_step``
            (a thinned log), the reach grows with their spacing up to this (m)
            (:func:`bioslam.closure.submap_span`).
        submap_spacing: the submap is thinned to one point per cell of this size (m).
        prefetch_submaps: on a scan that runs no check but is slow already (the odometry
            fused it, or a look ran), fuse the submap of the check the next look will make
            (:meth:`bioslam.slam.BioSLAM._prefetch_submap`): the same results, a third of a
            check's cost moved off its scan.
        search_distance, search_angle: caps (m, rad) on the window the verification
            searches around the map's prediction; within them the window is the drift bound.
            The distance is the drift bound's own cap (``max_drift``): searching less, a
            place the bound allows is found only by sliding out of the window, and refused
            (intel with 0.0005 rad/s of heading drift: a loop later the map is 1.5-2.1 m off,
            two loops later 3 m).
        search_level: the pyramid level (0 finest) whose grid the wide-basin search runs on;
            Gauss-Newton then refines on every level.
        rival_distance, rival_angle: a rival pose must lie farther than this from the best
            (m, rad) to count as another place (nearer ones are the best's own peak).
        max_ambiguity: a candidate is refused when its best distinct rival scores at least
            this fraction of the best: the scan fits a look-alike place as well.
        prior_margin: the map's prediction, refined where it stands, is a rival too: a best
            pose farther than the rival distance from it is refused unless its score (share
            of points on the submap) beats the prediction's by more than this (along a
            corridor the best may sit on a plateau the scan barely constrains).
        ambiguity_memory: a place a check found ambiguous (a rival nearly as good, or a
            look-alike outside the window fitting as well) stays so for the checks to it
            within this many metres of travel: the robot has not moved enough to see it
            differently, and a later check that passes by a hair is the same doubt
            (simulated hall, URG-04LX, reversing route: three checks to one place refused as
            ambiguous within 1 s, the fourth accepted 0.72 m off). 0 turns it off.
        ambiguity_radius: ... and so do the places within this many metres of it on the
            map: an ambiguity is the surroundings', which a neighbouring place of the same
            pass shares, and a check to it that passes by a hair is the same doubt
            (ring floor, URG-04LX, weaving route: checks to consecutive places 0.25-1 m
            apart refused as ambiguous and accepted 3 m off by turns). 0: the place alone.
        clear_ambiguity: a check that the odometry vouches for (no doubted step, break or
            jump since the place), fits well enough to close alone (``min_score``) and has no
            distinct pose in its window scoring within this share of its best stands at a
            place the memory above holds ambiguous: it passes the rival test clearly, not by
            a hair, and sees what tells the place from the look-alikes the checks before it
            saw from elsewhere (parking floor, UTM-30LX, heading drift injected: at the
            return of a 106 m loop, ten checks in ten seconds, four of them with no rival at
            ``max_ambiguity``, two of those with none above 0.69, 0.00 m off; the memory
            refused all ten, the robot never checked those places again and the map kept the
            area twice). At or above ``max_ambiguity``: off. The false closures the memory
            was made for came across the odometry's breaks.
        prior_tie: a best pose nearer the prediction than the rival distance must score
            more than this above the prediction refined where it stands, or the latter is
            taken (along a corridor the window's best is one point of a plateau; on the
            rooms world such picks were 22-36 cm off, the prediction 2 cm).
        tie_distance, tie_angle: a best pose farther than this (m, rad) from the prediction
            refined, but nearer than the rival distance, must beat it by ``prior_margin`` as
            one beyond the rival distance must (the ``prior_tie`` alone let a registration
            slide 0.39 m along a corridor with people in it, 0.948 against 0.893: a closure
            0.40 m off on the simulated rooms, SICK, 5 people, seed 171).
        search_prediction_plateau: where the prediction refined fits the place
            (``partner_score``), a correction beyond the rival distance must also beat by
            ``prior_margin`` the peaks found near the prediction along the line to it
            (:func:`bioslam.closure.verify`): Gauss-Newton stops where the scan stops pinning
            the pose, and along an aisle the true place 0.3 m from the prediction fitted
            within the margin of a look-alike 2.8 m on that outscored the prediction itself
            (the built-in warehouse, SICK, reversing, every third scan, seed 630: two false
            closures, 13.3 cm against the odometry's 1.0).
        partial_tie_angle: ``tie_angle`` for a partial closure (``reject_degenerate`` off):
            a corridor's walls pin the heading to tenths of a degree, so a turn from the
            prediction refined beyond this must beat it by ``prior_margin`` (simulated maze,
            SICK: a slide turned 4.4 deg from a prediction that was right fitted 0.946
            against 0.914).
        refuse_broken_odometry: distrust the odometry across its breaks (a step without a match,
            or a jump no robot can make between two scans: :func:`bioslam.closure.odometry_broke`).
            The map's prediction of where the robot is relative to a place made before a break is
            off by as much as the breaks since (:func:`bioslam.closure.break_extent`), so the
            verification's window is widened by that, and a closure is refused when one of the
            breaks departed from the robot's motion by more than the search window
            (:func:`bioslam.closure.break_departure`; their summed extent may be larger after gaps
            in a log); no scan is fused into a submap across a break. A registration within the
            unwidened window only confirms the break (a corridor seen along its axis fits anywhere
            along it). Refusing every closure across a break instead cost the maze's URG-04LX tour
            0.61 -> 0.08 of its revisits and freiburg-079 10 closures and 1.4 cm of ATE
            (``benchmarks/README.md``).
        outside_rival_distance, outside_rival_angle: how far (m, rad) from the map's
            prediction a check across breaks is challenged by poses outside its window
            (:func:`bioslam.closure.outside_rival`): as far as the breaks widened the
            window, up to this (at least the search window, the cap of a check across
            doubted steps). The odometry's own search reaches its window from its
            prediction, so a jump to a look-alike leaves the true place within about twice
            that. Challenged only within a 1.5 m search window, a simulated ring corridor's
            odometry made to jump 3 m had two closures confirm the jump, 3 m off. With the
            search window at 3 m, as by default, the distance adds nothing to it and only
            the angle widens the challenge (90° against the search's 45°).
        challenge_trusted: a check the odometry vouches for (no break or doubted step
            since the place) is challenged too, by poses outside its window up to
            ``outside_rival_distance`` within its own angle, and refused ('beyond drift')
            when one fits clearly better, on every point and where the submap looked
            (:func:`bioslam.closure.outside_rival` with ``better``): where the scan barely
            pins the motion the odometry can slide past its drift bound unflagged, and the
            window then holds a pose that fits well enough but not the place (simulated
            serpentine corridor, UTM-30LX, a reversal taken as going on: one closure
            1.40 m off). Only checks that score ``min_score`` are challenged: below it a
            look-alike often fits better than the true place, and the check waits for a
            partner anyway.
        break_distance, break_angle, break_acceleration, break_angular_acceleration: an
            odometry step is a break when it departs from the last step's velocity by more
            than this (m, rad) plus half this acceleration (m/s², rad/s²) times the time
            since the last scan squared (:func:`bioslam.closure.odometry_broke`).
        break_echo: within this many scans after a break, a search's step that turns away
            from the motion by more than the odometry's ``break_turn`` is a break too: the
            odometry turning back into the frame it left at the break
            (:func:`bioslam.closure.turned_after_break`).
        min_seen: the score counts only the points of the current scan where the submap's
            scans looked (a robot off the old centre-line sees what they never saw), but at
            least this share of the points (the unseen ones then as misses).
        consistency: a verified closure to a place the odometry relates to the robot only
            across a step it doubted or a break (:func:`bioslam.closure.odometry_doubted`,
            :func:`bioslam.closure.odometry_broke`) enters the map only once another closure
            confirms it (:class:`bioslam.closure.ClosureConsensus`): the two measurements
            and the odometry between them close a cycle within ``consistency_distance`` (m)
            / ``consistency_angle`` (rad) plus ``consistency_per_metre`` /
            ``consistency_angle_per_metre`` times the odometry they span, they were measured
            at least ``consistency_separation`` metres of travel apart, and no more of the
            closures within ``consistency_window`` metres contradict it than agree. One
            that finds no partner within the window is dropped. Requiring a partner for
            every closure also took the false ones out, but cost freiburg-079 (no doubted
            step, 26 breaks) 1 cm of ATE (6.84 -> 7.85 cm against the odometry's 7.64).
        weigh_jumps: the map's odometry link that carries a step no robot can make (one
            that departs from the last step's motion by more than the break thresholds,
            :func:`bioslam.closure.jumped`) is weighted by that departure, as one across a
            break, also when the odometry tracked it without a search (it is no break for
            the closures' checks): on the simulated rooms its one-scan slides of 20 cm
            otherwise held the map where a closure would have corrected it.
        distrust_jumps: such a step no robot can make is also, for the closures, a step the
            odometry cannot vouch for (:attr:`bioslam.slam.SelfMotion.jumps`; without a
            search it is no break, and it does not widen the verification's window): the
            robot's relation to a place made before it is not trusted (a closure needs
            another to agree with it and is challenged over the whole search window), and no
            submap fuses scans across it. Without it the maze's UTM-30LX thinned to every
            tenth scan, weaving route, accepted 5 false closures in seeds 0-4 (0.73-1.75 m
            off, each confirming a slide of the odometry); with it none, and every other of
            the seven default cases at those seeds closed the same loops
            (``benchmarks/README.md``, "Slides the odometry did not flag").
        distrust_slides: with ``distrust_jumps``, a step that departs by more than a robot
            can change its motion from the robot's steady motion (the last step that did not
            depart from the one before it, or that drove it back,
            :meth:`bioslam.slam.SelfMotion._reversed`), both as scaled by the stamps and as
            it was, is
            such a step too, though it departs from the step just before by less: the steps
            that carry a slide on until the motion comes back (a floor of curved corridors,
            RPLIDAR tour: the odometry slid 2 m back in 1 s, 0.07-0.3 m a scan, and a
            closure 4.7 s on confirmed the slide, 2.05 m off; with it the route accepts no
            closure). freiburg-079 124 closures against 126, ATE 7.16 against 7.13 cm
            (``benchmarks/README.md``, "Unseen floors").
        bridge_returns, return_tolerance, return_reach: a slide the odometry undid (jumps
            whose summed departure from the robot's motion comes back within
            ``return_tolerance`` times the break thresholds, within ``return_reach`` metres
            of travel: :class:`bioslam.closure.SlideReturns`) is bridged in the map by an
            odometry link from where the slide began to where it was undone, weighted as
            the odometry over that travel: the links that carry the slide and the return
            stay weak, so that a closure can move the stretch between, but its ends stay
            tied. Without it the two weak links let the rest of the run float along the
            slide (simulated rooms, UTM-30LX: four slides of 18-21 cm, each undone 3 s
            later, left the map 18 cm off after the first; ATE 11.9 cm against the
            odometry's 5.5).
        plateau_step, plateau_reach: an accepted closure's position information along the
            direction its scan constrains least is weakened to what its score pins there:
            how far (m, searched in steps of ``plateau_step`` up to ``plateau_reach``) the
            pose moves along it before the score where the submap looked drops by
            ``prior_tie`` (:func:`bioslam.closure.score_plateau`); 0 reach (the default)
            keeps the scan's geometry alone (:func:`bioslam.cognitive_map.registration_shape`).
            At 0.3 m it lowered the ATE of the simulated SICK maze tours (seeds 0 and 3: 1.58
            -> 0.74, 1.03 -> 0.86 cm) and of freiburg-079 (8.61 -> 8.00 cm), but the map it
            shaped led the maze's UTM-30LX weaving route, whose odometry broke 0.9 m there,
            to one closure 0.84 m off, so it is not the default (``benchmarks/README.md``).
        polish, line_distance, line_huber, line_reach, line_reach_angle: an accepted
            registration is polished by matching the scan's points to the lines through the
            submap's own points instead of its grid (:func:`bioslam.closure.polish_on_lines`,
            :mod:`bioslam.matching.point_to_line`): each point to the line of its nearest
            submap point within ``line_distance`` (m), Huber-weighted beyond ``line_huber``
            (m). The grid's bilinear map function pulls its optimum a fraction of a cell off,
            alike at every revisit; the rooms' SICK reversing route's loop links were off the
            truth by 0.53 cm (median), 0.26 polished, and its ATE went from 0.62 to 0.45 cm
            (odometry 0.26). A polish that moves the pose farther than
            ``line_reach`` (m) or ``line_reach_angle`` (rad) is not kept: the two then
            disagree about more than the grid's blur. Nor is one whose points scatter about
            their lines by more than ``line_max_spread`` (m, robust spread): lines fitted to
            noisy points (low-cost scanners, cluttered real rooms) tilt and shift by more than
            the blur. The median spreads of the polishes: maze UTM-30LX tour 7.9 mm, the rooms'
            SICK reversing run 8.3, intel 9.4, freiburg-079 11.7, the office ``lds01`` tour
            15.5, the maze RPLIDAR weaving 17.9; polished regardless, the last three's ATE
            grew (7.07 -> 7.21, 15.56 -> 19.04, 2.63 -> 2.64 cm).
        weak_margin: an accepted closure's correction of the map's prediction along the
            direction its scan constrains least (along a corridor) is kept only when its
            score where the submap looked is more than this above the score with the
            prediction's coordinate there (:func:`bioslam.closure.settle_weak_direction`);
            else the closure measures across that direction (and in heading) only. Along
            a corridor Gauss-Newton slides on a flat score: on the simulated SICK maze
            the closures 4-11 cm off were all slides along their corridor from a
            prediction 0.2-1.6 cm off there. 0 keeps every correction.
        lines_pin: a correction along those directions also stands where the polish on the
            submap's lines (``polish``) pins the position there: when it is more than this
            many of their standard deviations along it
            (:meth:`bioslam.matching.point_to_line.LineFit.position_sigma`), the lines
            measured it, though the grid's 10 cm cells score it as the prediction. Down a
            warehouse aisle with a drifting heading (SICK weaving route, 0.0002 rad/s), the
            polish put closures 0.1-0.6 cm from the truth along the aisle, and the settle
            took them back onto a prediction 2.4-4.4 cm off. Only while the heading drifts
            (``drift_scale``): where it holds the prediction is good along the aisle, and the
            lines' standard deviation, of residuals that are not independent, was too small
            (a warehouse aisle without drift, SICK reversing: a correction 3.2 cm off the
            truth kept at 0.8 cm, the run 1.32 -> 1.74 cm). 0, the default: the grid alone
            judges. On 24 drift runs of seeds neither option had seen, ``lines_pin`` 3 made 7
            better and 7 worse (median 4.01 -> 4.23 cm), with ``revisit_refused`` 7 and 8
            (benchmarks README, "The lines only where the heading drifts").
        weak_floor: a position correction along one of those directions of at most this
            (m) stands without the test: the score cannot judge millimetres, and on a scan
            that pins every direction the test took the polish's millimetres back to the
            prediction (the demo's maze: closures 2.4 mm off the truth polished, 5.5 mm
            settled, the odometry between the same stamps 4.3 mm), while a slide along a
            corridor is centimetres (the SICK maze's: 4-11 cm).
        refuse_far_settle: a correction taken back that way by more than ``rival_distance``
            or ``rival_angle`` refuses the closure as ambiguous: the prediction then fits
            about as well as the registration, a rival apart, and the scan cannot say which
            is the place. Kept, the closure would confirm the map's prediction there
            (a pillar hall seen to 3.5 m: registrations right to 2 cm settled 0.8-0.9 m back
            onto a prediction that closures across breaks had bent, three false closures).
        weak_modes: which corrections ``weak_margin`` judges, weakest first: 1 the
            position along the direction the scan constrains least, 2 also the heading, 3
            also the position along the best-constrained direction. 1: a heading
            correction stands, however little it moves the score. Where the odometry's
            heading drifted since the old pass the map's prediction carries the drift, and
            taken back (2) nine in ten closures did, each confirming the prediction's
            heading: with a heading drift injected, closures' heading errors 0.05-0.35 deg
            at the median of a run against 0.02-0.19 at 1 (15 runs on drawn floors), and
            the 20 min RPLIDAR route 2.54 -> 2.29 cm at the median over 14 seeds
            (``benchmarks/README.md``, "A closure's heading stands").
        close_to_first_scan: keep the run's first scan for closures to its experience
            where the scanner sweeps (``time_increment`` > 0). The odometry knew no
            velocity yet to de-skew it, so that scan and the odometry's first step carry
            the motion during the sweep, which a closure to it spreads over the whole loop
            (simulated hall, SICK scanner, seed 1: one closure to it, ATE 1.42 -> 2.86 cm).
        registration: the registration's map and Gauss-Newton parameters.
    """

    refine: bool = True
    min_score: float = 0.9
    partner_score: float = 0.7
    reject_degenerate: bool = False
    drift_floor: float = 0.3
    drift_per_metre: float = 0.02
    drift_angle_floor: float = 0.1
    drift_angle_per_metre: float = 0.005
    max_drift: float = 3.0
    max_drift_angle: float = 0.5
    link_floor: float = 0.05
    link_angle_floor: float = 0.03
    chain_distance: float = 2.0
    recognition_radius: float = 1.0
    deadband: float = 0.0
    deadband_angle: float = 0.0
    registration_interval: float = 0.25
    payload_spacing: float = 0.02
    max_scan_bend: float = 0.0087  # 0.5°
    proximity: bool = True
    revisit_refused: bool = False
    drift_scale: float = 0.1
    min_loop_travel: float = 3.0
    submap_reach: float = 1.5
    submap_step: float = 0.5
    submap_max_reach: float = 4.0
    submap_spacing: float = 0.03
    prefetch_submaps: bool = True
    search_distance: float = 3.0
    search_angle: float = math.radians(45.0)
    search_level: int = 1
    rival_distance: float = 0.5
    rival_angle: float = math.radians(20.0)
    max_ambiguity: float = 0.9
    ambiguity_memory: float = 2.0
    ambiguity_radius: float = 1.5
    clear_ambiguity: float = 0.8
    prior_margin: float = 0.1
    prior_tie: float = 0.02
    tie_distance: float = 0.15
    tie_angle: float = math.radians(5.0)
    search_prediction_plateau: bool = True
    partial_tie_angle: float = math.radians(1.0)
    min_seen: float = 0.6
    refuse_broken_odometry: bool = True
    outside_rival_distance: float = 3.0
    outside_rival_angle: float = math.radians(90.0)
    challenge_trusted: bool = True
    break_distance: float = 0.1
    break_angle: float = math.radians(10.0)
    break_acceleration: float = 2.0
    break_angular_acceleration: float = 10.0
    break_echo: int = 3
    consistency: bool = True
    weigh_jumps: bool = True
    distrust_jumps: bool = True
    distrust_slides: bool = True
    refuse_far_settle: bool = True
    bridge_returns: bool = True
    return_tolerance: float = 0.3
    return_reach: float = 10.0
    weak_margin: float = 0.05
    lines_pin: float = 0.0
    weak_modes: int = 1
    weak_floor: float = 0.02
    close_to_first_scan: bool = False
    plateau_step: float = 0.02
    plateau_reach: float = 0.0
    polish: bool = True
    line_distance: float = 0.1
    line_huber: float = 0.02
    line_reach: float = 0.05
    line_reach_angle: float = math.radians(1.0)
    line_max_spread: float = 0.01
    consistency_window: float = 10.0
    consistency_separation: float = 0.5
    consistency_distance: float = 0.1
    consistency_angle: float = 0.05
    consistency_per_metre: float = 0.005
    consistency_angle_per_metre: float = 0.002
    registration: RegistrationConfig = field(default_factory=RegistrationConfig)


@dataclass
class SLAMConfig:
    """Configuration of :class:`bioslam.slam.BioSLAM`.

    Attributes:
        view_distance, view_angle, view_min_scans: the view cells, pose cells and
            cognitive map take a new look after the robot has moved this far (m) or turned
            this much (rad) since the last, and at least ``view_min_scans`` scans later; in
            between only the odometry runs (and, while a registration is due, the map's
            proximity cue, which forces a look when it has a candidate). The paper looks at
            every scan; at 40 Hz consecutive scans are 1 cm apart and say nothing new, while
            a look costs 2-3 times the odometry's median scan. Every 0.05 m with a 10 Hz
            scanner meant a look at nearly every scan (median scan 3.5 times the
            odometry's); every 0.2 m cost the 600 s maze tour a tenth of its recall (views
            are recognised within a few centimetres of where they were learned, so sparse
            looks miss them). A look at most every third scan keeps the distance where the
            scanner is fast and bounds the cost where it is slow. 0 / 0 / 1 looks at every
            scan.
        view_wait: a look due waits up to this many scans for the next scan the odometry
            fuses into its map (every ``odometry.insert_distance`` / ``insert_angle``), when
            the last step says it comes within them. A fused scan costs the odometry about
            twice a matched one; a look on another scan made a third of the scans slow with
            a 10 Hz scanner (one look every three scans), which set the full system's median
            at the odometry's 75th percentile. On the scans the odometry fuses, the looks
            leave the others as fast as the odometry alone; the mean is unchanged. With 2
            the slow scanners' median scan went from 1.75-2.04 to 1.23-1.43 times the
            odometry's; freiburg-079 closed 143 loops instead of 156. It once let the maze's
            SICK weaving route accept a closure 0.98 m off, the true place outside the
            verification's window: closures across doubted odometry steps are now
            challenged from outside it (:func:`bioslam.closure.outside_rival`). 0 looks as
            soon as due (benchmarks README, "Loop closure").
        defer_relaxation: after a loop closure the map relaxes (Eq. 14) on a later scan,
            not on the one that registered the closure: the check (fusing its submap,
            registering) and the relaxation (a sparse solve over the map's recent window)
            together on one scan set the full system's p99 (benchmarks README, "Loop
            closure"). It waits for the next look, which reads the map and is slow
            already, up to ``relax_wait`` scans; then, as a look does (``view_wait``), for
            the next scan the odometry fuses. The proximity cue probed between looks reads
            the map as the last look left it (a look it forces relaxes first and asks the cue
            again). On a thinned log most scans are fused, so a relaxation on the next fused
            scan made one more slow scan per closure: relaxing on the looks took the median
            scan of a simulated SICK route, every 2nd scan kept, from 1.81 to 1.60 times the
            odometry's (benchmarks README, "Relaxations on the looks"). On freiburg-079
            relaxing on the next fused scan instead of the registration's had taken it from
            1.61 to 1.45. The closures are the same; the poses reported for the closure's
            scan and the few after it are the map's before its correction.
        relax_wait: scans a deferred relaxation waits for a look before it falls back to
            the next fused scan: looks come at least every ``view_min_scans`` scans while
            the robot moves ``view_distance`` in that many, so 8 covers a robot at a
            quarter of a metre a second with a 40 Hz scanner, and a stopped robot's map is
            corrected within 11 scans (1.1 s at 10 Hz).
        heading_bias: an artificial gyro-like heading drift (rad/s) added to every odometry
            step before it reaches the pose cells and the map; 0 in normal use. It exists for
            ablations that show loop closure pulling an extra drift back down.
    """

    odometry: OdometryConfig = field(default_factory=OdometryConfig)
    boundary: BoundaryCellConfig = field(default_factory=BoundaryCellConfig)
    views: ViewCellConfig = field(default_factory=ViewCellConfig)
    pose_cells: PoseCellConfig = field(default_factory=PoseCellConfig)
    cognitive_map: CognitiveMapConfig = field(default_factory=CognitiveMapConfig)
    loop_closure: LoopClosureConfig = field(default_factory=LoopClosureConfig)
    view_distance: float = 0.05
    view_angle: float = 0.05
    view_min_scans: int = 3
    view_wait: int = 2
    defer_relaxation: bool = True
    relax_wait: int = 8
    heading_bias: float = 0.0


#: Settings that may be negative (all other numbers are sizes, rates, thresholds or counts,
#: for which a negative value has no meaning).
SIGNED = frozenset({
    "heading_bias", "odometry.free_logodds", "odometry.log_odds.l_hit",
    "odometry.log_odds.l_miss", "odometry.log_odds.l_min", "odometry.log_odds.l_max",
    "pose_cells.start",
})
#: Settings with physical limits beyond their sign: ``key -> (low, high, low_inclusive)``.
RANGES: dict[str, tuple[float, float, bool]] = {
    "odometry.resolution": (1e-3, 10.0, True),
    "odometry.map_size": (1.0, 1e4, True),
    "odometry.max_range": (0.0, 1e4, False),
    "odometry.body_turn": (0.0, 1e3, False),
    "odometry.levels": (1, 8, True),
    "odometry.point_spacing": (0.0, 10.0, False),
    "odometry.recovery_free_fraction": (0.0, 1.0, True),
    "odometry.recovery_score_ratio": (0.0, 1.0, True),
    "odometry.search_free_fraction": (0.0, 1.0, True),
    "boundary.cells_per_ring": (1, 3600, True),
    "views.ds": (0.0, 1e3, False),
    "pose_cells.cell_size_xy": (0.0, 1e3, False),
    "loop_closure.min_score": (0.0, 1.0, True),
    "loop_closure.partner_score": (0.0, 1.0, True),
    "loop_closure.min_seen": (0.0, 1.0, True),
    "loop_closure.weak_margin": (0.0, 1.0, True),
    "loop_closure.weak_modes": (0, 3, True),
    "loop_closure.weak_floor": (0.0, 1.0, True),
    "loop_closure.clear_ambiguity": (0.0, 1.0, False),
    "loop_closure.payload_spacing": (1e-3, 10.0, True),
    "loop_closure.max_scan_bend": (0.0, 1e3, False),
    "loop_closure.line_distance": (0.0, 10.0, False),
    "loop_closure.line_huber": (0.0, 10.0, False),
    "loop_closure.line_max_spread": (0.0, 10.0, True),
    "loop_closure.registration.resolution": (1e-3, 10.0, True),
    "loop_closure.registration.max_range": (0.0, 1e4, False),
    "loop_closure.registration.levels": (1, 8, True),
    "loop_closure.registration.hit_level": (0.0, 1.0, True),
    "cognitive_map.correction": (0.0, 1.0, True),
}
#: Largest grid (cells) a setting may ask for. The odometry keeps several float64 layers per
#: cell, so 2.5e7 cells are about a gigabyte; a 48 m window at 1 cm (2.3e7 cells) still fits.
MAX_GRID_CELLS = 25 * 10**6
#: Largest count (iterations, sweeps, cells, scans) any integer setting may take: beyond it a
#: run would loop for hours or allocate without bound, and no setting needs more.
MAX_COUNT = 10**6


def _show(value: Any) -> str:
    """A value as the user wrote it in the file (JSON spelling: ``true``, ``"fine"``)."""
    try:
        text = json.dumps(value)
    except (TypeError, ValueError):
        text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _type_name(hint: Any) -> str:
    return getattr(hint, "__name__", None) or str(hint).replace("typing.", "")


def _check_number(value: Any, hint: type, key: str) -> float | int:
    """An int or float setting: a JSON/TOML number of the right kind, finite, in range."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        kind = "an integer" if hint is int else "a number"
        raise ValueError(f"{key} = {_show(value)}: expected {kind}")
    if hint is int and not isinstance(value, int):
        raise ValueError(f"{key} = {_show(value)}: expected an integer")
    if not math.isfinite(value):
        raise ValueError(f"{key} = {_show(value)}: expected a finite number")
    name = key.split("[")[0]
    if value < 0 and name not in SIGNED:
        raise ValueError(f"{key} = {_show(value)}: must not be negative")
    if hint is int and value > MAX_COUNT and name not in RANGES:
        raise ValueError(f"{key} = {_show(value)}: must be at most {MAX_COUNT}")
    if name in RANGES:
        lo, hi, inclusive = RANGES[name]
        if not (value >= lo if inclusive else value > lo) or value > hi:
            bracket = "[" if inclusive else "("
            raise ValueError(f"{key} = {_show(value)}: must be in {bracket}{lo:g}, {hi:g}]")
    return float(value) if hint is float else value


def _check_value(value: Any, hint: Any, key: str) -> Any:
    """``value`` checked (and converted: int -> float, list -> tuple) against ``hint``."""
    origin = typing.get_origin(hint)
    if origin in (typing.Union, types.UnionType):
        options = [h for h in typing.get_args(hint) if h is not type(None)]
        if value is None and len(options) < len(typing.get_args(hint)):
            return None
        errors = []
        for option in options:
            try:
                return _check_value(value, option, key)
            except ValueError as exc:
                errors.append(str(exc))
        raise ValueError(errors[0] if len(errors) == 1 else f"{key} = {_show(value)}: expected "
                         + " or ".join(_type_name(h) for h in typing.get_args(hint)))
    if origin is tuple:
        args = typing.get_args(hint)
        if not isinstance(value, (list, tuple)):
            raise ValueError(f"{key} = {_show(value)}: expected a list")
        if len(args) == 2 and args[1] is Ellipsis:
            args = (args[0],) * len(value)
            if not value:
                raise ValueError(f"{key} = []: expected at least one value")
        elif len(value) != len(args):
            raise ValueError(f"{key} = {_show(value)}: expected {len(args)} values")
        return tuple(_check_value(v, a, f"{key}[{i}]") for i, (v, a) in
                     enumerate(zip(value, args, strict=True)))
    if hint in (int, float):
        return _check_number(value, hint, key)
    if hint is bool:
        if not isinstance(value, bool):
            raise ValueError(f"{key} = {_show(value)}: expected true or false")
        return value
    if hint is str:
        if not isinstance(value, str):
            raise ValueError(f"{key} = {_show(value)}: expected a string")
        return value
    raise ValueError(f"{key}: settings of type {_type_name(hint)} cannot be given in a file")


def _apply(obj: Any, overrides: Any, where: str, prefix: str = "") -> Any:
    """A copy of the dataclass ``obj`` with ``overrides`` applied, recursing into sub-configs;
    each value is checked against the field's type hint (and :data:`RANGES`), and an error
    names ``where`` (the file) and the setting's dotted key."""
    section = prefix.rstrip(".") or "the top level"
    if not isinstance(overrides, dict):
        raise ValueError(f"{where}: {section} must be a table of settings, "
                         f"got {_show(overrides)}")
    names = {f.name: f for f in dataclasses.fields(obj)}
    hints = typing.get_type_hints(type(obj))
    changes: dict[str, Any] = {}
    for key, value in overrides.items():
        dotted = prefix + str(key)
        if key not in names:
            raise ValueError(f"{where}: unknown setting {dotted!r}; known in {section}: "
                             f"{', '.join(names)}")
        hint = hints[key]
        if dataclasses.is_dataclass(hint):
            changes[key] = _apply(getattr(obj, key), value, where, dotted + ".")
        else:
            try:
                changes[key] = _check_value(value, hint, dotted)
            except ValueError as exc:
                raise ValueError(f"{where}: {exc}") from None
    try:
        return dataclasses.replace(obj, **changes)
    except (ValueError, TypeError) as exc:
        raise ValueError(f"{where}: {section}: {exc}") from None


def check_sizes(config: SLAMConfig, where: str = "config") -> None:
    """Refuse settings whose grids would not fit in memory (a resolution of 1e-9 m asks for
    petabytes) before anything is allocated."""
    odo, reg = config.odometry, config.loop_closure.registration
    grids = {
        "odometry.map_size / odometry.resolution": (odo.map_size / odo.resolution) ** 2,
        "loop_closure.registration.max_range / resolution":
            (2 * reg.max_range / reg.resolution) ** 2,
        "pose_cells.dims": float(math.prod(config.pose_cells.dims)),
        "boundary.ring_distances x cells_per_ring":
            float(len(config.boundary.ring_distances) * config.boundary.cells_per_ring),
    }
    for what, cells in grids.items():
        if not cells <= MAX_GRID_CELLS:
            raise ValueError(f"{where}: {what} asks for a grid of {cells:.3g} cells, more than "
                             f"{MAX_GRID_CELLS:.1e} (it would not fit in memory)")


def config_from_dict(overrides: dict[str, Any], where: str = "config") -> SLAMConfig:
    """Defaults with ``overrides`` (nested dicts named like the fields) applied and checked."""
    config = _apply(SLAMConfig(), overrides, where)
    check_sizes(config, where)
    return config


def load_config(path: str | Path | None) -> SLAMConfig:
    """Read a TOML (``.toml``) or JSON file of overrides; ``None`` gives the defaults.

    Every problem (unreadable file, syntax, unknown key, wrong type, value out of range) is a
    ``ValueError`` naming the file and the key, raised before any work starts.
    """
    if path is None:
        return SLAMConfig()
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise FileNotFoundError(f"--config {path}: no such file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ValueError(f"--config {path}: cannot read it: {exc}") from None
    try:
        data = tomllib.loads(text) if path.suffix != ".json" else json.loads(text)
    except (tomllib.TOMLDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"{path}: cannot parse configuration: {exc}") from None
    return config_from_dict(data, str(path))


def config_to_dict(config: SLAMConfig) -> dict[str, Any]:
    """The full configuration as plain data, for the run summary."""
    return dataclasses.asdict(config)
