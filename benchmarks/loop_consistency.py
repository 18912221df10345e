"""Loop consistency for logs without a reference trajectory.

Definition (documented in benchmarks/README.md):

1. The *return scan* is found from the sensor data alone, so that every system is judged at the
   same moment: among the scans recorded after ``min_fraction`` of the log's duration, the one
   whose range profile best matches the first scan. The match score is the median absolute
   range difference (m) over beams valid in both scans, minimised over a shift of up to
   ``max_shift_deg`` of beam offset (the robot may return with a slightly different heading).
2. The *loop gap* of a trajectory is the distance between its first pose and its pose at the
   return scan (m), and the heading difference (deg). A consistent map has a gap close to the
   true offset between the two viewpoints, which the match score bounds loosely: two scans whose
   ranges agree to a few centimetres were taken from nearly the same place.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bioslam.geometry import wrap_angle
from bioslam.scan import LaserScan
from bioslam.trajectory import Trajectory


@dataclass
class LoopConfig:
    """``min_fraction``: the route must have run this share of the log before a return counts
    (0.3: a return in the first third is the robot still near its start, not a loop).
    ``max_shift_deg``: heading tolerance of the return, degrees (15: a returning robot or hand
    rarely faces the same way to better than this)."""

    min_fraction: float = 0.3
    max_shift_deg: float = 15.0


@dataclass
class LoopReturn:
    index: int
    stamp: float
    match_m: float


def _profile(scan: LaserScan) -> np.ndarray:
    r = np.asarray(scan.ranges, dtype=np.float64).copy()
    r[~scan.valid_mask] = np.nan
    return r


def _shifted_mismatch(a: np.ndarray, b: np.ndarray, shift: int) -> float:
    d = a[shift:] - b[: b.size - shift] if shift >= 0 else a[:shift] - b[-shift:]
    d = np.abs(d[np.isfinite(d)])
    return float(np.median(d)) if d.size >= 0.3 * a.size else np.inf


def find_return(scans: list[LaserScan], cfg: LoopConfig | None = None) -> LoopReturn:
    """The return scan (see the module docstring)."""
    cfg = cfg or LoopConfig()
    first = _profile(scans[0])
    t0, t1 = scans[0].stamp, scans[-1].stamp
    step = abs(float(np.median(np.diff(scans[0].angles)))) if scans[0].num_beams > 1 else 1.0
    max_shift = round(np.deg2rad(cfg.max_shift_deg) / step)
    best = LoopReturn(-1, float("nan"), np.inf)
    for i, scan in enumerate(scans):
        if scan.stamp < t0 + cfg.min_fraction * (t1 - t0) or scan.num_beams != first.size:
            continue
        prof = _profile(scan)
        score = min(_shifted_mismatch(prof, first, s) for s in range(-max_shift, max_shift + 1))
        if score < best.match_m:
            best = LoopReturn(i, float(scan.stamp), score)
    if best.index < 0:
        raise ValueError("no scan after the first third of the log matches the first scan")
    return best


def loop_gap(traj: Trajectory, ret: LoopReturn) -> dict[str, float]:
    """Distance (m) and heading difference (deg) between the first pose and the return pose."""
    if len(traj) == 0:
        raise ValueError("empty trajectory")
    j = int(np.argmin(np.abs(traj.stamps - ret.stamp)))
    d = traj.poses[j] - traj.poses[0]
    return {
        "loop_gap_m": float(np.hypot(d[0], d[1])),
        "loop_gap_deg": float(np.degrees(abs(wrap_angle(d[2])))),
    }
