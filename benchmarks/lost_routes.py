"""Where the thinned simulated routes a battery lost go wrong (LiDAR odometry alone).

Reads the output of ``bench_odometry.py`` (its ``case=`` lines), runs again each thinned
simulated route it lost (ATE above ``--lost`` cm) and stops at the route's first wrong step
(off by more than 0.3 m or 10° from the true step). There it says what the sparse chooser
(``LidarOdometry._choose_sparse``) had: how many options, whether one lay near the true pose
(within 0.1 m and 3°) and the merit (quality less the step prior's cost) of the best such
option against the one kept. With ``--next N`` it also runs the step twice from a copy of the
odometry, once as it was and once with the near option kept, and sums the match quality of
the next N scans after each: whether a decision deferred by N scans could tell them apart.

    python benchmarks/bench_odometry.py --only typicalstep15,office,turnonspot > bat.txt
    python benchmarks/lost_routes.py bat.txt --next 3

The results are in ``benchmarks/README.md`` ("A corner's arc").
"""

from __future__ import annotations

import argparse
import copy
import math
import re
from dataclasses import dataclass

import numpy as np
from bench_odometry import office_world, simulated_scans

from bioslam.geometry import between
from bioslam.odometry import LidarOdometry
from bioslam.odometry.choice import match_quality
from bioslam.sim import LIDAR_PRESETS

#: A thinned simulated route's name as ``bench_odometry.py`` prints it.
ROUTE_NAME = re.compile(
    r"(?P<world>\w+) (?P<route>tour|adversarial|reversing) (?P<lidar>\w+), a scan per "
    r"(?P<distance>[\d.]+) m (?:/ (?P<angle>[\d.]+) rad|by distance alone), seed (?P<seed>\d+)$"
)
NEAR_DISTANCE, NEAR_ANGLE = 0.1, math.radians(3.0)
WRONG_DISTANCE, WRONG_ANGLE = 0.3, math.radians(10.0)


def near(pose: np.ndarray, truth: np.ndarray) -> bool:
    """Within ``NEAR_DISTANCE`` and ``NEAR_ANGLE`` of the true pose."""
    d = between(truth, pose)
    return math.hypot(d[0], d[1]) < NEAR_DISTANCE and abs(d[2]) < NEAR_ANGLE


class WatchedOdometry(LidarOdometry):
    """The odometry, noting what the sparse chooser had against a known true pose
    (``truth``); with ``keep_true`` it keeps the best option near that pose instead."""

    truth: np.ndarray | None = None
    keep_true = False
    seen: tuple[int, float | None, float] | None = None

    def _choose_sparse(self, options, previous, reach, gapless=False):
        pose, report = super()._choose_sparse(options, previous, reach, gapless)

        def merit(option) -> float:
            return match_quality(option[1]) - self._step_cost(previous, option[0])

        close = [o for o in options if self.truth is not None and near(o[0], self.truth)]
        kept = next(o for o in options if o[1] is report)
        best = max(close, key=merit) if close else None
        self.seen = (len(options), None if best is None else merit(best), merit(kept))
        if self.keep_true and best is not None:
            return best[0], best[1]
        return pose, report


@dataclass
class FirstWrongStep:
    """What a route's first wrong step was chosen from (``WatchedOdometry.seen``; None where
    the scan was not chosen among sparse options) and, with ``--next``, the next scans'
    summed quality after the step kept and after the true one."""

    scan: int
    seen: tuple[int, float | None, float] | None
    next_quality: tuple[float, float] | None = None


def route_scans(name: str, duration: float) -> list[tuple]:
    """The (scan, true pose) pairs of a thinned simulated route named as the battery names it."""
    m = ROUTE_NAME.match(name)
    if m is None:
        raise ValueError(f"not a thinned simulated route: {name!r}")
    world = office_world() if m["world"] == "office" else m["world"]
    thin = (float(m["distance"]), float(m["angle"]) if m["angle"] else None)
    items = simulated_scans(
        world, LIDAR_PRESETS[m["lidar"]], duration, int(m["seed"]), m["route"], thin
    )
    return [(scan, np.asarray(truth, dtype=float)) for scan, truth in items]


def next_quality(before: WatchedOdometry, items: list[tuple], k: int, n: int, keep_true: bool):
    """The summed match quality of the ``n`` scans after scan ``k``, matched from a copy of
    ``before`` (the odometry before scan ``k``) with scan ``k`` as chosen or as the true step."""
    odo = copy.deepcopy(before)
    odo.truth, odo.keep_true = items[k][1], keep_true
    odo.update(items[k][0])
    odo.keep_true = False
    total = 0.0
    for scan, truth in items[k + 1 : k + 1 + n]:
        odo.truth = truth
        odo.update(scan)
        total += match_quality(odo.last_report)
    return total


def first_wrong_step(items: list[tuple], n_next: int) -> FirstWrongStep | None:
    """Run the odometry along ``items`` up to its first wrong step; None if it takes none."""
    odo = WatchedOdometry(initial_pose=items[0][1])
    odo.update(items[0][0])
    for k in range(1, len(items)):
        before = copy.deepcopy(odo) if n_next else None
        previous = odo.pose.copy()
        odo.truth, odo.seen = items[k][1], None
        odo.update(items[k][0])
        miss = between(between(items[k - 1][1], items[k][1]), between(previous, odo.pose))
        if math.hypot(miss[0], miss[1]) > WRONG_DISTANCE or abs(miss[2]) > WRONG_ANGLE:
            found = FirstWrongStep(k, odo.seen)
            if before is not None and odo.seen is not None and odo.seen[1] is not None:
                found.next_quality = tuple(
                    next_quality(before, items, k, n_next, keep) for keep in (False, True)
                )
            return found
    return None


def lost_routes(path: str, lost_cm: float) -> list[tuple[str, float]]:
    """The thinned simulated routes of a ``bench_odometry.py`` output with ATE above
    ``lost_cm`` (the variants without the search left out)."""
    with open(path, encoding="utf-8") as lines:
        rows = [re.match(r"case=(.*?)  scans=.*?ate_cm=([-\d.]+)", line) for line in lines]
    return [
        (m[1], float(m[2])) for m in rows if m and ROUTE_NAME.match(m[1]) and float(m[2]) > lost_cm
    ]


def describe(step: FirstWrongStep | None) -> str:
    if step is None:
        return "no wrong step (drift)"
    if step.seen is None:
        return f"scan {step.scan}: not chosen among sparse options"
    count, true_merit, kept_merit = step.seen
    text = f"scan {step.scan}: {count} options, kept merit {kept_merit:.3f}, "
    if true_merit is None:
        return text + "none near the true step"
    text += f"near the true step {true_merit:.3f}"
    if step.next_quality is not None:
        kept, true = step.next_quality
        text += f"; next scans' quality after the kept {kept:.3f}, after the true {true:.3f}"
    return text


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("results", help="bench_odometry.py output")
    p.add_argument("--lost", type=float, default=30.0, help="ATE (cm) above which a route is lost")
    p.add_argument("--next", type=int, default=0, help="scans after the wrong step to compare")
    p.add_argument("--duration", type=float, default=200.0, help="the routes' duration (s)")
    p.add_argument("--only", default="", help="routes whose name contains this")
    args = p.parse_args()
    for name, ate_cm in lost_routes(args.results, args.lost):
        if args.only in name:
            step = first_wrong_step(route_scans(name, args.duration), args.next)
            print(f"{ate_cm:8.1f} cm  {name}: {describe(step)}", flush=True)


if __name__ == "__main__":
    main()
