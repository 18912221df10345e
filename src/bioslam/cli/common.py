"""What the commands that read logs and write results share: exit codes, the options and checks
of the output directory, the reference and the log, and the end-of-run report on stderr.

Exit codes: 0 success; 1 the command ran but its result is incomplete (a partial read below
``--min-read-share``, 0 scans, a run stopped by an error, an output that could not be written);
2 invalid arguments or input, nothing run; 128 + signal number (130 SIGINT, 143 SIGTERM) when
interrupted, with everything computed so far written.
"""

from __future__ import annotations

import argparse
import signal
from pathlib import Path
from typing import Any

from bioslam import signals
from bioslam.io.outdir import OutputDir, check_output_dir
from bioslam.trajectory import Trajectory

EXIT_INCOMPLETE = 1
EXIT_INVALID = 2
#: Share of a log's scan records a run must read (the rest skipped as unusable) to succeed.
DEFAULT_MIN_READ_SHARE = 0.9


class CommandError(Exception):
    """The command ran and produced ``summary`` (printed as usual), but must exit ``code``."""

    def __init__(self, message: str, summary: dict[str, Any] | None, code: int) -> None:
        super().__init__(message)
        self.summary = summary
        self.code = code


def _share(text: str) -> float:
    value = float(text)
    if not 0.0 <= value <= 1.0:
        raise argparse.ArgumentTypeError(f"must be a fraction in [0, 1], got {text}")
    return value


def add_read_options(parser: argparse.ArgumentParser) -> None:
    """``--accept-partial`` and ``--min-read-share``."""
    parser.add_argument(
        "--min-read-share", type=_share, default=DEFAULT_MIN_READ_SHARE, metavar="FRACTION",
        help="fail (exit 1) when fewer than this share of the log's scan records could be "
        "read (default: %(default)s)",
    )
    parser.add_argument(
        "--accept-partial", action="store_true",
        help="succeed however few of the log's scan records were read (at least one)",
    )


def add_output_options(parser: argparse.ArgumentParser) -> None:
    """``--overwrite``."""
    parser.add_argument(
        "--overwrite", action="store_true",
        help="write into a non-empty --out: the files a previous bioslam run listed there are "
        "removed first, nothing else",
    )


def check_input(path: Path) -> None:
    """The log exists and can be opened (before any other work)."""
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such file or directory")
    if path.is_file():
        with path.open("rb") as fh:
            fh.read(1)


def check_system(config: Any, odometry_only: bool, where: Path | None) -> None:
    """Build the system once before the run: settings that pass their own checks but not one
    another's (or that the modules refuse) fail now, naming the configuration file, rather
    than after the log was opened and the output directory made."""
    from bioslam.pipeline import OdometryOnly
    from bioslam.slam import BioSLAM

    try:
        OdometryOnly(config) if odometry_only else BioSLAM(config)
    except Exception as exc:  # any failure here is the settings', reported as such
        source = f"--config {where}" if where is not None else "the default settings"
        raise ValueError(f"{source}: cannot build the system: {type(exc).__name__}: {exc}") \
            from None


def read_reference(path: Path) -> Trajectory:
    """``--gt``: parsed and checked before the run (a bad reference found after an hour of
    processing would cost the user that hour)."""
    from bioslam.evaluation import EvalConfig
    from bioslam.io.tum import read_tum

    if not path.is_file():
        raise FileNotFoundError(f"--gt {path}: no such file")
    reference = read_tum(path)
    if len(reference) < EvalConfig.min_pairs:
        raise ValueError(f"--gt {path}: {len(reference)} poses; at least "
                         f"{EvalConfig.min_pairs} are needed to evaluate against it")
    return reference


def open_output(path: Path, overwrite: bool, needed_bytes: int, argv: list[str]) -> OutputDir:
    """Check ``--out`` (see :func:`check_output_dir`), then create it with its marker. The
    caller opens it inside the :func:`bioslam.signals.protected` section that goes on to
    write the results: a signal arriving between the two once found the marker written
    ("running") and raised before anything could write the summary."""
    check_output_dir(path, overwrite, needed_bytes)
    out = OutputDir(path, command=["bioslam", *argv])
    with signals.protected():
        out.prepare(overwrite)
    return out


def read_report(source: Any, processed: int) -> list[str]:
    """What was read of a log and what was skipped and why, for stderr at the end of a run."""
    seen = source.records_seen
    lines = [f"read {source.scans_read} of {seen} scan records in {source.path}"
             + ("" if processed == source.scans_read else f", {processed} processed")]
    examples = source.skip_examples
    for reason, count in source_skipped(source).items():
        first = examples.get(reason)
        lines.append(f"  skipped {count} x {reason}" + (f" (first: {first})" if first else ""))
    lines += [f"  note: {note}" for note in source.notes()]
    return lines


def source_skipped(source: Any) -> dict[str, int]:
    """The skip counts of a source that was iterated; ``{}`` for one that never was (its
    ``skipped`` property would read the whole log, which an interrupted run must not do)."""
    return dict(source.skipped) if source.records_seen or source.complete else {}


def read_problem(
    processed: int, source: Any, min_share: float, accept_partial: bool
) -> str | None:
    """Why a run that read this little of its log must not count as a success, or ``None``."""
    seen = source.records_seen
    if processed == 0:
        found = f"none of its {seen} scan records" if seen else "no scan records"
        return f"{source.path}: 0 scans processed ({found} could be used)"
    share = source.scans_read / seen if seen else 1.0
    if not accept_partial and share < min_share:
        return (f"{source.path}: only {source.scans_read} of {seen} scan records read "
                f"({100 * share:.1f} % < {100 * min_share:g} %); the rest were skipped (see "
                "above); pass --accept-partial to accept a partial read")
    return None


def read_counts(source: Any) -> dict[str, Any]:
    """Summary keys: scan records met, the share read, and where the scans' stamps came from
    (the log's own, repaired, or record order when the log's were unusable)."""
    seen = source.records_seen
    return {"scan_records": seen,
            "read_share": round(source.scans_read / seen, 4) if seen else None,
            "time_source": source.time_source}


def run_status(summary: dict[str, Any], problems: list[str]) -> str:
    """The status a run's marker records: complete, incomplete or interrupted."""
    if summary.get("interrupted"):
        return "interrupted"
    return "incomplete" if problems or summary.get("write_errors") else "complete"


def conclude(summary: dict[str, Any], problems: list[str], where: Path | None) -> dict[str, Any]:
    """Return ``summary`` for a clean run; raise :class:`CommandError` for an interrupted one
    (exit 128 + signal) or one with problems (exit 1). Results are on disk either way."""
    kept = f"; results so far are in {where}" if where is not None else ""
    if summary.get("interrupted"):
        signum = signals.received() or signal.SIGINT
        raise CommandError(f"interrupted by {signal.Signals(signum).name}{kept}", summary,
                            128 + signum)
    if summary.get("write_errors"):
        problems = [*problems, "could not write " + "; ".join(summary["write_errors"])]
    if problems:
        raise CommandError("; ".join(problems) + kept, summary, EXIT_INCOMPLETE)
    return summary

