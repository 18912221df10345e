"""``odometry_uncertainty.csv``: how far each scan's odometry match can be trusted.

One row per scan: ``stamp``, the match's covariance in the map frame (``xx, xy, xt, yy, yt,
tt``; metres and radians, :func:`bioslam.matching.gauss_newton.match_covariance`), the
weakest horizontal direction's angle (degrees in the map frame, an axis in [-90, 90)) and its
standard deviation (m), and the flags ``degenerate`` (the scan left a direction unconstrained:
the pose kept the motion prior along it), ``ambiguous`` (a look-alike fitted about as well)
and ``predicted_only`` (no usable scan: the covariance is empty).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from bioslam.io.jsonio import atomic_path

HEADER = "stamp,xx,xy,xt,yy,yt,tt,weak_angle_deg,weak_std,degenerate,ambiguous,predicted_only"


def weakest_horizontal(covariances: NDArray) -> tuple[NDArray, NDArray]:
    """The principal axis of largest variance of each (x, y) block of ``covariances``
    (N, 6: upper triangles): its angle (degrees, in [-90, 90)) and standard deviation."""
    c = np.asarray(covariances, dtype=np.float64).reshape(-1, 6)
    xx, xy, yy = c[:, 0], c[:, 1], c[:, 3]
    half = 0.5 * (xx - yy)
    largest = 0.5 * (xx + yy) + np.hypot(half, xy)
    angle = np.degrees(0.5 * np.arctan2(2.0 * xy, xx - yy))
    angle = (angle + 90.0) % 180.0 - 90.0
    return angle, np.sqrt(np.maximum(largest, 0.0))


def write_uncertainty(
    path: str | Path, stamps: NDArray, covariances: NDArray, flags: NDArray
) -> None:
    """Write the table (atomically, like the trajectories)."""
    cov = np.asarray(covariances, dtype=np.float64).reshape(-1, 6)
    angle, std = weakest_horizontal(cov)
    bits = np.asarray(flags, dtype=np.int64).reshape(-1, 1) >> np.arange(3) & 1
    table = np.column_stack([np.asarray(stamps, dtype=np.float64), cov, angle, std, bits])
    with atomic_path(path) as tmp:
        np.savetxt(tmp, table, fmt=["%.6f"] + ["%.3g"] * 6 + ["%.1f", "%.3g"] + ["%d"] * 3,
                   delimiter=",", header=HEADER, comments="")  # fmt: skip


def read_uncertainty(path: str | Path) -> NDArray:
    """The table as an (N, 12) array (NaN where the covariance is empty)."""
    return np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
