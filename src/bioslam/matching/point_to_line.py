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
from dataclasses import dataclass, field

import numpy as np
from numba import njit
from numpy.typing import ArrayLike, NDArray

from bioslam.geometry import wrap_angle

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
#: A direction with more than this component along one the lines do not constrain is not
#: pinned by them (:meth:`LineFit.position_sigma`); below it, the component is the free
#: direction's tilt by the points' noise (across a corridor: 1e-3).
UNPINNED_SHARE = 0.05
#: Metres per radian when the heading's constraint is compared with the position's.
LENGTH_SCALE = 1.0


@dataclass(frozen=True)
class PointIndex:
    """Points binned into square cells (a counting sort by cell): the points of cell
    (col, row) are ``order[starts[k]:starts[k + 1]]``, ``k = row * width + col``, the
    cells counted from ``origin``. A submap's few thousand points are searched within a
    few cells of a query point in compiled code, where a k-d tree's queries cost a
    Python call and its result arrays each time (the polish iterates a dozen times)."""

    origin: FloatArray
    cell: float
    width: int
    height: int
    order: NDArray[np.int64]
    starts: NDArray[np.int64]

    @classmethod
    def build(cls, points: FloatArray, cell: float) -> PointIndex:
        """The index of ``points`` (n, 2) in cells of ``cell`` metres, coarsened where the
        points spread so far that the cells would number more than ``MAX_CELLS`` a side."""
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        if pts.shape[0] == 0:
            return cls(np.zeros(2), cell, 1, 1, np.zeros(0, np.int64), np.zeros(2, np.int64))
        origin = pts.min(axis=0)
        extent = float(np.max(pts.max(axis=0) - origin))
        cell = max(cell, extent / MAX_CELLS)
        width, height = (int((pts.max(axis=0)[k] - origin[k]) / cell) + 1 for k in range(2))
        order, starts = _bin_points(pts, origin[0], origin[1], cell, width, height)
        return cls(origin, cell, width, height, order, starts)

    def arrays(self) -> tuple:
        """The index as the compiled kernels take it."""
        return (self.order, self.starts, self.origin[0], self.origin[1], self.cell,
                self.width, self.height)  # fmt: skip


#: The most cells a :class:`PointIndex` has a side (a 25 cm cell over 500 m).
MAX_CELLS = 2048


@njit(cache=True)
def _bin_points(points, x0, y0, cell, width, height):
    """:meth:`PointIndex.build`'s counting sort: (order, starts)."""
    n = points.shape[0]
    keys = np.empty(n, dtype=np.int64)
    starts = np.zeros(width * height + 1, dtype=np.int64)
    for i in range(n):
        col = min(int((points[i, 0] - x0) / cell), width - 1)
        row = min(int((points[i, 1] - y0) / cell), height - 1)
        keys[i] = row * width + col
        starts[keys[i] + 1] += 1
    for k in range(width * height):
        starts[k + 1] += starts[k]
    filled = starts[:-1].copy()
    order = np.empty(n, dtype=np.int64)
    for i in range(n):
        order[filled[keys[i]]] = i
        filled[keys[i]] += 1
    return order, starts


@njit(cache=True)
def _cells_near(index, x, y, radius):
    """The rows [r0, r1) and columns [c0, c1) of ``index``'s cells that hold every point
    nearer than ``radius`` to (x, y)."""
    x0, y0, cell, width, height = index[2], index[3], index[4], index[5], index[6]
    return (max(math.floor((y - radius - y0) / cell), 0),
            min(math.floor((y + radius - y0) / cell) + 1, height),
            max(math.floor((x - radius - x0) / cell), 0),
            min(math.floor((x + radius - x0) / cell) + 1, width))  # fmt: skip


@njit(cache=True)
def _nearest_k(points, index, x, y, radius, found, dist2):
    """The ``found.size`` points of ``index`` nearest (x, y), nearer than ``radius``, into
    ``found`` nearest first, their squared distances into ``dist2``; returns how many.
    Kept by insertion into the short sorted list: in clutter hundreds of points may lie
    within the radius, and sorting them all cost ten times a k-d tree's query."""
    order, starts, width = index[0], index[1], index[5]
    r0, r1, c0, c1 = _cells_near(index, x, y, radius)
    k = found.size
    limit = radius * radius
    count = 0
    for r in range(r0, r1):
        for c in range(c0, c1):
            cell = r * width + c
            for t in range(starts[cell], starts[cell + 1]):
                j = order[t]
                dx = points[j, 0] - x
                dy = points[j, 1] - y
                d2 = dx * dx + dy * dy
                if d2 >= limit or (count == k and d2 >= dist2[k - 1]):
                    continue
                slot = min(count, k - 1)
                while slot > 0 and dist2[slot - 1] > d2:
                    found[slot] = found[slot - 1]
                    dist2[slot] = dist2[slot - 1]
                    slot -= 1
                found[slot] = j
                dist2[slot] = d2
                count = min(count + 1, k)
    return count


@dataclass(frozen=True)
class LineMap:
    """Map points binned for finding the nearest (:class:`PointIndex`), each with the line
    fitted to its neighbours: a point on it (their centroid: a line through the noisy point
    itself would carry its noise whole) and its normal (zero where they form no line)."""

    points: FloatArray
    anchors: FloatArray
    normals: FloatArray
    index: PointIndex

    @classmethod
    def build(cls, points: ArrayLike, radius: float = LINE_RADIUS) -> LineMap:
        """The line map of ``points`` (n, 2), each one's line fitted to its nearest
        neighbours within ``radius`` (m)."""
        pts = np.ascontiguousarray(np.asarray(points, dtype=np.float64).reshape(-1, 2))
        index = PointIndex.build(pts, radius)
        return cls(pts, *local_lines(pts, radius, index), index)


def local_lines(
    points: FloatArray, radius: float, index: PointIndex | None = None
) -> tuple[FloatArray, FloatArray]:
    """The lines fitted to each point's ``NEIGHBOURS`` nearest neighbours within ``radius``:
    (n, 2) centroids and (n, 2) unit normals, zero where fewer than three lie there or they
    spread more than ``MAX_THICKNESS`` across their line. ``index``: the points' own
    :class:`PointIndex`, else built here."""
    pts = np.ascontiguousarray(np.asarray(points, dtype=np.float64).reshape(-1, 2))
    index = index or PointIndex.build(pts, radius)
    return _fit_lines(pts, index.arrays(), radius, NEIGHBOURS, MAX_THICKNESS)


@njit(cache=True)
def _fit_lines(points, index, radius, neighbours, thickness):
    """:func:`local_lines` in compiled code: each point's nearest ``neighbours`` within
    ``radius``, nearest first."""
    n = points.shape[0]
    anchors = points.copy()
    normals = np.zeros((n, 2))
    found = np.empty(neighbours, dtype=np.int64)
    dist2 = np.empty(neighbours)
    for i in range(n):
        count = _nearest_k(points, index, points[i, 0], points[i, 1], radius, found, dist2)
        if count < 3:
            continue
        mx, my = 0.0, 0.0
        for j in found[:count]:
            mx += points[j, 0]
            my += points[j, 1]
        mx /= count
        my /= count
        sxx, sxy, syy = 0.0, 0.0, 0.0
        for j in found[:count]:
            dx = points[j, 0] - mx
            dy = points[j, 1] - my
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
    them; ``information``: the matched points' Huber-weighted Gauss-Newton information
    (x, y, and the heading times ``LENGTH_SCALE``) at the last step, per unit residual
    variance."""

    pose: FloatArray
    matched: int
    spread: float
    information: FloatArray = field(default_factory=lambda: np.zeros((3, 3)))

    def position_sigma(self, direction: ArrayLike) -> float:
        """The fit's standard deviation (m) of the position along ``direction`` (a unit
        vector in the frame of its ``pose``'s map), the heading left free: the residuals'
        spread over the lines' information there. Infinite where the lines do not pin it
        (along a corridor with no wall across it: the fit moves only in the directions they
        constrain, ``MIN_CONSTRAINT``)."""
        if not math.isfinite(self.spread):
            return math.inf
        u = np.zeros(3)
        u[:2] = np.asarray(direction, dtype=np.float64).reshape(2)
        values, vectors = np.linalg.eigh(self.information)
        pinned = values > _constraint_floor(values)
        along = vectors.T @ u
        if np.any(np.abs(along[~pinned]) > UNPINNED_SHARE):
            return math.inf
        return self.spread * math.sqrt(float(np.sum(along[pinned] ** 2 / values[pinned])))


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
    pts = np.ascontiguousarray(np.asarray(query, dtype=np.float64).reshape(-1, 2))
    residual = np.zeros(0)
    information = np.zeros((3, 3))
    lines = (line_map.points, line_map.anchors, line_map.normals, line_map.index.arrays())
    for _ in range(max_iterations):
        step, residual, information = _line_step(*lines, pose, pts, max_distance, huber)
        if residual.size < 3:
            break
        pose = pose + step
        pose[2] = wrap_angle(float(pose[2]))
        if math.hypot(step[0], step[1]) + LENGTH_SCALE * abs(step[2]) < tolerance:
            break
    spread = 1.4826 * float(np.median(np.abs(residual))) if residual.size else math.inf
    return LineFit(pose, int(residual.size), spread, information)


@njit(cache=True)
def _constraint_floor(values):
    """The information along a direction below which the matched lines do not constrain
    it: ``MIN_CONSTRAINT`` of the best-constrained one's (``values``: the information's
    eigenvalues, ascending)."""
    return MIN_CONSTRAINT * max(values[2], 1e-12)


@njit(cache=True)
def _line_step(points, anchors, normals, index, pose, pts, max_distance, huber):
    """One Gauss-Newton step of :func:`refine_point_to_line`, the residuals of the points it
    matched (m) and their information (the Gauss-Newton Hessian); a zero step when fewer
    than three points match."""
    c, s = math.cos(pose[2]), math.sin(pose[2])
    residual = np.empty(pts.shape[0])
    hessian = np.zeros((3, 3))
    gradient = np.zeros(3)
    jac = np.empty(3)
    nearest, dist2 = np.empty(1, dtype=np.int64), np.empty(1)
    matched = 0
    for i in range(pts.shape[0]):
        # the point's offset from the sensor, turned; d(world)/dθ is it turned a quarter
        lx = c * pts[i, 0] - s * pts[i, 1]
        ly = s * pts[i, 0] + c * pts[i, 1]
        wx, wy = lx + pose[0], ly + pose[1]
        if _nearest_k(points, index, wx, wy, max_distance, nearest, dist2) == 0:
            continue
        j = nearest[0]
        if normals[j, 0] == 0.0 and normals[j, 1] == 0.0:
            continue
        nx, ny = normals[j, 0], normals[j, 1]
        r = nx * (wx - anchors[j, 0]) + ny * (wy - anchors[j, 1])
        residual[matched] = r
        matched += 1
        weight = min(1.0, huber / max(abs(r), 1e-12))
        jac[0], jac[1], jac[2] = nx, ny, (ny * lx - nx * ly) / LENGTH_SCALE
        for a in range(3):
            gradient[a] += jac[a] * weight * r
            for b in range(3):
                hessian[a, b] += jac[a] * weight * jac[b]
    step = np.zeros(3)
    if matched < 3:
        return step, residual[:matched], hessian
    values, vectors = np.linalg.eigh(hessian)
    floor = _constraint_floor(values)
    for k in range(3):
        if values[k] > floor:
            along = (vectors[0, k] * gradient[0] + vectors[1, k] * gradient[1]
                     + vectors[2, k] * gradient[2]) / values[k]  # fmt: skip
            for a in range(3):
                step[a] -= vectors[a, k] * along
    step[2] /= LENGTH_SCALE
    return step, residual[:matched], hessian


__all__ = ["LineFit", "LineMap", "PointIndex", "local_lines", "refine_point_to_line"]
