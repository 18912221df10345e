"""``bioslam run``: the full system (or the odometry alone) over a log, with results on disk."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from bioslam.io.tum import read_tum, write_tum
from bioslam.recording import session as recording
from bioslam.trajectory import Trajectory


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "run",
        help="run SLAM on a log (CARMEN, ROS 1/2 bag, BreezySLAM .dat)",
        description="Run the LiDAR-only biologically-inspired SLAM on a log and write "
        "trajectory.tum, odometry.tum, cognitive_map.json, map.pgm/map.yaml, figures/ and "
        "summary.json into --out. With --gt (or a log that carries corrected poses) the "
        "trajectory is evaluated too.",
    )
    parser.add_argument("input", type=Path, help="log file or ROS 2 bag directory")
    parser.add_argument("--out", type=Path, required=True, help="output directory")
    parser.add_argument("--config", type=Path, help="TOML or JSON file of setting overrides")
    parser.add_argument("--topic", help="LaserScan topic when a bag holds several")
    parser.add_argument("--gt", type=Path, help="ground-truth trajectory (TUM) to evaluate")
    parser.add_argument(
        "--odometry-only", action="store_true", help="run the LiDAR odometry alone"
    )
    parser.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    recording.add_arguments(parser)
    parser.set_defaults(func=run_command)


def reference_trajectory(
    gt_path: Path | None, log_reference: Trajectory | None, out: Path
) -> tuple[Trajectory | None, str | None]:
    """The trajectory to evaluate against: ``--gt`` first, else the log's corrected poses
    (written to ``reference.tum`` so that other tools can use them)."""
    if gt_path is not None:
        return read_tum(gt_path), str(gt_path)
    if log_reference is not None and len(log_reference) > 1:
        write_tum(out / "reference.tum", log_reference)
        return log_reference, "log"
    return None, None


def run_command(args: argparse.Namespace) -> dict[str, Any]:
    # Imported here so that `bioslam --help` and the light subcommands start fast.
    from bioslam.config import load_config
    from bioslam.io.logs import open_log
    from bioslam.pipeline import RunOptions, run_slam, write_results

    session = recording.Session.from_args(args, args.odometry_only, input=args.input)
    config = load_config(args.config)
    source = open_log(args.input, topic=args.topic)
    options = RunOptions(odometry_only=args.odometry_only, progress=not args.no_progress)
    with session:
        result = run_slam(source, config, options, observer=session.observer)
        session.finish(result.system)
    reference, reference_name = reference_trajectory(args.gt, source.reference, args.out)
    extra: dict[str, Any] = {"input": str(args.input), "format": source.format}
    extra["skipped"] = source.skipped
    if reference_name:
        extra["reference"] = reference_name
    extra.update(session.summary())
    summary = write_results(result, args.out, reference, options, extra)
    if result.error:
        raise RuntimeError(f"{args.input}: run stopped early ({result.error}); "
                           f"results so far are in {args.out}")
    return summary
