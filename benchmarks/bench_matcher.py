"""The wide-basin matcher alone: branch and bound against brute force, same lattice, same run.

For each sensor, scans along a simulated route are searched against a local map made from
the scans of the previous seconds at their true poses (as the odometry's map is), from a
start offset by up to ``--offset`` metres and ``--turn`` degrees in a random direction.
Reported per sensor: the median and 90th-percentile CPU time of the branch-and-bound search
and of building its pooled grids, the brute-force search's median on the same lattice (a
subset of the queries: it is slow), how often the winner is within 10 cm / 2° of the truth
(and within 2 cm after Gauss-Newton), the median ambiguity, and whether the two searches
agreed on the best score (they must, always).

Usage: ``python benchmarks/bench_matcher.py [--queries 60] [--world maze,warehouse,hall]
[--depth 4|none] [--angular-cells 2]`` (the odometry's settings: depth 4, two cells; the
default one cell is the finer lattice, twice the headings). Worlds: maze, warehouse, rooms,
hall (comma-separated, each in turn).
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np

from bioslam.geometry import between, compose
from bioslam.matching.branch_and_bound import WideBasinConfig, WideBasinMatcher, refine
from bioslam.occupancy_grid import MapPyramid, subsample_by_spacing
from bioslam.sim import (
    LIDAR_PRESETS,
    LidarModel,
    load_world,
    make_route,
    maze_world,
    simulate_scans,
)

# SICK LMS 200/291 (most public 2D datasets): 180°, 181 beams, 80 m, 10 Hz
SICK = LidarModel("sick", math.pi, 181, 0.05, 80.0, 10.0, 0.01)


def _world(name: str):
    return maze_world() if name == "maze" else load_world(name)


def _sensors() -> dict[str, LidarModel]:
    return {
        "sick 181": LIDAR_PRESETS.get("sick", SICK),
        "utm30lx 1081": LIDAR_PRESETS["utm30lx"],
    }


def run(world_name: str, queries: int, brute_every: int, offset: float, turn: float,
        cfg: WideBasinConfig) -> None:  # fmt: skip
    world = _world(world_name)
    route = make_route(world, duration=max(queries * 1.2, 30.0), seed=3)
    print(f"world {world_name}, window ±{cfg.distance} m ±{math.degrees(cfg.angle):.0f}°, "
          f"start offset up to {offset} m / {turn}°, lattice at 0.1 m, depth {cfg.depth}, "
          f"heading step {cfg.angular_cells} cell(s)")  # fmt: skip
    header = ("sensor", "points", "B&B ms", "p90", "grids ms", "brute ms", "ratio",
              "within 10cm/2°", "GN within 2cm", "ambiguity", "same score")  # fmt: skip
    print(" | ".join(header))
    rng = np.random.default_rng(0)
    for label, lidar in _sensors().items():
        scans = list(simulate_scans(world, lidar, route, seed=1))
        step = max(len(scans) // (queries + 30), 1)
        pyramid = MapPyramid(0.05, 48.0, 3)
        pyramid.recenter(*scans[0][1][:2])
        matcher = WideBasinMatcher(cfg)
        bb, grids, brute, near, refined, amb, same = [], [], [], [], [], [], []
        history: list = []
        for k in range(0, len(scans), step):
            scan, truth = scans[k]
            pts = scan.endpoints()
            if len(history) >= 3 and len(bb) < queries:
                grid = pyramid.grids[1]
                sub = np.ascontiguousarray(pts[subsample_by_spacing(pts, grid.resolution)])
                reach = float(np.max(np.hypot(sub[:, 0], sub[:, 1]))) + cfg.distance + 0.5
                heading = rng.uniform(-math.pi, math.pi)
                start = compose(truth, (offset * math.cos(heading), offset * math.sin(heading),
                                        math.radians(turn) * rng.choice([-1, 1])))  # fmt: skip
                box = (start[0] - reach, start[1] - reach, start[0] + reach, start[1] + reach)
                t0 = time.thread_time()
                matcher.set_map(grid, box)
                t1 = time.thread_time()
                found = matcher.search(sub, start)
                t2 = time.thread_time()
                grids.append(t1 - t0)
                bb.append(t2 - t1)
                d = between(truth, found.pose)
                near.append(math.hypot(d[0], d[1]) < 0.1 and abs(d[2]) < math.radians(2))
                pose, _ = refine(pyramid, found.pose, pts)
                d = between(truth, pose)
                refined.append(math.hypot(d[0], d[1]) < 0.02)
                amb.append(found.ambiguity)
                if len(bb) % brute_every == 1:
                    t0 = time.thread_time()
                    scores, _ = matcher.brute_force_scores(sub, start)
                    brute.append(time.thread_time() - t0)
                    same.append(bool(scores.max() == found.score))
            pyramid.insert_scan(truth, pts)
            history.append(k)
        ms = np.array(bb) * 1e3
        brute_ms = float(np.median(brute)) * 1e3
        print(f"{label} | {len(sub)} | {np.median(ms):.2f} | {np.percentile(ms, 90):.2f} | "
              f"{np.median(grids) * 1e3:.2f} | {brute_ms:.1f} | {brute_ms / np.median(ms):.0f}x | "
              f"{np.mean(near):.0%} | {np.mean(refined):.0%} | {np.median(amb):.2f} | "
              f"{sum(same)}/{len(same)}")  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--queries", type=int, default=60)
    parser.add_argument("--brute-every", type=int, default=4)
    parser.add_argument("--world", default="maze", help="comma-separated world names")
    parser.add_argument("--offset", type=float, default=1.0, help="start offset, metres")
    parser.add_argument("--turn", type=float, default=30.0, help="start heading offset, deg")
    parser.add_argument("--depth", default="4", help="pooling levels, or none: the whole window")
    parser.add_argument("--angular-cells", type=float, default=1.0)
    a = parser.parse_args()
    depth = None if a.depth.lower() == "none" else int(a.depth)
    cfg = WideBasinConfig(depth=depth, angular_cells=a.angular_cells)
    for world in a.world.split(","):
        run(world, a.queries, a.brute_every, a.offset, a.turn, cfg)


if __name__ == "__main__":
    main()
