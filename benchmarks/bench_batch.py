"""``bioslam batch`` speed-up and engine overhead, on this machine, in one run.

Eight short runs (four simulated maze drives x two odometry resolutions, full system) are
carried out as one batch on 1 and on 2 workers, by each engine, ``--repeat`` times in turn;
reported are the median wall time of each, the speed-up (1-worker / 2-worker, as the ratio of
the medians and as the median of the per-repeat ratios), and what the engine itself costs:

- start: creating the engine (``ray.init`` of a local instance; nothing for the pool, whose
  processes start with the first task);
- overhead per run: (batch wall - the runs' own seconds in the workers) / runs, on 1 worker,
  i.e. worker start-up, dispatch, serialisation and collecting results, spread over the runs;
- round trip: median of ``--noops`` empty tasks submitted one after another to a warm
  engine (Ray remote function / process pool), i.e. the cost a task pays however small it is.

The machine is shared: run it when ``uptime`` shows little load, and read only ratios and
medians. Scratch files go to ``benchmarks/.work/batch/``.

Usage: ``nice -n 10 python benchmarks/bench_batch.py [--repeat 3] [--duration 60]``
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import time
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from pathlib import Path

from bioslam.batch import BatchSpec, expand_grid, run_batch
from bioslam.batch.engines import make_engine, ray_available
from bioslam.cli import main as cli

WORK = Path(__file__).resolve().parent / ".work" / "batch"
SEEDS = (11, 12, 13, 14)
GRID = {"mode": "full", "odometry.resolution": [0.04, 0.05]}


def simulated_logs(duration: float) -> list[Path]:
    """Four maze drives (UTM-30LX), made once and kept in the scratch folder."""
    logs = []
    for seed in SEEDS:
        folder = WORK / f"maze-{duration:g}s-seed{seed}"
        if not (folder / "gt.tum").is_file():
            shutil.rmtree(folder, ignore_errors=True)
            cli(["sim", "--duration", str(duration), "--seed", str(seed), "--out", str(folder)])
        logs.append(folder / "scans")
    return logs


def timed_batch(engine_name: str, workers: int, logs: list[Path]) -> dict[str, float]:
    out = WORK / f"out-{engine_name}-{workers}"
    shutil.rmtree(out, ignore_errors=True)
    started = time.perf_counter()
    engine = make_engine(engine_name, workers)
    engine_s = time.perf_counter() - started
    spec = BatchSpec(logs, out, expand_grid(GRID), gt_from="{dir}/gt.tum")
    report = run_batch(spec, engine, progress=False)
    wall = time.perf_counter() - started
    if report.ok != report.runs:
        raise RuntimeError(f"{report.failed} runs failed: {[r['error'] for r in report.rows]}")
    task_s = sum(float(r["seconds"]) for r in report.rows)
    return {"wall": wall, "engine_s": engine_s, "task_s": task_s, "runs": report.runs}


def _noop(x: int) -> int:
    return x


def round_trip_ms(engine_name: str, calls: int) -> float:
    """Median ms of an empty task on a warm engine of one worker."""
    times = []
    if engine_name == "ray":
        import ray

        ray.init(num_cpus=1, include_dashboard=False, log_to_driver=False)
        try:
            remote = ray.remote(num_cpus=1)(_noop)
            ray.get(remote.remote(0))
            for k in range(calls):
                t0 = time.perf_counter()
                ray.get(remote.remote(k))
                times.append(time.perf_counter() - t0)
        finally:
            ray.shutdown()
    else:
        with ProcessPoolExecutor(1, mp_context=get_context("spawn")) as pool:
            pool.submit(_noop, 0).result()
            for k in range(calls):
                t0 = time.perf_counter()
                pool.submit(_noop, k).result()
                times.append(time.perf_counter() - t0)
    return statistics.median(times) * 1e3


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--duration", type=float, default=60.0, help="seconds per drive")
    parser.add_argument("--noops", type=int, default=200)
    parser.add_argument("--engines", default="process,ray")
    parser.add_argument("--save", type=Path, help="also write the report to this file")
    args = parser.parse_args()
    report: list[str] = []

    def say(line: str = "") -> None:
        print(line, flush=True)
        report.append(line)

    engines = [e for e in args.engines.split(",") if e != "ray" or ray_available()]
    WORK.mkdir(parents=True, exist_ok=True)
    logs = simulated_logs(args.duration)
    say(f"load before: {os.getloadavg()[0]:.2f}; {len(logs)} logs x 2 configs, "
        f"{args.duration:g} s drives, {args.repeat} repeats")
    timed_batch(engines[0], 2, logs)  # untimed: fills Numba's cache and the page cache
    results: dict[tuple[str, int], list[dict[str, float]]] = {}
    for k in range(args.repeat):
        for name in engines:
            for workers in (1, 2):
                res = timed_batch(name, workers, logs)
                results.setdefault((name, workers), []).append(res)
                say(f"  repeat {k + 1} {name} x{workers}: {res['wall']:.1f} s "
                    f"(runs {res['task_s']:.1f} s), load {os.getloadavg()[0]:.1f}")
    say(f"load after: {os.getloadavg()[0]:.2f}")
    say()
    say("engine | workers | wall s (median) | speed-up (ratio of medians / median of "
        "ratios) | start s | overhead per run s | round trip ms")
    for name in engines:
        one, two = results[(name, 1)], results[(name, 2)]
        med1 = statistics.median(r["wall"] for r in one)
        med2 = statistics.median(r["wall"] for r in two)
        pair = statistics.median(a["wall"] / b["wall"] for a, b in zip(one, two, strict=True))
        start = statistics.median(r["engine_s"] for r in one)
        per_run = statistics.median(
            (r["wall"] - r["engine_s"] - r["task_s"]) / r["runs"] for r in one
        )
        runs1 = statistics.median(r["wall"] - r["engine_s"] for r in one)
        runs2 = statistics.median(r["wall"] - r["engine_s"] for r in two)
        trip = round_trip_ms(name, args.noops)
        say(f"{name} | 1 | {med1:.1f} | | {start:.2f} | {per_run:.2f} | {trip:.2f}")
        say(f"{name} | 2 | {med2:.1f} | {med1 / med2:.2f} / {pair:.2f} | | |")
        say(f"{name}: without the engine's start {runs1:.1f} s / {runs2:.1f} s, "
            f"speed-up {runs1 / runs2:.2f}")
    if args.save:
        args.save.write_text("\n".join(report) + "\n")


if __name__ == "__main__":
    main()
