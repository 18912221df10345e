"""``bioslam eval`` against evo on the same TUM files: agreement of every figure, and speed.

Cases:
- ``freiburg``: the raw wheel odometry (``ODOM``) of the Freiburg 079 CARMEN log against its
  GMapping-corrected ``FLASER`` poses (different rates and stamps, so the association matters);
- ``synthetic``: a drifting, jittered estimate of a wandering route (always available).

For each case the script writes both TUM files to a temporary folder, runs the ``evo_ape`` /
``evo_rpe`` command-line tools (``--align``, ``--delta 1 --delta_unit m``) and prints each value
from bioslam and evo with their relative difference, then the median time of ``evaluate`` and of
evo's Python API for ATE + RPE-per-metre over ``--repeat`` runs. evo has no time unit for RPE,
so the 1 s figures are printed without an evo column.

    /work/venv/bin/python benchmarks/eval_vs_evo.py [--case freiburg synthetic] [--repeat 5]
"""

from __future__ import annotations

import argparse
import copy
import gzip
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from bioslam.evaluation import EvalConfig, ate, evaluate, rpe_distance
from bioslam.geometry import compose
from bioslam.io.tum import read_tum, write_tum
from bioslam.trajectory import Trajectory

REPO_ROOT = Path(__file__).resolve().parents[1]
DATA_DIR = REPO_ROOT.parent / "shared" / "data"
EVO_BIN = Path(sys.executable).parent


def _increasing(stamps: list[float], poses: list[list[float]]) -> tuple[Trajectory, int]:
    """Keep records whose stamp is later than the last kept one; count the rest."""
    keep, last = [], -np.inf
    for k, t in enumerate(stamps):
        if t > last:
            keep.append(k)
            last = t
    return Trajectory(np.asarray(stamps)[keep], np.asarray(poses)[keep]), len(stamps) - len(keep)


def freiburg_case() -> tuple[Trajectory, Trajectory, str] | None:
    log = DATA_DIR / "freiburg-079-corrected.log.gz"
    if not log.is_file():
        return None
    odo_t, odo_p, ref_t, ref_p = [], [], [], []
    with gzip.open(log, "rt") as fh:
        for line in fh:
            f = line.split()
            if f and f[0] == "ODOM":
                odo_t.append(float(f[7]))
                odo_p.append([float(v) for v in f[1:4]])
            elif f and f[0] == "FLASER":
                n = int(f[1])
                ref_t.append(float(f[8 + n]))
                ref_p.append([float(v) for v in f[2 + n : 5 + n]])
    est, dropped_est = _increasing(odo_t, odo_p)
    gt, dropped_gt = _increasing(ref_t, ref_p)
    note = f"ODOM {len(est)} kept ({dropped_est} out-of-order/zero stamps skipped), "
    note += f"FLASER {len(gt)} kept ({dropped_gt} skipped)"
    return est, gt, note


def synthetic_case() -> tuple[Trajectory, Trajectory, str]:
    rng = np.random.default_rng(7)
    n, period = 6000, 0.1
    k = np.arange(n)
    steps = np.column_stack(
        [(0.6 + 0.2 * np.sin(0.05 * k)) * period, np.zeros(n), 0.04 * np.sin(0.03 * k)]
    )
    noisy = steps * [1.02, 1.0, 1.0] + rng.normal(0.0, [0.005, 0.002, 0.004], (n, 3))
    gt_p, est_p = np.zeros((n, 3)), np.zeros((n, 3))
    for i in range(1, n):
        gt_p[i] = compose(gt_p[i - 1], steps[i - 1])
        est_p[i] = compose(est_p[i - 1], noisy[i - 1])
    gt = Trajectory(period * k, gt_p)
    est = Trajectory(period * k + rng.uniform(-0.004, 0.004, n), compose([3.0, -2.0, 1.0], est_p))
    return est, gt, f"{n} poses at {1 / period:g} Hz, 2 % scale drift, stamps jittered ±4 ms"


def _evo_cli(tool: str, gt: Path, est: Path, args: list[str], work: Path) -> dict[str, float]:
    from evo.tools import file_interface

    out = work / f"{tool}_{len(list(work.iterdir()))}.zip"
    cmd = [str(EVO_BIN / tool), "tum", str(gt), str(est), "--align", "--no_warnings"]
    subprocess.run([*cmd, *args, "--save_results", str(out)], check=True, capture_output=True)
    return file_interface.load_res_file(str(out)).stats


def _median_time(fn, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return float(np.median(times))


def _evo_api_once(gt_path: Path, est_path: Path, max_dt: float) -> None:
    from evo.core import sync
    from evo.core.metrics import PoseRelation, Unit
    from evo.main_ape import ape
    from evo.main_rpe import rpe
    from evo.tools import file_interface

    ref = file_interface.read_tum_trajectory_file(str(gt_path))
    est = file_interface.read_tum_trajectory_file(str(est_path))
    ref, est = sync.associate_trajectories(ref, est, max_diff=max_dt)
    ape(copy.deepcopy(ref), copy.deepcopy(est), PoseRelation.translation_part, align=True)
    for relation in (PoseRelation.translation_part, PoseRelation.rotation_angle_deg):
        rpe(copy.deepcopy(ref), copy.deepcopy(est), relation, delta=1.0,
            delta_unit=Unit.meters, align=True)  # fmt: skip


def _ours_once(gt_path: Path, est_path: Path, max_dt: float) -> None:
    est, gt = read_tum(est_path), read_tum(gt_path)
    ate(est, gt, max_dt=max_dt)
    rpe_distance(est, gt, 1.0, max_dt)


def run_case(name: str, est: Trajectory, gt: Trajectory, note: str, max_dt: float,
             repeat: int) -> float:  # fmt: skip
    """Print the comparison table; return the largest relative difference seen."""
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        est_path, gt_path = work / "est.tum", work / "gt.tum"
        write_tum(est_path, est)
        write_tum(gt_path, gt)
        t_arg = ["--t_max_diff", str(max_dt)]
        evo_ape = _evo_cli("evo_ape", gt_path, est_path, t_arg, work)
        per_m = [*t_arg, "--delta", "1", "--delta_unit", "m"]
        evo_rpe_t = _evo_cli("evo_rpe", gt_path, est_path, per_m, work)
        evo_rpe_r = _evo_cli("evo_rpe", gt_path, est_path, [*per_m, "-r", "angle_deg"], work)
        ours = evaluate(read_tum(est_path), read_tum(gt_path), EvalConfig(max_dt=max_dt))
        rows = [
            ("ate_rmse_m", evo_ape["rmse"]),
            ("ate_mean_m", evo_ape["mean"]),
            ("ate_max_m", evo_ape["max"]),
            ("rpe_1m_trans_m", evo_rpe_t["rmse"]),
            ("rpe_1m_rot_deg", evo_rpe_r["rmse"]),
            ("rpe_1s_trans_m", None),
            ("rpe_1s_rot_deg", None),
        ]
        print(f"\n== {name}: {note}; {ours['pairs']} associated poses, max_dt {max_dt} s")
        print(f"{'figure':<16}{'bioslam':>14}{'evo':>14}{'rel. diff':>12}")
        worst = 0.0
        for key, ref in rows:
            if ref is None:
                print(f"{key:<16}{ours[key]:>14.6f}{'(n/a)':>14}")
                continue
            rel = abs(ours[key] - ref) / max(abs(ref), 1e-12)
            worst = max(worst, rel)
            print(f"{key:<16}{ours[key]:>14.6f}{ref:>14.6f}{rel:>12.1e}")
        t_ours = _median_time(lambda: _ours_once(gt_path, est_path, max_dt), repeat)
        t_evo = _median_time(lambda: _evo_api_once(gt_path, est_path, max_dt), repeat)
        print(
            f"time (read + ATE + RPE/m, median of {repeat}): bioslam {1e3 * t_ours:.1f} ms, "
            f"evo {1e3 * t_evo:.1f} ms, ratio evo/bioslam {t_evo / t_ours:.1f}"
        )
    return worst


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--case", nargs="+", default=["freiburg", "synthetic"])
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args()
    worst = 0.0
    for name in args.case:
        if name == "freiburg":
            case = freiburg_case()
            if case is None:
                print(f"== freiburg: skipped, {DATA_DIR} has no Freiburg log")
                continue
            worst = max(worst, run_case(name, *case, max_dt=0.05, repeat=args.repeat))
        elif name == "synthetic":
            worst = max(worst, run_case(name, *synthetic_case(), max_dt=0.02, repeat=args.repeat))
        else:
            parser.error(f"unknown case {name!r}")
    print(f"\nlargest relative difference to evo: {worst:.1e}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
