"""``bioslam run``: the full system (or the odometry alone) over a log, with results on disk."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from bioslam import signals
from bioslam.cli.common import (
    add_output_options,
    add_read_options,
    check_input,
    check_system,
    conclude,
    open_output,
    read_counts,
    read_problem,
    read_reference,
    read_report,
    run_status,
    source_skipped,
)
from bioslam.io.outdir import OutputDir, expected_output_bytes, path_bytes
from bioslam.io.tum import write_tum
from bioslam.recording import session as recording
from bioslam.trajectory import Trajectory


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "run",
        help="run SLAM on a log (CARMEN, ROS 1/2 bag, BreezySLAM .dat)",
        description="Run the LiDAR-only biologically-inspired SLAM on a log and write "
        "trajectory.tum, odometry.tum, cognitive_map.json, closures.csv, map.pgm/map.yaml, "
        "figures/ and summary.json into --out. With --gt (or a log that carries corrected "
        "poses) the trajectory is evaluated too. Exit codes: 0 success, 1 incomplete result "
        "(written), 2 invalid input (nothing run), 130/143 interrupted (results so far "
        "written).",
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
    parser.add_argument(
        "--one-process", action="store_true",
        help="read the log in the run's own process (by default, where there is a second "
        "core, a child process reads the log ahead of the run)",
    )
    parser.add_argument(
        "--draw-in-child", action="store_true",
        help="draw the figures in a child process while the other results are written "
        "(about a second sooner done; its memory and what it is sent add 70-150 MB to the "
        "run's peak on an hour's log)",
    )
    add_output_options(parser)
    add_read_options(parser)
    recording.add_arguments(parser)
    parser.set_defaults(func=run_command)


def reference_trajectory(
    gt_path: Path | None, log_reference: Trajectory | None, out: Path | OutputDir
) -> tuple[Trajectory | None, str | None]:
    """The trajectory to evaluate against: ``--gt`` first, else the log's corrected poses
    (written to ``reference.tum`` so that other tools can use them)."""
    if gt_path is not None:
        return read_reference(gt_path), str(gt_path)
    if log_reference is not None and len(log_reference) > 1:
        target = out if isinstance(out, OutputDir) else OutputDir(out, marker=False)
        target.save("reference.tum", write_tum, log_reference)
        return log_reference, "log"
    return None, None


def reference_label(reference_name: str | None) -> str:
    """What the figures call the reference named ``reference_name`` by
    :func:`reference_trajectory`: a log's corrected poses are no ground truth."""
    from bioslam.plots import GROUND_TRUTH, LOG_REFERENCE

    return LOG_REFERENCE if reference_name == "log" else GROUND_TRUTH


def run_command(args: argparse.Namespace) -> dict[str, Any]:
    # Imported here so that `bioslam --help` and the light subcommands start fast.
    from bioslam.io.forked import can_fork
    from bioslam.io.readahead import ReadAhead

    # Everything that can be checked is checked before the first scan.
    session = recording.Session.from_args(args, args.odometry_only, input=args.input)
    # The log is opened first so that its reading (the time plan's pass first) runs while the
    # settings are checked and the run starts up, and its reader forked before the settings'
    # module brings in Numba and SciPy: the child's memory is mostly this process's pages as
    # they were at the fork, which this process rewrites later (the reader's private memory
    # 42 MB forked after those imports, 21 MB before). A bad log is still reported after bad
    # settings or a bad --gt.
    source, bad_input = start_reading(args)
    helpers: list[Any] = [source] if isinstance(source, ReadAhead) else []
    try:
        # the figures' process, forked now, shares little of this process (Numba and the
        # system come next); it waits for the end of the run. Opt-in: on an hour's log it
        # and what it is sent raised the run's peak by 70-150 MB for about a second of wall
        # time, and memory is what the paper's robot lacks.
        figures = _figure_worker() if args.draw_in_child and can_fork() else None
        helpers += [figures] if figures is not None else []
        from bioslam.config import load_config

        config = load_config(args.config)
        check_system(config, args.odometry_only, args.config)
        gt = read_reference(args.gt) if args.gt is not None else None
        if bad_input is not None:
            raise bad_input
        return _run(args, source, config, gt, session, figures)
    finally:
        for helper in helpers:
            helper.close()


def _figure_worker() -> Any:
    from bioslam.plots.worker import FigureWorker

    return FigureWorker()


def start_reading(args: argparse.Namespace) -> tuple[Any, Exception | None]:
    """The log opened and, unless ``--one-process``, being read ahead in a child process
    (:func:`bioslam.io.readahead.read_ahead`); or ``None`` and why it cannot be read."""
    from bioslam.io.logs import open_log
    from bioslam.io.readahead import read_ahead

    try:
        check_input(args.input)
        source = open_log(args.input, topic=args.topic)
    except (OSError, ValueError) as exc:
        return None, exc
    return (source if args.one_process else read_ahead(source)), None


def _run(args: argparse.Namespace, source: Any, config: Any, gt: Trajectory | None,
         session: recording.Session, figures: Any) -> dict[str, Any]:
    from bioslam.pipeline import RunOptions, run_slam, write_results

    needed = expected_output_bytes(input_bytes=path_bytes(args.input))
    with signals.protected():
        out = open_output(args.out, args.overwrite, needed, getattr(args, "argv", []))
        options = RunOptions(
            odometry_only=args.odometry_only, progress=not args.no_progress, release=True,
            scan_store_dir=out.path,  # the experiences' scans on disk, beside the outputs
            drop_library_pages=True, figure_worker=figures,
        )
        with session:
            result = run_slam(source, config, options, observer=session.observer)
            session.finish(result.system)
        read = source.records_seen > 0 or source.complete
        log_reference = source.reference if read else None
        if gt is not None:
            reference, reference_name = gt, str(args.gt)
        else:
            reference, reference_name = reference_trajectory(None, log_reference, out)
        extra: dict[str, Any] = {"input": str(args.input), "format": source.format}
        extra["skipped"] = source_skipped(source)
        extra.update(read_counts(source))
        extra.update(session.summary())
        if reference_name:
            extra["reference"] = reference_name
        options.reference_label = reference_label(reference_name)
        summary = write_results(result, out, reference, options, extra)
        processed = summary["scans"]
        for line in read_report(source, processed):
            print(f"bioslam run: {line}", file=sys.stderr)
        problems = []
        if not summary.get("interrupted"):
            problem = read_problem(processed, source, args.min_read_share, args.accept_partial)
            problems += [problem] if problem else []
        if result.error:
            problems.append(f"{args.input}: run stopped early ({result.error})")
        out.finish(run_status(summary, problems))
    return conclude(summary, problems, args.out)

