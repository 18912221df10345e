"""Memory and whole-process time of ``bioslam run``, measured from outside the process.

For each input (a 600 s and a 60 min simulated 40 Hz UTM-30LX route through the maze, a 60 min
adversarial route through the warehouse of identical aisles that no setting was chosen on, and
every shared log) ``bioslam run`` is started as a fresh process; its resident memory is sampled from
``/proc`` while it runs, its progress bar tells which scan it is at, and ``wait4`` gives its peak
RSS. Reported per input:

- peak RSS, and RSS when the first scan is processed (imports and warm-up);
- the peak footprint of the whole process tree, sampled: ``bioslam run`` may fork a child that
  reads the log ahead and one that draws the figures, whose memory the parent's RSS does not
  include. The tree's footprint is the parent's RSS plus each descendant's private memory (its
  unique set size: the pages it shares copy-on-write with the parent are already in the
  parent's RSS);
- growth per hour of data after the first minute: the slope of RSS against the log's own time
  (from the progress), least squares, times 3600;
- the wall-clock real-time factor from outside (log duration / process wall time, start-up,
  reading, writing and figures included), the process wall time over the summed per-scan time
  (from the run's summary) and the process's CPU time over it (on a shared machine the wall
  clock also counts the time other jobs hold the cores; the CPU time does not), and with
  ``--peer`` the same real-time factor of MRPT icp-slam on the same data in the same run
  (conversion untimed);
- the first-run start-up: ``bioslam demo --duration 10`` with an empty Numba cache, then again
  with the cache it filled.

    python benchmarks/bench_memory.py [--cases sim-600,sim-3600,warehouse-adversarial-3600,...]
        [--odometry-only] [--peer [CASES]] [--interval 0.25] [--no-cold-start]

``--peer`` alone times MRPT icp-slam on every case; with a list, on those cases only (on the
60 min route icp-slam takes about half an hour).

Writes ``benchmarks/.work/memory/`` (bags, outputs, the RSS series as JSON) and prints a table.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from cases import DATA_DIR, bioslam_cli  # noqa: E402

WORK = HERE / ".work" / "memory"
# simulated routes: world, route, duration (s), seed (all 40 Hz UTM-30LX). The warehouse's
# adversarial route (off the aisles' centre, turn-backs, spins) learns half as many views
# again per hour as the maze's tour: the run-long stores' growth on a route not tuned on.
SIM = {
    "sim-600": ("maze", "tour", 600.0, 1),
    "sim-3600": ("maze", "tour", 3600.0, 1),
    "warehouse-adversarial-3600": ("warehouse", "adversarial", 3600.0, 3),
}
LOGS = {
    "freiburg-079": "freiburg-079-corrected.log.gz",
    "intel": "intel-corrected.log.gz",
    "exp1": "exp1.dat",
    "ros1-bag": "laser_scan_matcher_demo.bag",
}
# Data before this many seconds is start-up, not growth (the "after the first minute").
SETTLE_S = 60.0
# A tqdm update: "1234scan [..." or "1234/5678 [...": scans done so far.
_PROGRESS = re.compile(rb"(?:^|[\r\n])\s*(?:\d+%\|[^|]*\|\s*)?(\d+)(?:/\d+)?\s*(?:scan|\[)")
_STATUS = re.compile(rb"VmRSS:\s+(\d+) kB")
_PRIVATE = re.compile(rb"^Private_(?:Clean|Dirty):\s+(\d+) kB", re.MULTILINE)


def rss_mb(pid: int) -> float | None:
    """Resident memory of a live process, MB (``None`` once it is gone)."""
    try:
        with open(f"/proc/{pid}/status", "rb") as fh:
            match = _STATUS.search(fh.read())
    except OSError:
        return None
    return int(match.group(1)) / 1024.0 if match else None


def descendants(pid: int) -> list[int]:
    """The live processes below ``pid`` (children, their children, ...), from ``/proc``."""
    parents: dict[int, list[int]] = {}
    for entry in os.scandir("/proc"):
        if not entry.name.isdigit():
            continue
        try:
            with open(f"/proc/{entry.name}/stat", "rb") as fh:
                stat = fh.read()
        except OSError:
            continue
        # the command name may hold spaces and parentheses: the fields follow its last ')'
        ppid = int(stat[stat.rindex(b")") + 2:].split()[1])
        parents.setdefault(ppid, []).append(int(entry.name))
    found, todo = [], [pid]
    while todo:
        kids = parents.get(todo.pop(), [])
        found.extend(kids)
        todo.extend(kids)
    return found


def tree_rss_mb(pid: int) -> float | None:
    """RSS of ``pid`` plus its descendants' private memory, MB (``None`` once it is gone)."""
    total = rss_mb(pid)
    if total is None:
        return None
    for child in descendants(pid):
        try:
            with open(f"/proc/{child}/smaps_rollup", "rb") as fh:
                rollup = fh.read()
        except OSError:
            continue
        total += sum(int(kb) for kb in _PRIVATE.findall(rollup)) / 1024.0
    return total


class _Progress(threading.Thread):
    """Reads a child's stderr (a tqdm bar) and keeps ``(time, scans done)``."""

    def __init__(self, stream, t0: float) -> None:
        super().__init__(daemon=True)
        self.stream, self.t0 = stream, t0
        self.points: list[tuple[float, int]] = []
        self.tail = b""

    def run(self) -> None:
        for chunk in iter(lambda: self.stream.read1(4096), b""):
            now = time.perf_counter() - self.t0
            for done in _PROGRESS.findall(chunk):
                self.points.append((now, int(done)))
            self.tail = (self.tail + chunk)[-2000:]


def watch(cmd: list[str], interval: float, env: dict | None = None) -> dict:
    """Run ``cmd``; sample its RSS every ``interval`` s; return the series, the peak (wait4),
    the wall time, the progress points and the last stdout line (the run's JSON summary)."""
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            env={**os.environ, **(env or {})})  # fmt: skip
    progress = _Progress(proc.stderr, t0)
    progress.start()
    out: list[bytes] = []
    reader = threading.Thread(target=lambda: out.append(proc.stdout.read()), daemon=True)
    reader.start()
    samples: list[tuple[float, float]] = []
    tree_peak = 0.0
    while True:
        rss = rss_mb(proc.pid)
        if rss is not None:
            samples.append((time.perf_counter() - t0, rss))
        tree_peak = max(tree_peak, tree_rss_mb(proc.pid) or 0.0)
        finished, status, usage = os.wait4(proc.pid, os.WNOHANG)
        if finished:
            break
        time.sleep(interval)
    wall = time.perf_counter() - t0
    proc.returncode = os.waitstatus_to_exitcode(status)
    reader.join()
    progress.join(timeout=5.0)
    lines = (out[0] if out else b"").decode().strip().splitlines()
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed: {progress.tail.decode(errors='replace')}")
    return {
        "wall_s": wall,
        "peak_rss_mb": usage.ru_maxrss / 1024.0,
        "peak_tree_mb": tree_peak,
        "cpu_s": usage.ru_utime + usage.ru_stime,
        "samples": samples,
        "progress": progress.points,
        "summary": json.loads(lines[-1]) if lines else {},
    }


def growth_per_hour(samples, progress, scans: int, duration_s: float) -> tuple[float, float]:
    """RSS growth, MB per hour of data after the first minute (least squares), and the RSS
    when the first scan was processed. The progress bar maps wall time to scans, scans to
    the log's time (uniformly: the logs are near enough evenly paced)."""
    if not progress or not samples:
        return float("nan"), float("nan")
    pt = np.array([p[0] for p in progress])
    done = np.array([p[1] for p in progress], dtype=float)
    t = np.array([s[0] for s in samples])
    rss = np.array([s[1] for s in samples])
    feeding = (t >= pt[0]) & (t <= pt[-1])
    data_t = np.interp(t, pt, done) / max(scans, 1) * duration_s
    first = float(rss[feeding][0]) if feeding.any() else float("nan")
    use = feeding & (data_t >= SETTLE_S)
    if use.sum() < 3 or np.ptp(data_t[use]) <= 0.0:
        return float("nan"), first
    slope = np.polyfit(data_t[use], rss[use], 1)[0]
    return float(slope * 3600.0), first


def simulate(name: str, spec: tuple[str, str, float, int]) -> Path:
    world, route, duration, seed = spec
    folder = WORK / name
    bag = folder / "scans"
    if not (folder / "gt.tum").exists():
        cmd = [*bioslam_cli(), "sim", "--world", world, "--route", route, "--lidar", "utm30lx",
               "--duration", f"{duration:g}", "--seed", f"{seed}", "--out", str(folder),
               "--force"]  # fmt: skip
        subprocess.run(cmd, check=True, capture_output=True)
    return bag


def peer_realtime(input_path: Path, work: Path) -> float:
    """MRPT icp-slam's wall-clock real-time factor on the same scans (conversion untimed)."""
    from peers import mrpt_icp_slam as mrpt

    from bioslam.io.logs import open_log

    scans = list(open_log(input_path))
    ini, _, stamps = mrpt.convert(scans, work, mrpt.IcpSlamConfig())
    t0 = time.perf_counter()
    with (work / "stdout.txt").open("w") as fh:
        subprocess.run(mrpt.command(ini), stdout=fh, stderr=subprocess.STDOUT, cwd=work,
                       check=True)  # fmt: skip
    return (stamps[-1] - stamps[0]) / (time.perf_counter() - t0)


def rss_over_data(samples, progress, parts: int = 10) -> list[float]:
    """RSS (MB) when each tenth of the scans had been processed: RSS over the log's time."""
    if not progress or not samples:
        return []
    pt = np.array([p[0] for p in progress])
    done = np.array([p[1] for p in progress], dtype=float)
    t = np.array([s[0] for s in samples])
    rss = np.array([s[1] for s in samples])
    wanted = np.linspace(0.0, done[-1], parts + 1)
    at = np.interp(wanted, done, pt)  # wall time at which each share was reached
    return [round(float(rss[min(np.searchsorted(t, w), t.size - 1)])) for w in at]


def measure(name: str, input_path: Path, args: argparse.Namespace) -> dict:
    out = WORK / "runs" / name
    cmd = [*bioslam_cli(), "run", str(input_path), "--out", str(out), "--overwrite"]
    if args.odometry_only:
        cmd.append("--odometry-only")
    r = watch(cmd, args.interval)
    summary = r["summary"]
    duration = float(summary.get("duration_s", float("nan")))
    growth, first = growth_per_hour(r["samples"], r["progress"], summary.get("scans", 0),
                                    duration)
    compute = duration / summary["realtime_factor"] if summary.get("realtime_factor") else None
    row = {
        "case": name,
        "scans": summary.get("scans"),
        "duration_s": duration,
        "peak_rss_mb": round(r["peak_rss_mb"], 1),
        "peak_tree_mb": round(r["peak_tree_mb"], 1),
        "rss_first_scan_mb": round(first, 1),
        "growth_mb_per_h": round(growth, 1),
        "process_wall_s": round(r["wall_s"], 2),
        "process_cpu_s": round(r["cpu_s"], 2),
        "wall_rt_factor": round(duration / r["wall_s"], 2),
        "wall_over_per_scan_sum": round(r["wall_s"] / compute, 2) if compute else None,
        # the same with the process's CPU time: what a loaded machine's waits do not inflate
        "cpu_over_per_scan_sum": round(r["cpu_s"] / compute, 2) if compute else None,
        "ms_per_scan_median": summary.get("ms_per_scan_median"),
        "rss_by_tenth_mb": rss_over_data(r["samples"], r["progress"]),
    }
    if args.peer == "all" or name in (args.peer or "").split(","):
        try:
            peer = peer_realtime(input_path, WORK / "peer" / name)
            row["peer_wall_rt_factor"] = round(peer, 2)
            row["rt_factor_over_peer"] = round(row["wall_rt_factor"] / peer, 2)
        except Exception as exc:  # the peer is optional: say why it is missing
            row["peer_error"] = f"{type(exc).__name__}: {exc}"[:200]
    (WORK / "series").mkdir(parents=True, exist_ok=True)
    (WORK / "series" / f"{name}.json").write_text(json.dumps(
        {"samples": r["samples"], "progress": r["progress"], "summary": summary}))
    return row


def cold_start(interval: float) -> dict:
    """``bioslam demo --duration 10`` with an empty Numba cache, then with the one it filled."""
    with tempfile.TemporaryDirectory() as cache, tempfile.TemporaryDirectory() as out:
        cmd = [*bioslam_cli(), "demo", "--duration", "10", "--no-progress", "--overwrite",
               "--out", out]
        env = {"NUMBA_CACHE_DIR": cache}
        cold = watch(cmd, interval, env)
        warm = watch(cmd, interval, env)
    return {"cold_wall_s": round(cold["wall_s"], 2), "warm_wall_s": round(warm["wall_s"], 2),
            "compile_s": round(cold["wall_s"] - warm["wall_s"], 2),
            # CPU time: what other jobs on a shared machine do not inflate
            "cold_cpu_s": round(cold["cpu_s"], 2), "warm_cpu_s": round(warm["cpu_s"], 2),
            "cold_peak_rss_mb": round(cold["peak_rss_mb"], 1),
            "warm_peak_rss_mb": round(warm["peak_rss_mb"], 1)}  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", default=",".join([*SIM, *LOGS]))
    parser.add_argument("--odometry-only", action="store_true")
    parser.add_argument("--peer", nargs="?", const="all", default=None, metavar="CASES",
                        help="also time MRPT icp-slam (on these cases only, if given)")
    parser.add_argument("--no-cold-start", action="store_true")
    parser.add_argument("--interval", type=float, default=0.25, help="RSS sampling, seconds")
    args = parser.parse_args()
    WORK.mkdir(parents=True, exist_ok=True)
    rows = []
    for name in args.cases.split(","):
        if name in SIM:
            path = simulate(name, SIM[name])
        elif (DATA_DIR / LOGS.get(name, "")).is_file():
            path = DATA_DIR / LOGS[name]
        else:
            print(f"{name}: no such case or log missing; skipped", file=sys.stderr)
            continue
        print(f"[memory] {name} …", file=sys.stderr, flush=True)
        rows.append(measure(name, path, args))
        print(json.dumps(rows[-1]), flush=True)
    startup = None if args.no_cold_start else cold_start(args.interval)
    keys = ["case", "scans", "peak_rss_mb", "peak_tree_mb", "rss_first_scan_mb",
            "growth_mb_per_h",
            "wall_rt_factor", "wall_over_per_scan_sum", "cpu_over_per_scan_sum",
            "ms_per_scan_median",
            "peer_wall_rt_factor", "rt_factor_over_peer"]  # fmt: skip
    print("| " + " | ".join(keys) + " |")
    print("|" + "---|" * len(keys))
    for row in rows:
        print("| " + " | ".join(str(row.get(k, "")) for k in keys) + " |")
    for row in rows:
        print(f"{row['case']}: RSS (MB) at each tenth of the scans {row['rss_by_tenth_mb']}")
    if startup:
        print(f"start-up (bioslam demo --duration 10): {json.dumps(startup)}")
    print(f"load average {os.getloadavg()[0]:.1f}")
    (WORK / "results.json").write_text(json.dumps({"rows": rows, "startup": startup}, indent=1))


if __name__ == "__main__":
    main()
