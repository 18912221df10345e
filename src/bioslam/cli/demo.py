"""``bioslam demo``: the paper's simulation experiment (Sec. IV-A) end to end, nothing to set up.

Simulates the built-in maze for 600 s with the UTM-30LX model, runs the full system on the scans
as they are generated, evaluates it against the ground truth and writes the paper's figures
(Fig. 5: cognitive map at 200, 400 and 600 s beside the ground truth; Fig. 6: active view id and
position error over time).
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import Any

from bioslam import signals
from bioslam.cli.common import (
    add_output_options,
    check_system,
    conclude,
    open_output,
    run_status,
)
from bioslam.io.outdir import expected_output_bytes
from bioslam.recording import session as recording

#: The paper's reported simulation result (Sec. IV-A): mean and maximum position error.
PAPER_MEAN_ERROR_M = 0.0284
PAPER_MAX_ERROR_M = 0.127


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "demo",
        help="simulate the paper's maze for 600 s, run SLAM, evaluate, write the figures",
        description="Reproduce the paper's simulation experiment: the built-in maze, a 600 s "
        "drive with a UTM-30LX LiDAR model, the full system, evaluation against ground truth "
        "and the paper's figures. Writes the same files as `bioslam run` plus gt.tum.",
    )
    parser.add_argument("--out", type=Path, default=Path("demo_out"), help="output directory")
    parser.add_argument("--duration", type=float, default=600.0, help="seconds (default 600)")
    parser.add_argument("--seed", type=int, default=0, help="route and noise seed (default 0)")
    parser.add_argument("--config", type=Path, help="TOML or JSON file of setting overrides")
    parser.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    add_output_options(parser)
    recording.add_arguments(parser)
    parser.set_defaults(func=demo_command)


def snapshot_times(duration: float) -> tuple[float, ...]:
    """The paper's 200, 400 and 600 s for a 600 s run; thirds of shorter or longer ones."""
    return tuple(duration * k / 3.0 for k in (1, 2, 3))


def comparison_table(summary: dict[str, Any]) -> str:
    """The demo's result beside the paper's, as printed at the end of a demo."""
    def cm(value: float | None) -> str:
        return "n/a" if value is None or not math.isfinite(value) else f"{100 * value:.2f} cm"

    odo = summary.get("odometry", {})
    rows = [
        ("", "bioslam", "odometry only", "paper"),
        ("mean position error", cm(summary.get("ate_mean_m")), cm(odo.get("ate_mean_m")),
         cm(PAPER_MEAN_ERROR_M)),
        ("max position error", cm(summary.get("ate_max_m")), cm(odo.get("ate_max_m")),
         cm(PAPER_MAX_ERROR_M)),
        ("RMSE", cm(summary.get("ate_rmse_m")), cm(odo.get("ate_rmse_m")), ""),
        ("RPE over 1 m", cm(summary.get("rpe_1m_trans_m")), cm(odo.get("rpe_1m_trans_m")), ""),
        ("views", str(summary.get("views")), "", ""),
        ("experiences", str(summary.get("experiences")), "", ""),
        ("loop closures", str(summary.get("loop_closures")), "", ""),
        ("wall time", f"{summary.get('wall_s', math.nan):.1f} s", "", ""),
        ("ms per scan (median / p99)",
         f"{summary.get('ms_per_scan_median', math.nan):.2f} / "
         f"{summary.get('ms_per_scan_p99', math.nan):.2f}", "", ""),
        ("real-time factor", f"{summary.get('realtime_factor', math.nan):.1f}x", "", ""),
    ]
    widths = [max(len(row[i]) for row in rows) for i in range(4)]
    return "\n".join(
        "  ".join(cell.ljust(width) for cell, width in zip(row, widths, strict=True)).rstrip()
        for row in rows
    )


def demo_command(args: argparse.Namespace) -> dict[str, Any]:
    from bioslam.cli.sim import FIGURE_NAME, GT_NAME, save_world_figure
    from bioslam.config import load_config
    from bioslam.io.tum import write_tum
    from bioslam.pipeline import RunOptions, run_slam, write_results
    from bioslam.sim import LIDAR_PRESETS, make_route, maze_world, scan_stamps, simulate_scans

    if not (math.isfinite(args.duration) and args.duration > 0):
        raise ValueError(f"--duration must be a positive number of seconds, got {args.duration}")
    session = recording.Session.from_args(args, False, input="simulated maze")
    config = load_config(args.config)
    check_system(config, False, args.config)
    world = maze_world()
    lidar = LIDAR_PRESETS["utm30lx"]
    route = make_route(world, duration=args.duration, seed=args.seed)
    stamps = scan_stamps(lidar, route)
    gt = route.trajectory(stamps)
    needed = expected_output_bytes(scans=int(stamps.size))
    with signals.protected():
        out = open_output(args.out, args.overwrite, needed, getattr(args, "argv", []))
        out.save(GT_NAME, write_tum, gt)
        stopped = False
        try:
            with signals.interruptible():
                out.save(FIGURE_NAME, save_world_figure, world, route)
        except KeyboardInterrupt:
            stopped = True  # no run: write the (empty) results, marked interrupted
        options = RunOptions(
            progress=not args.no_progress and not stopped, warm_up=not stopped,
            snapshot_times=snapshot_times(route.duration), release=True,
            scan_store_dir=out.path, drop_library_pages=True,
        )
        scans = (scan for scan, _ in simulate_scans(world, lidar, route, seed=args.seed))
        with session:
            result = run_slam(iter(()) if stopped else scans, config, options,
                              int(stamps.size), observer=session.observer)
            session.finish(result.system)
        result.interrupted |= stopped
        extra = {"input": "simulated maze", "lidar": lidar.name, "seed": args.seed}
        extra.update(session.summary())
        summary = write_results(result, out, gt, options, extra)
        print(comparison_table(summary))
        print(f"results in {out.path}/ (figures in {out.path}/figures/)")
        print(f"bioslam demo: {summary['scans']} of {stamps.size} simulated scans processed, "
              "none skipped", file=sys.stderr)
        problems = []
        if result.error:
            problems.append(f"demo stopped early ({result.error})")
        elif summary["scans"] == 0 and not summary.get("interrupted"):
            problems.append("0 scans processed")
        out.finish(run_status(summary, problems))
    return conclude(summary, problems, out.path)
