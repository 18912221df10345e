"""``bioslam consistency LOG TRAJ.tum [TRAJ.tum ...]``: how well each trajectory makes the log's
scans agree with themselves where the robot came back (revisit sharpness,
:mod:`bioslam.consistency`). Needs no reference, and judges a reference like any trajectory."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

import numpy as np

from bioslam.cli.common import check_input, read_counts, read_report, source_skipped
from bioslam.consistency import RevisitConfig, find_revisits, revisit_residuals
from bioslam.trajectory import Trajectory

_DEFAULTS = RevisitConfig()


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "consistency",
        help="how sharp each TUM trajectory makes a log's map where the robot came back "
        "(no reference needed)",
        description="Revisit sharpness: at the scans where the robot came back near a pass "
        "made --gap seconds or more apart, the median distance of their endpoints to the "
        "other pass's, every scan placed by the trajectory. Lower is sharper. The revisits are "
        "chosen on the first trajectory and every trajectory is judged on the same scans, "
        "only where all of them have poses.",
    )
    parser.add_argument("log", type=Path, help="the log the trajectories were made from")
    parser.add_argument("trajectories", type=Path, nargs="+", metavar="TRAJ.tum",
                        help="trajectories of the scanner, TUM format (e.g. trajectory.tum, "
                        "odometry.tum, reference.tum of a bioslam run, or another system's)")
    parser.add_argument("--topic", help="LaserScan topic when the log has several")
    parser.add_argument("--gap", type=float, default=_DEFAULTS.min_gap_s, metavar="S",
                        help="another pass is a scan this many seconds away or more "
                        "(default: %(default)s)")
    parser.add_argument("--radius", type=float, default=_DEFAULTS.radius_m, metavar="M",
                        help="... whose pose is within this many metres (default: %(default)s)")
    parser.add_argument("--every", type=int, default=_DEFAULTS.every, metavar="N",
                        help="judge every N-th scan (default: %(default)s)")
    parser.add_argument("--csv", type=Path, metavar="FILE.csv",
                        help="write each judged scan: stamp, x, y (the first trajectory's) and "
                        "its residual in mm under every trajectory")
    parser.add_argument("--plot", type=Path, metavar="FILE.png",
                        help="draw the judged scans coloured by their residual, a panel per "
                        "trajectory")
    parser.set_defaults(func=run)


def _load(path: Path) -> Trajectory:
    from bioslam.io.tum import read_tum

    if not path.is_file():
        raise FileNotFoundError(f"trajectory {path} does not exist")
    trajectory = read_tum(path)
    if len(trajectory) < 2:
        raise ValueError(f"trajectory {path} holds {len(trajectory)} poses; at least 2 needed")
    return trajectory


def _covered(stamps: np.ndarray, trajectories: list[Trajectory]) -> np.ndarray:
    """The scans every trajectory has a pose for: within its span, half a median step either
    side (poses between two of its stamps are interpolated)."""
    inside = np.ones(len(stamps), dtype=bool)
    for trajectory in trajectories:
        slack = 0.5 * float(np.median(np.diff(trajectory.stamps)))
        first, last = trajectory.stamps[0] - slack, trajectory.stamps[-1] + slack
        inside &= (stamps >= first) & (stamps <= last)
    return inside


def run(args: argparse.Namespace) -> dict[str, Any]:
    from bioslam.io.logs import open_log

    config = RevisitConfig(min_gap_s=args.gap, radius_m=args.radius, every=args.every)
    trajectories = [_load(path) for path in args.trajectories]
    check_input(args.log)
    source = open_log(args.log, topic=args.topic)
    stamps = np.array([scan.stamp for scan in source])  # a first pass: the stamps alone
    for line in read_report(source, len(stamps)):
        print(f"bioslam consistency: {line}", file=sys.stderr)
    if stamps.size == 0:
        raise ValueError(f"{args.log}: no scan could be read")
    covered = np.flatnonzero(_covered(stamps, trajectories))
    if covered.size == 0:
        raise ValueError(f"{args.log}: none of its {len(stamps)} scans lies within the span of "
                         "every trajectory (do their stamps use the log's clock?)")
    poses = [trajectory.at(stamps[covered]).poses for trajectory in trajectories]
    revisits = find_revisits(poses[0], stamps[covered], config)
    needed = {r.scan for r in revisits} | {int(j) for r in revisits for j in r.partners}
    # a second pass keeps the endpoints of the scans compared alone (a long log's would not fit)
    endpoints: dict[int, np.ndarray] = {}
    position = {int(k): i for i, k in enumerate(covered)}
    for k, scan in enumerate(source):
        i = position.get(k)
        if i is not None and i in needed:
            endpoints[i] = scan.endpoints().astype(np.float32)
    residuals = [revisit_residuals(endpoints, p, revisits, config) for p in poses]
    judged = ~np.isnan(residuals[0])
    print(f"{args.log}: {int(judged.sum())} scans judged at revisits (of {covered.size} "
          f"covered by every trajectory, {len(stamps)} read)")
    rows = [_row(path, r[judged], residuals[0][judged], k) for k, (path, r) in
            enumerate(zip(args.trajectories, residuals, strict=True))]  # fmt: skip
    scans = np.array([r.scan for r in revisits], dtype=np.intp)
    table = (stamps[covered][scans], poses[0][scans, :2], residuals)
    if args.csv is not None:
        _write_csv(args.csv, _names(args.trajectories), *table)
    if args.plot is not None:
        from bioslam.plots.figures import plot_revisit_sharpness

        plot_revisit_sharpness(args.plot, table[1], list(zip(_names(args.trajectories),
                                                             residuals, strict=True)))
    return {"log": str(args.log), "scans": len(stamps), "judged": int(judged.sum()),
            "trajectories": rows, "skipped": source_skipped(source), **read_counts(source)}


def _row(path: Path, residual: np.ndarray, first: np.ndarray, k: int) -> dict[str, Any]:
    """A trajectory's line and summary entry."""
    if residual.size == 0:
        print(f"  {path}: no revisit judged")
        return {"path": str(path), "median_mm": None, "p75_mm": None}
    median, p75 = (round(1e3 * float(v), 2) for v in np.percentile(residual, [50, 75]))
    row: dict[str, Any] = {"path": str(path), "median_mm": median, "p75_mm": p75}
    line = f"  {path}: median {median:.1f} mm, 75th percentile {p75:.1f} mm"
    if k > 0:
        row["sharper_than_first"] = round(float(np.mean(residual < first)), 4)
        line += f"; sharper than the first at {row['sharper_than_first']:.0%} of the scans"
    print(line)
    return row


def _names(paths: list[Path]) -> list[str]:
    """The trajectories' file names, numbered where two are alike."""
    names = [path.name for path in paths]
    return [f"{k + 1}:{name}" if names.count(name) > 1 else name for k, name in enumerate(names)]


def _write_csv(
    path: Path, names: list[str], stamps: np.ndarray, xy: np.ndarray, residuals: list
) -> None:
    """One row per judged scan: stamp, x, y, and its residual (mm) under each trajectory
    (empty where it was not judged); a trajectory's name is quoted where it holds a comma."""
    import csv
    import io

    from bioslam.io.jsonio import atomic_write_text

    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(["stamp", "x", "y", *names])
    for k in range(len(stamps)):
        values = [f"{1e3 * r[k]:.2f}" if np.isfinite(r[k]) else "" for r in residuals]
        writer.writerow([f"{stamps[k]:.6f}", f"{xy[k, 0]:.3f}", f"{xy[k, 1]:.3f}", *values])
    atomic_write_text(path, buffer.getvalue())
