"""Ablation: odometry alone vs the full system on the demo's maze, with and without an injected
gyro-like heading drift, in one run. Prints a table and writes it to
``benchmarks/results/ablation/maze-<lidar>-<duration>s-<date>.md`` (``-seeds-A-B`` before the
date when several seeds are run).

    python benchmarks/ablation.py [--duration 600] [--bias 0.0005] [--lidar utm30lx] [--seed 0]
    python benchmarks/ablation.py ... --seeds 0-13 [--jobs 2]

The README's 20 min row: ``--duration 1200 --seed 2 --lidar rplidar --bias 0.0002007``
(0.0115 deg/s). One seed's figure is one draw: two odometries that differ by a fraction of
a millimetre in one match drift apart within a minute, so a change is judged on the median
over seeds (``--seeds``), which the several-seed table ends with.
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import NamedTuple

import numpy as np
from bench_loops import SimCase, simulate

from bioslam.config import SLAMConfig
from bioslam.evaluation import evaluate
from bioslam.sim import LIDAR_PRESETS
from bioslam.slam import BioSLAM
from bioslam.trajectory import Trajectory

RESULTS = Path(__file__).resolve().parent / "results" / "ablation"


class Row(NamedTuple):
    drift: str
    system: str
    metrics: dict  # evaluate()'s ATE figures against the simulator's truth
    closures: int | str  # blank for the odometry alone
    wall: float  # seconds for the whole run, both systems


def run(scans: list, gt: Trajectory, bias: float) -> list[Row]:
    slam = BioSLAM(dataclasses.replace(SLAMConfig(), heading_bias=bias))
    started = time.perf_counter()
    for scan in scans:
        slam.process(scan)
    slam.finish()
    wall = time.perf_counter() - started
    label = f"heading bias {bias:g} rad/s" if bias else "no injected drift"
    return [
        Row(label, "odometry only", evaluate(slam.odometry_trajectory(), gt), "", wall),
        Row(label, "bioslam", evaluate(slam.trajectory(), gt), slam.cognitive_map.loop_closures,
            wall),
    ]


def ablate(duration: float, seed: int, lidar: str, bias: float) -> list[Row]:
    """The four rows of one seed: each system without and with the drift, on the maze's
    tour (simulated as the loop-closure benchmark does)."""
    scans, gt = simulate(SimCase("maze", lidar, "tour"), duration, seed)
    return run(scans, gt, 0.0) + run(scans, gt, bias)


def seed_list(text: str) -> list[int]:
    """``"0-13"`` or ``"0,2,5"`` (or both, comma-separated) as a list of seeds."""
    seeds: list[int] = []
    for part in text.split(","):
        first, _, last = part.partition("-")
        seeds += range(int(first), int(last or first) + 1)
    return seeds


def table(by_seed: dict[int, list[Row]]) -> list[str]:
    """The rows of every seed (a seed column when there are several), then, for several,
    each row's ATE RMSE over the seeds: median, least and most."""
    several = len(by_seed) > 1
    head = "| seed " if several else ""
    lines = [
        f"{head}| drift | system | ATE RMSE m | ATE mean m | ATE max m | loop closures | wall s |",
        f"{'|---' if several else ''}|---|---|---|---|---|---|---|",
    ]
    for seed, rows in by_seed.items():
        for row in rows:
            ate = row.metrics
            lines.append(
                (f"| {seed} " if several else "")
                + f"| {row.drift} | {row.system} | {ate['ate_rmse_m']:.4f} | "
                f"{ate['ate_mean_m']:.4f} | {ate['ate_max_m']:.4f} | {row.closures} | "
                f"{row.wall:.0f} |"
            )
    if several:
        lines += [
            "", "| drift | system | ATE RMSE m, median | least | most |", "|---|---|---|---|---|",
        ]
        for k, row in enumerate(next(iter(by_seed.values()))):
            ates = np.array([rows[k].metrics["ate_rmse_m"] for rows in by_seed.values()])
            lines.append(
                f"| {row.drift} | {row.system} | {np.median(ates):.4f} | {ates.min():.4f} | "
                f"{ates.max():.4f} |"
            )
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--duration", type=float, default=600.0)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--seeds", type=seed_list, default=None,
                        help="several seeds instead, e.g. 0-13 or 0,2,5; medians at the end")
    parser.add_argument("--jobs", type=int, default=1, help="seeds run at once")
    parser.add_argument("--bias", type=float, default=0.0005, help="rad/s (0.0005 = 0.03 deg/s)")
    parser.add_argument("--lidar", default="utm30lx", choices=sorted(LIDAR_PRESETS))
    args = parser.parse_args()
    seeds = args.seeds or [args.seed]
    n = len(seeds)
    each = ([args.duration] * n, seeds, [args.lidar] * n, [args.bias] * n)
    if args.jobs > 1 and n > 1:
        with ProcessPoolExecutor(max_workers=args.jobs) as pool:
            runs = list(pool.map(ablate, *each))
    else:  # in this process, as a single seed always ran
        runs = list(map(ablate, *each))
    by_seed = dict(zip(seeds, runs, strict=True))
    named = f"seeds {','.join(map(str, seeds))}" if args.seeds else f"seed {args.seed}"
    lines = [
        f"# Ablation on the simulated maze ({args.duration:g} s, {args.lidar}, {named})",
        "",
        *table(by_seed),
    ]
    text = "\n".join(lines) + "\n"
    print(text)
    RESULTS.mkdir(parents=True, exist_ok=True)
    span = f"-seeds-{min(seeds)}-{max(seeds)}" if args.seeds else ""
    day = datetime.date.today().isoformat()
    out = RESULTS / f"maze-{args.lidar}-{args.duration:g}s{span}-{day}.md"
    out.write_text(text)
    print(f"written: {out}")


if __name__ == "__main__":
    main()
