"""Loop consistency for logs without a reference trajectory.

Definition (documented in benchmarks/README.md): a trajectory *goes away* once its position is
``away_m`` or more from its first pose; it *returns* at the later pose nearest to the first one.
The loop gap is the distance between the first pose and that return pose (m), with the heading
difference (deg) and the time of the return. A system that drifts reports a larger gap, one
that relocalises at the start a smaller one; a trajectory that never goes away has no gap.

A sensor-only return moment (the scan that best matches the first scan) was tried first and
dropped: in corridors and mazes the best-matching scan is often an aliased place metres away.

The gap alone cannot tell drift from where the route really ended: a handheld scanner brought
back 14 cm from where it started has a 14 cm gap however good the trajectory. The *return
misfit* separates them: the return scan registered (the closure verification's wide-basin
search and refinement) against the scans of the route's first metres, fused at the
trajectory's own poses; the correction that registration makes to the trajectory's return pose
is the trajectory's inconsistency there, near zero for one that did not drift.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from bioslam.closure import SeenArea, fuse_submap, verify
from bioslam.config import LoopClosureConfig
from bioslam.geometry import between, wrap_angle
from bioslam.scan import LaserScan
from bioslam.trajectory import Trajectory


@dataclass
class LoopConfig:
    """``away_m``: how far from the start a route must get before a return counts (1 m: well
    above the centimetre gaps a consistent system leaves, and below the 1.4 m a short handheld
    log such as the ROS 1 demo bag moves away)."""

    away_m: float = 1.0
    #: the return misfit's reference: the scans of the route's first this many metres
    start_m: float = 2.0
    #: ... and the window (m, rad) its registration searches around the return pose
    window: tuple[float, float] = (1.0, np.radians(30.0))
    #: ... and the share of its points on the start's walls it must reach to count: a
    #: measurement, not a closure, so below the closures' ``min_score`` (a cluttered room
    #: seen by a short-range scanner fits at 0.6-0.75 where it is right); the verification's
    #: rival tests still apply
    min_score: float = 0.6


def _return_index(traj: Trajectory, cfg: LoopConfig) -> tuple[int | None, np.ndarray]:
    """The index of the return pose (None when the route never goes away) and every pose's
    distance from the first."""
    dist = np.hypot(*(traj.poses[:, :2] - traj.poses[0, :2]).T)
    away = np.flatnonzero(dist >= cfg.away_m)
    return (None if away.size == 0 else int(away[0] + np.argmin(dist[away[0] :]))), dist


def loop_gap(traj: Trajectory, cfg: LoopConfig | None = None) -> dict[str, float]:
    """``loop_gap_m``, ``loop_gap_deg``, ``loop_return_t_s`` and ``max_excursion_m``."""
    cfg = cfg or LoopConfig()
    if len(traj) < 2:
        raise ValueError("a trajectory of fewer than two poses has no loop")
    j, dist = _return_index(traj, cfg)
    out = {"max_excursion_m": float(dist.max())}
    if j is None:
        return {**out, "loop_gap_m": float("nan"), "loop_gap_deg": float("nan")}
    return {
        **out,
        "loop_gap_m": float(dist[j]),
        "loop_gap_deg": float(np.degrees(abs(wrap_angle(traj.poses[j, 2] - traj.poses[0, 2])))),
        "loop_return_t_s": float(traj.stamps[j] - traj.stamps[0]),
    }


def return_misfit(
    traj: Trajectory, scans: Sequence[LaserScan], cfg: LoopConfig | None = None
) -> dict[str, float | str]:
    """The correction (``misfit_m``, ``misfit_deg``) that registering the return scan against
    the route's first ``start_m`` metres of scans, fused at ``traj``'s poses (one pose per
    scan), makes to ``traj``'s return pose, with the registration's ``score`` and, when the
    verification would refuse it as a closure, its ``reason`` (a low score or a rival: the
    misfit is then not measured). NaN when the route never goes away."""
    cfg = cfg or LoopConfig()
    if len(scans) != len(traj):
        raise ValueError(f"{len(scans)} scans for a trajectory of {len(traj)} poses")
    j, _ = _return_index(traj, cfg)
    if j is None:
        return {"misfit_m": float("nan"), "misfit_deg": float("nan"), "score": float("nan")}
    step = np.hypot(*np.diff(traj.poses[:, :2], axis=0).T)
    travelled = np.concatenate([[0.0], np.cumsum(step)])
    members = [int(i) for i in np.flatnonzero(travelled[:j] <= cfg.start_m)]
    payloads: list[np.ndarray | None] = [None] * j  # only the start's scans are read
    for i in members:
        payloads[i] = scans[i].endpoints()
    poses = traj.poses[:j]
    closure = LoopClosureConfig(min_score=cfg.min_score)
    reference = fuse_submap(poses, payloads, 0, members, closure.submap_spacing)
    reg = closure.registration
    seen = SeenArea(poses, payloads, 0, members, reg.resolution * 2**reg.score_level)
    predicted = between(traj.poses[0], traj.poses[j])
    verdict = verify(reference, scans[j].endpoints(), predicted, cfg.window, closure, seen)
    # what the verification alone would refuse for: the window here is no drift bound
    measured = verdict.reason in ("", "beyond drift")
    misfit = between(predicted, verdict.pose)
    return {
        "misfit_m": float(np.hypot(misfit[0], misfit[1])) if measured else float("nan"),
        "misfit_deg": float(np.degrees(abs(wrap_angle(misfit[2])))) if measured else float("nan"),
        "score": float(verdict.score),
        "reason": "" if measured else verdict.reason,
    }
