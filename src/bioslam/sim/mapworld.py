"""Worlds from occupancy maps (map_server PGM/PNG + YAML), so users can simulate their own
floor plans: occupied cells become walls, the free space gets a roadmap for routes."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from bioslam.io.mapfile import (
    DEFAULT_FREE_THRESH,
    DEFAULT_OCCUPIED_THRESH,
    OccupancyImage,
    read_map,
)
from bioslam.sim.world import Roadmap, World, segments_from_occupancy

# Neighbouring lattice blocks linked by roadmap edges (the other four are the same pairs).
_NEIGHBOUR_OFFSETS = ((0, 1), (1, 0), (1, 1), (1, -1))


@dataclass(frozen=True)
class MapWorldConfig:
    """How an occupancy map becomes a world.

    Attributes:
        occupied_thresh: occupancy at or above which a cell is a wall (map_server's default).
        free_thresh: occupancy below which a cell is drivable (map_server's default).
        unknown_is_wall: unknown cells (and the space beyond the map) block rays: in a
            floor plan or a SLAM map the unknown is behind walls, and rays must not leak out.
        roadmap_spacing: distance between roadmap nodes, metres; 0.5 m gives a node or two
            across a corridor.
        roadmap_clearance: roadmap nodes and edges keep this far from walls, metres: the
            route's 0.3 m clearance plus room for rounding corners and smoothing.
    """

    occupied_thresh: float = DEFAULT_OCCUPIED_THRESH
    free_thresh: float = DEFAULT_FREE_THRESH
    unknown_is_wall: bool = True
    roadmap_spacing: float = 0.5
    roadmap_clearance: float = 0.45


def _two_core(n: int, edges: NDArray[np.int64]) -> NDArray[np.bool_]:
    """Nodes that remain after repeatedly removing nodes with fewer than two edges (so a route
    never runs into a dead end it would have to turn back from)."""
    alive = np.ones(n, dtype=bool)
    while True:
        live = edges[alive[edges[:, 0]] & alive[edges[:, 1]]]
        degree = np.bincount(live.ravel(), minlength=n)
        dead = alive & (degree < 2)
        if not dead.any():
            return alive
        alive &= ~dead


def _largest_component(n: int, edges: NDArray[np.int64], alive: NDArray[np.bool_]) -> NDArray:
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    live = edges[alive[edges[:, 0]] & alive[edges[:, 1]]]
    graph = coo_matrix((np.ones(len(live)), (live[:, 0], live[:, 1])), shape=(n, n))
    _, labels = connected_components(graph, directed=False)
    sizes = np.bincount(labels[alive], minlength=labels.max() + 1)
    return alive & (labels == int(np.argmax(sizes)))


def lattice_roadmap(
    wall_distance: NDArray[np.float64],
    resolution: float,
    origin: tuple[float, float],
    spacing: float,
    min_clearance: float,
) -> Roadmap:
    """A roadmap over free space: the grid is cut into blocks ``spacing`` wide, each block's
    node is its cell farthest from walls (so nodes sit on corridor centre-lines), and nodes of
    neighbouring blocks are linked when the straight line between them keeps
    ``min_clearance`` from walls. Only the largest loop-closed part (2-core) is kept.

    ``wall_distance`` (H, W) is each cell centre's distance to the nearest wall, metres.
    """
    step = max(1, round(spacing / resolution))
    h, w = wall_distance.shape
    by, bx = -(-h // step), -(-w // step)
    padded = np.full((by * step, bx * step), -np.inf)
    padded[:h, :w] = wall_distance
    blocks = padded.reshape(by, step, bx, step).transpose(0, 2, 1, 3).reshape(by, bx, -1)
    best = blocks.argmax(axis=2)
    ok = np.take_along_axis(blocks, best[..., None], axis=2)[..., 0] >= min_clearance
    rows = np.arange(by)[:, None] * step + best // step
    cols = np.arange(bx)[None, :] * step + best % step
    index = np.full((by, bx), -1, dtype=np.int64)
    index[ok] = np.arange(int(ok.sum()))
    cells = np.column_stack([rows[ok], cols[ok]])
    edges = []
    for di, dj in _NEIGHBOUR_OFFSETS:
        a = index[max(0, -di) : by - max(0, di), max(0, -dj) : bx - max(0, dj)]
        b = index[max(0, di) : by + min(0, di) or None, max(0, dj) : bx + min(0, dj) or None]
        pairs = np.column_stack([a.ravel(), b.ravel()])
        edges.append(pairs[(pairs >= 0).all(axis=1)])
    pairs = np.vstack(edges)
    # Sample each candidate edge at quarter-cell steps and keep it if it stays clear.
    samples = int(np.ceil(4 * 3 * step)) + 2
    f = np.linspace(0.0, 1.0, samples)[None, :, None]
    along = cells[pairs[:, 0]][:, None, :] * (1 - f) + cells[pairs[:, 1]][:, None, :] * f
    ij = np.rint(along).astype(np.int64)
    clear = (wall_distance[ij[..., 0], ij[..., 1]] >= min_clearance).all(axis=1)
    pairs = pairs[clear]
    n = len(cells)
    keep = _largest_component(n, pairs, _two_core(n, pairs)) if len(pairs) else np.zeros(n, bool)
    if not keep.any():
        raise ValueError(
            f"no loop in the free space keeps {min_clearance} m from the walls: "
            "cannot build a route (is the map's free space too narrow?)"
        )
    renumber = np.cumsum(keep) - 1
    pairs = pairs[keep[pairs[:, 0]] & keep[pairs[:, 1]]]
    kept = cells[keep]
    nodes = np.column_stack(
        [origin[0] + (kept[:, 1] + 0.5) * resolution, origin[1] + (kept[:, 0] + 0.5) * resolution]
    )
    clearance = wall_distance[kept[:, 0], kept[:, 1]]
    return Roadmap(nodes, renumber[pairs], clearance)


def _rotate(points: NDArray, yaw: float, pivot: NDArray) -> NDArray:
    c, s = np.cos(yaw), np.sin(yaw)
    return (points - pivot) @ np.array([[c, s], [-s, c]]) + pivot


def world_from_occupancy(
    image: OccupancyImage, config: MapWorldConfig | None = None, name: str = "map"
) -> World:
    """A world whose walls are the borders of the occupied cells of ``image``."""
    from scipy.ndimage import distance_transform_edt  # SciPy only when a map is loaded

    cfg = config or MapWorldConfig()
    occ = image.occupancy
    unknown = np.isnan(occ)
    with np.errstate(invalid="ignore"):
        wall = (occ >= cfg.occupied_thresh) | (unknown & cfg.unknown_is_wall)
        free = (occ < cfg.free_thresh) & ~unknown
    if not wall.any():
        raise ValueError(f"map {name!r} has no occupied cells: nothing for the LiDAR to see")
    res = image.resolution
    ox, oy, yaw = image.origin
    segments = segments_from_occupancy(wall, res, (ox, oy), outside_occupied=cfg.unknown_is_wall)
    # Distance from a free cell's centre to the nearest wall cell's border.
    wall_distance = np.where(free, distance_transform_edt(free) * res - 0.5 * res, 0.0)
    roadmap = lattice_roadmap(
        wall_distance, res, (ox, oy), cfg.roadmap_spacing, cfg.roadmap_clearance
    )
    if yaw != 0.0:
        pivot = np.array([ox, oy])
        segments = np.hstack(
            [_rotate(segments[:, :2], yaw, pivot), _rotate(segments[:, 2:], yaw, pivot)]
        )
        roadmap = Roadmap(_rotate(roadmap.nodes, yaw, pivot), roadmap.edges, roadmap.clearance)
    return World(segments, name=name, roadmap=roadmap)


def world_from_map(yaml_path: str | Path, config: MapWorldConfig | None = None) -> World:
    """Load a map_server map (YAML + PGM/PNG) as a world (see :func:`world_from_occupancy`)."""
    path = Path(yaml_path)
    try:
        return world_from_occupancy(read_map(path), config, name=path.stem)
    except ValueError as exc:
        if str(path) in str(exc):
            raise
        raise ValueError(f"{path}: {exc}") from None
