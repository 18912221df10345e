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

With ``--defects`` it measures robustness instead (issue 14): each shared log is rewritten under
/tmp with each time-stamp defect of :mod:`bioslam.io.defects` (all zero, six significant
digits of an epoch time, decreasing, negative, one scan an hour late, concatenated with itself,
and for exp1.dat stamps in seconds instead of µs; for the ROS 1 bag the header and record
stamps alike) and the table gives the laser records read / in the file, the share and where
the stamps came from. ``--ate-prefix N`` adds, for freiburg and intel, the odometry-only ATE
(``bioslam run --odometry-only`` on the first N laser records, against the log's corrected
poses) of each defect beside the clean prefix's.

    python benchmarks/bench_readers.py --defects [--ate-prefix 400]
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
    parser.add_argument("--defects", action="store_true",
                        help="share of the laser records read from logs with stamp defects")
    parser.add_argument("--ate-only", action="store_true",
                        help="with --defects --ate-prefix: skip the table of shares read")
    parser.add_argument("--ate-prefix", type=int, default=0, metavar="N",
                        help="with --defects: odometry-only ATE on the first N laser records "
                        "of freiburg and intel (0 = skip)")
    args = parser.parse_args()
    if args.child:
        print(json.dumps(child(args.child[0], args.child[1], args.repeat)))
        return
    if args.defects:
        defects_report(args.ate_prefix, shares=not args.ate_only)
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


# -- robustness to time-stamp defects (--defects) ---------------------------------------------

def _text_lines(path: Path) -> list[str]:
    import gzip

    opener = gzip.open if path.suffix == ".gz" else open
    with opener(path, "rt", encoding="latin-1") as fh:
        return fh.readlines()


def _prefix(lines: list[str], scans: int, laser: str) -> list[str]:
    """The lines up to the ``scans``-th ``laser`` record (all of them when ``scans`` is 0)."""
    if not scans:
        return lines
    seen = 0
    for i, line in enumerate(lines):
        seen += line.startswith(laser + " ")
        if seen == scans:
            return lines[: i + 1]
    return lines


def mutated_text_logs(out: Path, prefix: int = 0) -> list[tuple[str, str, Path]]:
    """``(log, defect, path)`` of the clean and mutated copies of the shared text logs."""
    from bioslam.io.defects import (
        BREEZYSLAM_DEFECTS,
        CARMEN_DEFECTS,
        breezyslam_with_defect,
        carmen_with_defect,
    )

    cases = []
    for name in ("freiburg-079", "intel", "exp1"):
        src = DATA / LOGS[name]
        if not src.exists():
            continue
        carmen = name != "exp1"
        lines = _prefix(_text_lines(src), prefix, "FLASER" if carmen else "")
        # "corrected" in the name: the CARMEN reader takes the logs' poses as the reference
        suffix = "-corrected.log" if carmen else ".dat"
        clean = out / f"{name}-clean{suffix}"
        clean.write_text("".join(lines), encoding="latin-1")
        cases.append((name, "clean", clean))
        mutate = carmen_with_defect if carmen else breezyslam_with_defect
        for defect in CARMEN_DEFECTS if carmen else BREEZYSLAM_DEFECTS:
            path = out / f"{name}-{defect}{suffix}"
            path.write_text("".join(mutate(lines, defect)), encoding="latin-1")
            cases.append((name, defect, path))
    return cases


def mutated_bags(out: Path) -> list[tuple[str, str, Path]]:
    """The shared ROS 1 bag with each stamp defect applied to its scans' header stamps and
    record times (rewritten with rosbags' writer)."""
    import numpy as np
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    from bioslam.io.defects import FILE_DEFECTS, STAMP_DEFECTS
    from bioslam.io.rosbag import LASERSCAN, Bag1RecordReader

    src = DATA / LOGS["ros1-bag"]
    if not src.exists():
        return []
    store = get_typestore(Stores.ROS1_NOETIC)
    msgs = [(conn.topic, t, store.deserialize_ros1(raw, LASERSCAN))
            for conn, t, raw in Bag1RecordReader(src).messages() if conn.msgtype == LASERSCAN]
    stamps = np.array([m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec for _, _, m in msgs])
    cases = [("ros1-bag", "clean", src)]
    for defect in (*STAMP_DEFECTS, *FILE_DEFECTS):
        if defect == "concatenated":
            new, order = np.concatenate([stamps, stamps]), list(range(len(msgs))) * 2
        elif defect == "six-digits":  # the bag's stamps are epoch seconds already
            new, order = np.array([float(f"{v:.6g}") for v in stamps]), list(range(len(msgs)))
        else:
            new, order = STAMP_DEFECTS[defect](stamps), list(range(len(msgs)))
        path = out / f"ros1-bag-{defect}.bag"
        with Writer(path) as writer:
            conn = writer.add_connection(msgs[0][0], "sensor_msgs/msg/LaserScan", typestore=store)
            for k, value in zip(order, new.tolist(), strict=True):
                msg = msgs[k][2]
                sec = int(np.floor(value))
                msg.header.stamp.sec = sec
                msg.header.stamp.nanosec = int((value - sec) * 1e9) % 10**9
                t_ns = max(int(value * 1e9), 0)
                writer.write(conn, t_ns, store.serialize_ros1(msg, LASERSCAN))
        cases.append(("ros1-bag", defect, path))
    return cases


def read_share(path: Path) -> tuple[int, int, str]:
    from bioslam.io.logs import open_log

    source = open_log(path)
    read = sum(1 for _ in source)
    return read, source.records_seen, source.time_source


def odometry_ate(path: Path, out: Path) -> float | None:
    """ATE RMSE (m) of ``bioslam run --odometry-only`` on ``path`` against the log's poses."""
    cmd = [sys.executable, "-m", "bioslam.cli", "run", str(path), "--out", str(out),
           "--odometry-only", "--no-progress", "--overwrite"]
    env = {**os.environ, **ONE_THREAD}
    done = subprocess.run(cmd, capture_output=True, text=True, env=env)
    lines = [line for line in done.stdout.splitlines() if line.startswith("{")]
    if not lines:
        return None
    return json.loads(lines[-1]).get("ate_rmse_m")


def defects_report(ate_prefix: int, shares: bool = True) -> None:
    out = Path(tempfile.mkdtemp(prefix="bioslam-bench-readers-"))
    clean_counts: dict[str, int] = {}
    print(f"{'log':<14}{'defect':<15}{'read':>7}{'total':>7}{'share':>8}  time source")
    for log, defect, path in (mutated_text_logs(out) + mutated_bags(out)) if shares else []:
        read, seen, source = read_share(path)
        if defect == "clean":
            clean_counts[log] = seen
        total = clean_counts[log] * (2 if defect == "concatenated" else 1)
        print(f"{log:<14}{defect:<15}{read:>7}{total:>7}{read / total:>8.3f}  {source}")
    if ate_prefix:
        print(f"\nodometry-only ATE RMSE (m), bioslam run --odometry-only on the first "
              f"{ate_prefix} laser records, against the log's corrected poses")
        prefix_dir = out / "prefix"
        prefix_dir.mkdir()
        for log, defect, path in mutated_text_logs(prefix_dir, ate_prefix):
            if log == "exp1":
                continue
            ate = odometry_ate(path, out / "runs" / f"{log}-{defect}")
            shown = f"{ate:.3f}" if ate is not None else "failed"
            print(f"{log:<14}{defect:<15}{shown:>9}", flush=True)
    print(f"\nmutated copies under {out}; load average {os.getloadavg()[0]:.1f} on "
          f"{os.cpu_count()} cores")


if __name__ == "__main__":
    main()
