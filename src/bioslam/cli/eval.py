"""``bioslam eval EST.tum GT.tum [--third T.tum]``: ATE and RPE of an estimated trajectory
against a reference; with a third trajectory, each one's own RPE (three-cornered hat)."""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from bioslam.evaluation import EvalConfig, evaluate, three_cornered_hat
from bioslam.io.tum import read_tum
from bioslam.trajectory import Trajectory

_ROWS = (
    ("ATE rmse", "ate_rmse_m", "m"),
    ("ATE mean", "ate_mean_m", "m"),
    ("ATE max", "ate_max_m", "m"),
    ("RPE 1 m trans", "rpe_1m_trans_m", "m"),
    ("RPE 1 m rot", "rpe_1m_rot_deg", "deg"),
    ("RPE 1 s trans", "rpe_1s_trans_m", "m"),
    ("RPE 1 s rot", "rpe_1s_rot_deg", "deg"),
)


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "eval",
        help="ATE and RPE of an estimated TUM trajectory against a reference",
        description="Absolute trajectory error after SE(2) alignment and relative pose error "
        "over 1 m and over 1 s (RMSE over pairs), with evo's definitions.",
    )
    parser.add_argument("estimate", type=Path, help="estimated trajectory, TUM format")
    parser.add_argument("reference", type=Path, help="reference (ground truth), TUM format")
    parser.add_argument(
        "--max-dt",
        type=float,
        default=EvalConfig.max_dt,
        help="largest stamp difference for associating poses, s (default: %(default)s)",
    )
    parser.add_argument(
        "--third",
        type=Path,
        help="a third, independent estimate of the same motion (TUM): also estimate each "
        "trajectory's own 1 m RPE, the reference's included (three-cornered hat)",
    )
    parser.add_argument(
        "--min-pairs",
        type=int,
        default=EvalConfig.min_pairs,
        help="refuse (exit 2) fewer associated poses than this (default: %(default)s)",
    )
    parser.set_defaults(func=run)


def _load(path: Path, role: str) -> Trajectory:
    if not path.is_file():
        raise FileNotFoundError(f"{role} trajectory {path} does not exist")
    trajectory = read_tum(path)
    if len(trajectory) == 0:
        raise ValueError(f"{role} trajectory {path} holds no poses")
    return trajectory


def run(args: argparse.Namespace) -> dict:
    if not args.max_dt > 0 or not math.isfinite(args.max_dt):
        raise ValueError(f"--max-dt must be a positive number, got {args.max_dt}")
    if args.min_pairs < 1:
        raise ValueError(f"--min-pairs must be at least 1, got {args.min_pairs}")
    est = _load(args.estimate, "estimated")
    gt = _load(args.reference, "reference")
    try:
        summary = evaluate(est, gt, EvalConfig(max_dt=args.max_dt, min_pairs=args.min_pairs))
    except ValueError as exc:
        raise ValueError(f"{args.estimate} vs {args.reference}: {exc}") from None
    print(f"{summary['pairs']} associated poses ({len(est)} estimated, {len(gt)} reference)")
    for label, key, unit in _ROWS:
        print(f"  {label:<14} {summary[key]:10.4f} {unit}")
    if args.third is not None:
        summary["three_cornered_hat"] = _own_errors(args, est, gt)
    return summary


def _own_errors(args: argparse.Namespace, est: Trajectory, gt: Trajectory) -> dict:
    third = _load(args.third, "third")
    try:
        hat = three_cornered_hat(gt, est, third, EvalConfig.rpe_delta_m, args.max_dt)
    except ValueError as exc:
        raise ValueError(f"{args.reference} vs {args.third}: {exc}") from None
    print(f"own RPE 1 m of each, {hat['pairs']} pairs (three-cornered hat; assumes their errors")
    print("are independent: errors two of them share are blamed on the other one)")
    for k, role in enumerate(("reference", "estimate", "third")):
        trans, rot = hat["trans_rmse_m"][k], hat["rot_rmse_deg"][k]
        print(f"  {role:<14} {trans:10.4f} m {rot:8.3f} deg")
    return {"order": ["reference", "estimate", "third"], **hat}
