"""LiDAR odometry: accuracy, robustness and speed (issue 3's targets).

Cases (``--only`` picks some, ``--quick`` shortens the simulated runs to 120 s):

- ``maze``: simulated maze, 600 s, Hokuyo UTM-30LX (sigma 1 cm, 40 Hz): RPE over 1 m,
  end-point drift as % of the distance travelled, CPU ms per scan (median, p99).
- ``lowcost``: the 360° low-cost preset (sigma 3 cm, 7 Hz) with 20 % random dropouts.
- ``fastturns``: corners at 1 rad/s, the UTM-30LX run at 10 Hz (a 25 ms -> 100 ms sweep).
- ``person``: three people walking along the robot's route through the scans.
- ``deskew``: the fast-turn run with and without de-skewing.
- ``shortrange``: the URG-04LX preset (240°, 5.6 m) on three 60 s routes, beside the same
  sensor with a 30 m range and with a 360° field of view.
- ``shortrangeseeds``: the URG-04LX on the maze's 600 s tour, seeds 1-12, the hall's, rooms'
  and warehouse's tour (seed 7), and 300 s of the maze's and hall's adversarial and
  reversing routes (seed 8): where a corridor longer than the range is driven on the motion
  model and the few endpoints at its doors and ends.
- ``lds01``: the TurtleBot3's ROBOTIS LDS-01 (360°, 3.5 m, 5 Hz) on the four worlds, both
  routes, seeds 0-2: most of an aisle, a hall between its pillars or a room is beyond its
  reach, and what it matches near the end of that reach holds the pose.
- ``corridor``: corridors longer than the range, where only the motion model carries the
  pose: the URG-04LX out and back along a closed 24 m corridor (a door niche near each end,
  0.3 m off the centre-line), and the SICK preset along an 80 m corridor with a door every
  6 m on alternate sides, thinned to one scan per metre.
- ``mapfunc``: Hector's bilinear M* against the sub-cell map function, maze 120 s.
- ``thinned``: the maze run keeping one scan in 20 or 40 (0.25 / 0.5 m and up to 25 / 50
  degrees apart), beside the same with the close recovery search only.
- ``sickthinned``: the SICK preset (181 beams at 1°) in the rooms off a corridor, the
  warehouse and the maze, a third of the run's duration, thinned along the true path to a
  scan per 1 m / 0.6 rad as the public "corrected" logs are, two seeds each.
- ``sicksparse``: the same in the warehouse and the maze thinned further, to a scan per
  1.5 m (the warehouse's uprights repeat every 2.8 m).
- ``freiburg``: freiburg-079 (LiDAR only), RPE over 1 m against the log's corrected poses,
  and how much of it is the reference's own: its jitter, the local map's sharpness, and a
  three-cornered hat with the log's raw wheel odometry as the third trajectory.
- ``freiburgthinned``: freiburg-079 keeping a scan per 0.5 m / 0.4 rad or 1 m / 0.6 rad of
  the reference's motion (as the SLAM benchmark's logs are thinned), beside the close
  recovery search alone.
- ``intel``: the thinned Intel log (0.67 m and 22 degrees apart at the median), with and
  without the wide search, from each scan of ``--starts`` (a wrong step changes the map
  every later scan is matched against, so the result depends on where the run starts);
  ``--figure PNG`` draws each run's step errors.
- ``intelsparse``: the Intel log thinned further, to a scan per 1.5 m / 45 degrees of the
  reference's motion (steps up to 2.2 m and 70 degrees), from each scan of ``--starts``.
- ``typicalstep``: the SICK preset on the four worlds, both routes, seeds 2-7 (routes no
  default was tuned on), a third of the run's duration, thinned to a scan per 1 m / 0.6 rad,
  with and without the search around the typical step
  (``OdometryConfig.typical_search_distance``).
- ``typicalstepurg``: the same with the URG-04LX (240°, 5.6 m): a scanner that looks back
  through the doors it passes, at the far faces of walls the map saw from the other side.
- ``typicalstep15``: the same thinned coarser, to a scan per 1.5 m / 0.6 rad, on the
  warehouse, the maze and the rooms, seeds 2-4.
- ``typicalsteprplidar``: the RPLIDAR preset (360°, 12 m, sweeping at 7 Hz) on the four
  worlds, both routes, seeds 2-7 (2 and 3 until the sweep's turn was measured), thinned to
  a scan per 1 m / 0.6 rad.
- ``mounted``: the SICK preset mounted facing forward, backwards (180°) and sideways (90°)
  on the robot (``LidarModel.mount_yaw``: the robot drives backwards or sideways in the
  scan's frame), on the four worlds, tour and adversarial route, seeds 2 and 3, a third of
  the run's duration, thinned to a scan per 1 m / 0.6 rad and as scanned.
- ``typicalstepreversing``: the ``reversing`` route (the tour, backing up 12 s along its
  own path every 45 s) on the four worlds, SICK and URG-04LX, seeds 2-7, thinned to a
  scan per 1 m / 0.6 rad: steps a metre behind the robot.
- ``office``: an office floor plan no default was tuned on (``office_floor_plan.py``: a
  lobby of pillars, a corridor with doors into ten rooms of desks, a cross corridor), SICK
  and URG-04LX, the tour, adversarial and reversing routes, seeds 2-5, a third of the run's
  duration, thinned to a scan per 1 m / 0.6 rad.
- ``ring``: the ring-corridor floor plan (``ring_floor_plan.py``: identical offices off a
  ring corridor, a corridor cut through its core at 28°, a lab of pillars), SICK, its
  361-beam mode, RPLIDAR and URG-04LX, the tour, adversarial and reversing routes, seeds 131
  and 132, a third of the run's duration, thinned to a scan per 1 m / 0.6 rad.
- ``crowdedthinned``: routes and seeds no default was tuned on (seeds 51 and 52): the five
  worlds (the four and the office), tour and adversarial route, 300 s, three people walking
  the roadmap, the SICK preset with 5 % of its beams lost and its 361-beam mode, thinned to
  a scan per 1 m / 0.6 rad.
- ``turnonspot``: logs thinned by distance alone, which keep no scan while the robot turns
  on the spot (up to 180° between two scans): freiburg-079 at a scan per metre of
  displacement and of path (as ``bioslam thin`` does), and the SICK preset on the four
  worlds' ``adversarial`` route (it spins and turns back) and tour, seeds 4 and 5, a third
  of the run's duration.
- ``warehouse``: the warehouse of identical aisles, 600 s, SICK (181 beams, 10 Hz) and
  UTM-30LX, with and without the wide-basin search: ATE, and jumps (the position error
  changing by more than 0.3 m between consecutive scans).
- ``warehouseadv``: the same warehouse on the ``adversarial`` route (weaving up to 0.5 m off
  the aisles' centre-lines, turning back, spinning on the spot, then driving fast), 3600 s
  (720 s with ``--quick``), seed 3, UTM-30LX and SICK: a route the defaults were not tuned on.
- ``alignment``: the UTM-30LX on the four worlds' ``adversarial`` route, seed 15, a fifth
  of the run's duration, the odometry started on the world's frame and off it (half a
  coarsest cell, a finest cell, no whole cell, turned 7 and 33 degrees): where a log's walls
  fall in the map's cells is chance (``bioslam run`` starts the map at the first scan).
- ``origin``: every world, route and LiDAR preset (4 x 3 x 5), 240 s, seed 31 (not tuned
  on), the odometry started at the origin as ``bioslam run`` starts it: a sweep for
  failures, not a tuning set.
- ``maps``: occupancy maps built from the odometry poses of exp1.dat, the ROS 1 bag and
  freiburg-079, written to ``benchmarks/results/odometry_map_<name>.png``.

Per-scan time is the CPU time of ``LidarOdometry.update`` in this thread (matching plus the
amortised map update), so other processes on the machine do not inflate it.

Usage: ``python benchmarks/bench_odometry.py [--quick] [--only maze,freiburg,...]
[--starts 0,3,7] [--figure intel-steps.png]``
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import itertools
import math
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from bioslam.evaluation import associate, ate, rpe_distance, rpe_distance_pairs, three_cornered_hat
from bioslam.geometry import between, compose, transform_points
from bioslam.io.logs import open_log
from bioslam.occupancy_grid import OccupancyGrid
from bioslam.odometry import LidarOdometry, OdometryConfig
from bioslam.sim import (
    LIDAR_PRESETS,
    ROUTES,
    MovingObstacle,
    Route,
    World,
    load_world,
    make_route,
    maze_world,
    people_on_roadmap,
    people_on_route,
    simulate_scans,
)
from bioslam.thinning import thin_indices
from bioslam.trajectory import Trajectory

# where the odometry starts against the world's frame (the simulated worlds' walls lie on
# whole centimetres): on it, half a coarsest cell (20 cm) and a finest cell (5 cm) off, off
# by no whole cell, and turned
START_OFFSETS = ((0.0, 0.0, 0.0), (0.1, 0.0, 0.0), (0.05, 0.1, 0.0), (0.037, 0.013, 0.0),
                 (0.0, 0.0, 7.0), (0.0, 0.0, 33.0))  # fmt: skip

REPO = Path(__file__).resolve().parents[1]
DATA = REPO.parent / "shared" / "data"
RESULTS = REPO / "benchmarks" / "results"


def run_odometry(scans, config: OdometryConfig | None = None, keep_scans: bool = False,
                 start_offset=(0.0, 0.0, 0.0), from_origin: bool = False):  # fmt: skip
    """Feed scans to a fresh LidarOdometry; returns (estimate, truth or None, cpu ms, extra).
    With ``start_offset`` (x, y, theta) the odometry starts that far off the first true pose
    (where the world's walls fall in its map's cells changes with it), with ``from_origin``
    at the origin as ``bioslam run`` starts it; the estimate is then returned moved back
    onto the true start."""
    odo = None
    stamps, est, truth, times, kept = [], [], [], [], []
    for item in scans:
        scan, true = item if isinstance(item, tuple) else (item, None)
        if odo is None:
            start = np.zeros(3) if true is None or from_origin else np.asarray(true, dtype=float)
            odo = LidarOdometry(config, initial_pose=start + np.asarray(start_offset))
        t0 = time.thread_time()
        odo.update(scan)
        times.append(time.thread_time() - t0)
        stamps.append(scan.stamp)
        est.append(odo.pose.copy())
        if true is not None:
            truth.append(true)
        if keep_scans:
            kept.append(scan.endpoints())
    est = np.array(est)
    if (np.any(start_offset) or from_origin) and truth:
        est = compose(truth[0], between(est[0], est))
    est_t = Trajectory(np.array(stamps), est)
    gt_t = Trajectory(np.array(stamps), np.array(truth)) if truth else None
    extra = {**odo.summary(), "scans": kept}
    return est_t, gt_t, np.array(times[1:]) * 1e3, extra


def summary(name: str, est: Trajectory, gt: Trajectory, ms: np.ndarray, extra: dict) -> dict:
    rpe = rpe_distance(est, gt, 1.0)
    length = gt.path_length()
    end = float(np.hypot(*(est.poses[-1, :2] - gt.poses[-1, :2])))
    error = est.poses[:, :2] - gt.poses[:, :2]
    # a jump: the position error changing by more than 0.3 m from one scan to the next
    change = np.hypot(*np.diff(error, axis=0).T)
    row = {
        "case": name,
        "scans": len(est),
        "path_m": round(length, 1),
        "ate_cm": round(100 * ate(est, gt)["rmse"], 2),
        "rpe1m_cm": round(100 * rpe["trans_rmse_m"], 2),
        "rpe1m_deg": round(rpe["rot_rmse_deg"], 3),
        "end_drift_pct": round(100 * end / max(length, 1e-9), 3),
        "max_err_m": round(float(np.max(np.hypot(*(est.poses[:, :2] - gt.poses[:, :2]).T))), 3),
        "ms_median": round(float(np.median(ms)), 3),
        "ms_p99": round(float(np.percentile(ms, 99)), 3),
        "degenerate_scans": extra["odometry_degenerate"],
        "predicted_only": extra["odometry_predicted_only"],
        "recovered": extra["odometry_recovered"],
        "ambiguous": extra["odometry_ambiguous"],
        "broken": extra["odometry_broken"],
        "map_rebuilds": extra.get("odometry_map_rebuilds", 0),
        "max_error_change_m": round(float(change.max(initial=0.0)), 3),
        "jumps_over_0.3m": int(np.sum(change > 0.3)),
    }
    print("  ".join(f"{k}={v}" for k, v in row.items()), flush=True)
    return row


def sim_case(name, lidar, duration, config=None, fast_turns=False, obstacles=(), seed=0,
             every=1, world="maze", thin=None, route="tour",
             start_offset=(0.0, 0.0, 0.0), from_origin=False):  # fmt: skip
    """One simulated run (the maze by default); ``every`` > 1 keeps one scan in ``every``
    (a thinned log); ``thin=(metres, radians)`` keeps a scan per distance or angle travelled
    along the true path, as the public "corrected" logs were thinned; ``route`` names one of
    :data:`bioslam.sim.ROUTES` (``adversarial``: weaving off the centre-lines, turning back,
    spinning on the spot, then driving fast); ``start_offset``, ``from_origin``: see
    :func:`run_odometry`."""
    scans = simulated_scans(world, lidar, duration, seed, route, thin, fast_turns, obstacles)
    scans = itertools.islice(scans, 0, None, every)
    est, gt, ms, extra = run_odometry(scans, config, start_offset=start_offset,
                                      from_origin=from_origin)
    return summary(name, est, gt, ms, extra)


def simulated_scans(world, lidar, duration, seed=0, route="tour", thin=None, fast_turns=False,
                    obstacles=()):  # fmt: skip
    """The (scan, true pose) pairs of a simulated run of :func:`sim_case`: ``world`` a name
    for :func:`bioslam.sim.load_world`, ``route`` ``"tour"`` or one of
    :data:`bioslam.sim.ROUTES`, ``thin=(metres, radians)`` a scan per distance or angle
    travelled along the true path."""
    world = load_world(world)
    if route == "tour":
        route = make_route(world, duration=duration, seed=seed, fast_turns=fast_turns)
    else:
        route = ROUTES[route](world, duration=duration, seed=seed)
    obstacles = obstacles(route) if callable(obstacles) else obstacles
    scans = simulate_scans(world, lidar, route, seed=seed, obstacles=obstacles)
    if thin is None:
        return scans
    items = list(scans)
    keep = thin_indices(np.array([true for _, true in items]), *thin)
    return iter([items[k] for k in keep])


def _written_world(write: Callable[[Path], Path], prefix: str) -> str:
    """A floor plan written by ``write`` into a temporary folder (removed at exit): its map
    YAML's path, which :func:`bioslam.sim.load_world` reads."""
    import atexit
    import shutil
    import tempfile

    folder = Path(tempfile.mkdtemp(prefix=prefix))
    atexit.register(shutil.rmtree, folder, ignore_errors=True)
    return str(write(folder))


@functools.cache
def ring_world() -> str:
    """The ring-corridor floor plan (``ring_floor_plan.py``), written once."""
    from ring_floor_plan import write_ring

    return _written_world(write_ring, "bioslam-ring-")


@functools.cache
def office_world() -> str:
    """The office floor plan (``office_floor_plan.py``), written once."""
    from office_floor_plan import write_office

    return _written_world(write_office, "bioslam-office-")


def people_crossing(route, count: int = 6, half_width: float = 1.0) -> list[MovingObstacle]:
    """People walking across the robot's path, back and forth over +-``half_width`` m at
    1.2 m/s, at ``count`` places along the route, each crossing when the robot is about
    2 m before it."""
    d = route.duration
    people = []
    for k in range(1, count + 1):
        t = k * d / (count + 1)
        x, y, th = route.pose_at(t)
        n = np.array([-np.sin(th), np.cos(th)]) * half_width
        centre = np.array([x, y])
        start, end = centre - n, centre + n
        # at the middle of its path (half a crossing after ``start``) ~2 s before the robot
        phase = (t - 2.0) - half_width / 1.2
        people.append(MovingObstacle(tuple(start), tuple(end), 1.2, 0.25, phase))
    return people


def occupancy_png(name: str, est: Trajectory, scans: list[np.ndarray], resolution=0.05):
    from PIL import Image

    grid = OccupancyGrid(resolution, 20.0, origin=est.poses[0, :2] - 10.0, auto_grow=True)
    for pose, pts in zip(est.poses, scans, strict=True):
        if len(pts):
            grid.insert_scan(pose, pts, max_range=30.0)
    prob = grid.probability()
    img = np.where(grid.known_mask(), 255 * (1.0 - prob), 205).astype(np.uint8)[::-1]
    RESULTS.mkdir(parents=True, exist_ok=True)
    path = RESULTS / f"odometry_map_{name}.png"
    Image.fromarray(img).save(path)
    print(f"map {name}: {path.relative_to(REPO)} ({img.shape[1]}x{img.shape[0]} px, "
          f"{resolution} m/px)", flush=True)  # fmt: skip
    return path


def log_case(name: str, filename: str, make_png: bool, config=None, select=None,
             start: int = 0) -> dict | None:  # fmt: skip
    """The odometry on a log, against its corrected poses if it has them. ``select(scans,
    reference)`` picks the scans fed to it (all by default), from the ``start``-th on. With
    a reference the row also counts the wrong steps (the step between consecutive scans off
    by more than 0.2 m from the reference's) and keeps each step's error (``_step_errors``,
    not printed)."""
    path = DATA / filename
    if not path.exists():
        print(f"{name}: skipped, {path} not found", flush=True)
        return None
    source = open_log(path)
    ref = getattr(source, "reference", None)
    scans = list(source) if select is None else select(list(source), ref)
    est, _, ms, extra = run_odometry(iter(scans[start:]), config, keep_scans=make_png)
    row = {"case": name, "scans": len(est), "path_m": round(est.path_length(), 1),
           "ms_median": round(float(np.median(ms)), 3),
           "ms_p99": round(float(np.percentile(ms, 99)), 3),
           "degenerate_scans": extra["odometry_degenerate"]}  # fmt: skip
    if ref is not None and len(ref):
        rpe = rpe_distance(est, ref, 1.0)
        errors = step_errors(est, ref)
        row.update(rpe1m_cm=round(100 * rpe["trans_rmse_m"], 2),
                   rpe1m_deg=round(rpe["rot_rmse_deg"], 3), pairs=rpe["pairs"],
                   recovered=extra["odometry_recovered"], broken=extra["odometry_broken"],
                   wrong_steps=int(np.sum(errors > 0.2)), _step_errors=errors)  # fmt: skip
        if make_png:
            row.update(reference_check(est, ref, extra["scans"], source.odometry))
    print("  ".join(f"{k}={v}" for k, v in row.items() if not k.startswith("_")), flush=True)
    if make_png:
        occupancy_png(name, est, extra["scans"])
    return row


def step_errors(est: Trajectory, ref: Trajectory) -> np.ndarray:
    """Translation error (m) of each step between consecutive estimated poses against the
    reference's step between the same stamps."""
    truth = ref.at(est.stamps).poses
    miss = between(between(truth[:-1], truth[1:]), between(est.poses[:-1], est.poses[1:]))
    return np.hypot(miss[:, 0], miss[:, 1])


def step_error_png(rows: list[dict], path: Path) -> None:
    """Each run's step errors against the scan index (one panel per run): where the wrong
    steps are, and whether they come alone or in cascades."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = [r for r in rows if r and "_step_errors" in r]
    fig, axes = plt.subplots(len(rows), 1, figsize=(9, 1.8 * len(rows) + 0.4), sharex=True,
                             squeeze=False)  # fmt: skip
    for ax, row in zip(axes[:, 0], rows, strict=True):
        err = np.maximum(row["_step_errors"], 1e-3)
        ax.semilogy(np.arange(1, len(err) + 1), err, ".", ms=2)
        ax.axhline(0.2, color="r", lw=0.6)
        ax.set_ylim(1e-3, 10)
        ax.set_ylabel("step error m")
        ax.set_title(f"{row['case']}: RPE 1 m {row['rpe1m_cm']} cm, "
                     f"{row['wrong_steps']} steps off > 0.2 m", fontsize=9)  # fmt: skip
    axes[-1, 0].set_xlabel("scan")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    print(f"figure: {path}", flush=True)


def thinned(distance: float, angle: float):
    """A scan selector for :func:`log_case` that thins a log as the SLAM benchmark's logs
    are: a scan is kept when the reference has moved ``distance`` m or turned ``angle`` rad
    since the last kept one."""

    def select(scans: list, ref: Trajectory) -> list:
        kept, last = [], None
        for scan, pose in zip(scans, ref.at(np.array([s.stamp for s in scans])).poses,
                              strict=True):  # fmt: skip
            step = None if last is None else between(last, pose)
            if step is None or math.hypot(step[0], step[1]) >= distance or abs(step[2]) >= angle:
                kept.append(scan)
                last = pose
        return kept

    return select


def path_thinned(distance: float):
    """A scan selector for :func:`log_case` that thins a log as ``bioslam thin --distance``
    does: a scan per ``distance`` metres of the reference's path (a turn on the spot, or
    the way to a point and back, counts as no distance or as the whole path)."""

    def select(scans: list, ref: Trajectory) -> list:
        poses = ref.at(np.array([s.stamp for s in scans])).poses
        return [scans[k] for k in thin_indices(poses, distance)]

    return select


def _second_difference_cm(poses: np.ndarray) -> float:
    """Robust spread (1.4826 MAD, both axes) of x[k+1] - 2 x[k] + x[k-1]: near zero for a
    smooth path sampled at a steady rate, sqrt(6) sigma for white pose noise sigma."""
    d2 = poses[2:, :2] - 2.0 * poses[1:-1, :2] + poses[:-2, :2]
    mad = 1.4826 * np.median(np.abs(d2 - np.median(d2, axis=0)), axis=0)
    return round(100.0 * float(np.hypot(*mad)), 2)


def _neighbour_residual_mm(poses: np.ndarray, scans: list[np.ndarray], span: int = 10) -> float:
    """Median over scans of the median distance from a scan's endpoints (within 8 m) to the
    endpoints of the ``span`` scans either side, all placed by ``poses``: how sharp the
    trajectory makes the local map."""
    from scipy.spatial import cKDTree

    world = [transform_points(p, s) for p, s in zip(poses, scans, strict=True)]
    out = []
    for i in range(span, len(scans) - span, 7):
        near = np.hypot(scans[i][:, 0], scans[i][:, 1]) < 8.0
        others = [world[j] for j in range(i - span, i + span + 1) if j != i and len(world[j])]
        if near.sum() >= 20 and others:
            out.append(np.median(cKDTree(np.vstack(others)).query(world[i][near])[0]))
    return round(1e3 * float(np.median(out)), 2)


def reference_check(est: Trajectory, ref: Trajectory, scans: list[np.ndarray],
                    wheels: Trajectory | None = None) -> dict:  # fmt: skip
    """How noisy the reference itself is, beside the estimate: a log's "corrected" poses come
    from another SLAM system, and an RPE against them cannot fall below their own noise.
    With the log's raw wheel odometry, a three-cornered hat splits the 1 m RPE into the
    reference's own error and the estimate's."""
    est_idx, ref_idx = associate(est, ref)
    est_poses, ref_poses = est.poses[est_idx], ref.poses[ref_idx]
    scans = [scans[i] for i in est_idx]
    row = {
        "jitter_cm": _second_difference_cm(est_poses),
        "ref_jitter_cm": _second_difference_cm(ref_poses),
        "local_residual_mm": _neighbour_residual_mm(est_poses, scans),
        "ref_local_residual_mm": _neighbour_residual_mm(ref_poses, scans),
        **_worst_pairs(est, ref, est_idx, ref_poses, scans),
    }
    if wheels is not None and len(wheels):
        hat = three_cornered_hat(ref, est, wheels.at(ref.stamps))
        own = [round(100 * v, 2) for v in hat["trans_rmse_m"]]
        row.update(zip(("own_rpe1m_cm_ref", "own_rpe1m_cm_est", "own_rpe1m_cm_wheels"), own,
                       strict=True))  # fmt: skip
    return row


def _worst_pairs(est: Trajectory, ref: Trajectory, est_idx: np.ndarray, ref_poses: np.ndarray,
                 scans: list, share: float = 0.1) -> dict:  # fmt: skip
    """The worst ``share`` of the 1 m RPE pairs: in how many is the local map sharper with
    the estimate's poses than with the reference's (the scans from 10 before to 10 after
    the pair, each against its 5 neighbours either side)? And the RMSE of the other pairs.
    ``est_idx``, ``ref_poses`` and ``scans`` are the associated poses' estimate indices,
    reference poses and scans."""
    est_pairs, _, trans, _ = rpe_distance_pairs(est, ref, 1.0)
    est_poses = est.poses[est_idx]
    worst = np.argsort(-trans)[: max(int(share * len(trans)), 1)]
    sharper = 0
    for a, b in np.searchsorted(est_idx, est_pairs[worst]):
        seg = slice(max(a - 10, 0), b + 11)
        ours = _neighbour_residual_mm(est_poses[seg], scans[seg], span=5)
        sharper += ours < _neighbour_residual_mm(ref_poses[seg], scans[seg], span=5)
    rest = np.delete(trans, worst)
    return {"worst_pairs_sharper_with_estimate": f"{sharper}/{len(worst)}",
            "rpe1m_cm_without_worst": round(100 * float(np.sqrt(np.mean(rest**2))), 2)}  # fmt: skip


# no wide-basin search: Gauss-Newton from the prediction alone
NO_SEARCH = OdometryConfig(search_distance=0.0)
NO_TYPICAL = OdometryConfig(typical_search_distance=0.0)


def short_range_models() -> list[tuple[str, object]]:
    """The 240-degree, 5.6 m URG-04LX, and the same with a longer range or a full circle:
    what a short forward-looking range does to tracking in long corridors."""
    urg = LIDAR_PRESETS["urg04lx"]
    return [
        ("5.6 m 240 deg", urg),
        ("30 m 240 deg", dataclasses.replace(urg, range_max=30.0)),
        ("5.6 m 360 deg", dataclasses.replace(urg, fov=2 * np.pi, beams=1024)),
    ]


def _wall(x0: float, y0: float, x1: float, y1: float) -> tuple[float, float, float, float]:
    return (x0, y0, x1, y1)


def _niche(x: float, side: float, width: float = 1.0, depth: float = 0.5) -> list:
    """A door recess of ``width`` x ``depth`` metres at ``x`` in the wall at y = ``side``."""
    out = side * (1.0 + depth)
    end = x + width
    return [_wall(x, side, x, out), _wall(x, out, end, out), _wall(end, out, end, side)]


def _wall_with_doors(side: float, doors: list[float], x0: float, x1: float) -> list:
    """The corridor wall at y = ``side`` from ``x0`` to ``x1``, a 1 m door niche at each of
    ``doors``."""
    walls, x = [], x0
    for d in doors:
        walls += [_wall(x, side, d, side), *_niche(d, side)]
        x = d + 1.0
    return [*walls, _wall(x, side, x1, side)]


def straight_route(xs: np.ndarray, y: float, heading: float, speed: float) -> tuple:
    """Poses along x (``xs`` in order) at ``y`` weaving by +-0.1 m, driven at ``speed``."""
    ys = y + 0.1 * np.sin(xs / 5.0)
    poses = np.column_stack([xs, ys, np.full(len(xs), heading)])
    steps = np.hypot(np.diff(xs), np.diff(ys))
    return poses, np.concatenate([[0.0], np.cumsum(steps) / speed])


def closed_corridor_case() -> dict:
    """URG-04LX out and back along a closed 24 m corridor, 0.3 m off its centre-line: from
    x = 3 to 17 it sees two parallel walls only (240 degrees never see the end behind it)."""
    walls = (
        _wall_with_doors(1.0, [1.0], -1.0, 23.0) + _wall_with_doors(-1.0, [18.0], -1.0, 23.0)
        + [_wall(-1.0, -1.0, -1.0, 1.0), _wall(23.0, -1.0, 23.0, 1.0)]
    )  # fmt: skip
    out, t_out = straight_route(np.linspace(0.0, 20.0, 2001), 0.3, 0.0, 0.5)
    back, t_back = straight_route(np.linspace(20.0, 1.0, 1901), 0.3, np.pi, 0.5)
    turn_t = np.linspace(0.0, np.pi, 50)[1:]  # on the spot at 1 rad/s
    turn = np.column_stack([np.full(49, out[-1, 0]), np.full(49, out[-1, 1]), turn_t])
    poses = np.vstack([out, turn, back])
    times = np.concatenate([t_out, t_out[-1] + turn_t, t_out[-1] + np.pi + t_back + 0.1])
    route = Route(times, poses)
    scans = simulate_scans(World(np.array(walls), "closed corridor"), LIDAR_PRESETS["urg04lx"],
                           route, seed=0)  # fmt: skip
    est, gt, ms, extra = run_odometry(scans)
    return summary("urg04lx closed 24 m corridor, out and back", est, gt, ms, extra)


def doors_corridor_case() -> dict:
    """SICK (180 degrees, 181 beams) along an 80 m corridor 2 m wide with a door every 6 m on
    alternate sides, thinned to one scan per metre: the doors are the only features."""
    walls = (
        _wall_with_doors(1.0, list(np.arange(6.0, 78.0, 6.0)), 0.0, 80.0)
        + _wall_with_doors(-1.0, list(np.arange(3.0, 78.0, 6.0)), 0.0, 80.0)
        + [_wall(0.0, -1.0, 0.0, 1.0), _wall(80.0, -1.0, 80.0, 1.0)]
    )  # fmt: skip
    poses, times = straight_route(np.linspace(1.0, 70.0, 6901), 0.2, 0.0, 0.5)
    scans = list(simulate_scans(World(np.array(walls), "corridor with doors"),
                                LIDAR_PRESETS["sick"], Route(times, poses), seed=0))  # fmt: skip
    keep = thin_indices(np.array([true for _, true in scans]), distance=1.0)
    est, gt, ms, extra = run_odometry([scans[i] for i in keep])
    return summary("sick 80 m corridor, doors every 6 m, 1 scan per metre", est, gt, ms, extra)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="120 s simulated runs")
    parser.add_argument("--only", default="", help="comma-separated case names")
    parser.add_argument("--starts", default="0",
                        help="comma-separated scans to start the intel case at (its result "
                             "depends on where it starts); the run without search only at "
                             "the first")  # fmt: skip
    parser.add_argument("--figure", type=Path, default=None,
                        help="PNG of the intel runs' step errors against the reference")
    args = parser.parse_args()
    starts = [int(v) for v in args.starts.split(",")]
    only = set(filter(None, args.only.split(",")))
    duration = 120.0 if args.quick else 600.0
    utm = LIDAR_PRESETS["utm30lx"]
    utm10 = dataclasses.replace(utm, rate_hz=10.0)
    def thinned_worlds(lidar: str, seeds) -> list[dict]:
        """``lidar`` on the four worlds' tour and adversarial route, a third of the run's
        duration, thinned to a scan per 1 m / 0.6 rad."""
        return [
            sim_case(f"{world} {route} {lidar}, a scan per 1 m / 0.6 rad, seed {seed}",
                     LIDAR_PRESETS[lidar], duration / 3, world=world, seed=seed,
                     thin=(1.0, 0.6), route=route)
            for world in ("rooms", "warehouse", "maze", "hall")
            for route in ("tour", "adversarial")
            for seed in seeds
        ]

    def crowded_thinned() -> list[dict]:
        """The five worlds' tour and adversarial route, half the run's duration, seeds 51
        and 52, three people walking the roadmap, the SICK preset with 5 % of its beams lost
        and its 361-beam mode, thinned to a scan per 1 m / 0.6 rad."""
        sick = dataclasses.replace(LIDAR_PRESETS["sick"], dropout_prob=0.05)
        rows = []
        for name in ("maze", "rooms", "warehouse", "hall", "office"):
            world = office_world() if name == "office" else name
            roadmap = load_world(world)  # the people walk its roadmap
            for route, (label, lidar), seed in itertools.product(
                ("tour", "adversarial"), (("sick361", LIDAR_PRESETS["sick361"]),
                                          ("sick, 5 % dropouts", sick)), (51, 52),
            ):  # fmt: skip
                rows.append(sim_case(
                    f"{name} {route} {label}, 3 people, a scan per 1 m / 0.6 rad, seed {seed}",
                    lidar, duration / 2, world=world, seed=seed, thin=(1.0, 0.6), route=route,
                    obstacles=lambda _, w=roadmap, s=seed: people_on_roadmap(w, 3, seed=s),
                ))  # fmt: skip
        return rows

    cases = {
        "maze": lambda: sim_case("maze utm30lx", utm, duration),
        "lowcost": lambda: sim_case(
            "maze rplidar 20% dropouts",
            dataclasses.replace(LIDAR_PRESETS["rplidar"], dropout_prob=0.2), duration,
        ),
        "fastturns": lambda: sim_case("fast turns 1 rad/s, 10 Hz", utm10, 120.0, fast_turns=True),
        "person": lambda: [
            sim_case("6 people crossing the path", utm, 120.0, obstacles=people_crossing),
            sim_case("8 people pacing the corridors", utm, 120.0,
                     obstacles=lambda route: people_on_roadmap(maze_world(), 8, seed=1)),
            sim_case("3 people walking along the path", utm, 120.0, obstacles=people_on_route),
        ],
        "deskew": lambda: [
            sim_case(f"fast turns 10 Hz deskew={flag}", utm10, 120.0,
                     OdometryConfig(deskew=flag), fast_turns=True)
            for flag in (True, False)
        ],
        "mapfunc": lambda: [
            sim_case(f"maze 120 s subcell_sigma={s}", utm, 120.0, OdometryConfig(subcell_sigma=s))
            for s in (1.0, None)
        ],
        "shortrange": lambda: [
            sim_case(f"urg04lx {label} seed {seed}", model, 60.0, seed=seed)
            for label, model in short_range_models()
            for seed in range(3)
        ],
        "lds01": lambda: [
            sim_case(f"{world} {route} lds01, {duration:.0f} s, seed {seed}",
                     LIDAR_PRESETS["lds01"], duration, seed=seed, world=world, route=route)
            for world in ("maze", "rooms", "warehouse", "hall")
            for route in ("tour", "adversarial")
            for seed in range(3)
        ],
        "shortrangeseeds": lambda: [
            sim_case(f"{world} {route} urg04lx, {length:.0f} s, seed {seed}",
                     LIDAR_PRESETS["urg04lx"], length, seed=seed, world=world, route=route)
            for world, route, length, seeds in (
                ("maze", "tour", duration, range(1, 13)),
                ("hall", "tour", duration, (7,)),
                ("rooms", "tour", duration, (7,)),
                ("warehouse", "tour", duration, (7,)),
                ("maze", "adversarial", duration / 2, (8,)),
                ("maze", "reversing", duration / 2, (8,)),
                ("hall", "adversarial", duration / 2, (8,)),
                ("hall", "reversing", duration / 2, (8,)),
            )
            for seed in seeds
        ],
        "corridor": lambda: [closed_corridor_case(), doors_corridor_case()],
        "thinned": lambda: [
            sim_case(f"maze utm30lx, 1 scan in {n} ({n / 40:.1f} s apart){label}", utm,
                     duration, config, every=n)
            for n in (20, 40)
            for label, config in (("", None), (", no search", NO_SEARCH))
        ],
        "sickthinned": lambda: [
            sim_case(f"{world} sick, a scan per 1 m / 0.6 rad, seed {seed}", LIDAR_PRESETS["sick"],
                     duration / 3, world=world, seed=seed, thin=(1.0, 0.6))
            for world in ("rooms", "warehouse", "maze")
            for seed in (0, 1)
        ],
        "freiburg": lambda: log_case("freiburg079", "freiburg-079-corrected.log.gz", True),
        "freiburgthinned": lambda: [
            log_case(f"freiburg079 thinned to {d} m / {a} rad{label}",
                     "freiburg-079-corrected.log.gz", False, config, thinned(d, a))
            for d, a in ((0.5, 0.4), (1.0, 0.6))
            for label, config in (("", None), (", no search", NO_SEARCH))
        ],
        "intel": lambda: [
            log_case(f"intel (thinned){label}" + (f" from scan {start}" if start else ""),
                     "intel-corrected.log.gz", False, config, start=start)
            for start in starts
            for label, config in (("", None), (", no search", NO_SEARCH))
            if start == starts[0] or config is None
        ],
        "intelsparse": lambda: [
            log_case("intel thinned to 1.5 m / 45 deg" + (f" from scan {start}" if start else ""),
                     "intel-corrected.log.gz", False, None, thinned(1.5, math.pi / 4), start)
            for start in starts
        ],
        "sicksparse": lambda: [
            sim_case(f"{world} sick, a scan per 1.5 m / 0.6 rad, seed {seed}",
                     LIDAR_PRESETS["sick"], duration / 3, world=world, seed=seed,
                     thin=(1.5, 0.6))
            for world in ("warehouse", "maze")
            for seed in (0, 1)
        ],
        "typicalstep": lambda: [
            sim_case(f"{world} {route} sick, a scan per 1 m / 0.6 rad, seed {seed}{label}",
                     LIDAR_PRESETS["sick"], duration / 3, config, world=world, seed=seed,
                     thin=(1.0, 0.6), route=route)
            for world in ("rooms", "warehouse", "maze", "hall")
            for route in ("tour", "adversarial")
            for seed in range(2, 8)
            for label, config in (("", None), (", no typical search", NO_TYPICAL))
        ],
        "typicalstepurg": lambda: thinned_worlds("urg04lx", range(2, 8)),
        "typicalstep15": lambda: [
            sim_case(f"{world} {route} sick, a scan per 1.5 m / 0.6 rad, seed {seed}",
                     LIDAR_PRESETS["sick"], duration / 3, world=world, seed=seed,
                     thin=(1.5, 0.6), route=route)
            for world in ("warehouse", "maze", "rooms")
            for route in ("tour", "adversarial")
            for seed in range(2, 5)
        ],
        "typicalsteprplidar": lambda: thinned_worlds("rplidar", range(2, 8)),
        "mounted": lambda: [
            sim_case(f"{world} {route} sick mounted at {yaw} deg{label}, seed {seed}",
                     dataclasses.replace(LIDAR_PRESETS["sick"], mount_yaw=math.radians(yaw)),
                     duration / 3, world=world, seed=seed, thin=thin, route=route)
            for world in ("rooms", "warehouse", "maze", "hall")
            for route in ("tour", "adversarial")
            for yaw in (0, 180, 90)
            for label, thin in ((", a scan per 1 m / 0.6 rad", (1.0, 0.6)), ("", None))
            for seed in (2, 3)
        ],
        "typicalstepreversing": lambda: [
            sim_case(f"{world} reversing {lidar}, a scan per 1 m / 0.6 rad, seed {seed}",
                     LIDAR_PRESETS[lidar], duration / 3, world=world, seed=seed,
                     thin=(1.0, 0.6), route="reversing")
            for world in ("rooms", "warehouse", "maze", "hall")
            for lidar in ("sick", "urg04lx")
            for seed in range(2, 8)
        ],
        "office": lambda: [
            sim_case(f"office {route} {lidar}, a scan per 1 m / 0.6 rad, seed {seed}",
                     LIDAR_PRESETS[lidar], duration / 3, world=office_world(), seed=seed,
                     thin=(1.0, 0.6), route=route)
            for lidar in ("sick", "urg04lx")
            for route in ("tour", "adversarial", "reversing")
            for seed in range(2, 6)
        ],
        "ring": lambda: [
            sim_case(f"ring {route} {lidar}, a scan per 1 m / 0.6 rad, seed {seed}",
                     LIDAR_PRESETS[lidar], duration / 3, world=ring_world(), seed=seed,
                     thin=(1.0, 0.6), route=route)
            for lidar in ("sick", "sick361", "rplidar", "urg04lx")
            for route in ("tour", "adversarial", "reversing")
            for seed in (131, 132)
        ],
        "crowdedthinned": crowded_thinned,
        "turnonspot": lambda: [
            log_case("freiburg-079 thinned to a scan per 1 m by distance alone",
                     "freiburg-079-corrected.log.gz", False, None, thinned(1.0, math.inf)),
            log_case("freiburg-079 thinned to a scan per 1 m of path (bioslam thin)",
                     "freiburg-079-corrected.log.gz", False, None, path_thinned(1.0)),
            *(sim_case(f"{world} {route} sick, a scan per 1 m by distance alone, seed {seed}",
                       LIDAR_PRESETS["sick"], duration / 3, world=world, seed=seed,
                       thin=(1.0, None), route=route)
              for route in ("adversarial", "tour")
              for world in ("hall", "maze", "warehouse", "rooms")
              for seed in (4, 5)),
        ],
        "alignment": lambda: [
            sim_case(f"{world} adversarial utm30lx, {duration / 5:.0f} s, seed 15, started "
                     f"({dx}, {dy}) m, {dth} deg off the world's frame", LIDAR_PRESETS["utm30lx"],
                     duration / 5, world=world, seed=15, route="adversarial",
                     start_offset=(dx, dy, math.radians(dth)))
            for world in ("rooms", "hall", "maze", "warehouse")
            for dx, dy, dth in START_OFFSETS
        ],
        "origin": lambda: [
            sim_case(f"{world} {route} {lidar}, {duration * 0.4:.0f} s, seed 31, from the origin",
                     LIDAR_PRESETS[lidar], duration * 0.4, world=world, seed=31, route=route,
                     from_origin=True)
            for world in ("rooms", "hall", "maze", "warehouse")
            for route in ("tour", "adversarial", "reversing")
            for lidar in ("utm30lx", "sick", "sick361", "urg04lx", "rplidar")
        ],
        "warehouse": lambda: [
            sim_case(f"warehouse {lidar}{label}", LIDAR_PRESETS[lidar], duration, config,
                     world="warehouse")
            for lidar in ("sick", "utm30lx")
            for label, config in (("", None), (", no search", NO_SEARCH))
        ],
        "warehouseadv": lambda: [
            sim_case(f"warehouse adversarial route {lidar}, {duration * 6:.0f} s, seed 3",
                     LIDAR_PRESETS[lidar], duration * 6, world="warehouse", seed=3,
                     route="adversarial")
            for lidar in ("utm30lx", "sick")
        ],
        "maps": lambda: [
            log_case("exp1", "exp1.dat", True),
            log_case("rosbag1", "laser_scan_matcher_demo.bag", True),
        ],
    }
    for name, case in cases.items():
        if not only or name in only:
            rows = case()
            if name == "intel" and args.figure is not None:
                step_error_png([r for r in rows if r and "no search" not in r["case"]],
                               args.figure)  # fmt: skip


if __name__ == "__main__":
    main()
