"""Exact 2D ray casting against line segments, accelerated by a uniform grid (Numba).

Each segment is listed in every grid cell it crosses; a ray walks the cells it crosses in order
(Amanatides & Woo 1987) and tests only the segments listed there, stopping as soon as the
nearest hit found lies inside the cell just tested. The hit distance is the exact ray/segment
intersection, so the grid only changes speed, never the result.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit
from numpy.typing import NDArray

# Segments shorter than this (metres) are dropped: they cannot be hit by a ray reliably.
_MIN_SEGMENT_LENGTH = 1e-9
# Segment-to-cell assignment inflates cells by this much so that a ray grazing a cell corner
# still sees a segment passing through that corner.
_CELL_MARGIN = 1e-6


@dataclass(frozen=True, eq=False)
class SegmentGrid:
    """Segments ``(S, 4)`` bucketed into a uniform grid (CSR layout: ``cell_start``, ``items``)."""

    segments: NDArray[np.float64]
    origin: tuple[float, float]
    cell: float
    nx: int
    ny: int
    cell_start: NDArray[np.int64]
    items: NDArray[np.int64]


@njit(cache=True)
def _segment_touches_box(x0, y0, x1, y1, bx0, by0, bx1, by1):  # pragma: no cover - numba
    # Liang-Barsky clipping of the segment against the box.
    dx = x1 - x0
    dy = y1 - y0
    t0 = 0.0
    t1 = 1.0
    for p, q in ((-dx, x0 - bx0), (dx, bx1 - x0), (-dy, y0 - by0), (dy, by1 - y0)):
        if p == 0.0:
            if q < 0.0:
                return False
        else:
            r = q / p
            if p < 0.0:
                if r > t1:
                    return False
                if r > t0:
                    t0 = r
            else:
                if r < t0:
                    return False
                if r < t1:
                    t1 = r
    return True


@njit(cache=True)
def _bucket(segs, gx0, gy0, cell, nx, ny, counts, items, fill):  # pragma: no cover - numba
    for s in range(segs.shape[0]):
        x0, y0, x1, y1 = segs[s, 0], segs[s, 1], segs[s, 2], segs[s, 3]
        i0 = max(int(np.floor((min(x0, x1) - gx0) / cell)) - 1, 0)
        i1 = min(int(np.floor((max(x0, x1) - gx0) / cell)) + 1, nx - 1)
        j0 = max(int(np.floor((min(y0, y1) - gy0) / cell)) - 1, 0)
        j1 = min(int(np.floor((max(y0, y1) - gy0) / cell)) + 1, ny - 1)
        for i in range(i0, i1 + 1):
            bx0 = gx0 + i * cell - _CELL_MARGIN
            bx1 = gx0 + (i + 1) * cell + _CELL_MARGIN
            for j in range(j0, j1 + 1):
                by0 = gy0 + j * cell - _CELL_MARGIN
                by1 = gy0 + (j + 1) * cell + _CELL_MARGIN
                if _segment_touches_box(x0, y0, x1, y1, bx0, by0, bx1, by1):
                    c = i * ny + j
                    if fill:
                        items[counts[c]] = s
                    counts[c] += 1


def build_segment_grid(segments: NDArray[np.float64], cell: float = 0.5) -> SegmentGrid:
    """Bucket ``segments`` (S, 4) into square cells of side ``cell`` metres.

    0.5 m (default) keeps a few wall segments per cell in indoor worlds, so a ray tests a few
    dozen segments at most whatever the size of the world.
    """
    segs = np.ascontiguousarray(segments, dtype=np.float64).reshape(-1, 4)
    lengths = np.hypot(segs[:, 2] - segs[:, 0], segs[:, 3] - segs[:, 1])
    segs = np.ascontiguousarray(segs[lengths > _MIN_SEGMENT_LENGTH])
    if segs.shape[0] == 0:
        raise ValueError("a world needs at least one wall segment")
    if not cell > 0:
        raise ValueError(f"grid cell size must be positive, got {cell}")
    xs = np.concatenate([segs[:, 0], segs[:, 2]])
    ys = np.concatenate([segs[:, 1], segs[:, 3]])
    gx0, gy0 = float(xs.min()) - cell, float(ys.min()) - cell
    nx = int(np.ceil((xs.max() - gx0) / cell)) + 1
    ny = int(np.ceil((ys.max() - gy0) / cell)) + 1
    counts = np.zeros(nx * ny, dtype=np.int64)
    dummy = np.zeros(0, dtype=np.int64)
    _bucket(segs, gx0, gy0, cell, nx, ny, counts, dummy, False)
    cell_start = np.zeros(nx * ny + 1, dtype=np.int64)
    np.cumsum(counts, out=cell_start[1:])
    items = np.zeros(int(cell_start[-1]), dtype=np.int64)
    cursor = cell_start[:-1].copy()
    _bucket(segs, gx0, gy0, cell, nx, ny, cursor, items, True)
    return SegmentGrid(segs, (gx0, gy0), float(cell), nx, ny, cell_start, items)


@njit(cache=True)
def _hit_segment(ox, oy, dx, dy, x0, y0, x1, y1):  # pragma: no cover - numba
    ex = x1 - x0
    ey = y1 - y0
    denom = dx * ey - dy * ex
    if denom == 0.0:
        return np.inf
    ax = x0 - ox
    ay = y0 - oy
    t = (ax * ey - ay * ex) / denom
    u = (ax * dy - ay * dx) / denom
    if t < 0.0 or u < 0.0 or u > 1.0:
        return np.inf
    return t


@njit(cache=True)
def _cast_one(
    ox, oy, angle, max_range, segs, gx0, gy0, cell, nx, ny, cell_start, items
):  # pragma: no cover - numba
    dx = np.cos(angle)
    dy = np.sin(angle)
    gx1 = gx0 + nx * cell
    gy1 = gy0 + ny * cell
    t0 = 0.0
    t1 = max_range
    # Clip the ray to the grid box (slab method) so origins outside the grid still work.
    if dx == 0.0:
        if ox < gx0 or ox > gx1:
            return np.inf
    else:
        ta = (gx0 - ox) / dx
        tb = (gx1 - ox) / dx
        t0 = max(t0, min(ta, tb))
        t1 = min(t1, max(ta, tb))
    if dy == 0.0:
        if oy < gy0 or oy > gy1:
            return np.inf
    else:
        ta = (gy0 - oy) / dy
        tb = (gy1 - oy) / dy
        t0 = max(t0, min(ta, tb))
        t1 = min(t1, max(ta, tb))
    if t0 > t1:
        return np.inf
    ix = min(max(int((ox + t0 * dx - gx0) / cell), 0), nx - 1)
    iy = min(max(int((oy + t0 * dy - gy0) / cell), 0), ny - 1)
    if dx > 0.0:
        sx, tmx, tdx = 1, (gx0 + (ix + 1) * cell - ox) / dx, cell / dx
    elif dx < 0.0:
        sx, tmx, tdx = -1, (gx0 + ix * cell - ox) / dx, -cell / dx
    else:
        sx, tmx, tdx = 0, np.inf, np.inf
    if dy > 0.0:
        sy, tmy, tdy = 1, (gy0 + (iy + 1) * cell - oy) / dy, cell / dy
    elif dy < 0.0:
        sy, tmy, tdy = -1, (gy0 + iy * cell - oy) / dy, -cell / dy
    else:
        sy, tmy, tdy = 0, np.inf, np.inf
    best = np.inf
    while True:
        c = ix * ny + iy
        for k in range(cell_start[c], cell_start[c + 1]):
            s = items[k]
            t = _hit_segment(ox, oy, dx, dy, segs[s, 0], segs[s, 1], segs[s, 2], segs[s, 3])
            if t < best:
                best = t
        t_exit = min(tmx, tmy)
        if best <= t_exit or t_exit > t1:
            break
        if tmx < tmy:
            ix += sx
            if ix < 0 or ix >= nx:
                break
            tmx += tdx
        else:
            iy += sy
            if iy < 0 or iy >= ny:
                break
            tmy += tdy
    if best > max_range:
        return np.inf
    return best


@njit(cache=True)
def _cast_many(ox, oy, angles, max_range, segs, gx0, gy0, cell, nx, ny, cell_start, items, out):
    for i in range(out.shape[0]):  # pragma: no cover - numba
        out[i] = _cast_one(
            ox[i], oy[i], angles[i], max_range, segs, gx0, gy0, cell, nx, ny, cell_start, items
        )


def cast_rays(
    grid: SegmentGrid,
    origins: NDArray[np.float64],
    angles: NDArray[np.float64],
    max_range: float = np.inf,
) -> NDArray[np.float64]:
    """Distance from each origin ``(..., 2)`` along each world-frame angle ``(...)`` to the
    nearest segment; ``inf`` when nothing is hit within ``max_range``."""
    origins = np.asarray(origins, dtype=np.float64)
    angles = np.asarray(angles, dtype=np.float64)
    shape = np.broadcast_shapes(origins.shape[:-1], angles.shape)
    o = np.broadcast_to(origins, (*shape, 2)).reshape(-1, 2)
    a = np.ascontiguousarray(np.broadcast_to(angles, shape).reshape(-1))
    out = np.empty(a.shape[0], dtype=np.float64)
    _cast_many(
        np.ascontiguousarray(o[:, 0]),
        np.ascontiguousarray(o[:, 1]),
        a,
        float(max_range),
        grid.segments,
        grid.origin[0],
        grid.origin[1],
        grid.cell,
        grid.nx,
        grid.ny,
        grid.cell_start,
        grid.items,
        out,
    )
    return out.reshape(shape)
