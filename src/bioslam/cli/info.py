"""``bioslam info INPUT``: what a LiDAR log holds, in the manner of ``ros2 bag info``."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

from bioslam import signals
from bioslam.cli.common import (
    add_read_options,
    check_input,
    conclude,
    read_counts,
    read_problem,
    read_report,
)
from bioslam.io.logs import SUPPORTED_FORMATS, open_log
from bioslam.scan import LaserScan

# Keys of the one-line JSON summary (besides the details bioslam info prints as a table).
SUMMARY_KEYS = (
    "format", "path", "topic", "scans", "beams", "fov_deg", "angle_min_deg", "angle_max_deg",
    "angle_increment_deg", "range_min_m", "range_max_m", "duration_s", "rate_hz",
    "time_increment_s", "valid_return_fraction", "reference_poses", "odometry_poses",
    "skipped",
)


def register(subparsers: argparse._SubParsersAction) -> None:
    formats = "; ".join(f"{k}: {v}" for k, v in SUPPORTED_FORMATS.items())
    p = subparsers.add_parser(
        "info",
        help="show what a LiDAR log holds (format, topics, scans, beams, FOV, duration)",
        description="Read a whole LiDAR log and print its format, topics, scan count, beams, "
        "field of view, range limits, duration and the records skipped and why, then a "
        f"one-line JSON summary. Supported formats: {formats}.",
    )
    p.add_argument("input", help="log file or ROS 2 bag directory")
    p.add_argument("--topic", help="LaserScan topic (bags) or laser message (CARMEN) to read")
    p.add_argument(
        "--strict", action="store_true", help="fail on the first bad record instead of skipping"
    )
    add_read_options(p)
    p.set_defaults(func=run)


def _progress(scans: Iterable[LaserScan], label: str) -> Iterator[LaserScan]:
    """A progress bar on stderr when it is a terminal (quiet in scripts and CI logs); stops
    at the first SIGINT/SIGTERM so that what was read so far is still reported."""
    from tqdm import tqdm

    for scan in tqdm(scans, desc=label, unit=" scans", disable=not sys.stderr.isatty(),
                     leave=False, file=sys.stderr):
        if signals.received() is not None:
            return
        yield scan


def format_table(info: dict[str, Any]) -> str:
    """The human-readable report of :meth:`LogSource.info`."""
    rows: list[tuple[str, str]] = [
        ("Path", str(info["path"])),
        ("Format", f"{info['format']} ({SUPPORTED_FORMATS[info['format']]})"),
    ]
    scans = info["scans"]
    if scans:
        rows += [
            ("Duration", f"{info['duration_s']:.3f} s"),
            ("Start", f"{info['start_s']:.6f} s"),
            ("End", f"{info['end_s']:.6f} s"),
            ("Scans", f"{scans} ({info['rate_hz']:.2f} Hz)"),
            ("Beams", str(info["beams"]) + _beam_counts(info)),
            ("Field of view", _fov(info)),
            ("Range limits", f"{info['range_min_m']:.3f} - {info['range_max_m']:.3f} m"),
            ("Time increment", f"{info['time_increment_s'] * 1e6:.2f} µs per beam"),
            ("Valid returns", f"{100 * info['valid_return_fraction']:.1f} % of beams"),
        ]
    else:
        rows.append(("Scans", "0"))
    rows += [
        ("Reference poses", str(info["reference_poses"])),
        ("Odometry poses", str(info["odometry_poses"])),
    ]
    lines = [f"{name + ':':<19}{value}" for name, value in rows]
    lines += _section("Topics", [
        f"{t['name']} | Type: {t['type']} | Count: {t['count']}"
        + (" (read)" if t["name"] == info.get("topic") else "")
        for t in info["topics"]
    ])
    lines += _section("Skipped", [
        f"{count} x {reason} (first: {info['skip_examples'].get(reason, '?')})"
        for reason, count in info["skipped"].items()
    ] or ["none"])
    lines += _section("Notes", info["notes"])
    return "\n".join(lines)


def _fov(info: dict[str, Any]) -> str:
    return (
        f"{info['fov_deg']:.2f}° ({info['angle_min_deg']:.2f}° to {info['angle_max_deg']:.2f}°, "
        f"step {info['angle_increment_deg']:.4f}°)"
    )


def _beam_counts(info: dict[str, Any]) -> str:
    counts = info.get("beam_counts")
    if not counts:
        return ""
    return " (varies: " + ", ".join(f"{n} beams x {c}" for n, c in counts.items()) + ")"


def _section(title: str, items: list[str]) -> list[str]:
    if not items:
        return []
    head = f"{title + ':':<19}"
    return [head + items[0]] + [" " * 19 + item for item in items[1:]]


def run(args: argparse.Namespace) -> dict[str, Any]:
    check_input(Path(args.input))
    source = open_log(args.input, args.topic, strict=args.strict)
    with signals.protected():
        info = source.info(progress=lambda scans: _progress(scans, source.path.name))
        print(format_table(info), flush=True)
        for line in read_report(source, source.scans_read):
            print(f"bioslam info: {line}", file=sys.stderr)
    summary = {key: info[key] for key in SUMMARY_KEYS if key in info}
    summary.update(read_counts(source))
    problems = []
    if signals.received() is not None:
        summary["interrupted"] = True
    else:
        problem = read_problem(source.scans_read, source, args.min_read_share,
                               args.accept_partial)
        problems += [problem] if problem else []
    return conclude(summary, problems, None)
