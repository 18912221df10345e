"""Ablation: odometry alone vs the full system on the demo's maze, with and without an injected
gyro-like heading drift, in one run. Prints a table and writes it to
``benchmarks/results/ablation/maze-<duration>s-<date>.md``.

    python benchmarks/ablation.py [--duration 600] [--bias 0.0005] [--lidar utm30lx] [--seed 0]

The README's 20 min row: ``--duration 1200 --seed 2 --lidar rplidar --bias 0.0002007``
(0.0115 deg/s).
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import time
from pathlib import Path

import numpy as np

from bioslam.config import SLAMConfig
from bioslam.evaluation import evaluate
from bioslam.sim import LIDAR_PRESETS, make_route, maze_world, simulate_scans
from bioslam.slam import BioSLAM
from bioslam.trajectory import Trajectory

RESULTS = Path(__file__).resolve().parent / "results" / "ablation"


def run(scans: list, gt: Trajectory, bias: float) -> list[tuple[str, dict, dict, float]]:
    slam = BioSLAM(dataclasses.replace(SLAMConfig(), heading_bias=bias))
    started = time.perf_counter()
    for scan in scans:
        slam.process(scan)
    slam.finish()
    wall = time.perf_counter() - started
    label = f"heading bias {bias:g} rad/s" if bias else "no injected drift"
    return [
        (label, {"system": "odometry only"}, evaluate(slam.odometry_trajectory(), gt), wall),
        (label, {"system": "bioslam", **slam.summary()}, evaluate(slam.trajectory(), gt), wall),
    ]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--duration", type=float, default=600.0)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--bias", type=float, default=0.0005, help="rad/s (0.0005 = 0.03 deg/s)")
    parser.add_argument("--lidar", default="utm30lx", choices=sorted(LIDAR_PRESETS))
    args = parser.parse_args()
    world = maze_world()
    route = make_route(world, duration=args.duration, seed=args.seed)
    pairs = list(simulate_scans(world, LIDAR_PRESETS[args.lidar], route, seed=args.seed))
    scans = [scan for scan, _ in pairs]
    gt = Trajectory(np.array([s.stamp for s in scans]), np.array([p for _, p in pairs]))
    rows = run(scans, gt, 0.0) + run(scans, gt, args.bias)
    lines = [
        f"# Ablation on the simulated maze ({args.duration:g} s, {args.lidar}, seed {args.seed})",
        "",
        "| drift | system | ATE RMSE m | ATE mean m | ATE max m | loop closures | wall s |",
        "|---|---|---|---|---|---|---|",
    ]
    for label, info, metrics, wall in rows:
        lines.append(
            f"| {label} | {info['system']} | {metrics['ate_rmse_m']:.4f} | "
            f"{metrics['ate_mean_m']:.4f} | {metrics['ate_max_m']:.4f} | "
            f"{info.get('loop_closures', '')} | {wall:.0f} |"
        )
    text = "\n".join(lines) + "\n"
    print(text)
    RESULTS.mkdir(parents=True, exist_ok=True)
    out = RESULTS / f"maze-{args.lidar}-{args.duration:g}s-{datetime.date.today().isoformat()}.md"
    out.write_text(text)
    print(f"written: {out}")


if __name__ == "__main__":
    main()
