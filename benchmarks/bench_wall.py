"""Whole-process wall clock of ``bioslam run``, code against code, alternating in one run.

Each arm is a source tree (``PYTHONPATH``) and extra ``bioslam run`` arguments; the arms run in
turn, ``--pairs`` times, the order reversed every other round so that a change in the
machine's load falls on both. Measured from outside as ``bench_memory.py`` does: wall time,
CPU time (the helpers' included), the summed per-scan time from the run's summary, their
ratios, the per-scan median and peak RSS. Prints each run and the medians per arm.

    python benchmarks/bench_wall.py INPUT --arm before=/path/to/old/src \\
        --arm now=src --arm one-process=src:--one-process [--pairs 3]

A tree's Numba cache must be warm (run it once first): a compiling run is not a timing.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from bench_memory import WORK, watch  # noqa: E402
from cases import bioslam_cli  # noqa: E402


def arm(text: str) -> tuple[str, str, list[str]]:
    """``NAME=SRC[:ARG,ARG...]``."""
    name, _, rest = text.partition("=")
    src, _, extra = rest.partition(":")
    return name, str(Path(src).resolve()), [a for a in extra.split(",") if a]


def measure(input_path: str, name: str, src: str, extra: list[str]) -> dict[str, float]:
    out = WORK / "wall" / name
    cmd = [*bioslam_cli(), "run", input_path, "--out", str(out), "--overwrite", *extra]
    r = watch(cmd, 0.25, {"PYTHONPATH": src})
    summary = r["summary"]
    per_scan = summary["duration_s"] / summary["realtime_factor"]
    return {"wall_s": r["wall_s"], "cpu_s": r["cpu_s"], "per_scan_sum_s": per_scan,
            "wall_over_per_scan_sum": r["wall_s"] / per_scan,
            "cpu_over_per_scan_sum": r["cpu_s"] / per_scan,
            "wall_rt_factor": summary["duration_s"] / r["wall_s"],
            "ms_per_scan_median": summary["ms_per_scan_median"],
            "peak_rss_mb": r["peak_rss_mb"], "peak_tree_mb": r["peak_tree_mb"],
            "load": os.getloadavg()[0]}  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("input")
    parser.add_argument("--arm", action="append", type=arm, required=True,
                        help="NAME=SRC[:ARG,...], repeated")
    parser.add_argument("--pairs", type=int, default=3)
    args = parser.parse_args()
    rows: dict[str, list[dict[str, float]]] = {name: [] for name, _, _ in args.arm}
    for k in range(args.pairs):
        for name, src, extra in args.arm if k % 2 == 0 else reversed(args.arm):
            rows[name].append(measure(args.input, name, src, extra))
            print(name, json.dumps({key: round(v, 3) for key, v in rows[name][-1].items()}),
                  flush=True)
    for name, runs in rows.items():
        medians = {key: round(statistics.median(r[key] for r in runs), 3) for key in runs[0]}
        print(f"{name} median of {len(runs)}: {json.dumps(medians)}")


if __name__ == "__main__":
    main()
