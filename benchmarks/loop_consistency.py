"""Loop consistency for logs without a reference trajectory.

Definition (documented in benchmarks/README.md): a trajectory *goes away* once its position is
``away_m`` or more from its first pose; it *returns* at the later pose nearest to the first one.
The loop gap is the distance between the first pose and that return pose (m), with the heading
difference (deg) and the time of the return. A system that drifts reports a larger gap, one
that relocalises at the start a smaller one; a trajectory that never goes away has no gap.

A sensor-only return moment (the scan that best matches the first scan) was tried first and
dropped: in corridors and mazes the best-matching scan is often an aliased place metres away.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bioslam.geometry import wrap_angle
from bioslam.trajectory import Trajectory


@dataclass
class LoopConfig:
    """``away_m``: how far from the start a route must get before a return counts (1 m: well
    above the centimetre gaps a consistent system leaves, and below the 1.4 m a short handheld
    log such as the ROS 1 demo bag moves away)."""

    away_m: float = 1.0


def loop_gap(traj: Trajectory, cfg: LoopConfig | None = None) -> dict[str, float]:
    """``loop_gap_m``, ``loop_gap_deg``, ``loop_return_t_s`` and ``max_excursion_m``."""
    cfg = cfg or LoopConfig()
    if len(traj) < 2:
        raise ValueError("a trajectory of fewer than two poses has no loop")
    dist = np.hypot(*(traj.poses[:, :2] - traj.poses[0, :2]).T)
    away = np.flatnonzero(dist >= cfg.away_m)
    out = {"max_excursion_m": float(dist.max())}
    if away.size == 0:
        return {**out, "loop_gap_m": float("nan"), "loop_gap_deg": float("nan")}
    j = int(away[0] + np.argmin(dist[away[0] :]))
    return {
        **out,
        "loop_gap_m": float(dist[j]),
        "loop_gap_deg": float(np.degrees(abs(wrap_angle(traj.poses[j, 2] - traj.poses[0, 2])))),
        "loop_return_t_s": float(traj.stamps[j] - traj.stamps[0]),
    }
