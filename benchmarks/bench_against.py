"""The odometry of this checkout against an earlier revision's, in one process.

A speed change is a few percent to a few tens; a shared machine's per-scan medians move by
as much between two runs of the same code. Here both versions run in the same process, scan
by scan, each on its own copy of the scans (read by its own log reader), which one goes
first alternating from scan to scan: whatever else loads the machine weighs on both alike.
The earlier revision's ``src/bioslam`` is taken from git (``git archive``) into a temporary
folder as a package of another name, so that the two import side by side. Per case: the
per-scan thread CPU medians and means of both, their ratios, and whether the two ended on
the same pose (a change meant to be of speed alone must leave every pose as it was).

    python benchmarks/bench_against.py --base 8431bd7 [--reps 2] [--only intel,fr1m,maze]

Cases: ``intel`` (the shared thinned Intel log), ``fr1m`` (freiburg-079 thinned to a scan
per 1 m / 0.6 rad), ``maze`` (the simulated maze, UTM-30LX at 40 Hz, 60 s: dense scans).
Both copies keep their own compiled kernels' caches (Numba caches by file), so the first
repetition, not timed, also warms both.
"""

from __future__ import annotations

import argparse
import importlib
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from bench_odometry import DATA, REPO, thinned

BASE_NAME = "bioslam_base"
IMPORTS = re.compile(r"\bbioslam(?=[.\s])")


def base_package(revision: str, into: Path) -> None:
    """``src/bioslam`` at ``revision`` as the package ``bioslam_base`` in ``into``."""
    archive = subprocess.run(
        ["git", "-C", str(REPO), "archive", revision, "src/bioslam"],
        check=True, capture_output=True,
    ).stdout  # fmt: skip
    subprocess.run(["tar", "-x", "-C", str(into)], input=archive, check=True)
    package = into / BASE_NAME
    (into / "src" / "bioslam").rename(package)
    for path in package.rglob("*.py"):
        text = path.read_text()
        path.write_text(IMPORTS.sub(BASE_NAME, text))


def log_scans(package: str, filename: str, select=None) -> list:
    """The scans of a shared log as ``package``'s reader reads them (``select(scans,
    reference)`` keeps some)."""
    open_log = importlib.import_module(f"{package}.io.logs").open_log
    source = open_log(DATA / filename)
    scans = list(source)
    return select(scans, source.reference) if select else scans


def sim_scans(package: str) -> list:
    """The simulated maze, UTM-30LX, 60 s, seed 1, through ``package``'s simulator."""
    sim = importlib.import_module(f"{package}.sim")
    world = sim.load_world("maze")
    route = sim.make_route(world, duration=60.0, seed=1)
    pairs = sim.simulate_scans(world, sim.LIDAR_PRESETS["utm30lx"], route, seed=1)
    return [scan for scan, _ in pairs]


CASES = {
    "intel": lambda package: log_scans(package, "intel-corrected.log.gz"),
    "fr1m": lambda package: log_scans(package, "freiburg-079-corrected.log.gz", thinned(1.0, 0.6)),
    "maze": sim_scans,
}


def interleaved(odometries: list, scans: list[list], reps: int) -> tuple[list, list]:
    """Per-scan thread CPU seconds of each odometry class over ``reps`` timed repetitions
    (after one untimed), the two fed the same scan one after the other, in alternating
    order; and each one's last pose of the last repetition."""
    times: list[list[float]] = [[] for _ in odometries]
    poses: list = []
    for rep in range(reps + 1):
        runs = [make(None) for make in odometries]
        for k in range(len(scans[0])):
            order = (0, 1) if k % 2 else (1, 0)
            for i in order:
                t0 = time.thread_time()
                runs[i].update(scans[i][k])
                if rep:
                    times[i].append(time.thread_time() - t0)
        poses = [run.pose.copy() for run in runs]
    return times, poses


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--base", required=True, help="the git revision to compare against")
    ap.add_argument("--reps", type=int, default=2)
    ap.add_argument("--only", default=",".join(CASES))
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as folder:
        base_package(args.base, Path(folder))
        sys.path.insert(0, folder)
        classes = [
            importlib.import_module(f"{p}.odometry").LidarOdometry for p in ("bioslam", BASE_NAME)
        ]
        print(f"this checkout against {args.base}, {args.reps} timed repetitions", flush=True)
        for name in args.only.split(","):
            scans = [CASES[name](p) for p in ("bioslam", BASE_NAME)]
            (new, base), (end_new, end_base) = interleaved(classes, scans, args.reps)
            mn, mb = 1e3 * np.median(new), 1e3 * np.median(base)
            print(
                f"case={name}  scans={len(scans[0])}  ms_median_base={mb:.3f}  "
                f"ms_median_new={mn:.3f}  ratio_medians={mn / mb:.3f}  "
                f"ratio_means={np.mean(new) / np.mean(base):.3f}  "
                f"ms_p99_base={1e3 * np.percentile(base, 99):.2f}  "
                f"ms_p99_new={1e3 * np.percentile(new, 99):.2f}  "
                f"same_last_pose={bool(np.array_equal(end_new, end_base))}",
                flush=True,
            )


if __name__ == "__main__":
    main()
