"""What ``--record`` and ``--live`` cost on the demo run (simulated maze, UTM-30LX, 40 Hz).

Two measures, both printed:

1. **Same run, per scan** (robust to other jobs on the machine): in one run with recording,
   the CPU time of each ``process`` call (the system) and of the observer's call right after
   it (both on the run's thread: copying out what the channels need and piping it to the
   writing process). The cost is the ratio of medians of per-scan time with and without the
   observer (``(process + observer) / process``), and the ratio of the totals (which counts
   the throttled maps and neurons that the median leaves out); last, all the CPU that
   recording used, the writing process's (message building, the SDK's compression) included,
   against the system's. The same for a live view that nobody watches.
2. **Separate runs, wall time**: plain, recorded and live runs alternating ``--repeat`` times,
   median wall time of each and its ratio to the plain run's. On a machine shared with other
   jobs these swing with their load; (1) does not.

Also the file size (scaled to 600 s) and the ``mcap info``-style summary of the recording.
``--on-the-fly`` simulates each scan as the run consumes it, as ``bioslam demo`` does (the
run time then includes the simulation); by default the scans are simulated beforehand, so
that the run time is the system's alone (the stricter ratio).

    python benchmarks/bench_recording.py [--duration 600] [--repeat 3] [--on-the-fly]
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from collections.abc import Callable, Iterable
from pathlib import Path

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np

from bioslam.config import SLAMConfig
from bioslam.pipeline import RunOptions, run_slam, warm_up
from bioslam.recording.reading import format_summary, summarize
from bioslam.recording.session import Session
from bioslam.sim import LIDAR_PRESETS, make_route, maze_world, simulate_scans

VARIANTS = ("off", "record", "live")


def demo_scans(duration: float, seed: int) -> Callable[[], Iterable]:
    """A callable that yields the demo's scans (simulated anew on each call)."""
    world = maze_world()
    route = make_route(world, duration=duration, seed=seed)
    lidar = LIDAR_PRESETS["utm30lx"]
    return lambda: (scan for scan, _ in simulate_scans(world, lidar, route, seed=seed))


class TimedObserver:
    """The session's observer, with the CPU time of each call kept."""

    def __init__(self, session: Session) -> None:
        self.session = session
        self.seconds: list[float] = []

    def __call__(self, scan, pose, system) -> None:
        started = time.thread_time()
        self.session(scan, pose, system)
        self.seconds.append(time.thread_time() - started)


def timed_run(scans: Iterable, variant: str, out: Path) -> dict:
    session = Session(
        record=out if variant == "record" else None,
        live_port=0 if variant == "live" else None,
        announce=False,
    )
    observer = TimedObserver(session) if session.active else None
    options = RunOptions(progress=False, warm_up=False)
    cpu, thread = time.process_time(), time.thread_time()
    with session:
        result = run_slam(scans, SLAMConfig(), options, observer=observer)
        started = time.perf_counter()
        session.finish(result.system)
        session.close()
        closing = time.perf_counter() - started
    cpu, thread = time.process_time() - cpu, time.thread_time() - thread
    if result.error:
        raise RuntimeError(result.error)
    process = np.asarray(result.scan_seconds)
    recorder = np.asarray(observer.seconds if observer else np.zeros_like(process))
    worker = sum(part["worker_cpu_seconds"] for part in session.summary().values())
    return {
        "wall_s": result.wall_s + closing,
        "process": process,
        "recorder": recorder,
        "other_threads_s": cpu - thread,
        "worker_s": worker,
    }


def report_same_run(name: str, run: dict) -> None:
    process, recorder = run["process"], run["recorder"]
    median_ratio = np.median(process + recorder) / np.median(process)
    total = process.sum()
    total_ratio = (total + recorder.sum()) / total
    everything = (total + recorder.sum() + run["other_threads_s"] + run["worker_s"]) / total
    print(f"{name:>7}: per scan median {1e3 * np.median(process):.3f} ms -> "
          f"{1e3 * np.median(process + recorder):.3f} ms (x{median_ratio:.3f}); "
          f"totals {total:.2f} s + {recorder.sum():.2f} s (x{total_ratio:.3f}); "
          f"CPU of all, with the run's other threads ({run['other_threads_s']:.2f} s) and the "
          f"writing process ({run['worker_s']:.2f} s): x{everything:.3f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--duration", type=float, default=600.0)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--on-the-fly", action="store_true",
                        help="simulate each scan as the run takes it, as bioslam demo does")
    parser.add_argument("--out", type=Path, default=Path("benchmarks/.work/recording"))
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    source = demo_scans(args.duration, args.seed)
    if not args.on_the_fly:
        t0 = time.perf_counter()
        held = list(source())
        print(f"simulated {len(held)} scans in {time.perf_counter() - t0:.0f} s")
        source = lambda: held  # noqa: E731
    warm_up(SLAMConfig())
    mcap = args.out / "demo.mcap"
    runs: dict[str, list[dict]] = {v: [] for v in VARIANTS}
    for k in range(args.repeat):
        for variant in VARIANTS if k % 2 == 0 else VARIANTS[::-1]:
            run = timed_run(source(), variant, mcap)
            runs[variant].append(run)
            print(f"  repeat {k + 1} {variant:>6}: wall {run['wall_s']:.2f} s", flush=True)
    scans = len(runs["off"][0]["process"])
    print(f"\n{scans} scans ({'simulated on the fly' if args.on_the_fly else 'held in memory'})")
    print("\n1. same run, CPU per scan (the last repeat):")
    for variant in ("record", "live"):
        report_same_run(variant, runs[variant][-1])
    print(f"\n2. separate runs, median wall time over {args.repeat}:")
    base = statistics.median(r["wall_s"] for r in runs["off"])
    for variant in VARIANTS:
        wall = statistics.median(r["wall_s"] for r in runs[variant])
        print(f"{variant:>7}: {wall:8.2f} s  x{wall / base:.3f}")
    info = summarize(mcap)
    duration = max(info.duration_s, 1e-9)
    print(f"\nfile {info.bytes / 1e6:.1f} MB for {duration:.0f} s: "
          f"{info.bytes / 1e6 * 600.0 / duration:.1f} MB per 600 s\n")
    print(format_summary(info))


if __name__ == "__main__":
    main()
