"""The batch's results table: one row per run, as CSV (for tools) and Markdown (for people).

Rows are appended to ``results.csv`` as runs finish, so an interrupted batch keeps every row
it had; when the batch ends (or stops) both files are rewritten whole, in grid order, with the
best configuration per metric under the Markdown table.
"""

from __future__ import annotations

import csv
import io
import math
import os
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

from bioslam.batch.task import Outcome
from bioslam.io.jsonio import atomic_write_text

#: Accuracy and cost columns (key in the row, heading in Markdown); smaller is better for all.
METRICS: tuple[tuple[str, str], ...] = (
    ("ate_rmse_m", "ATE rmse (m)"),
    ("rpe_1m_trans_m", "RPE 1 m (m)"),
    ("rpe_1m_rot_deg", "RPE 1 m (deg)"),
    ("odometry_ate_rmse_m", "odometry ATE (m)"),
    ("seconds", "time (s)"),
    ("peak_rss_mb", "peak RSS (MB)"),
)
#: Columns that measure the machine rather than the run (they differ between identical runs).
MACHINE_COLUMNS = ("seconds", "peak_rss_mb")


def columns(varying: Sequence[str]) -> list[str]:
    """The table's columns: the run, the settings the grid varies, what it gave, what it cost."""
    return [
        "log", "config", *varying, "status", "scans", "ate_rmse_m", "rpe_1m_trans_m",
        "rpe_1m_rot_deg", "odometry_ate_rmse_m", "loop_closures", "experiences", "reference",
        "seconds", "peak_rss_mb", "error",
    ]


def make_row(outcome: Outcome, settings: dict[str, Any], varying: Sequence[str]) -> dict:
    """A table row from a run's outcome (missing figures stay empty)."""
    summary = outcome.summary
    odometry = summary.get("odometry") or {}
    row: dict[str, Any] = {"log": outcome.key[0], "config": outcome.key[1]}
    row.update({key: settings.get(key) for key in varying})
    row.update({
        "status": outcome.status,
        "scans": summary.get("scans"),
        "ate_rmse_m": summary.get("ate_rmse_m"),
        "rpe_1m_trans_m": summary.get("rpe_1m_trans_m"),
        "rpe_1m_rot_deg": summary.get("rpe_1m_rot_deg"),
        "odometry_ate_rmse_m": odometry.get("ate_rmse_m"),
        "loop_closures": summary.get("loop_closures"),
        "experiences": summary.get("experiences"),
        "reference": summary.get("reference"),
        "seconds": outcome.seconds,
        "peak_rss_mb": outcome.peak_rss_mb,
        "error": outcome.error,
    })
    return row


def _cell(value: Any) -> str:
    """CSV text of a value: empty for missing or non-finite, full precision for floats."""
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return ""
    if isinstance(value, list):
        return " ".join(_cell(v) for v in value)
    return str(value)


def csv_text(rows: Iterable[dict], header: Sequence[str], with_header: bool = True) -> str:
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    if with_header:
        writer.writerow(header)
    for row in rows:
        writer.writerow([_cell(row.get(column)) for column in header])
    return buffer.getvalue()


def read_csv(path: str | Path) -> list[dict[str, str]]:
    """Rows of a ``results.csv`` as strings (empty cells are empty strings)."""
    with open(path, newline="", encoding="utf-8") as fh:
        return list(csv.DictReader(fh))


class ResultsWriter:
    """Appends rows to ``results.csv`` as they come, and writes both tables at the end."""

    def __init__(self, out: Path, varying: Sequence[str], fixed: dict[str, Any]) -> None:
        self.out = out
        self.varying = list(varying)
        self.fixed = fixed
        self.header = columns(varying)
        self.rows: list[dict] = []
        atomic_write_text(self.csv_path, csv_text([], self.header))

    @property
    def csv_path(self) -> Path:
        return self.out / "results.csv"

    @property
    def md_path(self) -> Path:
        return self.out / "results.md"

    def add(self, row: dict) -> None:
        self.rows.append(row)
        with open(self.csv_path, "a", encoding="utf-8", newline="") as fh:
            fh.write(csv_text([row], self.header, with_header=False))
            fh.flush()
            os.fsync(fh.fileno())

    def finish(self, order: Sequence[tuple[str, str]], note: str = "") -> None:
        """Rewrite both tables with the rows in grid order (``order`` of (log, config))."""
        rank = {key: k for k, key in enumerate(order)}
        self.rows.sort(key=lambda r: rank.get((r["log"], r["config"]), len(rank)))
        atomic_write_text(self.csv_path, csv_text(self.rows, self.header))
        atomic_write_text(self.md_path, markdown(self.rows, self.header, self.fixed, note))


def _fmt(value: Any) -> str:
    if value is None or value == "":
        return ""
    if isinstance(value, float):
        if not math.isfinite(value):
            return ""
        return f"{value:.4g}" if abs(value) < 1e4 else f"{value:.0f}"
    return str(value).replace("|", "\\|").replace("\n", " ")


def best_per_metric(rows: Sequence[dict]) -> list[tuple[str, str, str]]:
    """For each metric: the configuration with the lowest mean rank over the logs where every
    configuration gave a value (logs differ in scale, so values are ranked, not averaged), and
    each log's own best. Rows: (metric heading, overall best, per-log bests)."""
    logs = list(dict.fromkeys(r["log"] for r in rows))
    configs = list(dict.fromkeys(r["config"] for r in rows))
    table = []
    for key, heading in METRICS:
        ranks: dict[str, list[int]] = {c: [] for c in configs}
        per_log = []
        for log in logs:
            values = {
                r["config"]: r[key] for r in rows
                if r["log"] == log and r["status"] == "ok" and _finite(r.get(key))
            }
            if not values:
                continue
            best = min(values, key=values.__getitem__)
            per_log.append(f"{log}: {best} ({_fmt(values[best])})")
            if len(values) == len(configs):
                for k, config in enumerate(sorted(values, key=values.__getitem__)):
                    ranks[config].append(k)
        scored = {c: sum(r) / len(r) for c, r in ranks.items() if r}
        overall = min(scored, key=scored.__getitem__) if scored else ""
        if per_log:
            table.append((heading, overall, "; ".join(per_log)))
    return table


def _finite(value: Any) -> bool:
    return isinstance(value, (int, float)) and math.isfinite(value)


def markdown(rows: Sequence[dict], header: Sequence[str], fixed: dict[str, Any],
             note: str = "") -> str:
    """The results as Markdown: settings every run shares, the table, the best per metric."""
    done = sum(r["status"] == "ok" for r in rows)
    lines = [
        "# Batch results",
        "",
        f"{len(rows)} runs, {done} ok, {len(rows) - done} failed.{' ' + note if note else ''}",
        "",
    ]
    if fixed:
        shared = ", ".join(f"`{k} = {v}`" for k, v in fixed.items())
        lines += [f"Settings of every run: {shared}.", ""]
    # the settings' own columns say what the config id says
    shown = [c for c in header if c != "config"] if len(header) > len(columns(())) else header
    lines += ["| " + " | ".join(shown) + " |", "|" + "---|" * len(shown)]
    lines += ["| " + " | ".join(_fmt(r.get(c)) for c in shown) + " |" for r in rows]
    best = best_per_metric(rows)
    if best and len({r["config"] for r in rows}) > 1:
        lines += [
            "",
            "## Best configuration per metric",
            "",
            "Overall: lowest mean rank over the logs where every configuration finished "
            "(smaller values are better for every metric).",
            "",
            "| metric | overall | per log |",
            "|---|---|---|",
        ]
        lines += [f"| {m} | {o} | {p} |" for m, o, p in best]
    return "\n".join(lines) + "\n"
