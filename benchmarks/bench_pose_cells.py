"""Pose cell network and cognitive map: per-update cost, path-integration fidelity, the
ambiguity rule, and relaxation cost vs map size.

Targets (issue 5): the whole pipeline at <= 2 ms per scan (median) and >= 20x real time on
40 Hz data, so the pose cells and the map must stay a small share of that; relaxation cost per
scan must not grow without bound on long runs.

Tables printed (all measured in this run, one thread):

1. pose cells per update (path integration + view injection + step + read-out) on a 40 Hz,
   0.5 m/s route: median / p99 / mean, beside a dense baseline (the same dynamics computed on
   the whole network with ``scipy.ndimage`` wrap-around convolutions, as a non-sparse
   implementation would) and the ratio;
2. path-integration fidelity: the distance the packet covers / the odometry's, for several
   step sizes per update, with and without the accumulation of sub-cell motion;
3. the ambiguity rule: consecutive view matches needed to move the packet, vs k_V and offset;
4. cognitive map vs size (100 / 1,000 / 10,000 experiences): ``update`` per call, ``relax``
   on a consistent map (the cost on all scans between closures), ``relax`` right after a loop
   closure (direct solve + confirming sweep), one Eq. 14 sweep, and the error left after the
   closure's relaxation on a route with a gyro-like heading bias;
5. the solve a closure runs, on the map the full system builds on the demo's simulated maze
   (``--map-seconds`` of its route, 0 to skip): on the map's junctions
   (:mod:`bioslam.link_solve`) against the whole Laplacian factorised, as before it, on
   the same map in this run, and how far apart their solutions are.

    python benchmarks/bench_pose_cells.py [--updates 4000] [--sizes 100,1000,10000]
        [--map-seconds 600]
"""

from __future__ import annotations

import argparse
import math
import os
import statistics
import time

os.environ.setdefault("NUMBA_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np
from scipy import ndimage

import bioslam.cognitive_map as cognitive_map
from bioslam.cognitive_map import (
    CognitiveMap,
    CognitiveMapConfig,
    _ground_numbered,
    _relax_sweep,
)
from bioslam.geometry import between, compose
from bioslam.link_solve import _eliminate, factorised_solve
from bioslam.pose_cells import (
    PoseCellConfig,
    PoseCellNetwork,
    consecutive_matches_to_shift,
    gaussian_kernel_1d,
)

RATE_HZ = 40.0
SPEED = 0.5


def route_steps(n: int, seed: int = 0) -> np.ndarray:
    """40 Hz odometry increments: 0.5 m/s with slowly varying turn rate."""
    rng = np.random.default_rng(seed)
    turn = np.convolve(rng.normal(0.0, 0.6, n), np.ones(80) / 80, mode="same")
    return np.stack([np.full(n, SPEED / RATE_HZ), np.zeros(n), turn / RATE_HZ], axis=1)


def dense_step(pc: np.ndarray, cfg: PoseCellConfig) -> np.ndarray:
    """The same excitation / inhibition / normalisation over the whole network."""

    def blur(a: np.ndarray, var: float, r: int) -> np.ndarray:
        g = gaussian_kernel_1d(var, r)
        for axis in range(3):
            a = ndimage.convolve1d(a, g, axis=axis, mode="wrap")
        return a

    exc = blur(pc, cfg.excite_var, cfg.excite_radius)
    out = exc - blur(exc, cfg.inhibit_var, cfg.inhibit_radius) - cfg.global_inhibition
    np.maximum(out, 0.0, out=out)
    return out / out.sum()


def percentile(values: list[float], q: float) -> float:
    return float(np.percentile(np.asarray(values), q))


def bench_updates(n_updates: int) -> None:
    cfg = PoseCellConfig()
    net = PoseCellNetwork(cfg)
    steps = route_steps(n_updates)
    times: list[float] = []
    for k, dp in enumerate(steps):
        view = k // 20  # a new view every 0.25 m; re-seen for the next 19 updates
        t0 = time.perf_counter()
        net.path_integrate(dp)
        net.inject_view(view, 1.0, is_new=(k % 20 == 0))
        net.step()
        net.centre()
        times.append(time.perf_counter() - t0)
    active = net.active_count
    dense = net.activity.copy()
    dense_times: list[float] = []
    for _ in range(max(50, n_updates // 20)):
        t0 = time.perf_counter()
        dense = dense_step(dense, cfg)
        dense_times.append(time.perf_counter() - t0)
    med, dmed = statistics.median(times), statistics.median(dense_times)
    print(f"\n## Pose cells per update ({n_updates} updates, dims {cfg.dims}, {active} active)\n")
    print("| implementation | median ms | p99 ms | mean ms |")
    print("|---|---|---|---|")
    print(
        f"| sparse (bioslam), full update | {med * 1e3:.3f} | {percentile(times, 99) * 1e3:.3f}"
        f" | {statistics.fmean(times) * 1e3:.3f} |"
    )
    print(
        f"| dense baseline, step only | {dmed * 1e3:.3f} | {percentile(dense_times, 99) * 1e3:.3f}"
        f" | {statistics.fmean(dense_times) * 1e3:.3f} |"
    )
    print(f"\nratio sparse full update / dense step alone: {med / dmed:.2f}")


def tracking_ratio(cells_per_update: float, min_shift: float, heading: float) -> float:
    cfg = PoseCellConfig(min_shift_cells=min_shift, start=(10.0, 10.0, heading * 36 / math.tau))
    net = PoseCellNetwork(cfg)
    for _ in range(10):
        net.step()
    start = net.centre()
    distance = 8.0  # cells: inside half the 21-cell period, so the wrapped delta is unambiguous
    n = round(distance / cells_per_update)
    for _ in range(n):
        net.path_integrate((cells_per_update * cfg.cell_size_xy, 0.0, 0.0))
        net.step()
    dims = np.asarray(cfg.dims, dtype=float)
    d = np.mod(net.centre() - start + dims / 2, dims) - dims / 2
    return float(np.hypot(d[0], d[1]) / (n * cells_per_update))


def bench_tracking() -> None:
    print("\n## Path integration: packet distance / odometry distance (8 cells, 3 headings)\n")
    print("| cells per update | every step applied | accumulated to 0.5 cell (default) |")
    print("|---|---|---|")
    for cpu in (0.05, 0.1, 0.25, 0.5, 1.5, 4.0):
        row = []
        for ms in (0.0, 0.5):
            ratios = [tracking_ratio(cpu, ms, h) for h in (0.0, 0.45, 2.2)]
            row.append(f"{min(ratios):.3f}-{max(ratios):.3f}")
        print(f"| {cpu} | {row[0]} | {row[1]} |")


def bench_ambiguity() -> None:
    print("\n## Ambiguity rule: consecutive matches until the packet moves to the views\n")
    print("(route re-driven at 0.25 cell per update, a view every cell; '-' = never in 400)\n")
    offsets = [(3.0, 0.0, 0.0), (6.0, 0.0, 0.0), (0.0, 5.0, 0.0), (0.0, 0.0, 8.0)]
    print(
        "| k_V | "
        + " | ".join(f"offset {o}" for o in offsets)
        + " | one isolated match moves it (at any of 50 steps)? |"
    )
    print("|---|" + "---|" * (len(offsets) + 1))
    for kv in (0.05, 0.1, 0.2, 0.5):
        cfg = PoseCellConfig(view_energy=kv)
        counts = [consecutive_matches_to_shift(cfg, offset_cells=o) for o in offsets]
        moved = single_match_moves(cfg)
        cells = " | ".join("-" if c is None else str(c) for c in counts)
        print(
            f"| {kv}{' (default)' if kv == PoseCellConfig().view_energy else ''} | {cells} |"
            f" {'yes' if moved else 'no'} |"
        )


def single_match_moves(cfg: PoseCellConfig) -> bool:
    net = PoseCellNetwork(cfg)
    start = net.centre()
    net.view_links[0] = np.mod(start + np.array([6.0, 0.0, 0.0]), cfg.dims)
    net.inject_view(0, 1.0)
    moved = 0.0
    for _ in range(50):
        net.step()
        moved = max(moved, float(net.centre_distance(net.centre(), start)))
    return moved > 1.0


def lap_route(n_nodes: int, lap: int, spacing: float) -> np.ndarray:
    """Experience-to-experience motions around a circle of ``lap`` nodes."""
    return np.tile([spacing, 0.0, math.tau / lap], (n_nodes, 1))


def max_link_residual(cm: CognitiveMap) -> float:
    """The largest |p_target - p_source ⊕ Δp| over all links (0 on a consistent map)."""
    poses = cm.experience_poses
    ends = np.array([(lk.source, lk.target) for lk in cm.links])
    dps = np.array([lk.dp for lk in cm.links])
    d = poses[ends[:, 1], :2] - compose(poses[ends[:, 0]], dps)[:, :2]
    return float(np.max(np.hypot(d[:, 0], d[:, 1])))


def build_and_close(
    n_nodes: int, lap: int, bias: float, config: CognitiveMapConfig
) -> dict[str, float]:
    """Drive ``n_nodes`` experiences around a circle with a biased gyro; at every lap's start
    the robot recognises the previous lap's first place (closure refined with the true pose,
    like a precise scan registration) and relaxes. Times ``update``, the closures' ``relax``
    and ``relax`` on the consistent map between closures."""
    steps = lap_route(n_nodes, lap, 0.3)
    truth = [np.zeros(3)]
    for d in steps[:-1]:
        truth.append(compose(truth[-1], d))
    truth_arr = np.array(truth)
    cm = CognitiveMap(config)
    update_t: list[float] = []
    loop_t: list[float] = []
    quiet_t: list[float] = []
    misfit_before = 0.0
    for k in range(n_nodes):
        if k:
            cm.integrate_odometry(steps[k - 1] + np.array([0.0, 0.0, bias]))
        if k >= lap and k % lap == 0:
            here = k
            cm.update(
                k - lap,
                False,
                (float((k - lap) % 7), 0.0, 0.0),
                float(k),
                refine=lambda e, here=here: between(truth_arr[e.payload], truth_arr[here]),
            )
            misfit_before = max_link_residual(cm) if k + lap >= n_nodes else misfit_before
            t0 = time.perf_counter()
            cm.relax()
            loop_t.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        cm.update(k, True, (float(k % 7), 0.0, 0.0), float(k), payload=k)
        update_t.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        cm.relax()
        quiet_t.append(time.perf_counter() - t0)
    closed = (n_nodes - 1) // lap * lap  # the last lap is still open
    err = np.hypot(*(cm.experience_poses[:closed] - truth_arr[:closed])[:, :2].T)
    return {
        "update": statistics.median(update_t),
        "quiet": statistics.median(quiet_t),
        "loop": statistics.median(loop_t[-6:]),
        "loops": cm.loop_closures,
        "misfit_before": misfit_before,
        "misfit_after": max_link_residual(cm),
        "err": float(np.max(err)),
        "cm": cm,  # type: ignore[dict-item]
    }


def bench_relaxation(sizes: list[int]) -> None:
    print("\n## Cognitive map vs size (circular laps, experiences 0.3 m apart, 1 mrad/step bias)\n")
    print(
        "| experiences | loops | update ms | relax between closures ms | relax after a closure"
        " ms (last 6) | one Eq. 14 sweep ms | worst link misfit before / after last relax m |"
        " max error of closed laps vs truth m |"
    )
    print("|---|---|---|---|---|---|---|---|")
    default_window = CognitiveMapConfig().solve_window
    runs = [(n, CognitiveMapConfig()) for n in sizes]
    runs += [(n, CognitiveMapConfig(solve_window=None)) for n in sizes if n > default_window]
    for n, config in runs:
        r = build_and_close(n, max(10, min(100, n // 7)), 0.001, config)
        cm = r["cm"]
        label = (
            f"{n}"
            if config.solve_window is None or n <= config.solve_window
            else (f"{n} (window {config.solve_window})")
        )
        if config.solve_window is None:
            label = f"{n} (no window)"
        src, dst, out_ptr, out_e, in_ptr, in_e = cm._adjacency()
        poses = cm.experience_poses
        dps = np.array([lk.dp for lk in cm.links])
        weights = cm.link_weights()
        sweeps = []
        for _ in range(20):
            t0 = time.perf_counter()
            _relax_sweep(poses, src, dst, dps, weights, out_ptr, out_e, in_ptr, in_e, 0.5)
            sweeps.append(time.perf_counter() - t0)
        print(
            f"| {label} | {r['loops']} | {r['update'] * 1e3:.4f} | {r['quiet'] * 1e3:.4f} |"
            f" {r['loop'] * 1e3:.2f} | {statistics.median(sweeps) * 1e3:.3f} |"
            f" {r['misfit_before']:.3f} / {r['misfit_after']:.4f} | {r['err']:.3f} |"
        )


def whole_laplacian_solve(
    src: np.ndarray, dst: np.ndarray, info: np.ndarray, rel: np.ndarray, n: int
) -> np.ndarray:
    """``bioslam.link_solve.solve_links`` without the elimination: the whole Laplacian of
    every experience factorised, the solve as it was before the junctions (the baseline)."""
    d = 1 if info.ndim == 1 else 2
    x = factorised_solve(src, dst, info.reshape(-1, d, d), rel.reshape(-1, d), n)
    return x[:, 0] if d == 1 else x


def timed_solves(cm: CognitiveMap, repeats: int) -> tuple[list[float], np.ndarray]:
    """Wall times of ``repeats`` solves of ``cm`` as a closure runs it, and the poses."""
    poses = cm._poses.view()
    start = poses.copy()
    scale = cm._link_scale.view()
    robust = scale.copy()  # the robust kernel's weights, which a solve updates
    times = []
    for _ in range(repeats):
        poses[:] = start
        scale[:] = robust
        t0 = time.perf_counter()
        cm.solve()
        times.append(time.perf_counter() - t0)
    solved = poses.copy()
    poses[:] = start
    scale[:] = robust
    return times, solved


def bench_map_solve(seconds: float, repeats: int = 20) -> None:
    from bioslam.config import SLAMConfig
    from bioslam.sim import LIDAR_PRESETS, make_route, maze_world, simulate_scans
    from bioslam.slam import BioSLAM

    world = maze_world()
    route = make_route(world, duration=seconds, seed=0)
    slam = BioSLAM(SLAMConfig())
    for scan, _ in simulate_scans(world, LIDAR_PRESETS["utm30lx"], route, seed=0):
        slam.process(scan)
    cm = slam.cognitive_map
    src, dst, *_ = cm._adjacency()
    n = len(cm)
    window = cm.config.solve_window
    lo = 1 if window is None else max(1, n - window)  # the first experience the solve moves
    ls, lt = _ground_numbered(src, lo, n - lo), _ground_numbered(dst, lo, n - lo)
    ones = np.ones((src.size, 1, 1))
    kept = _eliminate(n - lo + 1, ls, lt, ones, np.zeros((src.size, 1)))[0]
    print(f"\n## The solve after a closure on the demo maze's map ({seconds:g} s, UTM-30LX)\n")
    print(f"{n} experiences, {cm.num_links} links ({cm.loop_closures} loops), "
          f"{kept.size - 1} junctions left to factorise; ms per solve over {repeats} solves:\n")
    print("| solve | median ms | p90 ms |\n|---|---|---|")
    junctions, by_junctions = timed_solves(cm, repeats)
    saved = cognitive_map.solve_links
    cognitive_map.solve_links = whole_laplacian_solve  # type: ignore[assignment]
    try:
        whole, by_whole = timed_solves(cm, repeats)
    finally:
        cognitive_map.solve_links = saved
    for name, times in (("on the junctions", junctions), ("whole Laplacian", whole)):
        print(f"| {name} | {statistics.median(times) * 1e3:.2f} |"
              f" {percentile(times, 90) * 1e3:.2f} |")
    gap = np.abs(by_junctions[:, :2] - by_whole[:, :2]).max()
    print(f"\nratio of medians {statistics.median(whole) / statistics.median(junctions):.2f}; "
          f"largest difference between the two solutions {gap:.1e} m")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--updates", type=int, default=4000)
    parser.add_argument("--sizes", default="100,1000,10000")
    parser.add_argument("--map-seconds", type=float, default=600.0)
    args = parser.parse_args()
    # Compile the Numba kernels outside the timings.
    warm = PoseCellNetwork()
    warm.path_integrate((0.3, 0.0, 0.3))
    warm.step()
    bench_updates(args.updates)
    bench_tracking()
    bench_ambiguity()
    bench_relaxation([int(s) for s in args.sizes.split(",")])
    if args.map_seconds > 0:
        bench_map_solve(args.map_seconds)


if __name__ == "__main__":
    main()
