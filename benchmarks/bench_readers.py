"""Log reader speed and memory on the shared real logs (and a simulated ROS 2 bag).

Target (issue 2): reading freiburg-079 (4791 scans) takes under 2 s; memory under 1 GB.

Each log is read in a fresh child process (one thread), ``--repeat`` times; the table shows the
median and worst wall time of a full iteration (``for scan in open_log(path)``), the median CPU
time (what the reader costs on an idle core when the machine is shared), the peak resident
memory of the child, and the same run's baseline: the bare cost of getting the bytes off the
disk and into lines (gzip + ``str.split`` for text logs, the record walk without deserialising
for the ROS 1 bag, rosbags' raw messages for ROS 2 bags), i.e. the floor any Python reader of
the format pays.
``ratio`` = reader / baseline (medians).

    python benchmarks/bench_readers.py [--repeat 5] [--sim-scans 4000]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
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
DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
LOGS = {
    "freiburg-079": "freiburg-079-corrected.log.gz",
    "intel": "intel-corrected.log.gz",
    "exp1": "exp1.dat",
    "ros1-bag": "laser_scan_matcher_demo.bag",
}


def read_log(path: str) -> int:
    from bioslam.io.logs import open_log

    return sum(1 for _ in open_log(path))


def read_baseline(path: str) -> int:
    """Lines split (text logs) or raw message bytes (bags): the floor for any reader."""
    p = Path(path)
    if p.is_dir() or p.suffix in (".bag", ".mcap", ".db3"):
        return _baseline_bag(p)
    import gzip

    opener = gzip.open if p.suffix == ".gz" else open
    n = 0
    with opener(p, "rt", encoding="latin-1") as fh:
        for line in fh:
            n += len(line.split()) > 0
    return n


def _baseline_bag(p: Path) -> int:
    if p.suffix == ".bag":
        # walking the records without deserialising them: what the sequential reader must do
        from bioslam.io.rosbag import Bag1RecordReader

        return sum(1 for _ in Bag1RecordReader(p).messages())
    from rosbags.rosbag2 import Reader

    with Reader(p) as reader:
        return sum(1 for _ in reader.messages())


def child(kind: str, path: str, repeat: int) -> dict:
    fn = read_log if kind == "reader" else read_baseline
    times, cpu = [], []
    count = 0
    for _ in range(repeat):
        t0, c0 = time.perf_counter(), time.process_time()
        count = fn(path)
        times.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    peak_kb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return {"times": times, "cpu": cpu, "count": count, "peak_mb": peak_kb / 1024}


def run_child(kind: str, path: Path, repeat: int) -> dict:
    cmd = [sys.executable, __file__, "--child", kind, str(path), "--repeat", str(repeat)]
    env = {**os.environ, **ONE_THREAD}
    out = subprocess.run(cmd, check=True, capture_output=True, text=True, env=env).stdout
    return json.loads(out.strip().splitlines()[-1])


def make_sim_bag(directory: Path, scans: int) -> Path:
    """A ROS 2 bag of ``scans`` utm30lx-sized scans (1081 beams) written by the simulator's
    bag writer, as ``bioslam sim`` would."""
    import numpy as np

    from bioslam.io.bag_writer import write_scan_bag
    from bioslam.scan import LaserScan

    rng = np.random.default_rng(0)
    angles = np.linspace(-0.75 * np.pi, 0.75 * np.pi, 1081)
    stream = (
        LaserScan(0.025 * k, rng.uniform(0.5, 20.0, 1081).astype(np.float32), angles, 0.1,
                  30.0, 0.025 / 1440)
        for k in range(scans)
    )
    path = directory / "sim-bag"
    write_scan_bag(path, stream, scan_time=0.025)
    return path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--sim-scans", type=int, default=4000,
                        help="scans in the simulated ROS 2 bag (0 = skip it)")
    parser.add_argument("--child", nargs=2, metavar=("KIND", "PATH"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        print(json.dumps(child(args.child[0], args.child[1], args.repeat)))
        return
    with tempfile.TemporaryDirectory() as tmp:
        cases = {name: DATA / file for name, file in LOGS.items()}
        if args.sim_scans:
            cases[f"sim-bag ({args.sim_scans}x1081)"] = make_sim_bag(Path(tmp), args.sim_scans)
        header = (f"{'log':<22}{'scans':>7}{'median s':>10}{'max s':>9}{'cpu s':>8}"
                  f"{'scans/s':>10}{'base s':>9}{'ratio':>7}{'peak MB':>9}")
        print(header)
        print("-" * len(header))
        for name, path in cases.items():
            if not path.exists():
                print(f"{name:<22}missing: {path}")
                continue
            reader = run_child("reader", path, args.repeat)
            base = run_child("baseline", path, args.repeat)
            median = statistics.median(reader["times"])
            base_median = statistics.median(base["times"])
            cpu = statistics.median(reader["cpu"])
            print(f"{name:<22}{reader['count']:>7}{median:>10.3f}{max(reader['times']):>9.3f}"
                  f"{cpu:>8.3f}{reader['count'] / median:>10.0f}{base_median:>9.3f}"
                  f"{median / base_median:>7.1f}{reader['peak_mb']:>9.0f}")
    print(f"\n{args.repeat} runs per log, one thread, fresh process per log; load average "
          f"{os.getloadavg()[0]:.1f} on {os.cpu_count()} cores; "
          "target: freiburg-079 < 2 s, peak memory < 1024 MB")


if __name__ == "__main__":
    main()
