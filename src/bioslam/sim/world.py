"""Worlds made of wall segments, with a roadmap of drivable centre-lines for routes."""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray

if TYPE_CHECKING:
    from bioslam.sim.raycast import SegmentGrid

# Point-segment pairs per batch when measuring distances to walls: bounds the temporary
# (points x segments) buffers to a few tens of megabytes whatever the size of the world.
_DISTANCE_PAIRS = 1 << 20


@dataclass(frozen=True, eq=False)
class Roadmap:
    """A graph a robot may drive along: ``nodes`` (K, 2) in metres, undirected ``edges``
    (E, 2) of node indices, and ``clearance`` (K,) the distance from each node to the nearest
    wall (how far a route may cut a corner there)."""

    nodes: NDArray[np.float64]
    edges: NDArray[np.int64]
    clearance: NDArray[np.float64]

    def neighbours(self) -> list[list[int]]:
        adj: list[list[int]] = [[] for _ in range(len(self.nodes))]
        for a, b in self.edges:
            adj[int(a)].append(int(b))
            adj[int(b)].append(int(a))
        return adj


@dataclass(eq=False)
class World:
    """Walls as line segments ``(S, 4)`` rows ``x0 y0 x1 y1`` in metres, a name, and
    optionally the roadmap that :func:`bioslam.sim.make_route` drives along. ``grid_cell``
    is the cell size of the ray-casting index, metres (see
    :func:`bioslam.sim.raycast.build_segment_grid`)."""

    segments: NDArray[np.float64]
    name: str = "world"
    roadmap: Roadmap | None = None
    grid_cell: float = field(default=0.5)

    def __post_init__(self) -> None:
        segs = np.asarray(self.segments, dtype=np.float64)
        if segs.ndim != 2 or segs.shape[1] != 4 or segs.shape[0] == 0:
            raise ValueError(f"world segments must be a non-empty (S, 4) array, got {segs.shape}")
        if not np.all(np.isfinite(segs)):
            raise ValueError("world segments contain NaN or inf coordinates")
        self.segments = segs

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        """``(xmin, ymin, xmax, ymax)`` of all walls."""
        xs = self.segments[:, [0, 2]]
        ys = self.segments[:, [1, 3]]
        return float(xs.min()), float(ys.min()), float(xs.max()), float(ys.max())

    @cached_property
    def grid(self) -> SegmentGrid:
        """The ray-casting index over the walls (built once, on first use)."""
        from bioslam.sim.raycast import build_segment_grid  # Numba: only when casting rays

        return build_segment_grid(self.segments, self.grid_cell)

    def distance_to_walls(self, points: NDArray[np.float64]) -> NDArray[np.float64]:
        """Euclidean distance from each point ``(..., 2)`` to the nearest wall segment."""
        pts = np.asarray(points, dtype=np.float64)
        flat = pts.reshape(-1, 2)
        out = np.empty(flat.shape[0])
        a = self.segments[:, :2]
        d = self.segments[:, 2:] - a
        dd = np.maximum(np.einsum("ij,ij->i", d, d), 1e-300)
        batch = max(1, _DISTANCE_PAIRS // len(a))
        for lo in range(0, flat.shape[0], batch):
            p = flat[lo : lo + batch, None, :] - a[None]
            u = np.clip(np.einsum("nsk,sk->ns", p, d) / dd, 0.0, 1.0)
            diff = p - u[..., None] * d[None]
            squared = np.einsum("nsk,nsk->ns", diff, diff)
            out[lo : lo + batch] = np.sqrt(squared.min(axis=1))
        return out.reshape(pts.shape[:-1])


def _runs(mask: NDArray[np.bool_]) -> tuple[NDArray, NDArray, NDArray]:
    """Maximal runs of True along the last axis of a 2-D mask: ``(row, start, stop)``."""
    padded = np.zeros((mask.shape[0], mask.shape[1] + 2), dtype=np.int8)
    padded[:, 1:-1] = mask
    change = np.diff(padded, axis=1)
    rows_s, starts = np.nonzero(change == 1)
    _, stops = np.nonzero(change == -1)
    return rows_s, starts, stops


def segments_from_occupancy(
    occupied: NDArray[np.bool_],
    resolution: float,
    origin: tuple[float, float] = (0.0, 0.0),
    outside_occupied: bool = False,
) -> NDArray[np.float64]:
    """Wall segments along every border between an occupied and a non-occupied cell.

    ``occupied`` is (H, W) with row 0 at the lowest y; cell ``(i, j)`` covers
    ``[origin + (j, i) * resolution, origin + (j + 1, i + 1) * resolution]``. Collinear
    borders are merged into one segment, so a straight wall of any length is one segment.
    Cells beyond the array count as free, or as occupied with ``outside_occupied`` (then the
    array's own border becomes a wall wherever a free cell touches it).
    """
    occ = np.asarray(occupied, dtype=bool)
    if occ.ndim != 2:
        raise ValueError(f"occupancy must be 2-D, got shape {occ.shape}")
    pad = np.pad(occ, 1, constant_values=outside_occupied)
    # Horizontal borders: between rows i-1 and i of the padded grid (y = origin + (i-1) * res).
    h = pad[1:, 1:-1] != pad[:-1, 1:-1]
    rows, starts, stops = _runs(h)
    x0, y0 = origin
    horiz = np.column_stack(
        [
            x0 + starts * resolution,
            y0 + rows * resolution,
            x0 + stops * resolution,
            y0 + rows * resolution,
        ]
    )
    v = (pad[1:-1, 1:] != pad[1:-1, :-1]).T
    cols, starts, stops = _runs(v)
    vert = np.column_stack(
        [
            x0 + cols * resolution,
            y0 + starts * resolution,
            x0 + cols * resolution,
            y0 + stops * resolution,
        ]
    )
    return np.vstack([horiz, vert]).astype(np.float64)


def box_segments(xmin: float, ymin: float, xmax: float, ymax: float) -> NDArray[np.float64]:
    """The four walls of an axis-aligned rectangle."""
    return np.array(
        [
            [xmin, ymin, xmax, ymin],
            [xmax, ymin, xmax, ymax],
            [xmax, ymax, xmin, ymax],
            [xmin, ymax, xmin, ymin],
        ],
        dtype=np.float64,
    )


def world_from_free_mask(
    free: NDArray[np.bool_],
    step: float,
    name: str,
    nodes: NDArray[np.float64],
    edges: NDArray[np.int64],
) -> World:
    """A built-in world drawn as a free-space mask (row 0 at y = 0, cells ``step`` wide, the
    space beyond the array solid) with a hand-made roadmap; each node's clearance is measured
    from the walls, so the route's corner arcs fit whatever the layout."""
    segments = segments_from_occupancy(~free, step, (0.0, 0.0), outside_occupied=True)
    world = World(segments, name=name)
    nodes = np.asarray(nodes, dtype=np.float64)
    edges = np.asarray(edges, dtype=np.int64)
    world.roadmap = Roadmap(nodes, edges, world.distance_to_walls(nodes))
    return world


class FloorPlan:
    """A free-space mask drawn from axis-aligned rectangles, for the built-in worlds.

    Cells are ``step`` wide, row 0 at y = 0, and every coordinate a multiple of ``step`` so
    that walls fall exactly where the layout says. Start solid, :meth:`carve` free space,
    :meth:`fill` solid things back in (shelves, pillars, furniture).
    """

    def __init__(self, width: float, height: float, step: float = 0.1) -> None:
        self.step = step
        self.free = np.zeros((round(height / step), round(width / step)), dtype=bool)

    def _cells(self, lo: float, hi: float) -> slice:
        return slice(round(lo / self.step), round(hi / self.step))

    def carve(self, x0: float, y0: float, x1: float, y1: float) -> None:
        self.free[self._cells(y0, y1), self._cells(x0, x1)] = True

    def fill(self, x0: float, y0: float, x1: float, y1: float) -> None:
        self.free[self._cells(y0, y1), self._cells(x0, x1)] = False

    def world(self, name: str, nodes: ArrayLike, edges: ArrayLike) -> World:
        return world_from_free_mask(
            self.free, self.step, name, np.asarray(nodes), np.asarray(edges)
        )
