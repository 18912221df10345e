"""The rows of the table: each runs one system on one prepared case in a fresh child process,
times it (wall clock, peak RSS of that child) and evaluates its trajectory."""

from __future__ import annotations

import json
import os
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from subprocess import Popen
from typing import Any

import numpy as np
from cases import PreparedCase, bioslam_cli, read_reference
from loop_consistency import loop_gap
from peers import mrpt_icp_slam as mrpt

from bioslam.evaluation import evaluate
from bioslam.io.tum import read_tum, write_tum
from bioslam.trajectory import Trajectory

ROW_FULL = "bioslam"
ROW_ODOM = "bioslam odometry only"
ROW_PEER = "MRPT icp-slam (peer)"


@dataclass
class Timed:
    """One child process run: exit code, wall time (s), peak resident memory (MB)."""

    returncode: int
    wall_s: float
    peak_rss_mb: float
    log: Path


def run_timed(cmd: list[str], log: Path, cwd: Path | None = None, timeout_s: float = 3600) -> Timed:
    """Run ``cmd`` with stdout+stderr to ``log``; the rusage of exactly this child via wait4."""
    log.parent.mkdir(parents=True, exist_ok=True)
    with log.open("w") as out:
        t0 = time.perf_counter()
        proc = Popen(cmd, stdout=out, stderr=out, cwd=cwd)
        killer = threading.Timer(timeout_s, proc.kill)
        killer.start()
        try:
            _, status, usage = os.wait4(proc.pid, 0)
        finally:
            killer.cancel()
        wall = time.perf_counter() - t0
    proc.returncode = os.waitstatus_to_exitcode(status)
    # Linux reports ru_maxrss in KiB.
    return Timed(proc.returncode, wall, usage.ru_maxrss / 1024.0, log)


def _tail(path: Path) -> str:
    """The last non-empty line of a child's output: the exception or error message."""
    lines = path.read_text(errors="replace").strip().splitlines() if path.exists() else []
    return lines[-1].strip()[-300:] if lines else "(no output)"


@dataclass
class RowRun:
    """What one row produced on one case: metrics from the first run, timings from all runs."""

    row: str
    case: str
    metrics: dict[str, Any] = field(default_factory=dict)
    walls: list[float] = field(default_factory=list)
    rss_mb: list[float] = field(default_factory=list)
    error: str = ""
    trajectory: Trajectory | None = None
    artefacts: dict[str, str] = field(default_factory=dict)

    def add_timing(self, t: Timed) -> None:
        self.walls.append(t.wall_s)
        self.rss_mb.append(t.peak_rss_mb)


def _accuracy(traj: Trajectory, prepared: PreparedCase) -> dict:
    ref = read_reference(prepared)
    out: dict[str, Any] = {}
    if ref is not None:
        ev = evaluate(traj, ref)
        out.update(
            {
                k: ev[k]
                for k in (
                    "ate_rmse_m",
                    "ate_mean_m",
                    "ate_max_m",
                    "rpe_1m_trans_m",
                    "rpe_1m_rot_deg",
                    "pairs",
                )
            }
        )
    else:
        out.update(loop_gap(traj))
    return out


def _last_json(path: Path) -> dict:
    for line in reversed(path.read_text(errors="replace").splitlines()):
        if line.startswith("{"):
            return json.loads(line)
    raise RuntimeError(f"no JSON summary in {path}: {_tail(path)}")


def run_bioslam(
    row: RowRun,
    prepared: PreparedCase,
    out: Path,
    odometry_only: bool,
    first: bool,
) -> None:
    """One ``bioslam run`` of the case; accuracy and counters are read on the first run."""
    out.mkdir(parents=True, exist_ok=True)
    # --overwrite: timed repeats rerun into the same folder, which also holds stdout.txt
    cmd = [*bioslam_cli(), "run", str(prepared.input_path), "--out", str(out), "--no-progress",
           "--overwrite"]
    if odometry_only:
        cmd.append("--odometry-only")
    if prepared.config_path is not None:
        cmd += ["--config", str(prepared.config_path)]
    t = run_timed(cmd, out / "stdout.txt")
    if t.returncode != 0:
        raise RuntimeError(f"bioslam run exited {t.returncode}: {_tail(out / 'stdout.txt')}")
    row.add_timing(t)
    summary = _last_json(out / "stdout.txt")
    row.metrics.setdefault("per_run", []).append(
        {k: summary.get(k) for k in ("ms_per_scan_median", "ms_per_scan_p99")}
    )
    if not first:
        return
    traj = read_tum(out / "trajectory.tum")
    row.trajectory = traj
    counters = ("scans",) if odometry_only else ("scans", "views", "experiences", "loop_closures")
    row.metrics.update({k: summary.get(k) for k in counters})
    row.metrics.update(_accuracy(traj, prepared))
    if (out / "map.pgm").exists():
        row.artefacts["map"] = str(out / "map.pgm")


def prepare_peer(
    prepared: PreparedCase, work: Path, cfg: mrpt.IcpSlamConfig
) -> tuple[Path, list[float]]:
    """Convert the case for the peer once (untimed: the peer's format, not its SLAM)."""
    ini, _, stamps = mrpt.convert(prepared.scans, work, cfg)
    return ini, stamps


def run_peer(
    row: RowRun,
    prepared: PreparedCase,
    work: Path,
    ini: Path,
    stamps: list[float],
    first: bool,
) -> None:
    """One ``icp-slam`` run; poses are mapped back to the scans' stamps by index."""
    t = run_timed(mrpt.command(ini), work / "stdout.txt", cwd=work)
    if t.returncode != 0:
        raise RuntimeError(f"icp-slam exited {t.returncode}: {_tail(work / 'stdout.txt')}")
    row.add_timing(t)
    ms = mrpt.per_scan_ms(work, len(stamps))
    row.metrics.setdefault("per_run", []).append(
        {
            "ms_per_scan_median": float(np.median(ms)),
            "ms_per_scan_p99": float(np.percentile(ms, 99)),
        }
    )
    if not first:
        return
    traj = mrpt.read_path(work, stamps)
    row.trajectory = traj
    write_tum(work / "trajectory.tum", traj)
    row.metrics["scans"] = len(stamps)
    row.metrics.update(_accuracy(traj, prepared))
    picture = mrpt.render_point_map(work)
    if picture is not None:
        row.artefacts["map"] = str(picture)


def _median_of(runs: list[dict], key: str) -> float:
    values = [r[key] for r in runs if r.get(key) is not None]
    return float(np.median(values)) if values else float("nan")


def finalize_timing(row: RowRun, log_duration_s: float, scans: int) -> None:
    """Medians over the repeated runs."""
    if not row.walls:
        return
    wall = float(np.median(row.walls))
    per = row.metrics.pop("per_run", [])
    row.metrics.update({
        "wall_s": wall,
        "runs": len(row.walls),
        "ms_per_scan_median": _median_of(per, "ms_per_scan_median"),
        "ms_per_scan_p99": _median_of(per, "ms_per_scan_p99"),
        "realtime_factor": log_duration_s / wall if wall > 0 else float("nan"),
        "peak_rss_mb": float(np.median(row.rss_mb)),
        "scans_per_s": scans / wall if wall > 0 else float("nan"),
    })  # fmt: skip
