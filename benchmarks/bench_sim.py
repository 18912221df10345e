"""Simulator speed and memory: 600 s of the utm30lx preset at 40 Hz (24,000 scans x 1081
beams) through the maze, on one core. Targets (issue 2): < 60 s, peak memory < 1 GB.
``--world``, ``--lidar`` and ``--route`` measure the same on another world (the warehouse has
15 times the maze's walls), sensor or route.

Each phase runs in a fresh child process (one thread) so that its wall time and peak resident
memory are its own. The baseline, measured in the same run, is brute-force ray casting (every
beam against every wall, vectorised NumPy) on the same scans, to show what the grid buys.

    python benchmarks/bench_sim.py [--duration 600] [--repeat 1] [--world maze] [--lidar utm30lx]
        [--route tour]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ONE_THREAD = {
    "NUMBA_NUM_THREADS": "1",
    "OMP_NUM_THREADS": "1",
    "OPENBLAS_NUM_THREADS": "1",
    "MKL_NUM_THREADS": "1",
}
BASELINE_SCANS = 200


def _setup(args: argparse.Namespace, duration: float | None = None):
    """The world, the route (``duration`` or the run's) and the LiDAR asked for."""
    from bioslam.sim import LIDAR_PRESETS, ROUTES, load_world

    world = load_world(args.world)
    route = ROUTES[args.route](world, duration=duration or args.duration, seed=0)
    return world, route, LIDAR_PRESETS[args.lidar]


def phase_route(args: argparse.Namespace) -> dict:
    from bioslam.sim import ROUTES, load_world

    world = load_world(args.world)
    t0 = time.perf_counter()
    route = ROUTES[args.route](world, duration=args.duration, seed=0)
    return {"route_s": time.perf_counter() - t0, "path_length_m": route.path_length()}


def phase_scans(args: argparse.Namespace) -> dict:
    from bioslam.sim import simulate_scans

    world, route, lidar = _setup(args)
    next(iter(simulate_scans(world, lidar, route)))  # JIT warm-up
    t0 = time.perf_counter()
    n = beams = 0
    for scan, _ in simulate_scans(world, lidar, route, seed=0):
        n += 1
        beams += scan.num_beams
    return {"scans": n, "beams": beams, "simulate_s": time.perf_counter() - t0}


def phase_cli(args: argparse.Namespace) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "sim"
        t0 = time.perf_counter()
        from bioslam.cli import sim

        parser = argparse.ArgumentParser()
        sim.register(parser.add_subparsers(dest="command"))
        cli = parser.parse_args(["sim", "--duration", str(args.duration), "--world", args.world,
                                 "--lidar", args.lidar, "--route", args.route, "--out", str(out)])
        summary = cli.func(cli)
        wall = time.perf_counter() - t0
        bag_mb = sum(f.stat().st_size for f in (out / "scans").iterdir()) / 1e6
    return {"cli_s": wall, "bag_mb": bag_mb, "scans": summary["scans"]}


def phase_baseline(args: argparse.Namespace) -> dict:
    """Grid ray casting vs brute force on the same first BASELINE_SCANS scans."""
    import numpy as np

    from bioslam.sim.raycast import cast_rays
    from bioslam.sim.simulate import scan_stamps

    world, route, lidar = _setup(args, min(args.duration, 60.0))
    stamps = scan_stamps(lidar, route)[:BASELINE_SCANS]
    times = stamps[:, None] + lidar.time_increment * np.arange(lidar.beams)
    poses = route.pose_at(times)
    origins, angles = poses[..., :2], poses[..., 2] + lidar.angles()
    cast_rays(world.grid, origins[:1], angles[:1])  # JIT warm-up
    t0 = time.perf_counter()
    grid = cast_rays(world.grid, origins, angles, lidar.range_max)
    grid_s = time.perf_counter() - t0
    seg = world.segments
    a, e = seg[:, :2], seg[:, 2:] - seg[:, :2]
    t0 = time.perf_counter()
    brute = np.empty(angles.shape)
    for k in range(len(stamps)):
        d = np.stack([np.cos(angles[k]), np.sin(angles[k])], -1)[:, None, :]
        ao = a[None] - origins[k][:, None, :]
        denom = d[..., 0] * e[None, :, 1] - d[..., 1] * e[None, :, 0]
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (ao[..., 0] * e[None, :, 1] - ao[..., 1] * e[None, :, 0]) / denom
            u = (ao[..., 0] * d[..., 1] - ao[..., 1] * d[..., 0]) / denom
        ok = (denom != 0) & (t >= 0) & (u >= 0) & (u <= 1)
        brute[k] = np.where(ok, t, np.inf).min(axis=1)
    brute_s = time.perf_counter() - t0
    brute[brute > lidar.range_max] = np.inf
    return {
        "grid_ms_per_scan": 1e3 * grid_s / len(stamps),
        "brute_ms_per_scan": 1e3 * brute_s / len(stamps),
        "max_abs_diff_m": float(np.max(np.abs(np.nan_to_num(grid - brute, posinf=0.0)))),
    }


PHASES = {
    "route": phase_route,
    "scans": phase_scans,
    "cli": phase_cli,
    "baseline": phase_baseline,
}


def run_child(phase: str, args: argparse.Namespace) -> dict:
    """Run one phase in a fresh interpreter; add its wall time and peak RSS (wait4)."""
    cmd = [sys.executable, __file__, "--child", phase, "--duration", str(args.duration),
           "--world", args.world, "--lidar", args.lidar, "--route", args.route]  # fmt: skip
    t0 = time.perf_counter()
    proc = subprocess.Popen(
        cmd, stdout=subprocess.PIPE, env={**os.environ, **ONE_THREAD}, text=True
    )
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - t0
    out = proc.stdout.read() if proc.stdout else ""
    if os.waitstatus_to_exitcode(status) != 0:
        raise RuntimeError(f"phase {phase} failed:\n{out}")
    result = json.loads(out.strip().splitlines()[-1])
    result["process_wall_s"] = wall
    result["peak_rss_mb"] = usage.ru_maxrss / 1024.0  # Linux reports kilobytes
    # CPU time of the child: the fair figure when other jobs share the cores.
    result["process_cpu_s"] = usage.ru_utime + usage.ru_stime
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=600.0)
    parser.add_argument("--repeat", type=int, default=1, help="timed runs of the scan phase")
    parser.add_argument("--world", default="maze", help="built-in world or map YAML")
    parser.add_argument("--lidar", default="utm30lx", help="LiDAR preset")
    parser.add_argument("--route", default="tour", help="tour or adversarial")
    parser.add_argument("--child", choices=sorted(PHASES), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        print(json.dumps(PHASES[args.child](args)))
        return
    route = run_child("route", args)
    scans = [run_child("scans", args) for _ in range(args.repeat)]
    cli = run_child("cli", args)
    base = run_child("baseline", args)
    sim_s = statistics.median(r["simulate_s"] for r in scans)
    summary = {
        "world": args.world,
        "lidar": args.lidar,
        "route": args.route,
        "duration_s": args.duration,
        "scans": scans[0]["scans"],
        "route_s": round(route["route_s"], 2),
        "simulate_s_median": round(sim_s, 2),
        "simulate_scans_per_s": round(scans[0]["scans"] / sim_s, 1),
        "simulate_peak_rss_mb": round(max(r["peak_rss_mb"] for r in scans), 1),
        "simulate_process_cpu_s": round(statistics.median(r["process_cpu_s"] for r in scans), 2),
        "cli_s": round(cli["cli_s"], 2),
        "cli_process_cpu_s": round(cli["process_cpu_s"], 2),
        "cli_peak_rss_mb": round(cli["peak_rss_mb"], 1),
        "bag_mb": round(cli["bag_mb"], 1),
        "grid_ms_per_scan": round(base["grid_ms_per_scan"], 3),
        "brute_ms_per_scan": round(base["brute_ms_per_scan"], 3),
        "grid_speedup": round(base["brute_ms_per_scan"] / base["grid_ms_per_scan"], 1),
        "grid_vs_brute_max_diff_m": base["max_abs_diff_m"],
    }
    load = os.getloadavg()[0]
    print(f"target for 600 s of utm30lx in the maze: < 60 s on one core, < 1024 MB; "
          f"load average {load:.1f}")
    for key, value in summary.items():
        print(f"  {key:28s} {value}")
    print(json.dumps(summary))


if __name__ == "__main__":
    main()
