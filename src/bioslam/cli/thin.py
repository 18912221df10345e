"""``bioslam thin INPUT --out OUT``: keep one scan per distance or angle travelled, as the public
"corrected" logs were made, and write a log bioslam reads back with its reference poses.

A CARMEN log becomes a CARMEN log (ODOM records all kept); any other log a ROS 2 bag directory
``OUT/scans`` with the reference on ``/ground_truth`` and in ``OUT/gt.tum``.
"""

from __future__ import annotations

import argparse
import math
import shutil
from pathlib import Path
from typing import Any

import numpy as np

from bioslam.cli.sim import BAG_NAME, GT_NAME, GT_TOPIC, SCAN_TOPIC
from bioslam.geometry import between
from bioslam.trajectory import Trajectory

#: What a CARMEN log's name must contain for its laser poses to be read as a reference.
CORRECTED = "corrected"


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "thin",
        help="keep one scan per distance or angle travelled (like the public corrected logs)",
        description="Thin a LiDAR log to one scan per --distance metres or --angle degrees "
        "travelled since the last scan kept, measured along a trajectory (--by): the log's "
        "reference (corrected) poses, its odometry, or a TUM file such as the simulator's "
        "gt.tum. A CARMEN log is written as a CARMEN log (its name must say 'corrected' when "
        f"it carries reference poses, so that they are read back as such); other logs as a "
        f"ROS 2 bag OUT/{BAG_NAME} with the reference on {GT_TOPIC} and in OUT/{GT_NAME}.",
    )
    p.add_argument("input", help="log file or ROS 2 bag directory")
    p.add_argument("--out", required=True, type=Path, help="CARMEN file, or output directory")
    p.add_argument("--distance", type=float, help="metres travelled between kept scans")
    p.add_argument("--angle", type=float, help="degrees turned between kept scans")
    p.add_argument(
        "--by",
        default="auto",
        help="'reference', 'odometry' or a TUM file (default: the reference if the log has "
        "one, else its odometry)",
    )
    p.add_argument("--topic", help="LaserScan topic (bags) or laser message (CARMEN) to read")
    p.add_argument("--storage", choices=("sqlite3", "mcap"), default="sqlite3",
                   help="bag storage (bag output)")
    p.add_argument("--force", action="store_true", help="replace an existing output")
    p.set_defaults(func=run)


def guide_trajectory(
    by: str, stamps: np.ndarray, reference: Trajectory | None, odometry: Trajectory | None
) -> tuple[str, Trajectory]:
    """The trajectory that measures the motion, at the scans' stamps, and what it is."""
    from bioslam.io.tum import read_tum

    if by == "auto":
        by = "reference" if reference is not None else "odometry"
    if by == "reference":
        if reference is None or len(reference) != len(stamps):
            raise ValueError("the log has no reference poses for its scans; use --by odometry "
                             "or --by a TUM file")
        return by, reference
    if by == "odometry":
        if odometry is None or len(odometry) == 0:
            raise ValueError("the log has no odometry; use --by reference or --by a TUM file")
        return by, odometry.at(stamps)
    path = Path(by)
    if not path.is_file():
        raise FileNotFoundError(f"--by {by}: not 'reference', 'odometry' or a TUM file")
    return str(path), read_tum(path).at(stamps)


def _check_carmen_name(out: Path, has_reference: bool) -> None:
    named = CORRECTED in out.name.lower()
    if has_reference and not named:
        raise ValueError(f"{out}: a CARMEN log's poses are read as reference only when its "
                         f"name contains '{CORRECTED}'; name it e.g. "
                         f"{out.stem}-{CORRECTED}{''.join(out.suffixes)}")
    if named and not has_reference:
        raise ValueError(f"{out}: the input has no reference poses, but a name containing "
                         f"'{CORRECTED}' would make its odometry read as one")


def _clear(path: Path, force: bool) -> None:
    if not path.exists():
        return
    if not force:
        raise ValueError(f"{path} already exists; pass --force to replace it")
    if path.is_dir():
        shutil.rmtree(path)
    else:
        path.unlink()


def _write_carmen(log, keep: np.ndarray, out: Path, reference: Trajectory | None,
                  odometry: Trajectory | None, comment: str) -> int:
    from bioslam.io.carmen_writer import CarmenWriter

    message = "FLASER" if log.topic in ("FLASER", "RLASER") else "ROBOTLASER1"
    kept = set(keep.tolist())
    odo = odometry if odometry is not None and len(odometry) else Trajectory.empty()
    odo_at = odo.at(reference.stamps) if reference is not None and len(odo) else None
    next_odo = 0
    with CarmenWriter(out, message, comment) as writer:
        for i, scan in enumerate(log):
            while next_odo < len(odo) and odo.stamps[next_odo] <= scan.stamp:
                writer.write_odometry(odo.stamps[next_odo], odo.poses[next_odo])
                next_odo += 1
            if i in kept:
                pose = reference.poses[i] if reference is not None else None
                odom = odo_at.poses[i] if odo_at is not None else None
                writer.write_scan(scan, pose, odom)
        for k in range(next_odo, len(odo)):
            writer.write_odometry(odo.stamps[k], odo.poses[k])
        return writer.count


def _write_bag(log, keep: np.ndarray, out: Path, reference: Trajectory | None,
               scan_time: float, storage: str) -> int:
    from bioslam.io.bag_writer import ScanBagWriter
    from bioslam.io.tum import write_tum

    kept = set(keep.tolist())
    out.mkdir(parents=True, exist_ok=True)
    pose_topic = GT_TOPIC if reference is not None else None
    with ScanBagWriter(out / BAG_NAME, SCAN_TOPIC, scan_time=scan_time, storage=storage,
                       pose_topic=pose_topic) as writer:
        for i, scan in enumerate(log):
            if i in kept:
                writer.write(scan)
                if reference is not None:
                    writer.write_pose(scan.stamp, reference.poses[i])
    if reference is not None:
        write_tum(out / GT_NAME, Trajectory(reference.stamps[keep], reference.poses[keep]))
    return writer.count


def run(args: argparse.Namespace) -> dict[str, Any]:
    from bioslam.io.logs import open_log
    from bioslam.thinning import thin_indices

    angle = None if args.angle is None else math.radians(args.angle)
    log = open_log(args.input, args.topic)
    stamps = np.array([scan.stamp for scan in log])
    if stamps.size == 0:
        raise ValueError(f"{args.input}: no usable scans")
    log_reference, odometry = log.reference, log.odometry
    by, guide = guide_trajectory(args.by, stamps, log_reference, odometry)
    keep = thin_indices(guide.poses, args.distance, angle)
    # The reference written: the log's own, else the ground truth the thinning followed.
    reference = log_reference
    if reference is None and by not in ("reference", "odometry"):
        reference = guide
    out: Path = args.out
    comment = (f"thinned by bioslam thin from {Path(args.input).name}: one scan per "
               f"{args.distance} m or {args.angle} deg travelled along the {by}")
    if log.format == "carmen":
        _check_carmen_name(out, reference is not None)
        _clear(out, args.force)
        written = _write_carmen(log, keep, out, reference, odometry, comment)
        gt = None
    else:
        _clear(out / BAG_NAME, args.force)
        scan_time = float(np.median(np.diff(stamps))) if stamps.size > 1 else 0.0
        written = _write_bag(log, keep, out, reference, scan_time, args.storage)
        gt = str(out / GT_NAME) if reference is not None else None
    return {
        "input": str(args.input),
        "output": str(out / BAG_NAME) if gt is not None or log.format != "carmen" else str(out),
        "reference": gt if gt is not None else ("in log" if reference is not None else None),
        "by": by,
        "distance_m": args.distance,
        "angle_deg": args.angle,
        "scans_in": int(stamps.size),
        "scans_kept": int(written),
        "path_length_m": round(guide.path_length(), 3),
        **_largest_steps(guide.poses[keep]),
    }


def _largest_steps(kept: np.ndarray) -> dict[str, float]:
    """The largest displacement and turn between consecutive kept scans, along the guide:
    what the odometry must bridge (with ``--distance`` alone a turn on the spot between two
    scans can reach 180°)."""
    if len(kept) < 2:
        return {"largest_step_m": 0.0, "largest_turn_deg": 0.0}
    steps = between(kept[:-1], kept[1:])
    return {
        "largest_step_m": round(float(np.hypot(steps[:, 0], steps[:, 1]).max()), 3),
        "largest_turn_deg": round(float(np.degrees(np.abs(steps[:, 2])).max()), 1),
    }
