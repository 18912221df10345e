"""Log-odds occupancy grids, their multi-resolution pyramid and the continuous map function M*.

The map function is the one of Hector SLAM (Kohlbrecher et al. 2011, Sec. IV-A), which the paper
cites for the upsampled local map M* of its Eq. 3: cell values are occupancy probabilities at
the cell centres, M* interpolates them bilinearly and its gradient is the analytic derivative of
that interpolation.

Array layout: ``logodds[row, col]`` with row 0 at the lowest y; cell ``(row, col)`` covers
``[origin_x + col * res, origin_x + (col + 1) * res) x [origin_y + row * res, ...)``.

No file or terminal I/O here.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray

from bioslam.geometry import inverse, rotation, transform_points

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class LogOddsConfig:
    """How one observation changes a cell's log-odds.

    Defaults follow the ROS ``hector_mapping`` parameters ``update_factor_occupied = 0.9`` and
    ``update_factor_free = 0.4`` (log-odds of 0.9 and 0.4). The clamps are ours: a cell never
    gets so certain that a moved object (a door, a person) could not be erased again by a few
    dozen observations.
    """

    l_hit: float = math.log(0.9 / 0.1)
    l_miss: float = math.log(0.4 / 0.6)
    l_min: float = -8.0
    l_max: float = 8.0
    mean_memory: int = 32

    # ``mean_memory``: the sub-cell mean hit position of a cell averages at most this many
    # hits (a running mean that then turns exponential), so it follows a cell whose content
    # changes while averaging the range noise of ~30 observations (ours).


# --------------------------------------------------------------------------------------------
# Numba kernels


@numba.njit(cache=True)
def _cell_of(x: float, y: float, ox: float, oy: float, res: float) -> tuple[int, int]:
    return math.floor((y - oy) / res), math.floor((x - ox) / res)


@numba.njit(cache=True)
def above_near_point(logodds, x, y, ox, oy, res, level):
    """Whether the cell of world point (x, y) or one of its 8 neighbours has a log-odds above
    ``level`` (a Numba helper for kernels over scan points). Cells beyond the grid are
    unknown (log-odds 0): clamped to its border instead, the far endpoints of a long-range
    scanner, past a local map's edge, counted as landing where the map saw free space
    (simulated hall, SICK: a fifth of every scan's endpoints, and its matches failed)."""
    rows, cols = logodds.shape
    r0, c0 = _cell_of(x, y, ox, oy, res)
    for r in range(r0 - 1, r0 + 2):
        for c in range(c0 - 1, c0 + 2):
            inside = 0 <= r < rows and 0 <= c < cols
            if (logodds[r, c] if inside else 0.0) > level:
                return True
    return False


@numba.njit(cache=True)
def _above(logodds, world, ox, oy, res, level):
    rows, cols = logodds.shape
    out = np.zeros(world.shape[0], dtype=np.bool_)
    for k in range(world.shape[0]):
        r, c = _cell_of(world[k, 0], world[k, 1], ox, oy, res)
        out[k] = (logodds[r, c] if 0 <= r < rows and 0 <= c < cols else 0.0) > level
    return out


@numba.njit(cache=True)
def _above_near(logodds, world, ox, oy, res, level):
    out = np.zeros(world.shape[0], dtype=np.bool_)
    for k in range(world.shape[0]):
        out[k] = above_near_point(logodds, world[k, 0], world[k, 1], ox, oy, res, level)
    return out


@numba.njit(cache=True)
def _count_not_above_near(logodds, pts, x, y, theta, ox, oy, res, level):
    c = math.cos(theta)
    s = math.sin(theta)
    n = 0
    for k in range(pts.shape[0]):
        wx = c * pts[k, 0] - s * pts[k, 1] + x
        wy = s * pts[k, 0] + c * pts[k, 1] + y
        if not above_near_point(logodds, wx, wy, ox, oy, res, level):
            n += 1
    return n


@numba.njit(cache=True, inline="always")
def _bresenham_start(r0, c0, r1, c1):
    """Bresenham's line from cell (r0, c0) to (r1, c1): row and column deltas, steps and the
    initial error term, for ``_bresenham_step``."""
    dc = abs(c1 - c0)
    dr = -abs(r1 - r0)
    sc = 1 if c0 < c1 else -1
    sr = 1 if r0 < r1 else -1
    return dr, dc, sr, sc, dc + dr


@numba.njit(cache=True, inline="always")
def _bresenham_step(r, c, err, dr, dc, sr, sc):
    """One cell further along the line ``_bresenham_start`` began."""
    e2 = 2 * err
    if e2 >= dr:
        err += dr
        c += sc
    if e2 <= dc:
        err += dc
        r += sr
    return r, c, err


@numba.njit(cache=True)
def _ray_blocked(logodds, r0, c0, r1, c1, level):
    """Whether a cell above ``level`` lies on the Bresenham line from (r0, c0) to (r1, c1),
    both ends excluded (cells outside the grid count as unknown, not blocked)."""
    rows, cols = logodds.shape
    dr, dc, sr, sc, err = _bresenham_start(r0, c0, r1, c1)
    r, c = r0, c0
    while not (r == r1 and c == c1):
        r, c, err = _bresenham_step(r, c, err, dr, dc, sr, sc)
        if (r != r1 or c != c1) and 0 <= r < rows and 0 <= c < cols and logodds[r, c] > level:
            return True
    return False


@numba.njit(cache=True)
def _count_through_walls(logodds, pts, x, y, theta, ox, oy, res, level, margin):
    cos_t = math.cos(theta)
    sin_t = math.sin(theta)
    r0, c0 = _cell_of(x, y, ox, oy, res)
    n = 0
    for k in range(pts.shape[0]):
        px = pts[k, 0]
        py = pts[k, 1]
        rng = math.sqrt(px * px + py * py)
        if rng <= margin:
            continue
        f = (rng - margin) / rng  # stop short of the endpoint's own wall
        wx = cos_t * px * f - sin_t * py * f + x
        wy = sin_t * px * f + cos_t * py * f + y
        r1, c1 = _cell_of(wx, wy, ox, oy, res)
        if _ray_blocked(logodds, r0, c0, r1, c1, level):
            n += 1
    return n


@numba.njit(cache=True)
def _scroll_in_place(a, drow, dcol):
    """``a[r, c] = a[r + drow, c + dcol]`` for every cell, 0 where that lies outside ``a``,
    without a second array: rows are visited in the order that reads each row before it is
    overwritten, and a row that only moves sideways goes through a one-row buffer."""
    rows, cols = a.shape
    lo, hi = max(-dcol, 0), min(cols, cols - dcol)  # the columns that keep a value
    buffer = np.empty(max(hi - lo, 0), dtype=a.dtype)
    for k in range(rows):
        r = k if drow >= 0 else rows - 1 - k
        src = r + drow
        if src < 0 or src >= rows or hi <= lo:
            a[r, :] = 0
            continue
        if src == r:
            buffer[:] = a[src, lo + dcol : hi + dcol]
            a[r, lo:hi] = buffer
        else:
            a[r, lo:hi] = a[src, lo + dcol : hi + dcol]
        a[r, :lo] = 0
        a[r, hi:] = 0


@numba.njit(cache=True)
def _add_clamped(grid, r, c, delta, lo, hi) -> None:
    v = grid[r, c] + delta
    if v < lo:
        v = lo
    elif v > hi:
        v = hi
    grid[r, c] = v


@numba.njit(cache=True)
def _insert_scan_kernel(
    logodds, stamps, means, hits, weights, stamp, ox, oy, res, sx, sy, world_pts, normals,
    l_hit, l_miss, l_min, l_max, memory, subcell, rays,
) -> None:  # fmt: skip
    rows, cols = logodds.shape
    n = world_pts.shape[0]
    # Hits first and stamped, so that a ray grazing a wall cell in the same scan does not erase
    # it, and every cell gets at most one log-odds update per scan (Hector's update index).
    for k in range(n):
        x = world_pts[k, 0]
        y = world_pts[k, 1]
        r, c = _cell_of(x, y, ox, oy, res)
        if not (0 <= r < rows and 0 <= c < cols):
            continue
        if stamps[r, c] != stamp:
            stamps[r, c] = stamp
            _add_clamped(logodds, r, c, l_hit, l_min, l_max)
            if subcell:
                weights[r, c] = _prob(logodds[r, c])
        if not subcell:
            continue
        if hits[r, c] < memory:
            hits[r, c] += 1
        w = 1.0 / hits[r, c]
        means[r, c, 0] += w * ((x - ox - c * res) - means[r, c, 0])
        means[r, c, 1] += w * ((y - oy - r * res) - means[r, c, 1])
        means[r, c, 2] += w * (normals[k, 0] - means[r, c, 2])
        means[r, c, 3] += w * (normals[k, 1] - means[r, c, 3])
    if not rays:
        return
    r0, c0 = _cell_of(sx, sy, ox, oy, res)
    for k in range(n):
        r1, c1 = _cell_of(world_pts[k, 0], world_pts[k, 1], ox, oy, res)
        # Bresenham from the sensor cell to the endpoint cell, the endpoint excluded.
        dr, dc, sr, sc, err = _bresenham_start(r0, c0, r1, c1)
        r, c = r0, c0
        while not (r == r1 and c == c1):
            if 0 <= r < rows and 0 <= c < cols:
                if stamps[r, c] != stamp:
                    stamps[r, c] = stamp
                    _add_clamped(logodds, r, c, l_miss, l_min, l_max)
                    if subcell and hits[r, c] > 0:
                        weights[r, c] = _prob(logodds[r, c])
            elif (r < 0 and sr < 0) or (r >= rows and sr > 0) or (c < 0 and sc < 0) or (
                c >= cols and sc > 0
            ):
                break  # left the grid for good
            r, c, err = _bresenham_step(r, c, err, dr, dc, sr, sc)


# Surface normals average the endpoints within this radius, enough to turn 1-3 cm range
# noise into a few degrees of normal error, along runs without gaps above NORMAL_MAX_GAP.
NORMAL_RADIUS = 0.15
# An endpoint draws on a cell scaled by min(1, FACE_SLOPE * (1 + n_endpoint . n_cell)): fully
# until their normals are 120° apart, not at all when they face each other (subcell_point).
FACE_SLOPE = 2.0
NORMAL_MAX_GAP = 0.3


@numba.njit(cache=True)
def scan_normals(pts, radius, max_gap):
    """Unit surface normals ``(N, 2)`` of endpoints given in scan order, pointing towards the
    sensor at the origin: the principal axis of the run of scan neighbours within ``radius``
    of the endpoint (no gap between consecutive ones above ``max_gap``), metres. Zero where
    fewer than 3 neighbours or the run is not line-like (no direction there). (No default
    arguments: Numba dispatches calls that omit some through a slow Python path.)"""
    n = pts.shape[0]
    out = np.zeros((n, 2))
    r2 = radius * radius
    g2 = max_gap * max_gap
    for k in range(n):
        lo = k
        while lo > 0:
            dx = pts[lo - 1, 0] - pts[lo, 0]
            dy = pts[lo - 1, 1] - pts[lo, 1]
            ex = pts[lo - 1, 0] - pts[k, 0]
            ey = pts[lo - 1, 1] - pts[k, 1]
            if dx * dx + dy * dy > g2 or ex * ex + ey * ey > r2:
                break
            lo -= 1
        hi = k
        while hi < n - 1:
            dx = pts[hi + 1, 0] - pts[hi, 0]
            dy = pts[hi + 1, 1] - pts[hi, 1]
            ex = pts[hi + 1, 0] - pts[k, 0]
            ey = pts[hi + 1, 1] - pts[k, 1]
            if dx * dx + dy * dy > g2 or ex * ex + ey * ey > r2:
                break
            hi += 1
        m = hi - lo + 1
        if m < 3:
            continue
        mx = 0.0
        my = 0.0
        for j in range(lo, hi + 1):
            mx += pts[j, 0]
            my += pts[j, 1]
        mx /= m
        my /= m
        cxx = 0.0
        cxy = 0.0
        cyy = 0.0
        for j in range(lo, hi + 1):
            dx = pts[j, 0] - mx
            dy = pts[j, 1] - my
            cxx += dx * dx
            cxy += dx * dy
            cyy += dy * dy
        # the normal is the eigenvector of the smaller eigenvalue of the 2x2 covariance
        tr = cxx + cyy
        disc = math.sqrt(max(0.25 * tr * tr - (cxx * cyy - cxy * cxy), 0.0))
        lmin = 0.5 * tr - disc
        lmax = 0.5 * tr + disc
        if lmax <= 0.0 or lmin > 0.1 * lmax:
            continue
        if abs(cxy) > 1e-12 * tr:
            nx = cxy
            ny = lmin - cxx
        elif cxx <= cyy:
            nx, ny = 1.0, 0.0
        else:
            nx, ny = 0.0, 1.0
        norm = math.hypot(nx, ny)
        nx /= norm
        ny /= norm
        if nx * pts[k, 0] + ny * pts[k, 1] > 0.0:
            nx = -nx
            ny = -ny
        out[k, 0] = nx
        out[k, 1] = ny
    return out


@numba.njit(cache=True)
def subsample_by_spacing(pts, spacing):
    """Keep endpoints at least ``spacing`` from the previously kept one (scan order)."""
    n = pts.shape[0]
    keep = np.zeros(n, dtype=np.bool_)
    if n == 0:
        return keep
    keep[0] = True
    lx, ly = pts[0, 0], pts[0, 1]
    s2 = spacing * spacing
    for k in range(1, n):
        dx = pts[k, 0] - lx
        dy = pts[k, 1] - ly
        if dx * dx + dy * dy >= s2:
            keep[k] = True
            lx, ly = pts[k, 0], pts[k, 1]
    return keep


# A surface counts as running along a grid axis when its normal is within 45° of the other.
_AXIS_FACING = math.cos(math.pi / 4)
# Surface points within this fraction of a cell of a cell edge get a twin across it: range
# noise of 1-3 cm spreads a wall's hits over both sides of an edge that near, and the twin,
# on the edge, stays that close to the measured wall.
_EDGE_BAND = 0.25
# How far past a cell edge a twin is put (metres): inside the neighbour, not on the edge.
_TWIN_MARGIN = 1e-3


def edge_twins(
    world: FloatArray, world_normals: FloatArray, origin: FloatArray, resolution: float
) -> tuple[FloatArray, FloatArray]:
    """Copies of surface points ``world`` (grid frame, with their unit ``world_normals``)
    that lie within a quarter cell of a cell edge across their surface (the axis the
    surface faces: its normal within 45° of it), moved just across that edge, and their
    normals: the cells either side of the edge then both hold the surface. Range noise
    spreads the hits of a wall that runs along an edge over both sides of it only over many
    scans; one scan holds it on one side or the other, where each beam happened to land,
    and another scan's endpoints on it score by that pattern (:func:`subcell_point` blends
    the four cells around a point)."""
    moved, normals = [], []
    for axis in (0, 1):
        u = (world[:, axis] - origin[axis]) / resolution
        frac = u - np.floor(u)
        near = np.minimum(frac, 1.0 - frac) <= _EDGE_BAND
        keep = near & (np.abs(world_normals[:, axis]) > _AXIS_FACING)
        twins = world[keep]
        twins[:, axis] += np.where(frac[keep] < 0.5, -frac[keep] * resolution - _TWIN_MARGIN,
                                   (1.0 - frac[keep]) * resolution + _TWIN_MARGIN)  # fmt: skip
        moved.append(twins)
        normals.append(world_normals[keep])
    return np.vstack(moved), np.vstack(normals)


def thinned_normals(
    points: FloatArray, keep: NDArray[np.bool_] | None = None, spacing: float = 0.05
) -> FloatArray:
    """Surface normals of all endpoints, computed on the thinned ones (``keep``) and passed
    on to the raw endpoints that follow each in scan order: on dense scans the neighbour
    windows of the raw points are long and the cost of the normals grows with their square,
    while at the thinning spacing (a few cm) the normal of a wall does not change. Without
    ``keep`` the endpoints are thinned to ``spacing`` metres (:func:`subsample_by_spacing`)."""
    if keep is None:
        keep = subsample_by_spacing(points, spacing)
    return _spread_normals(np.ascontiguousarray(points, dtype=np.float64), keep)


@numba.njit(cache=True)
def _spread_normals(points, keep):
    sub = scan_normals(points[keep], NORMAL_RADIUS, NORMAL_MAX_GAP)
    out = np.zeros_like(points)
    if sub.shape[0] == 0:
        return out
    owner = -1
    for k in range(points.shape[0]):
        if keep[k]:
            owner += 1
        j = max(owner, 0)
        out[k, 0] = sub[j, 0]  # (element-wise: a row slice per point costs 30 ns)
        out[k, 1] = sub[j, 1]
    return out


@numba.njit(cache=True)
def _prob(logodd: float) -> float:
    return 1.0 / (1.0 + math.exp(-logodd))


@numba.njit(cache=True)
def interpolate_point(logodds, ox: float, oy: float, res: float, x: float, y: float):
    """M*(x, y) and its gradient (Eq. 3's M*, Hector SLAM's Eq. 4-6).

    Returns ``(value, d/dx, d/dy, inside)``; outside the grid the value is 0.5 (unknown) with a
    zero gradient and ``inside`` False.
    """
    rows, cols = logodds.shape
    u = (x - ox) / res - 0.5
    v = (y - oy) / res - 0.5
    c0 = math.floor(u)
    r0 = math.floor(v)
    if c0 < 0 or r0 < 0 or c0 + 1 >= cols or r0 + 1 >= rows:
        return 0.5, 0.0, 0.0, False
    fu = u - c0
    fv = v - r0
    m00 = _prob(logodds[r0, c0])
    m01 = _prob(logodds[r0, c0 + 1])
    m10 = _prob(logodds[r0 + 1, c0])
    m11 = _prob(logodds[r0 + 1, c0 + 1])
    bottom = m00 + fu * (m01 - m00)
    top = m10 + fu * (m11 - m10)
    value = bottom + fv * (top - bottom)
    dx = ((1.0 - fv) * (m01 - m00) + fv * (m11 - m10)) / res
    dy = (top - bottom) / res
    return value, dx, dy, True


@numba.njit(cache=True)
def _map_many(kind, logodds, means, weights, ox, oy, res, sigma, pts):
    n = pts.shape[0]
    out = np.empty((n, 3))
    for k in range(n):
        val, dx, dy, _ = map_point(
            kind, logodds, means, weights, ox, oy, res, sigma, pts[k, 0], pts[k, 1]
        )
        out[k, 0] = val
        out[k, 1] = dx
        out[k, 2] = dy
    return out


@numba.njit(cache=True)
def subcell_point(means, weights, ox, oy, res, sigma, x, y, fx, fy):
    """A sub-cell accurate map function and its gradient (our variant of Eq. 3's M*).

    The bilinear M* peaks at cell centres, so a wall between two centres pulls the scan by up
    to half a cell, and that bias changes as walls come and go: the odometry drifts. Here each
    occupied cell contributes a Gaussian bump of width ``sigma`` centred on the mean of the
    endpoints that hit it, weighted by its occupancy probability, and the four cells around
    the query are blended with the bilinear weights (which keeps M* continuous). Range noise
    spreads a wall's hits over two cells, whose means then straddle the wall, and the peak of
    the blend sits near the measured wall instead of a cell centre. (On noise-free, one
    cell thick walls the bilinear weights still pull towards the centre; a 3x3 "noisy-OR"
    of the bumps avoids that but measured worse on the simulated maze.) Returns ``(value,
    d/dx, d/dy, inside)``; 0 where no cell nearby was ever hit. ``weights`` holds each
    cell's occupancy probability, 0 for cells never hit (:attr:`OccupancyGrid.weights`).
    ``fx, fy``: the endpoint's surface normal (world frame, towards its sensor; zeros for
    none): a cell whose mean normal faces against it contributes less (``FACE_SLOPE``).
    """
    rows, cols = weights.shape
    u = (x - ox) / res - 0.5
    v = (y - oy) / res - 0.5
    c0 = math.floor(u)
    r0 = math.floor(v)
    if c0 < 0 or r0 < 0 or c0 + 1 >= cols or r0 + 1 >= rows:
        return 0.0, 0.0, 0.0, False
    fu = u - c0
    fv = v - r0
    inv_s2 = 1.0 / (sigma * sigma)
    value = 0.0
    gx = 0.0
    gy = 0.0
    for dr in range(2):
        for dc in range(2):
            r = r0 + dr
            c = c0 + dc
            w = weights[r, c]
            if w == 0.0:
                continue
            ex = ox + c * res + means[r, c, 0] - x
            ey = oy + r * res + means[r, c, 1] - y
            nx = means[r, c, 2]
            ny = means[r, c, 3]
            # a surface facing against the endpoint's own counts less, nothing at 180°:
            # the far face of a thin wall is not the face the map saw
            facing = FACE_SLOPE * (1.0 + fx * nx + fy * ny)
            if facing <= 0.0:
                continue
            if facing < 1.0:
                w *= facing
            # distance across the surface where the cell's normals agree (|n| -> 1), plain
            # distance where they do not (|n| -> 0): no ripple along a wall's cells
            spread = 1.0 - (nx * nx + ny * ny)
            dn = ex * nx + ey * ny
            d2 = dn * dn + spread * (ex * ex + ey * ey)
            g = w * math.exp(-0.5 * d2 * inv_s2)
            px = dn * nx + spread * ex
            py = dn * ny + spread * ey
            bu = fu if dc == 1 else 1.0 - fu
            bv = fv if dr == 1 else 1.0 - fv
            dbu = 1.0 if dc == 1 else -1.0
            dbv = 1.0 if dr == 1 else -1.0
            value += bu * bv * g
            gx += g * (dbu * bv / res + bu * bv * px * inv_s2)
            gy += g * (bu * dbv / res + bu * bv * py * inv_s2)
    return value, gx, gy, True


@numba.njit(cache=True)
def map_point(kind, logodds, means, weights, ox, oy, res, sigma, x, y):
    """The map function selected by ``kind`` (0 = Hector's bilinear M*, 1 = sub-cell)."""
    if kind == 0:
        return interpolate_point(logodds, ox, oy, res, x, y)
    return subcell_point(means, weights, ox, oy, res, sigma, x, y, 0.0, 0.0)


# --------------------------------------------------------------------------------------------
# Grid


def _as_points(points: ArrayLike) -> FloatArray:
    pts = np.ascontiguousarray(np.asarray(points, dtype=np.float64))
    if pts.ndim != 2 or pts.shape[1] != 2:
        raise ValueError(f"points must have shape (N, 2), got {pts.shape}")
    return pts


class OccupancyGrid:
    """A log-odds occupancy grid with hit/miss ray updates.

    Args:
        resolution: cell size, metres.
        size: width and height in metres (one number for a square); rounded up to whole cells.
        origin: world coordinates of the lower-left corner of cell (0, 0); by default the grid
            is centred on (0, 0).
        update: the log-odds increments and clamps.
        auto_grow: grow the grid (by whole blocks) when a scan reaches beyond it, for global maps
            of unknown extent; a local map leaves it off and scrolls with :meth:`recenter`.
        subcell: keep what the map function M* reads besides the log-odds (sub-cell means,
            normals, hit counts, probabilities: 22 of the 30 bytes a cell); a grid only drawn
            (the output map) leaves it off and gets the same log-odds.
    """

    _LAYERS = ("logodds", "_stamps", "means", "hits", "weights")

    def __init__(
        self,
        resolution: float,
        size: float | tuple[float, float],
        origin: ArrayLike | None = None,
        update: LogOddsConfig | None = None,
        auto_grow: bool = False,
        subcell: bool = True,
    ) -> None:
        if not resolution > 0:
            raise ValueError(f"grid resolution must be positive, got {resolution}")
        width, height = (size, size) if np.isscalar(size) else size  # type: ignore[misc]
        cols = max(2, math.ceil(float(width) / resolution - 1e-9))
        rows = max(2, math.ceil(float(height) / resolution - 1e-9))
        self.resolution = float(resolution)
        self.update = update or LogOddsConfig()
        self.auto_grow = auto_grow
        if origin is None:
            origin = (-0.5 * cols * resolution, -0.5 * rows * resolution)
        self.origin = np.array(origin, dtype=np.float64).reshape(2)
        self.logodds = np.zeros((rows, cols), dtype=np.float32)
        self._stamps = np.zeros((rows, cols), dtype=np.int32)
        # Sub-cell mean endpoint of each cell, relative to its lower-left corner, the mean
        # surface normal there, and the number of hits averaged (see subcell_point).
        self.subcell = subcell
        layer_shape = (rows, cols) if subcell else (1, 1)
        self.means = np.zeros((*layer_shape, 4), dtype=np.float32)
        self.hits = np.zeros(layer_shape, dtype=np.uint16)
        # The occupancy probability of every cell ever hit (0 elsewhere), kept up to date by
        # the updates: the matcher reads it at four cells per point and iteration, where
        # converting log-odds each time would cost a third of its time.
        self.weights = np.zeros(layer_shape, dtype=np.float32)
        self._stamp = 0

    @property
    def _layers(self) -> tuple[str, ...]:
        return self._LAYERS if self.subcell else self._LAYERS[:2]

    @classmethod
    def from_extent(
        cls,
        resolution: float,
        extent: tuple[float, float, float, float],
        update: LogOddsConfig | None = None,
        auto_grow: bool = False,
        subcell: bool = True,
    ) -> OccupancyGrid:
        """A grid covering ``(xmin, ymin, xmax, ymax)``."""
        xmin, ymin, xmax, ymax = extent
        if not (xmax > xmin and ymax > ymin):
            raise ValueError(f"empty grid extent {extent}")
        return cls(
            resolution, (xmax - xmin, ymax - ymin), (xmin, ymin), update, auto_grow, subcell
        )

    @property
    def shape(self) -> tuple[int, int]:
        return self.logodds.shape  # type: ignore[return-value]

    @property
    def extent(self) -> tuple[float, float, float, float]:
        """``(xmin, ymin, xmax, ymax)`` in metres."""
        rows, cols = self.shape
        x0, y0 = self.origin
        return (x0, y0, x0 + cols * self.resolution, y0 + rows * self.resolution)

    @property
    def insertions(self) -> int:
        """Scans inserted so far: it changes whenever the map's content does (scrolling and
        growing change :attr:`origin` or :attr:`shape` instead)."""
        return self._stamp

    @property
    def nbytes(self) -> int:
        return int(sum(getattr(self, n).nbytes for n in self._layers))

    def probability(self, unknown: float = 0.5) -> FloatArray:
        """Occupancy probabilities ``(H, W)`` in [0, 1]; never-observed cells get ``unknown``."""
        prob = 1.0 / (1.0 + np.exp(-self.logodds))
        if unknown != 0.5:
            prob[self._stamps == 0] = unknown
        return prob

    def known_mask(self) -> NDArray[np.bool_]:
        """Cells observed at least once."""
        return self._stamps != 0

    def above_near(self, points: ArrayLike, level: float) -> NDArray[np.bool_]:
        """For world points ``(N, 2)``: whether the cell of each, or one of its 8 neighbours
        (clamped to the grid), has a log-odds above ``level``."""
        ox, oy = self.origin.tolist()
        return _above_near(self.logodds, _as_points(points), ox, oy, self.resolution, level)

    def above(self, points: ArrayLike, level: float) -> NDArray[np.bool_]:
        """For world points ``(N, 2)``: whether the cell of each has a log-odds above
        ``level`` (cells beyond the grid are unknown, log-odds 0)."""
        ox, oy = self.origin.tolist()
        return _above(self.logodds, _as_points(points), ox, oy, self.resolution, level)

    def fraction_not_above_near(self, pose: ArrayLike, points: ArrayLike, level: float) -> float:
        """:meth:`above_near`'s complement as a fraction, for sensor-frame ``points`` placed
        by ``pose`` (x, y, theta); 0 for no points."""
        return self._fraction_placed(_count_not_above_near, pose, points, level)

    def fraction_through_walls(
        self, pose: ArrayLike, points: ArrayLike, level: float, margin: float
    ) -> float:
        """The fraction of the beams to sensor-frame ``points`` placed by ``pose`` that cross
        a cell with a log-odds above ``level`` before ``margin`` metres short of their
        endpoint: a scan placed there would have seen through a known wall (free-space
        consistency, the evidence a pose off along a corridor leaves that the endpoints'
        map values do not). 0 for no points."""
        return self._fraction_placed(_count_through_walls, pose, points, level, margin)

    def _fraction_placed(
        self, count: Callable[..., int], pose: ArrayLike, points: ArrayLike, *args: float
    ) -> float:
        """``count``'s share of the sensor-frame ``points`` placed by ``pose`` on this grid
        (a kernel taking the log-odds, points, pose, origin, resolution, then ``args``); 0
        for no points."""
        pts = _as_points(points)
        if pts.shape[0] == 0:
            return 0.0
        x, y, theta = np.asarray(pose, dtype=np.float64).reshape(3).tolist()
        ox, oy = self.origin.tolist()
        return count(self.logodds, pts, x, y, theta, ox, oy, self.resolution, *args) / pts.shape[0]

    def world_to_cell(self, points: ArrayLike) -> NDArray[np.int64]:
        """``(N, 2)`` world points to integer ``(row, col)`` indices (possibly out of range)."""
        pts = _as_points(points)
        return np.floor((pts[:, ::-1] - self.origin[::-1]) / self.resolution).astype(np.int64)

    def insert_scan(
        self,
        pose: ArrayLike,
        endpoints: ArrayLike,
        max_range: float = np.inf,
        normals: ArrayLike | None = None,
        rays: bool = True,
    ) -> None:
        """Fuse one scan: a hit at every endpoint, a miss in every cell its beam crosses.

        Args:
            pose: sensor pose ``(x, y, theta)`` in the grid's frame.
            endpoints: ``(N, 2)`` beam endpoints in the sensor frame (valid returns only), in
                scan order (their neighbours give the surface normals).
            max_range: endpoints farther than this are ignored (their rays too).
            normals: ``(N, 2)`` sensor-frame surface normals (:func:`thinned_normals`), used
                by the sub-cell map function; without them cells get none (isotropic bumps),
                which is all a map drawn for display needs.
            rays: False: the hits alone, no cell marked free (for a map whose free space
                nothing reads: its hit cells come out the same, their rays never touch them).
        """
        pose = np.asarray(pose, dtype=np.float64).reshape(3)
        pts = _as_points(endpoints)
        nrm = np.zeros_like(pts) if normals is None else _as_points(normals)
        if np.isfinite(max_range):
            near = np.einsum("ij,ij->i", pts, pts) <= max_range * max_range
            pts, nrm = pts[near], nrm[near]
        c, s = math.cos(pose[2]), math.sin(pose[2])
        rot_t = np.array([[c, s], [-s, c]])
        world = np.ascontiguousarray(pts @ rot_t + pose[:2])
        world_normals = np.ascontiguousarray(nrm @ rot_t)
        if self.auto_grow and world.size:
            lo = np.minimum(world.min(axis=0), pose[:2])
            hi = np.maximum(world.max(axis=0), pose[:2])
            self.grow_to_include((lo[0], lo[1], hi[0], hi[1]))
        self._stamp += 1
        u = self.update
        _insert_scan_kernel(
            self.logodds, self._stamps, self.means, self.hits, self.weights, self._stamp,
            self.origin[0], self.origin[1], self.resolution, pose[0], pose[1], world,
            world_normals, u.l_hit, u.l_miss, u.l_min, u.l_max, u.mean_memory, self.subcell,
            rays,
        )  # fmt: skip

    def insert_edge_twins(self, pose: ArrayLike, endpoints: ArrayLike, normals: ArrayLike) -> None:
        """Fuse, as hits without rays, the :func:`edge_twins` of sensor-frame ``endpoints``
        on surfaces (sensor-frame unit ``normals``) seen from ``pose``: the walls a lone scan
        holds, in the cells on both sides of the cell edges they run along."""
        pose = np.asarray(pose, dtype=np.float64).reshape(3)
        turn = rotation(float(pose[2]))
        twins, twin_normals = edge_twins(
            transform_points(pose, endpoints), _as_points(normals) @ turn.T, self.origin,
            self.resolution,
        )  # fmt: skip
        # back to the sensor frame, as :meth:`insert_scan` takes them
        self.insert_scan(
            pose, transform_points(inverse(pose), twins), normals=twin_normals @ turn, rays=False
        )

    def value_and_gradient(
        self, points: ArrayLike, subcell_sigma: float | None = None
    ) -> tuple[FloatArray, FloatArray]:
        """M* at world points ``(N, 2)`` and its gradient ``(N, 2)``: Hector's bilinear M*
        of Eq. 3 by default, the sub-cell variant (:func:`subcell_point`) with kernel width
        ``subcell_sigma`` when given."""
        if not self.subcell:
            raise ValueError("a grid made with subcell=False has no map function")
        pts = _as_points(points)
        kind = 0 if subcell_sigma is None else 1
        out = _map_many(
            kind, self.logodds, self.means, self.weights, self.origin[0], self.origin[1],
            self.resolution, subcell_sigma or 1.0, pts,
        )  # fmt: skip
        return out[:, 0], out[:, 1:]

    def shift_cells(self, drow: int, dcol: int) -> None:
        """Scroll the window by whole cells: the origin moves by ``(dcol, drow) * res`` and
        what falls outside is forgotten, so memory stays constant."""
        if drow == 0 and dcol == 0:
            return
        # in place: a new array per layer (28 MB for a 48 m grid at 5 cm) cost its page
        # faults on every scroll, 6-53 ms a time on intel, the slowest of its scans
        for name in self._layers:
            layer = getattr(self, name)
            if not layer.flags.c_contiguous:
                layer = np.ascontiguousarray(layer)
                setattr(self, name, layer)
            rows, cols = layer.shape[:2]
            per_cell = layer.size // max(rows * cols, 1)  # a cell's values, side by side
            _scroll_in_place(layer.reshape(rows, -1), drow, dcol * per_cell)
        self.origin = self.origin + self.resolution * np.array([dcol, drow], dtype=np.float64)

    def recenter(self, x: float, y: float, quantum: int = 1) -> None:
        """Scroll so that ``(x, y)`` is near the centre, by a multiple of ``quantum`` cells."""
        rows, cols = self.shape
        cx, cy = self.origin + 0.5 * self.resolution * np.array([cols, rows])
        dcol = round((x - cx) / (self.resolution * quantum)) * quantum
        drow = round((y - cy) / (self.resolution * quantum)) * quantum
        self.shift_cells(drow, dcol)

    def grow_to_include(self, extent: tuple[float, float, float, float], block: float = 10.0):
        """Enlarge the grid (keeping its content and cell alignment) to cover ``extent``,
        rounding each enlargement up to ``block`` metres so growth is amortised."""
        xmin, ymin, xmax, ymax = self.extent
        res = self.resolution
        nblk = max(1, round(block / res))

        def cells_needed(gap: float) -> int:
            return 0 if gap <= 0 else nblk * math.ceil(gap / res / nblk)

        left = cells_needed(xmin - extent[0])
        right = cells_needed(extent[2] - xmax)
        below = cells_needed(ymin - extent[1])
        above = cells_needed(extent[3] - ymax)
        if left == right == below == above == 0:
            return
        pad = ((below, above), (left, right))
        for name in self._layers:
            layer = getattr(self, name)
            setattr(self, name, np.pad(layer, pad + ((0, 0),) * (layer.ndim - 2)))
        self.origin = self.origin - res * np.array([left, below], dtype=np.float64)


class MapPyramid:
    """Several grids of the same area, each twice as coarse as the previous (finest first),
    all updated with every inserted scan (Hector SLAM, Sec. IV-C)."""

    def __init__(
        self,
        resolution: float,
        size: float | tuple[float, float],
        levels: int,
        update: LogOddsConfig | None = None,
        origin: ArrayLike | None = None,
    ) -> None:
        if levels < 1:
            raise ValueError(f"a map pyramid needs at least one level, got {levels}")
        coarsest = resolution * 2 ** (levels - 1)
        # Every level spans the same whole number of coarsest cells, so they stay aligned.
        width, height = (size, size) if np.isscalar(size) else size  # type: ignore[misc]
        width = coarsest * math.ceil(float(width) / coarsest)
        height = coarsest * math.ceil(float(height) / coarsest)
        if origin is None:
            origin = (-0.5 * width, -0.5 * height)
        self.grids = [
            OccupancyGrid(resolution * 2**k, (width, height), origin, update)
            for k in range(levels)
        ]

    @property
    def finest(self) -> OccupancyGrid:
        return self.grids[0]

    @property
    def nbytes(self) -> int:
        return sum(g.nbytes for g in self.grids)

    def insert_scan(
        self,
        pose: ArrayLike,
        endpoints: ArrayLike,
        max_range: float = np.inf,
        normals: ArrayLike | None = None,
        rays: bool = True,
    ) -> None:
        """:meth:`OccupancyGrid.insert_scan` on every level."""
        pts = _as_points(endpoints)
        normals = thinned_normals(pts) if normals is None else _as_points(normals)
        for grid in self.grids:
            grid.insert_scan(pose, pts, max_range, normals, rays)

    def recenter(self, x: float, y: float) -> None:
        """Scroll every level by the same distance (whole coarsest cells)."""
        top = self.grids[-1]
        rows, cols = top.shape
        cx, cy = top.origin + 0.5 * top.resolution * np.array([cols, rows])
        dcol = round((x - cx) / top.resolution)
        drow = round((y - cy) / top.resolution)
        for k, grid in enumerate(self.grids):
            factor = 2 ** (len(self.grids) - 1 - k)
            grid.shift_cells(drow * factor, dcol * factor)
