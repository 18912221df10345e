"""One batch run: a log under one grid configuration, as a function any worker can call.

The function takes everything it needs as plain, picklable data and returns its outcome
instead of raising, so that a failure is a row of the results table and never ends the batch.
With shipped data the log arrives as bytes and the outputs go back as bytes, so the worker
needs no file system in common with the machine that started the batch.
"""

from __future__ import annotations

import os
import resource
import shutil
import sys
import tempfile
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from itertools import islice
from pathlib import Path
from typing import Any

from bioslam.batch.grid import GridPoint
from bioslam.trajectory import Trajectory

#: A log or a run's outputs as bytes: path relative to the shipped root -> file contents.
Files = dict[str, bytes]


@dataclass
class Task:
    """What a worker needs for one run.

    Attributes:
        log_name: the log's name in the batch (its folder under ``--out``).
        log_path: where the log is on the machine that reads it (unused when shipped).
        point: the grid configuration.
        out_dir: the run's output folder, written by the worker unless data is shipped.
        topic: the scan stream of a log with several.
        reference: the trajectory to evaluate against, read by the batch from ``--gt-from``;
            ``None`` uses the log's own reference poses when it has them.
        reference_name: where ``reference`` came from, for the summary.
    """

    log_name: str
    log_path: str
    point: GridPoint
    out_dir: str
    topic: str | None = None
    reference: Trajectory | None = None
    reference_name: str | None = None

    @property
    def key(self) -> tuple[str, str]:
        return (self.log_name, self.point.config_id)


@dataclass
class Outcome:
    """What a run gave back.

    Attributes:
        key: the task's (log name, config id).
        status: ``ok`` or ``failed``.
        summary: the run's ``summary.json`` content (empty when it failed before running).
        error: what went wrong, ``None`` when nothing did.
        seconds: wall time of the whole task in the worker (reading, running, writing).
        peak_rss_mb: the worker's largest resident memory while the task ran.
        files: the run's outputs when data is shipped.
    """

    key: tuple[str, str]
    status: str
    summary: dict[str, Any] = field(default_factory=dict)
    error: str | None = None
    seconds: float = 0.0
    peak_rss_mb: float = float("nan")
    files: Files | None = None


class PeakRSS:
    """The process's resident memory sampled every ``interval`` seconds in a thread.

    ``ru_maxrss`` is the peak over the process's whole life, and a pool worker runs many tasks;
    sampling gives the peak during this one. Where ``/proc`` is missing it falls back to
    ``ru_maxrss``.
    """

    def __init__(self, interval: float = 0.05) -> None:
        self.interval = interval
        self.peak = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._sample, daemon=True)
        self._page = os.sysconf("SC_PAGE_SIZE") if hasattr(os, "sysconf") else 4096

    def _rss(self) -> int | None:
        try:
            with open("/proc/self/statm", "rb") as fh:
                return int(fh.read().split()[1]) * self._page
        except (OSError, ValueError, IndexError):
            return None

    def _sample(self) -> None:
        while True:
            rss = self._rss()
            if rss is not None:
                self.peak = max(self.peak, rss)
            if self._stop.wait(self.interval):
                return

    def __enter__(self) -> PeakRSS:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join()
        rss = self._rss()
        self.peak = max(self.peak, rss or 0)
        if not self.peak:  # no /proc: the process's lifetime peak (KiB on Linux, bytes on macOS)
            scale = 1 if sys.platform == "darwin" else 1024
            self.peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * scale

    @property
    def megabytes(self) -> float:
        return round(self.peak / 2**20, 1)


def pack(path: str | Path) -> Files:
    """A log file, or every file of a log directory (a ROS 2 bag), as bytes."""
    path = Path(path)
    if path.is_file():
        return {path.name: path.read_bytes()}
    if not path.is_dir():
        raise FileNotFoundError(f"{path}: no such file or directory")
    return {
        str(Path(path.name) / item.relative_to(path)): item.read_bytes()
        for item in sorted(path.rglob("*"))
        if item.is_file()
    }


def unpack(files: Files, root: Path) -> None:
    """Write shipped files under ``root``; paths may not leave it."""
    base = root.resolve()
    for name, data in files.items():
        target = (root / name).resolve()
        if not target.is_relative_to(base):
            raise ValueError(f"shipped file {name!r} would be written outside {root}")
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_bytes(data)


@contextmanager
def _workspace(task: Task, shipped: Files | None) -> Iterator[tuple[Path, Path]]:
    """The log's path and the output folder: the shared ones, or a private copy of the log
    and a private folder whose files are sent back."""
    if shipped is None:
        yield Path(task.log_path), Path(task.out_dir)
        return
    with tempfile.TemporaryDirectory(prefix="bioslam-batch-") as tmp:
        root = Path(tmp)
        unpack(shipped, root / "log")
        top = sorted({Path(name).parts[0] for name in shipped})
        if len(top) != 1:
            raise ValueError(f"shipped log of {task.log_name} holds {len(top)} top-level entries")
        yield root / "log" / top[0], root / "out"


def _run(task: Task, log_path: Path, out_path: Path) -> dict[str, Any]:
    """The run itself, with the same pipeline, outputs, output marker and checks of what was
    read as ``bioslam run``; a problem those checks find is the summary's ``error``."""
    from bioslam.cli.common import (
        DEFAULT_MIN_READ_SHARE,
        read_counts,
        read_problem,
        run_status,
        source_skipped,
    )
    from bioslam.cli.run import reference_label, reference_trajectory
    from bioslam.io.logs import open_log
    from bioslam.io.outdir import OutputDir
    from bioslam.pipeline import RunOptions, run_slam, write_results

    point = task.point
    config = point.config()
    source = open_log(log_path, topic=task.topic)
    out = OutputDir(out_path, command=["bioslam", "batch", task.log_path, point.config_id])
    out.prepare()
    scans = source if point.max_scans is None else islice(source, point.max_scans)
    options = RunOptions(
        odometry_only=point.mode == "odometry-only", progress=False, release=True,
        scan_store_dir=out.path,
    )
    result = run_slam(scans, config, options)
    if task.reference is not None:
        reference, reference_name = task.reference, task.reference_name
    else:
        reference, reference_name = reference_trajectory(None, source.reference, out)
    extra: dict[str, Any] = {
        "input": task.log_path,
        "format": source.format,
        "skipped": source_skipped(source),
        **read_counts(source),
        "batch": {"log": task.log_name, "config_id": point.config_id, "settings": point.settings},
    }
    if reference_name:
        extra["reference"] = reference_name
    options.reference_label = reference_label(reference_name)
    summary = write_results(result, out, reference, options, extra)
    problems = [f"run stopped early ({result.error})"] if result.error else []
    # a prefix (max_scans) is a complete read of what was asked for
    problem = read_problem(summary["scans"], source, DEFAULT_MIN_READ_SHARE, False)
    problems += [problem] if problem else []
    problems += [f"could not write {e}" for e in summary.get("write_errors", [])]
    if result.interrupted:
        problems.append("interrupted")
    out.finish(run_status(summary, problems))
    if problems:
        summary["error"] = "; ".join(problems)
    return summary


def run_task(task: Task, shipped: Files | None = None) -> Outcome:
    """Run one task; never raises for a failure of the run (it becomes the outcome)."""
    started = time.perf_counter()
    outcome = Outcome(task.key, "failed")
    local = task.log_path
    with PeakRSS() as memory:
        try:
            with _workspace(task, shipped) as (log_path, out):
                local = str(log_path)
                outcome.summary = _run(task, log_path, out)
                if shipped is not None:
                    outcome.files = {
                        str(p.relative_to(out)): p.read_bytes()
                        for p in sorted(out.rglob("*")) if p.is_file()
                    }
            outcome.error = outcome.summary.get("error")
            outcome.status = "failed" if outcome.error else "ok"
        except Exception as exc:
            outcome.error = f"{type(exc).__name__}: {exc}"
        if outcome.error and shipped is not None:  # name the log as the user knows it
            outcome.error = outcome.error.replace(local, task.log_path)
    outcome.seconds = round(time.perf_counter() - started, 3)
    outcome.peak_rss_mb = memory.megabytes
    return outcome


def clear_run_dir(path: Path) -> None:
    """Remove what an unfinished earlier attempt left, so stale files cannot mix in."""
    if path.exists():
        shutil.rmtree(path)
