"""What ``--record`` and ``--live`` cost: the demo run (simulated maze, UTM-30LX, 40 Hz) with
and without them, in the same process, alternating.

The scans are simulated once beforehand and held in memory, so the run times below are the
system's own (the demo also simulates while it runs, which would make recording look cheaper).
Per variant and repeat: the run's wall time (``wall_s``, which includes the observer) plus, for
a recording, the final publish and closing the file, and the CPU time of the whole process
over the same span (all threads: the SDK compresses on its own); the median over repeats, and
its ratio to the plain run's median. Also: the median CPU ms per ``process`` call (must not
change: the recorder runs outside it), the recorder's CPU ms per scan (calling thread), the
file size (scaled to 600 s), and the ``mcap info``-style summary of the recording.

Variants: ``off`` (no flags), ``record`` (``--record``), ``live`` (``--live`` with no viewer
connected: messages are built only for channels someone subscribed to).

    python benchmarks/bench_recording.py [--duration 600] [--repeat 3] [--out DIR]
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from pathlib import Path

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np

from bioslam.config import SLAMConfig
from bioslam.pipeline import RunOptions, run_slam, warm_up
from bioslam.recording.reading import format_summary, summarize
from bioslam.recording.session import Session
from bioslam.sim import LIDAR_PRESETS, make_route, maze_world, simulate_scans

VARIANTS = ("off", "record", "live")


def demo_scans(duration: float, seed: int) -> list:
    world = maze_world()
    route = make_route(world, duration=duration, seed=seed)
    return [scan for scan, _ in simulate_scans(world, LIDAR_PRESETS["utm30lx"], route, seed=seed)]


def timed_run(scans: list, variant: str, out: Path) -> dict:
    """One run; returns its wall time (with the recording's final publish and close)."""
    session = Session(
        record=out if variant == "record" else None,
        live_port=0 if variant == "live" else None,
        announce=False,
    )
    options = RunOptions(progress=False, warm_up=False)
    cpu = time.process_time()
    with session:
        result = run_slam(scans, SLAMConfig(), options, observer=session.observer)
        started = time.perf_counter()
        session.finish(result.system)
        session.close()
        closing = time.perf_counter() - started
    cpu = time.process_time() - cpu
    if result.error:
        raise RuntimeError(result.error)
    summary = session.summary()
    recorder_s = sum(part["cpu_seconds"] for part in summary.values())
    return {
        "wall_s": result.wall_s + closing,
        "cpu_s": cpu,
        "cpu_ms_median": 1e3 * float(np.median(result.scan_seconds)),
        "recorder_ms_per_scan": 1e3 * recorder_s / len(scans),
        "scans": len(scans),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--duration", type=float, default=600.0)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=Path("benchmarks/.work/recording"))
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    scans = demo_scans(args.duration, args.seed)
    print(f"simulated {len(scans)} scans ({scans[-1].stamp:.0f} s) in "
          f"{time.perf_counter() - t0:.0f} s")
    warm_up(SLAMConfig())
    mcap = args.out / "demo.mcap"
    runs: dict[str, list[dict]] = {v: [] for v in VARIANTS}
    for k in range(args.repeat):
        order = VARIANTS if k % 2 == 0 else VARIANTS[::-1]
        for variant in order:
            run = timed_run(scans, variant, mcap)
            runs[variant].append(run)
            print(f"  repeat {k + 1} {variant:>6}: wall {run['wall_s']:.2f} s, "
                  f"recorder {run['recorder_ms_per_scan']:.3f} ms/scan", flush=True)
    def median(variant: str, key: str) -> float:
        return statistics.median(r[key] for r in runs[variant])

    print(f"\n{len(scans)} scans, {args.repeat} repeats, medians:")
    print(f"{'variant':>8} {'wall s':>8} {'ratio':>6} {'CPU s':>7} {'ratio':>6} "
          f"{'process ms/scan':>16} {'recorder ms/scan':>17}")
    for variant in VARIANTS:
        wall, cpu = median(variant, "wall_s"), median(variant, "cpu_s")
        print(f"{variant:>8} {wall:8.2f} {wall / median('off', 'wall_s'):6.3f} {cpu:7.2f} "
              f"{cpu / median('off', 'cpu_s'):6.3f} {median(variant, 'cpu_ms_median'):16.3f} "
              f"{median(variant, 'recorder_ms_per_scan'):17.3f}")
    info = summarize(mcap)
    duration = max(info.duration_s, 1e-9)
    print(f"\nfile {info.bytes / 1e6:.1f} MB for {duration:.0f} s: "
          f"{info.bytes / 1e6 * 600.0 / duration:.1f} MB per 600 s\n")
    print(format_summary(info))


if __name__ == "__main__":
    main()
