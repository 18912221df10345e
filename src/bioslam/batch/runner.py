"""Planning and carrying out a batch: tasks from logs x grid, resume, results, progress.

Layout under the output folder::

    batch.json                 what the batch is (logs, grid); marks the folder as a batch's
    results.csv, results.md    one row per run
    <log>/<config-id>/         the run's usual outputs (as ``bioslam run`` writes them)
    <log>/<config-id>/batch-run.json   written last, only for a finished run: its row

A run whose ``batch-run.json`` exists and names the same log, settings and ground-truth file
is finished and is not run again; any other run folder is an unfinished attempt and is
cleared before running.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from tqdm import tqdm

from bioslam import signals
from bioslam.batch.engines import Engine, close_engine
from bioslam.batch.grid import GridPoint
from bioslam.batch.results import ResultsWriter, make_row
from bioslam.batch.task import Files, Outcome, Task, clear_run_dir, pack, unpack
from bioslam.io.jsonio import read_json, write_json
from bioslam.io.outdir import check_output_dir, expected_output_bytes, path_bytes
from bioslam.io.tum import read_tum
from bioslam.trajectory import Trajectory

BATCH_FILE = "batch.json"
DONE_MARKER = "batch-run.json"
_COMPRESSED = (".gz", ".bz2", ".xz", ".zst")


@dataclass
class BatchSpec:
    """What to run.

    Attributes:
        logs: the log files or bag folders.
        out: the output folder.
        points: the grid's configurations.
        gt_from: ``reference`` (each log's own reference poses) or a pattern of a TUM file per
            log with ``{dir}`` (the log's folder), ``{name}`` (its file name) and ``{stem}``
            (the name without extensions), e.g. ``{dir}/gt.tum``.
        topic: the scan stream of logs with several.
        ship_data: send logs to the workers as bytes and get outputs back the same way.
    """

    logs: Sequence[Path]
    out: Path
    points: Sequence[GridPoint]
    gt_from: str = "reference"
    topic: str | None = None
    ship_data: bool = False


@dataclass
class BatchReport:
    """How the batch went; ``rows`` are in grid order."""

    runs: int
    skipped: int = 0
    ok: int = 0
    failed: int = 0
    interrupted: bool = False
    seconds: float = 0.0
    rows: list[dict] = field(default_factory=list)


def _stem(path: Path) -> str:
    name = path.name
    for suffix in _COMPRESSED:
        name = name.removesuffix(suffix)
    return Path(name).stem or name


def log_names(paths: Sequence[Path]) -> list[str]:
    """A distinct folder name per log: its stem, and for logs that share a stem as many of
    their parent folders as it takes to tell them apart (``a/scans``, ``b/scans`` and ``c.log``
    give ``a-scans``, ``b-scans`` and ``c``)."""
    resolved = [p.resolve() for p in paths]
    if len(set(resolved)) != len(resolved):
        raise ValueError("a log is given twice")
    depth = [0] * len(resolved)

    def name(k: int) -> str:
        parents = resolved[k].parent.parts[1:]  # without the root
        return "-".join([*parents[len(parents) - depth[k]:], _stem(resolved[k])])

    while True:
        names = [name(k) for k in range(len(resolved))]
        clashing = [k for k, n in enumerate(names) if names.count(n) > 1]
        if not clashing:
            return names
        for k in clashing:
            depth[k] += 1


def find_reference(log: Path, gt_from: str) -> tuple[Trajectory | None, str | None]:
    """The ground truth ``--gt-from`` names for ``log``; ``None`` lets the run use the log's own
    reference poses (and is what a pattern gives when its file does not exist)."""
    if gt_from == "reference":
        return None, None
    name = log.name
    stem = _stem(log)
    path = Path(gt_from.format(dir=log.parent, name=name, stem=stem))
    if not path.is_file():
        return None, None
    reference = read_tum(path)
    if len(reference) < 2:
        raise ValueError(f"ground truth {path} for {log} holds {len(reference)} poses")
    return reference, str(path)


def plan(spec: BatchSpec) -> list[Task]:
    """Every log x every grid point, log by log."""
    tasks = []
    for log, name in zip(spec.logs, log_names(spec.logs), strict=True):
        if not log.exists():
            raise FileNotFoundError(f"log {log} does not exist")
        reference, reference_name = find_reference(log, spec.gt_from)
        for point in spec.points:
            out = spec.out / name / point.config_id
            tasks.append(Task(name, str(log.resolve()), point, str(out), spec.topic,
                              reference, reference_name))
    return tasks


def finished_row(task: Task) -> dict | None:
    """The row a finished run left, if the run is finished for this same log and settings."""
    marker = Path(task.out_dir) / DONE_MARKER
    if not marker.is_file():
        return None
    try:
        done = read_json(marker)
    except ValueError:
        return None
    same = (done.get("log_path"), done.get("settings"), done.get("reference")) == (
        task.log_path, task.point.settings, task.reference_name
    )
    return done.get("row") if same else None


def prepare_out_dir(spec: BatchSpec) -> None:
    """Create the output folder or accept a previous batch's; refuse any other non-empty one
    rather than mix results into it."""
    out = spec.out
    if out.is_dir() and any(out.iterdir()) and not (out / BATCH_FILE).is_file():
        raise ValueError(f"--out {out} is not empty and holds no {BATCH_FILE}: not a batch "
                         "output folder; choose a new or empty folder")
    # writable, and room for the largest log's run at least (as `bioslam run` checks)
    largest = max(path_bytes(log) for log in spec.logs)
    check_output_dir(out, True, expected_output_bytes(input_bytes=largest))
    write_json(out / BATCH_FILE, {
        "logs": [str(p.resolve()) for p in spec.logs],
        "configs": {p.config_id: p.settings for p in spec.points},
        "gt_from": spec.gt_from,
    })


def _fixed_settings(points: Sequence[GridPoint]) -> dict[str, Any]:
    first = points[0]
    return {k: v for k, v in first.settings.items() if k not in first.varying}


class _Progress:
    """done / running / failed and the time left, on stderr."""

    def __init__(self, total: int, workers: int, enabled: bool) -> None:
        self.total, self.workers = total, workers
        self.done = self.failed = 0
        self.bar = tqdm(total=total, desc="batch", unit="run", file=sys.stderr,
                        disable=not enabled, dynamic_ncols=True, smoothing=0.0)
        self._show()

    def _show(self) -> None:
        running = min(self.workers, self.total - self.done)
        self.bar.set_postfix_str(f"running {running}, failed {self.failed}", refresh=True)

    def add(self, outcome: Outcome) -> None:
        self.done += 1
        self.failed += outcome.status != "ok"
        self.bar.update(1)
        self._show()
        if outcome.status != "ok":
            self.bar.write(f"batch: {outcome.key[0]} / {outcome.key[1]} failed: {outcome.error}")

    def close(self) -> None:
        self.bar.close()


def _record(task: Task, outcome: Outcome) -> dict:
    """Put a finished run's outputs in place and mark it finished (last, once all is there)."""
    out = Path(task.out_dir)
    if outcome.files is not None:
        unpack(outcome.files, out)
    row = make_row(outcome, task.point.settings, task.point.varying)
    if outcome.status == "ok":
        write_json(out / DONE_MARKER, {
            "log_path": task.log_path, "settings": task.point.settings,
            "reference": task.reference_name, "row": row,
        })
    return row


def run_batch(spec: BatchSpec, engine: Engine, progress: bool = True) -> BatchReport:
    """Run every task not already finished; rows are written as runs finish. Ctrl-C ends the
    runs under way and keeps every finished row; the engine is released in any case."""
    started = time.perf_counter()
    try:
        prepare_out_dir(spec)
        tasks = plan(spec)
        writer = ResultsWriter(spec.out, spec.points[0].varying, _fixed_settings(spec.points))
        report = BatchReport(runs=len(tasks))
        todo: list[Task] = []
        for task in tasks:
            row = finished_row(task)
            if row is None:
                clear_run_dir(Path(task.out_dir))
                todo.append(task)
            else:
                writer.add(row)
                report.skipped += 1
        shipped: dict[str, Files] | None = None
        if spec.ship_data:
            shipped = {t.log_name: pack(t.log_path) for t in todo}
        if report.skipped:
            print(f"batch: {report.skipped} of {len(tasks)} runs already finished in "
                  f"{spec.out}; running the other {len(todo)}", file=sys.stderr)
        by_key = {task.key: task for task in todo}
        bar = _Progress(len(todo), engine.workers, progress)
        try:
            for outcome in engine.run(todo, shipped):
                with signals.protected():  # a row and its run's marker are written whole
                    writer.add(_record(by_key[outcome.key], outcome))
                bar.add(outcome)
        except KeyboardInterrupt:  # Ctrl-C, or SIGTERM under the command's handlers
            report.interrupted = True
            with signals.protected():
                engine.stop()
        finally:
            bar.close()
            note = "Stopped early (interrupted); re-run the command to finish." \
                if report.interrupted else ""
            with signals.protected():
                writer.finish([t.key for t in tasks], note)
    finally:
        close_engine(engine)
    report.rows = writer.rows
    report.ok = sum(r["status"] == "ok" for r in writer.rows)
    report.failed = len(writer.rows) - report.ok
    report.seconds = round(time.perf_counter() - started, 3)
    return report
