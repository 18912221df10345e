"""``bioslam eval EST.tum GT.tum``: ATE and RPE of an estimated trajectory against a reference."""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from bioslam.evaluation import EvalConfig, evaluate
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
    parser.set_defaults(func=run)


def _load(path: Path, role: str) -> Trajectory:
    if not path.is_file():
        raise FileNotFoundError(f"{role} trajectory {path} does not exist")
    trajectory = read_tum(path)
    if len(trajectory) == 0:
        raise ValueError(f"{role} trajectory {path} holds no poses")
    return trajectory


def _json_safe(summary: dict) -> dict:
    """NaN (a path too short for any RPE pair) becomes null, which every JSON reader accepts."""
    return {k: None if isinstance(v, float) and math.isnan(v) else v for k, v in summary.items()}


def run(args: argparse.Namespace) -> dict:
    if args.max_dt <= 0:
        raise ValueError(f"--max-dt must be positive, got {args.max_dt}")
    est = _load(args.estimate, "estimated")
    gt = _load(args.reference, "reference")
    try:
        summary = evaluate(est, gt, EvalConfig(max_dt=args.max_dt))
    except ValueError as exc:
        raise ValueError(f"{args.estimate} vs {args.reference}: {exc}") from None
    print(f"{summary['pairs']} associated poses ({len(est)} estimated, {len(gt)} reference)")
    for label, key, unit in _ROWS:
        print(f"  {label:<14} {summary[key]:10.4f} {unit}")
    return _json_safe(summary)
