"""Thinning a log to one scan per distance or angle travelled.

The public "corrected" logs (Intel, the Freiburg and MIT CARMEN logs of the Radish repository)
keep a scan only after the robot has moved some distance or turned some angle since the last
one kept, so consecutive scans are up to a metre and tens of degrees apart. Thinning any log the
same way (by its ground truth, its reference, or its odometry) makes such data from logs and
simulations whose truth is known.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from bioslam.geometry import wrap_angle

# Thresholds are reached when within this of them: a metre in ten steps of 0.1 m is a metre.
_TOLERANCE = 1e-9


def thin_indices(
    poses: ArrayLike, distance: float | None = None, angle: float | None = None
) -> NDArray[np.int64]:
    """Indices of the scans to keep, given each scan's pose ``(N, 3)``: the first, then each
    scan at which the robot has travelled at least ``distance`` metres (along its path) or
    turned at least ``angle`` radians (summed absolute heading change) since the last scan
    kept. ``None`` disables a criterion; at least one must be given, positive.

    Both are measured along the path, as a robot's odometry accumulates them (a robot spinning
    on the spot turns, one driving a circle travels), not as the displacement between the two
    scans.
    """
    if distance is None and angle is None:
        raise ValueError("thinning needs a distance or an angle (or both)")
    for name, value in (("distance", distance), ("angle", angle)):
        if value is not None and not value > 0.0:
            raise ValueError(f"thinning {name} must be positive, got {value}")
    p = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
    if len(p) == 0:
        return np.zeros(0, dtype=np.int64)
    travelled = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(p[:, :2], axis=0).T))])
    turned = np.concatenate([[0.0], np.cumsum(np.abs(wrap_angle(np.diff(p[:, 2]))))])
    keep = [0]
    n = len(p)
    while True:
        last = keep[-1]
        nxt = n
        if distance is not None:
            nxt = min(nxt, _first_reaching(travelled, travelled[last] + distance, last))
        if angle is not None:
            nxt = min(nxt, _first_reaching(turned, turned[last] + angle, last))
        if nxt >= n:
            return np.asarray(keep, dtype=np.int64)
        keep.append(nxt)


def _first_reaching(cumulative: NDArray, target: float, after: int) -> int:
    """First index past ``after`` where the non-decreasing ``cumulative`` reaches ``target``
    (``len(cumulative)`` if it never does)."""
    return max(int(np.searchsorted(cumulative, target - _TOLERANCE, side="left")), after + 1)
