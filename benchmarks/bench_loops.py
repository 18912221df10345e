"""Loop closure on simulated worlds with ground truth: how many revisits are recognised and
verified, whether any accepted closure is false, what the closures do to the trajectory, and
what they cost. Every figure is measured in this run.

For each case (world, scanner, route):

* checks: loop-closure verifications run, by cue (``view``: a view cell recognised the place;
  ``proximity``: the map put the robot near an old experience) and by outcome;
* precision: an accepted closure is true when its measured pose of the robot in the
  experience's frame is within 0.5 m and 20 deg of the true one (also the median error of the
  true ones, cm / deg);
* recall: the route is cut into 1 m bins of travel; a bin is a *revisit* when the robot passes
  within 0.5 m of where it was at least ``--gap`` metres of travel earlier, and is *recognised*
  when a true closure was accepted in it; also split by the heading offset from the earlier
  pass (median over the bin): up to 30 deg, 30-90 deg, and beyond 90 deg (the other way: a
  180 or 270 deg scanner then shares little or nothing of its field of view with it); and,
  with the revisits taken out to 1 m beside the earlier pass, by how far beside it the robot
  ran (median over the bin): under 0.25 m, 0.25-0.5, 0.5-0.75, 0.75-1 m (both cues and the
  verification together: the views alone recognise a place within about 5 cm sideways,
  ``bench_views.py``);
* ATE RMSE of the full system and of its own odometry;
* revisit sharpness (:mod:`bioslam.consistency`): at the scans where the robot came back
  within 3 m of a pass 30 s or more earlier (chosen on the truth, a log's reference, or the
  full system's trajectory when the log has none), the median distance of their endpoints to
  the other pass's, placed by each trajectory: the median over those scans, and at how many
  of them the full system's map is sharper than the other's. It needs no reference, and a
  log's reference is judged by it like any trajectory;
* per-scan wall time: the full system's median, p99 and mean, and the odometry alone on the
  same scans, run interleaved with it scan by scan (ratios of medians and of means), after
  the warm-up ``bioslam run`` does before its first scan (every compiled kernel's first call,
  SciPy's sparse solver loaded by a loop closure: :func:`bioslam.pipeline.warm_up`), so that
  start-up costs are not counted as the first scans' (``--cold`` counts them); and the full
  system's on the scans that ran a closure check's registration and on the others.

    python benchmarks/bench_loops.py [--cases maze-tour,rooms-adversarial,...] [--duration 600]
        [--thin 5]
        [--set view_distance=0.2 --set loop_closure.min_score=0.9 ...] [--log LOG --cases ""]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, replace

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np

from bioslam.closure import slides
from bioslam.cognitive_map import configured_noise, untaught_noise
from bioslam.config import SLAMConfig, config_from_dict
from bioslam.consistency import SharpnessComparison, find_revisits, revisit_residuals
from bioslam.evaluation import (
    FALSE_CLOSURE_ANGLE_DEG,
    FALSE_CLOSURE_DISTANCE,
    evaluate,
    relative_pose_errors,
)
from bioslam.geometry import between, wrap_angle
from bioslam.odometry import LidarOdometry
from bioslam.pipeline import warm_up
from bioslam.scan import LaserScan
from bioslam.sim import LIDAR_PRESETS, ROUTES, load_world, people_on_roadmap, simulate_scans
from bioslam.slam import BioSLAM
from bioslam.trajectory import Trajectory

TRUE_DISTANCE = FALSE_CLOSURE_DISTANCE
TRUE_ANGLE = math.radians(FALSE_CLOSURE_ANGLE_DEG)


@dataclass(frozen=True)
class SimCase:
    world: str
    lidar: str
    route: str
    #: the scanner's heading on the robot, degrees (``bioslam sim --mount-yaw``)
    mount_yaw: float = 0.0
    #: the scanner sweeps clockwise, its angles counting down (``bioslam sim --clockwise``)
    clockwise: bool = False
    #: a beam that met nothing reported as the maximum range (``bioslam sim --no-return-as-max``)
    no_return_as_max: bool = False

    @property
    def name(self) -> str:
        mounted = f" (mounted at {self.mount_yaw:g} deg)" if self.mount_yaw else ""
        swept = " (clockwise)" if self.clockwise else ""
        maxed = " (no return as the maximum)" if self.no_return_as_max else ""
        return f"{self.world}-{self.lidar}-{self.route}{mounted}{swept}{maxed}"


DEFAULT_CASES = (
    SimCase("maze", "utm30lx", "tour"),
    SimCase("maze", "utm30lx", "adversarial"),
    SimCase("maze", "rplidar", "adversarial"),
    SimCase("rooms", "sick", "adversarial"),
    SimCase("rooms", "utm30lx", "tour"),
    SimCase("warehouse", "sick", "tour"),
    SimCase("warehouse", "utm30lx", "adversarial"),
)


def sim_cases(names: str, *options: float | bool) -> list[SimCase]:
    """The cases named in ``names``, comma-separated world-lidar-route (none for ''), each
    with ``options`` (:class:`SimCase`'s after the route); ValueError naming a bad one."""
    cases = []
    for name in names.split(",") if names else ():
        parts = name.rsplit("-", 2)  # the world may be a map YAML's path
        if len(parts) != 3:
            raise ValueError(f"{name!r} is not world-lidar-route (none at all: '')")
        cases.append(SimCase(*parts, *options))
    return cases


def simulate(
    case: SimCase, duration: float, seed: int, thin: int = 1, people: int = 0
) -> tuple[list, Trajectory]:
    """The case's scans (every ``thin``-th, as a log thinned for size) and ground truth, with
    ``people`` walking the corridors as ``bioslam sim --people`` has them."""
    world = load_world(case.world)
    route = ROUTES[case.route](world, duration=duration, seed=seed)
    walkers = people_on_roadmap(world, people, seed=seed) if people else []
    lidar = replace(
        LIDAR_PRESETS[case.lidar], mount_yaw=math.radians(case.mount_yaw),
        clockwise=case.clockwise, no_return_as_max=case.no_return_as_max,
    )  # fmt: skip
    pairs = list(simulate_scans(world, lidar, route, seed=seed, obstacles=walkers))[::thin]
    scans = [scan for scan, _ in pairs]
    return scans, Trajectory(np.array([s.stamp for s in scans]), np.array([p for _, p in pairs]))


def timed_run(scans: list, config: SLAMConfig) -> tuple[BioSLAM, np.ndarray, np.ndarray]:
    """The full system and the odometry alone on the same scans, per-scan wall ms of each.
    The two run interleaved, scan by scan, so that whatever else loads the machine weighs
    on both alike: run one after the other, their ratio of medians moved by 0.2-0.3 between
    runs of the same code on a shared machine. Which of the two goes first alternates from
    scan to scan: the second to take a scan runs on warm caches, and on freiburg-079 that
    alone made the odometry inside the full system 0.07 ms slower than the one beside it
    on the scans without a look (ratio of medians 1.67 with the full system always first,
    1.46 with it always second)."""
    slam = BioSLAM(config)
    odo = LidarOdometry(config.odometry)
    full_ms, odo_ms = np.empty(len(scans)), np.empty(len(scans))
    for k, scan in enumerate(scans):
        if k % 2:
            odo_ms[k] = wall_ms(odo.update, scan)
            full_ms[k] = wall_ms(slam.process, scan)
        else:
            full_ms[k] = wall_ms(slam.process, scan)
            odo_ms[k] = wall_ms(odo.update, scan)
    slam.finish()
    return slam, full_ms, odo_ms


def wall_ms(step: Callable[[LaserScan], object], scan: LaserScan) -> float:
    t0 = time.perf_counter()
    step(scan)
    return (time.perf_counter() - t0) * 1e3


def closure_errors(slam: BioSLAM, gt: Trajectory) -> list[tuple[float, str, float, float]]:
    """(stamp, cue, metres, degrees) of each accepted closure's error against the truth."""
    accepted = [check for check in slam.checks if check.verdict.accepted]
    errors = relative_pose_errors(
        [c.experience_stamp for c in accepted], [c.stamp for c in accepted],
        [c.verdict.pose for c in accepted], gt, max_dt=math.inf, free=slides(accepted),
    )  # fmt: skip
    pairs = zip(accepted, errors, strict=True)
    return [(c.stamp, c.cue, float(m), float(d)) for c, (m, d) in pairs]


def sharpness_line(slam: BioSLAM, scans: list, reference: Trajectory | None, name: str) -> str:
    """Revisit sharpness of the full system's map, its odometry's and ``reference``'s (called
    ``name``; None: the revisits chosen on the full system's trajectory)."""
    stamps = np.array([scan.stamp for scan in scans])
    placed = {"full": slam.trajectory(), "odometry": slam.odometry_trajectory()}
    if reference is not None:
        placed[name] = reference
    poses = {key: traj.at(stamps).poses for key, traj in placed.items()}
    revisits = find_revisits(poses[name if reference is not None else "full"], stamps)
    if not revisits:
        return "  revisit sharpness: no revisit"
    endpoints = [scan.endpoints() for scan in scans]
    residual = {key: revisit_residuals(endpoints, p, revisits) for key, p in poses.items()}
    judged = ~np.isnan(residual["full"])
    medians = ", ".join(f"{key} {1e3 * np.nanmedian(r):.1f}" for key, r in residual.items())
    sharper = ", ".join(
        f"than {key} at {np.mean(residual['full'][judged] < r[judged]):.0%}"
        for key, r in residual.items() if key != "full"
    )
    return (f"  revisit sharpness over {int(judged.sum())} scans, median mm: {medians}; "
            f"full sharper {sharper}")


def correction_lines(slam: BioSLAM, truth: Trajectory) -> list[str]:
    """What the closures do to the map, against ``truth`` (ground truth or a log's corrected
    poses): the loop links' own errors (their measured relative pose against the truth's
    between the two experiences' stamps; a partial one's position across its slide only), and
    the ATE of the whole map re-solved with every
    link given the truth's relative pose ("true closures": each loop link's, the odometry's
    kept; "all true": every link's, the floor left by the per-scan odometry), and with the
    loop links left out (the odometry's own, through the map), and with the links weighed
    by the configured link noise instead of the one the closures taught (:func:`noise_line`).
    A full ATE above the true closures' is the registrations' error; true closures no better
    than none say that the closures have nothing to correct there. (Where the finished map
    dropped its closures, each re-solve weighs them nothing.)"""
    cmap = slam.cognitive_map
    if cmap.num_links == 0:
        return []
    stamps, poses = truth.stamps, truth.poses
    at = np.clip(np.searchsorted(stamps, [e.stamp for e in cmap.experiences]), 0, len(stamps) - 1)
    links = cmap.links
    ends = np.array([(k.source, k.target) for k in links])
    loop = np.array([k.kind == "loop" for k in links])
    measured = np.array([k.dp for k in links])
    true = between(poses[at[ends[:, 0]]], poses[at[ends[:, 1]]])
    with_true_loops = np.where(loop[:, None], true, measured)

    def figures(nodes: np.ndarray) -> dict:
        return evaluate(slam.trajectory(nodes), truth)

    def ate_cm(nodes: np.ndarray) -> float:
        return 100 * figures(nodes)["ate_rmse_m"]

    # at the truth's own stamps, as ``true``; a partial link judged across its slide only
    slide = np.array([(np.nan, np.nan) if k.free is None else k.free for k in links])[loop]
    near = stamps[at]
    errors = relative_pose_errors(
        near[ends[loop, 0]], near[ends[loop, 1]], measured[loop], truth, np.inf, slide
    )
    metres, degrees = errors[:, 0], errors[:, 1]
    spread = (
        f"median {100 * np.median(metres):.2f} cm / {np.median(degrees):.2f} deg, 90th "
        f"percentile {100 * np.percentile(metres, 90):.2f} cm / {np.percentile(degrees, 90):.2f}"
        f" deg" if loop.any() else "-"
    )
    as_run, without = figures(cmap.solved()), figures(cmap.solved(loops=False))
    as_run_cm = 100 * as_run["ate_rmse_m"]
    settings = configured_noise(cmap.config)
    configured = as_run_cm if cmap.noise == settings else ate_cm(cmap.solved(noise=settings))
    return [
        f"  loop links against the truth: {spread}",
        f"  ATE re-solved: as run {as_run_cm:.2f} cm, true closures "
        f"{ate_cm(cmap.solved(with_true_loops)):.2f}, all links true "
        f"{ate_cm(cmap.solved(true)):.2f}, no closures {100 * without['ate_rmse_m']:.2f}"
        f", the configured link noise {configured:.2f}"
        + (" (the closures dropped: weighing nothing in each)" if cmap.closures_dropped else ""),
        spread_line(as_run, without),
        noise_line(slam),
    ]


def spread_line(as_run: dict, without: dict) -> str:
    """The largest error and the 1 m RPE of the map as run and without its closures
    (:func:`bioslam.evaluation.evaluate`'s figures of each): where the closures bring
    earlier passes onto one another but an uncorrected stretch stays off, the whole-run ATE
    can rise while both of these fall."""
    largest, rpe = (f"{100 * as_run[key]:.2f} / {100 * without[key]:.2f}"
                    for key in ("ate_max_m", "rpe_1m_trans_m"))  # fmt: skip
    return f"  as run / no closures: largest error {largest} cm, RPE over 1 m {rpe} cm"


def noise_line(slam: BioSLAM) -> str:
    """The link noise the finished map was solved with, and how many of the accepted
    closures taught it: only those the odometry relates to their place without a break or
    a jump (:meth:`bioslam.slam.BioSLAM._learn_noise`); the model is the settings' until
    ``noise_min_closures`` have, and the finished map's until ``noise_min_closures_finished``
    have (:meth:`bioslam.slam.BioSLAM._finished_noise`)."""
    noise = slam.cognitive_map.noise
    accepted = sum(check.verdict.accepted for check in slam.checks)
    config = slam.cognitive_map.config
    models = {"the settings'": configured_noise(config), "untaught": untaught_noise(config)}
    settings = next((name for name, model in models.items()
                     if dataclasses.replace(model, jump_scale=noise.jump_scale) == noise), "taught")
    jumps = "held" if noise.jump_scale == 0.0 else "free"
    return (
        f"  link noise from {len(slam.link_noise)} of {accepted} closures: odometry "
        f"{noise.odometry_var_per_m:.1e} m²/m, heading scale {noise.heading_scale:.1e}; "
        f"closure {100 * math.sqrt(noise.closure_var):.2f} cm / "
        f"{math.degrees(math.sqrt(noise.closure_heading_var)):.3f} deg; model "
        f"{settings}{_test_text(slam.settings_test, 'taught', 'settings')}, jumps "
        f"{jumps}{_test_text(slam.jump_test, 'free', 'held')}"
        + (f", {slam.unbent_held} bent little held"
           f"{_test_text(slam.unbent_test, 'held', 'free')}"
           if slam.unbent_test is not None else "")
        + ", closures "
        f"{'dropped' if slam.cognitive_map.closures_dropped else 'kept'}"
        f"{_test_text(slam.closures_test, 'kept', 'dropped')}"
    )


def _test_text(test: SharpnessComparison | None, first: str, second: str) -> str:
    """A scans' test of the finished map (:meth:`CognitiveMap.adopt_if_sharper`) in words."""
    if test is None:
        return ""
    return (f" (the scans' revisits, {test.judged}: {first} {1e3 * test.median_first:.2f} mm, "
            f"{second} {1e3 * test.median_second:.2f}, p {test.p_second_sharper:.2g})")


#: Heading-offset classes of revisits (degrees from the earlier pass), as reported.
OFFSET_CLASSES = ((0.0, 30.0, "<=30deg"), (30.0, 90.0, "30-90deg"), (90.0, 180.1, ">90deg"))
#: how far beside the earlier pass a revisit ran (the median over its bin), metres
SIDEWAYS_CLASSES = ((0.0, 0.25, "<0.25m"), (0.25, 0.5, "0.25-0.5m"), (0.5, 0.75, "0.5-0.75m"),
                    (0.75, 1.0, "0.75-1m"))  # fmt: skip
SIDEWAYS_REACH = SIDEWAYS_CLASSES[-1][1]


@dataclass(frozen=True)
class RevisitBin:
    """A revisit bin's median heading offset (deg) and distance (m) from the earlier pass."""

    heading: float
    distance: float


def revisit_bins(
    gt: Trajectory, gap: float, reach: float = TRUE_DISTANCE
) -> tuple[np.ndarray, dict[int, RevisitBin]]:
    """The travel bin of every pose and, per revisit bin (the robot within ``reach`` of
    where it was ``gap`` metres of travel or more before), its offsets from that pass."""
    xy = gt.poses[:, :2]
    travel = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(xy, axis=0).T))])
    bins = np.floor(travel).astype(np.int64)
    near: dict[int, list[tuple[float, float]]] = {}
    # a sparse sample of the route is enough to find where it was before
    sample = np.arange(0, len(xy), max(1, len(xy) // 4000))
    for i in sample:
        old = sample[travel[sample] <= travel[i] - gap]
        if not old.size:
            continue
        d = np.hypot(*(xy[old] - xy[i]).T)
        j = int(np.argmin(d))
        if d[j] <= reach:
            turn = abs(math.degrees(wrap_angle(gt.poses[i, 2] - gt.poses[old[j], 2])))
            near.setdefault(int(bins[i]), []).append((turn, float(d[j])))
    medians = {b: np.median(np.array(v), axis=0) for b, v in near.items()}
    return bins, {b: RevisitBin(float(m[0]), float(m[1])) for b, m in medians.items()}


def bins_at(gt: Trajectory, bins: np.ndarray, stamps: np.ndarray) -> np.ndarray:
    """The travel bin of the ground-truth pose at each of ``stamps``."""
    return bins[np.clip(np.searchsorted(gt.stamps, stamps), 0, len(bins) - 1)]


def _recall_by(
    revisits: dict[int, RevisitBin], hit: set, classes: tuple, of: Callable[[RevisitBin], float]
) -> dict[str, tuple[int, int]]:
    out = {}
    for lo, hi, name in classes:
        members = [b for b, revisit in revisits.items() if lo <= of(revisit) < hi]
        out[name] = (len(members), sum(b in hit for b in members))
    return out


def recognised_bins(gt: Trajectory, bins: np.ndarray, true_stamps: np.ndarray) -> set[int]:
    """The travel bins in which a true closure was accepted (at ``true_stamps``)."""
    return set(bins_at(gt, bins, true_stamps).tolist())


def revisit_recall(revisits: dict[int, RevisitBin], hit: set[int]) -> dict[str, tuple[int, int]]:
    """(revisit bins, recognised bins), all and per heading-offset class (module docstring)."""
    out = {"all": (len(revisits), sum(b in hit for b in revisits))}
    return out | _recall_by(revisits, hit, OFFSET_CLASSES, lambda r: r.heading)


def sideways_recall(
    gt: Trajectory, true_stamps: np.ndarray, gap: float
) -> dict[str, tuple[int, int]]:
    """(revisit bins, recognised bins) per class of distance from the earlier pass, the
    revisits taken out to ``SIDEWAYS_REACH`` beside it (module docstring)."""
    bins, revisits = revisit_bins(gt, gap, SIDEWAYS_REACH)
    hit = recognised_bins(gt, bins, true_stamps)
    return _recall_by(revisits, hit, SIDEWAYS_CLASSES, lambda r: r.distance)


def revisit_stages(
    gt: Trajectory, bins: np.ndarray, revisits: dict[int, RevisitBin], hit: set[int],
    checks: list,
) -> dict[str, int]:  # fmt: skip
    """Where each revisit bin's recognition stopped: ``recognised`` (a true closure accepted
    in it); ``refused <reason>`` (checks ran and the verification refused them all, by the
    bin's most frequent reason; ``accepted false`` if only a false one passed); ``no check``
    (no candidate from either cue reached the verification)."""
    reasons: dict[int, list[str]] = {}
    stamps = np.array([c.stamp for c in checks])
    for check, b in zip(checks, bins_at(gt, bins, stamps), strict=True):
        reasons.setdefault(int(b), []).append(check.verdict.reason or "accepted false")
    out: dict[str, int] = {}
    for b in revisits:
        if b in hit:
            stage = "recognised"
        elif b in reasons:
            # ties to the first reason in alphabetical order, not to the set's hash order
            stage = "refused " + max(sorted(set(reasons[b])), key=reasons[b].count)
        else:
            stage = "no check"
        out[stage] = out.get(stage, 0) + 1
    return out


def _shares(recall: dict[str, tuple[int, int]]) -> str:
    return ", ".join(
        f"{name} {hit}/{n}" + (f" {hit / n:.2f}" if n else "") for name, (n, hit) in recall.items()
    )


def report(
    case: SimCase, duration: float, seed: int, gap: float, config: SLAMConfig, thin: int = 1,
    people: int = 0,
) -> str:
    scans, gt = simulate(case, duration, seed, thin, people)
    slam, full_ms, odo_ms = timed_run(scans, config)
    errors = closure_errors(slam, gt)
    true = [e for e in errors if e[2] <= TRUE_DISTANCE and e[3] <= math.degrees(TRUE_ANGLE)]
    true_stamps = np.array([e[0] for e in true])
    bins, revisit_of = revisit_bins(gt, gap)
    hit = recognised_bins(gt, bins, true_stamps)
    recall = revisit_recall(revisit_of, hit)
    revisits, recognised = recall["all"]
    stages = revisit_stages(gt, bins, revisit_of, hit, slam.checks)
    by_offset = _shares({k: v for k, v in recall.items() if k != "all"})
    by_distance = _shares(sideways_recall(gt, true_stamps, gap))
    by = checks_by_outcome(slam)
    full = evaluate(slam.trajectory(), gt)["ate_rmse_m"]
    odo = evaluate(slam.odometry_trajectory(), gt)["ate_rmse_m"]
    med_err = (
        f"{100 * np.median([e[2] for e in true]):.1f} cm / "
        f"{np.median([e[3] for e in true]):.2f} deg, largest "
        f"{100 * max(e[2] for e in true):.1f} cm / {max(e[3] for e in true):.2f} deg"
        if true else "-"
    )
    lines = [
        f"{case.name} ({len(scans)} scans, {duration:g} s, seed {seed}"
        + (f", {people} people" if people else "")
        + (f", every {thin}th scan)" if thin > 1 else ")"),
        f"  checks: {', '.join(f'{k} {v}' for k, v in sorted(by.items()))}",
        f"  accepted {len(errors)} ({slam.summary()['closures_partial']} partial), false "
        f"{len(errors) - len(true)}, precision "
        f"{len(true) / max(len(errors), 1):.3f}; median error of true ones {med_err}",
        f"  revisit bins {revisits}, recognised {recognised}, recall "
        f"{recognised / max(revisits, 1):.3f}; loop links {slam.summary()['loop_closures']}",
        f"  recall by heading offset from the earlier pass: {by_offset}",
        f"  recall by distance from the earlier pass (revisits within {SIDEWAYS_REACH:g} m):"
        f" {by_distance}",
        "  revisit bins by stage: "
        + ", ".join(f"{k} {v}" for k, v in sorted(stages.items(), key=lambda kv: -kv[1])),
        f"  ATE RMSE full {100 * full:.2f} cm, odometry {100 * odo:.2f} cm",
        *correction_lines(slam, gt),
        sharpness_line(slam, scans, gt, "truth"),
        *cost_lines(slam, scans, full_ms, odo_ms),
    ]
    if len(errors) > len(true):
        worst = max(errors, key=lambda e: e[2])
        lines.append(
            f"  worst false: t={worst[0]:.1f} s {worst[1]} {worst[2]:.2f} m {worst[3]:.1f} deg"
        )
    return "\n".join(lines)


def report_log(path: str, config: SLAMConfig) -> str:
    """The same figures on a real log against the corrected poses it carries (closure errors
    against them are an upper bound: the reference is itself a SLAM system's output)."""
    from bioslam.io.logs import open_log

    source = open_log(path)
    scans = list(source)
    reference = source.reference
    slam, full_ms, odo_ms = timed_run(scans, config)
    if reference is None:
        return report_loop_gap(path, slam, full_ms, odo_ms, scans)
    errors = closure_errors(slam, reference)
    metres = np.array([e[2] for e in errors])
    full = evaluate(slam.trajectory(), reference)["ate_rmse_m"]
    odo = evaluate(slam.odometry_trajectory(), reference)["ate_rmse_m"]
    spread = (
        f"median {100 * np.median(metres):.1f} cm, 90th percentile "
        f"{100 * np.percentile(metres, 90):.1f} cm, largest {100 * metres.max():.1f} cm"
        if metres.size else "-"
    )
    return "\n".join([
        f"{path} ({len(scans)} scans)",
        f"  accepted closures {len(errors)} of {len(slam.checks)} checks; error against the "
        f"reference {spread}",
        f"  ATE RMSE full {100 * full:.2f} cm, odometry {100 * odo:.2f} cm",
        *correction_lines(slam, reference),
        sharpness_line(slam, scans, reference, "reference"),
        *cost_lines(slam, scans, full_ms, odo_ms),
    ])


def checks_by_outcome(slam: BioSLAM) -> dict[str, int]:
    """Verifications counted by ``cue:outcome`` (the refusal's reason, or ``accepted``)."""
    by: dict[str, int] = {}
    for check in slam.checks:
        key = f"{check.cue}:{check.verdict.reason or 'accepted'}"
        by[key] = by.get(key, 0) + 1
    return by


def cost_lines(slam: BioSLAM, scans: list, full_ms: np.ndarray, odo_ms: np.ndarray) -> list[str]:
    """The per-scan wall times of the full system and of the odometry alone, same run; and
    the full system's on the scans that ran a loop-closure check's registration, and on the
    others (where a check runs on more than 1 % of the scans, the p99 is a check's cost)."""
    checked = np.isin([scan.stamp for scan in scans], [check.stamp for check in slam.checks])
    parts = [
        f"{name} median {np.median(ms):.2f} p99 {np.percentile(ms, 99):.2f}"
        for name, ms in (("with", full_ms[checked]), ("without", full_ms[~checked]))
        if ms.size
    ]
    return [
        f"  per-scan ms full median {np.median(full_ms):.2f} p99 {np.percentile(full_ms, 99):.2f};"
        f" odometry median {np.median(odo_ms):.2f} p99 {np.percentile(odo_ms, 99):.2f};"
        f" ratio of medians {np.median(full_ms) / np.median(odo_ms):.2f};"
        f" means {np.mean(full_ms):.2f} / {np.mean(odo_ms):.2f} = "
        f"{np.mean(full_ms) / np.mean(odo_ms):.2f}",
        f"  scans with a closure check's registration {int(checked.sum())} of {len(scans)}"
        f" ({100 * checked.mean():.1f} %); full ms {'; '.join(parts)}",
    ]


def report_loop_gap(
    path: str, slam: BioSLAM, full_ms: np.ndarray, odo_ms: np.ndarray, scans: list
) -> str:
    """A log without corrected poses: closures, checks, the loop gap and the return misfit
    (``loop_consistency``) of the full system against its own odometry's."""
    from loop_consistency import loop_gap, return_misfit

    by = checks_by_outcome(slam)
    full, odo = loop_gap(slam.trajectory()), loop_gap(slam.odometry_trajectory())
    misfits = [
        return_misfit(traj, scans) for traj in (slam.trajectory(), slam.odometry_trajectory())
    ]
    return "\n".join([
        f"{path} ({slam.num_scans} scans, no reference)",
        f"  accepted closures {slam.summary()['loop_closures']} of {len(slam.checks)} checks: "
        + ", ".join(f"{k} {v}" for k, v in sorted(by.items())),
        f"  loop gap full {full['loop_gap_m']:.3f} m / {full['loop_gap_deg']:.1f} deg, odometry "
        f"{odo['loop_gap_m']:.3f} m / {odo['loop_gap_deg']:.1f} deg",
        "  return misfit (the return scan registered against the start's): "
        + ", ".join(
            f"{name} {m['misfit_m']:.3f} m / {m['misfit_deg']:.1f} deg at score {m['score']:.3f}"
            + (f" (not measured: {m['reason']})" if m.get("reason") else "")
            for name, m in zip(("full", "odometry"), misfits, strict=True)
        ),
        sharpness_line(slam, scans, None, ""),
        *cost_lines(slam, scans, full_ms, odo_ms),
    ])


def overrides(items: list[str]) -> dict:
    """``key=value`` settings (dotted keys nest; a key that is no top-level setting is a
    ``loop_closure`` one, as before) as the nested dict ``config_from_dict`` takes."""
    top = {f.name for f in dataclasses.fields(SLAMConfig)}
    out: dict = {}
    for item in items:
        key, value = item.split("=", 1)
        path = key.split(".")
        if path[0] not in top:
            path = ["loop_closure", *path]
        node = out
        for part in path[:-1]:
            node = node.setdefault(part, {})
        node[path[-1]] = json.loads(value)  # numbers, true/false
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", default=",".join(c.name for c in DEFAULT_CASES),
                    help="world-lidar-route names, comma-separated (the world a built-in "
                    "one's name or a map YAML's path, e.g. from office_floor_plan.py)")
    ap.add_argument("--duration", type=float, default=600.0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--gap", type=float, default=10.0, help="metres of travel before a revisit")
    ap.add_argument("--thin", type=int, default=1,
                    help="keep every n-th scan only (a thinned log: the odometry's steps grow)")
    ap.add_argument("--people", type=int, default=0,
                    help="people walking the corridors (as bioslam sim --people)")
    ap.add_argument("--mount-yaw", type=float, default=0.0,
                    help="the scanner's heading on the robot, degrees (as bioslam sim "
                         "--mount-yaw; the ground truth is the scanner's pose)")
    ap.add_argument("--clockwise", action="store_true",
                    help="the scanner sweeps clockwise, its angles counting down (as bioslam "
                         "sim --clockwise)")
    ap.add_argument("--no-return-as-max", action="store_true",
                    help="a beam that met nothing reported as the maximum range (as bioslam "
                         "sim --no-return-as-max)")
    ap.add_argument("--log", action="append", default=[],
                    help="also a real log: against its corrected poses (e.g. freiburg-079), "
                         "or by its loop gap when it has none (exp1.dat, the ROS 1 bag)")
    ap.add_argument("--set", action="append", default=[],
                    help="setting override, e.g. --set loop_closure.deadband=0 (a bare name "
                         "is a loop_closure setting)")
    ap.add_argument("--cold", action="store_true",
                    help="no warm-up: the first calls of the compiled kernels and the first "
                         "closure's loading of the sparse solver count as the scans'")
    args = ap.parse_args()
    config = config_from_dict(overrides(args.set), "--set")
    try:
        cases = sim_cases(args.cases, args.mount_yaw, args.clockwise, args.no_return_as_max)
    except ValueError as error:
        ap.error(f"--cases: {error}")
    if not args.cold:
        print(f"warm-up (as bioslam run does): {warm_up(config):.1f} s", flush=True)
    for path in args.log:
        print(report_log(path, config), flush=True)
    for case in cases:
        print(
            report(case, args.duration, args.seed, args.gap, config, args.thin, args.people),
            flush=True,
        )


if __name__ == "__main__":
    main()
