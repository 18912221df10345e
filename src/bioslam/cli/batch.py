"""``bioslam batch LOGS... --out DIR``: every log under every configuration of a grid, on Ray or
a local process pool, with a results table."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "batch",
        help="run many logs x many settings (Ray or a local process pool) into a results table",
        description="Run every log under every configuration of --grid, each as one task, on "
        "Ray (a local instance, or the cluster at --address / RAY_ADDRESS) or, without Ray, on "
        "a local process pool. Each run's outputs go to OUT/<log>/<config-id>/; results.csv and "
        "results.md get one row per run and the best configuration per metric. Re-running the "
        "same command skips the runs already finished; Ctrl-C stops and keeps finished rows. "
        "Exit codes: 0 every run ok, 1 some runs failed (rows with their errors), 2 invalid "
        "input (nothing run), 130/143 interrupted (finished rows kept).",
    )
    parser.add_argument("logs", nargs="+", type=Path, help="log files or ROS 2 bag directories")
    parser.add_argument("--out", type=Path, required=True, help="output directory")
    parser.add_argument(
        "--grid", type=Path,
        help="TOML of setting lists with dotted keys, e.g. \"odometry.resolution\" = [0.03, "
        "0.05]; 'mode' (full, odometry-only) and 'max_scans' say how each run is made "
        "(default: one run per log with the default settings)",
    )
    parser.add_argument(
        "--gt-from", default="reference", metavar="reference|PATTERN",
        help="ground truth per log: 'reference' (the log's own corrected poses, the default) "
        "or a TUM file pattern with {dir}, {name}, {stem} of the log, e.g. '{dir}/gt.tum'",
    )
    parser.add_argument("--workers", type=int,
                        help="runs at a time (default: CPU count; a cluster's CPU count)")
    parser.add_argument("--engine", choices=("ray", "process"),
                        help="default: ray when installed (pip install 'bioslam[ray]'), "
                        "else process")
    parser.add_argument("--address", help="Ray cluster to join (default: $RAY_ADDRESS, else a "
                        "local Ray instance)")
    parser.add_argument("--ship-data", action="store_true",
                        help="send logs to the workers and outputs back through the engine "
                        "instead of reading and writing shared paths")
    parser.add_argument("--topic", help="LaserScan topic when a bag holds several")
    parser.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> dict[str, Any]:
    from bioslam.batch import BatchSpec, load_grid, run_batch
    from bioslam.batch.engines import default_engine, make_engine
    from bioslam.cli.common import conclude

    points = load_grid(args.grid)
    for log in args.logs:
        if not log.exists():
            raise FileNotFoundError(f"log {log} does not exist")
    spec = BatchSpec(args.logs, args.out, points, args.gt_from, args.topic, args.ship_data)
    name = args.engine or default_engine()
    engine = make_engine(name, args.workers, args.address)
    report = run_batch(spec, engine, progress=not args.no_progress)
    results = args.out / "results.csv"
    summary: dict[str, Any] = {
        "engine": name, "workers": engine.workers, "runs": report.runs,
        "skipped": report.skipped, "ok": report.ok, "failed": report.failed,
        "seconds": report.seconds, "results": str(results),
    }
    if report.interrupted:
        summary["interrupted"] = True
    problems = [f"{report.failed} of {len(report.rows)} runs failed (their errors are in "
                f"{results})"] if report.failed else []
    return conclude(summary, problems, None)
