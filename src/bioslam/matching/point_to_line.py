"""Point-to-line refinement of a registration against the points of a map, not a grid.

Gauss-Newton on an occupancy grid (Eq. 3) reads the bilinear map function, a blur a cell
wide: two parallel walls a few cells apart, or a wall and a corner beside it, pull the
optimum a fraction of a cell off the truth, and the pull is alike for every revisit of a
place (the rooms' SICK reversing route: its loop links off by alike 3-4 mm along the
direction each scan pins best). Matching each point to the line through its nearest map
points has no such blur: the residual is the point's distance to the wall itself.

The refinement only polishes: it starts from a registration already within a cell or two,
and its caller keeps the grid's pose where the two disagree by more than that.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numba import njit
from numpy.typing import ArrayLike, NDArray

from bioslam.geometry import transform_points, wrap_angle

if TYPE_CHECKING:
    from scipy.spatial import cKDTree

FloatArray = NDArray[np.float64]

#: Map points whose neighbourhood is at most this thick across its line (smallest / largest
#: spread) have a normal; corners and clutter have none and are not matched.
MAX_THICKNESS = 0.3
#: Neighbours (including the point itself) a map point's line is fitted to, within
#: ``LINE_RADIUS`` (m): a line fitted over a few centimetres tilts with the scanner's noise
#: (over 6 points, 0.15 m: the corridor test's pose 4 mm off, against 1.3 mm over 16), and
#: a low-cost scanner's (3 cm) needs the longer reach (simulated hall, 12 revisits: polished
#: 4.0 mm off over 0.15 m, 2.2 mm over 0.25 m, the grid 4.8 mm).
NEIGHBOURS = 24
LINE_RADIUS = 0.25
#: A direction of the pose is updated only where the matched lines constrain it at least
#: this share of the best-constrained one (the heading scaled by ``LENGTH_SCALE``): along a
#: corridor nothing pins the position, and noise would move it.
MIN_CONSTRAINT = 1e-3
#: Metres per radian when the heading's constraint is compared with the position's.
LENGTH_SCALE = 1.0


@dataclass(frozen=True)
class LineMap:
    """Map points in a k-d tree to find the nearest, each with the line fitted to its
    neighbours: a point on it (their centroid: a line through the noisy point itself would
    carry its noise whole) and its normal (zero where they form no line)."""

    anchors: FloatArray
    normals: FloatArray
    tree: cKDTree

    @classmethod
    def build(cls, points: ArrayLike, radius: float = LINE_RADIUS) -> LineMap:
        """The line map of ``points`` (n, 2), each one's line fitted to its nearest
        neighbours within ``radius`` (m)."""
        # SciPy is imported only where a run polishes a closure
        from scipy.spatial import cKDTree

        pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        tree = cKDTree(pts)
        return cls(*local_lines(pts, tree, radius), tree)


def local_lines(points: FloatArray, tree: cKDTree, radius: float) -> tuple[FloatArray, FloatArray]:
    """The lines fitted to each point's ``NEIGHBOURS`` nearest neighbours within ``radius``:
    (n, 2) centroids and (n, 2) unit normals, zero where fewer than three lie there or they
    spread more than ``MAX_THICKNESS`` across their line."""
    n = points.shape[0]
    if n < 3:
        return points.copy(), np.zeros((n, 2))
    dist, idx = tree.query(points, k=min(NEIGHBOURS, n), distance_upper_bound=radius)
    return _fit_lines(points, np.asarray(idx, dtype=np.int64), np.isfinite(dist), MAX_THICKNESS)


@njit(cache=True)
def _fit_lines(
    points: FloatArray, idx: NDArray[np.int64], found: NDArray[np.bool_], thickness: float
) -> tuple[FloatArray, FloatArray]:
    """:func:`local_lines` from each point's neighbours (``idx`` where ``found``)."""
    n = points.shape[0]
    anchors = points.copy()
    normals = np.zeros((n, 2))
    for i in range(n):
        count, mx, my = 0, 0.0, 0.0
        for j in range(idx.shape[1]):
            if found[i, j]:
                count += 1
                mx += points[idx[i, j], 0]
                my += points[idx[i, j], 1]
        if count < 3:
            continue
        mx /= count
        my /= count
        sxx, sxy, syy = 0.0, 0.0, 0.0
        for j in range(idx.shape[1]):
            if found[i, j]:
                dx = points[idx[i, j], 0] - mx
                dy = points[idx[i, j], 1] - my
                sxx += dx * dx
                sxy += dx * dy
                syy += dy * dy
        half_trace = 0.5 * (sxx + syy)
        spread = math.hypot(0.5 * (sxx - syy), sxy)
        along, across = half_trace + spread, half_trace - spread
        anchors[i, 0], anchors[i, 1] = mx, my
        if along > 0.0 and across <= thickness * thickness * along:
            axis = 0.5 * math.atan2(2.0 * sxy, sxx - syy)
            normals[i, 0], normals[i, 1] = -math.sin(axis), math.cos(axis)
    return anchors, normals


@dataclass(frozen=True)
class LineFit:
    """A :func:`refine_point_to_line` result: the pose, the points matched to a line at its
    last step, and their residuals' robust spread (m, 1.4826 times the median absolute
    distance to their lines): the scanner's noise and the walls' roughness as the lines see
    them."""

    pose: FloatArray
    matched: int
    spread: float


def refine_point_to_line(
    line_map: LineMap,
    start: ArrayLike,
    query: ArrayLike,
    max_distance: float,
    huber: float,
    max_iterations: int = 20,
    tolerance: float = 1e-5,
) -> LineFit:
    """The pose (x, y, θ) of sensor-frame ``query`` points in ``line_map``'s frame that
    minimises their robust (Huber, ``huber`` m) distances to the lines of their nearest map
    points within ``max_distance``, by Gauss-Newton from ``start``. The pose moves only in
    the directions the matched lines constrain (``MIN_CONSTRAINT``): along a corridor it
    keeps ``start``'s position."""
    pose = np.asarray(start, dtype=np.float64).copy()
    pts = np.asarray(query, dtype=np.float64).reshape(-1, 2)
    residual = np.zeros(0)
    for _ in range(max_iterations):
        step, residual = _line_step(line_map, pose, pts, max_distance, huber)
        if step is None:
            break
        pose = pose + step
        pose[2] = float(wrap_angle(pose[2]))
        if np.hypot(step[0], step[1]) + LENGTH_SCALE * abs(step[2]) < tolerance:
            break
    spread = 1.4826 * float(np.median(np.abs(residual))) if residual.size else math.inf
    return LineFit(pose, int(residual.size), spread)


def _line_step(
    line_map: LineMap, pose: FloatArray, pts: FloatArray, max_distance: float, huber: float
) -> tuple[FloatArray | None, FloatArray]:
    """One Gauss-Newton step of :func:`refine_point_to_line` and the residuals of the
    points it matched (m); no step when fewer than three points match."""
    world = transform_points(pose, pts)
    dist, idx = line_map.tree.query(world, distance_upper_bound=max_distance)
    ok = np.isfinite(dist)
    ok[ok] = np.any(line_map.normals[idx[ok]] != 0.0, axis=1)
    normal = line_map.normals[idx[ok]]
    offset = world[ok] - line_map.anchors[idx[ok]]
    residual = np.einsum("ij,ij->i", normal, offset)
    if residual.size < 3:
        return None, residual
    # d(world)/dθ is the point's offset from the sensor turned a quarter
    lever = world[ok] - pose[:2]
    jacobian = np.column_stack(
        [normal[:, 0], normal[:, 1], normal[:, 1] * lever[:, 0] - normal[:, 0] * lever[:, 1]]
    )
    weight = np.minimum(1.0, huber / np.maximum(np.abs(residual), 1e-12))
    scale = np.array([1.0, 1.0, 1.0 / LENGTH_SCALE])
    scaled = jacobian * scale
    hessian = scaled.T @ (scaled * weight[:, None])
    gradient = scaled.T @ (weight * residual)
    values, vectors = np.linalg.eigh(hessian)
    keep = values > MIN_CONSTRAINT * max(float(values[-1]), 1e-12)
    step = -(vectors[:, keep] @ ((vectors[:, keep].T @ gradient) / values[keep]))
    return step * scale, residual


__all__ = ["LineFit", "LineMap", "local_lines", "refine_point_to_line"]
