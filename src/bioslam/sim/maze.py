"""The built-in ``maze``: a 16.8 m x 12.6 m arena of corridors in the spirit of the iRat 2011
Australia maze that the paper rebuilt for its simulation (Sec. IV-A).

The layout is ours: five north-south and four east-west corridors, 1.2-1.5 m wide, with the
blocks between them merged in five places so that the arena has loops of different sizes and
shapes (identical blocks everywhere would make every junction look alike). Every junction keeps
at least two exits, so a route never has to turn back in a dead end.
"""

from __future__ import annotations

import numpy as np

from bioslam.sim.world import FloorPlan, Roadmap, World

MAZE_SIZE = (16.8, 12.6)
# Corridor extents (metres) across the arena; their widths are 1.2-1.5 m as in the issue.
VERTICAL_CORRIDORS = ((0.0, 1.4), (3.9, 5.2), (7.9, 9.4), (11.6, 12.8), (15.4, 16.8))
HORIZONTAL_CORRIDORS = ((0.0, 1.4), (3.6, 4.9), (7.6, 9.1), (11.4, 12.6))
# Corridor pieces walled off, as (column, row) junction pairs: ("v", c, r) closes corridor
# column c between rows r and r + 1; ("h", c, r) closes corridor row r between columns c, c + 1.
CLOSED = (("v", 1, 2), ("h", 2, 1), ("v", 3, 0), ("h", 0, 2), ("v", 2, 1))
# Rasterisation step: every coordinate above is a multiple of it, so the walls are exact.
_STEP = 0.1


def _closed_rect(kind: str, c: int, r: int) -> tuple[float, float, float, float]:
    if kind == "v":
        (x0, x1), y0, y1 = (
            VERTICAL_CORRIDORS[c],
            HORIZONTAL_CORRIDORS[r][1],
            HORIZONTAL_CORRIDORS[r + 1][0],
        )
        return x0, y0, x1, y1
    (y0, y1), x0, x1 = (
        HORIZONTAL_CORRIDORS[r],
        VERTICAL_CORRIDORS[c][1],
        VERTICAL_CORRIDORS[c + 1][0],
    )
    return x0, y0, x1, y1


def _floor_plan() -> FloorPlan:
    """Free space of the arena at ``_STEP`` resolution."""
    width, height = MAZE_SIZE
    plan = FloorPlan(width, height, _STEP)
    for x0, x1 in VERTICAL_CORRIDORS:
        plan.carve(x0, 0.0, x1, height)
    for y0, y1 in HORIZONTAL_CORRIDORS:
        plan.carve(0.0, y0, width, y1)
    for kind, c, r in CLOSED:
        plan.fill(*_closed_rect(kind, c, r))
    return plan


def _roadmap() -> Roadmap:
    xs = [0.5 * (a + b) for a, b in VERTICAL_CORRIDORS]
    ys = [0.5 * (a + b) for a, b in HORIZONTAL_CORRIDORS]
    nc, nr = len(xs), len(ys)
    nodes = np.array([[xs[c], ys[r]] for c in range(nc) for r in range(nr)])
    closed = set(CLOSED)
    edges = [
        (c * nr + r, c * nr + r + 1)
        for c in range(nc)
        for r in range(nr - 1)
        if ("v", c, r) not in closed
    ] + [
        (c * nr + r, (c + 1) * nr + r)
        for c in range(nc - 1)
        for r in range(nr)
        if ("h", c, r) not in closed
    ]
    return Roadmap(nodes, np.array(edges, dtype=np.int64), np.zeros(len(nodes)))


def maze_world() -> World:
    """The built-in 16.8 m x 12.6 m maze (walls, plus a roadmap along corridor centre-lines)."""
    road = _roadmap()
    return _floor_plan().world("maze", road.nodes, road.edges)
