"""Position error along the URG-04LX maze route of two ``run.py --cases sim-maze-urg04lx``
runs (their ``--work`` folders, e.g. before and after a change) and of MRPT icp-slam (from the
second), each trajectory aligned on its first pose.

Usage: ``python benchmarks/plot_run_errors.py WORK_BEFORE WORK_AFTER OUT.png``
"""

import sys

import matplotlib
import numpy as np

matplotlib.use("Agg")
import matplotlib.pyplot as plt

from bioslam.geometry import compose


def load(path: str) -> tuple[np.ndarray, np.ndarray]:
    """Stamps and (x, y, yaw) of a TUM file."""
    d = np.loadtxt(path)
    return d[:, 0], np.column_stack([d[:, 1], d[:, 2], 2 * np.arctan2(d[:, 6], d[:, 7])])

def error(est_path: str, gt_path: str) -> tuple[np.ndarray, np.ndarray]:
    """Time from the start and position error of an estimate against the ground truth."""
    te, e = load(est_path)
    tg, g = load(gt_path)
    idx = np.clip(np.searchsorted(tg, te), 0, len(tg) - 1)
    g = g[idx]
    w = compose(np.broadcast_to(g[0], e.shape), e)  # first pose aligned
    return te - te[0], np.hypot(*(w[:, :2] - g[:, :2]).T)

def main() -> None:
    before, after, out = sys.argv[1], sys.argv[2], sys.argv[3]
    truth = "full/cases/sim-urg04lx-600s-seed1/gt.tum"
    fig, ax = plt.subplots(figsize=(9, 3.5))
    for label, run in (("bioslam odometry before", before), ("bioslam odometry after", after)):
        t, err = error(f"{run}/full/runs/sim-maze-urg04lx/odometry/odometry.tum",
                       f"{run}/{truth}")  # fmt: skip
        ax.plot(t, err, label=f"{label} (RMS {np.sqrt(np.mean(err**2)):.2f} m)")
    t, err = error(f"{after}/full/runs/sim-maze-urg04lx/mrpt/trajectory.tum", f"{after}/{truth}")
    ax.plot(t, err, label=f"MRPT icp-slam (RMS {np.sqrt(np.mean(err**2)):.2f} m)", alpha=0.7)
    ax.set_xlabel("time, s")
    ax.set_ylabel("position error, m (first pose aligned)")
    ax.set_title("URG-04LX (240°, 5.6 m) in the maze, 600 s, LiDAR only")
    ax.legend()
    fig.tight_layout()
    fig.savefig(out, dpi=100)
    print(out)


if __name__ == "__main__":
    main()
