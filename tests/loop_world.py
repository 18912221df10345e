"""A small ring-corridor world and a route that drives it twice: the shortest drive on which a
SLAM system must close a loop. Shared by the end-to-end tests."""

from __future__ import annotations

import numpy as np

from bioslam.sim import Route, World
from bioslam.sim.world import box_segments


def ring_world() -> World:
    """An 8 m x 6 m block with a 5 m x 3 m core, 1.5 m corridors, and a few recesses and
    pillars so that places along the ring look different from one another."""
    walls = [
        box_segments(0.0, 0.0, 8.0, 6.0),
        box_segments(1.5, 1.5, 6.5, 4.5),
        box_segments(2.2, 0.0, 2.6, 0.35),
        box_segments(5.0, 5.6, 5.6, 6.0),
        box_segments(7.6, 2.0, 8.0, 2.3),
        box_segments(0.0, 3.6, 0.3, 4.4),
        box_segments(3.5, 1.2, 4.3, 1.5),
        box_segments(6.5, 3.0, 6.8, 3.3),
    ]
    return World(np.concatenate(walls), name="ring")


def ring_route(laps: float = 2.0, speed: float = 0.4, radius: float = 0.5) -> Route:
    """Counter-clockwise laps along the corridor centre line (0.75 m from the walls) with
    rounded corners, at constant speed."""
    x0, y0, x1, y1 = 0.75, 0.75, 7.25, 5.25
    corners = [(x1 - radius, y0 + radius, -np.pi / 2), (x1 - radius, y1 - radius, 0.0),
               (x0 + radius, y1 - radius, np.pi / 2), (x0 + radius, y0 + radius, np.pi)]
    step = 0.01
    points: list[np.ndarray] = []
    starts = [(x0 + radius, y0), (x1, y0 + radius), (x1 - radius, y1), (x0, y1 - radius)]
    ends = [(x1 - radius, y0), (x1, y1 - radius), (x0 + radius, y1), (x0, y0 + radius)]
    for (sx, sy), (ex, ey), (cx, cy, a0) in zip(starts, ends, corners, strict=True):
        n = max(2, int(np.hypot(ex - sx, ey - sy) / step))
        points.append(np.column_stack([np.linspace(sx, ex, n), np.linspace(sy, ey, n)]))
        arc = np.linspace(a0, a0 + np.pi / 2, max(2, int(radius * np.pi / 2 / step)))
        points.append(np.column_stack([cx + radius * np.cos(arc), cy + radius * np.sin(arc)]))
    lap = np.concatenate(points)
    lap = lap[np.concatenate([[True], np.hypot(*np.diff(lap, axis=0).T) > 1e-9])]
    if np.allclose(lap[0], lap[-1]):
        lap = lap[:-1]
    lap_length = float(np.sum(np.hypot(*np.diff(np.vstack([lap, lap[:1]]), axis=0).T)))
    path = np.concatenate([lap] * int(np.ceil(laps)))
    s = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(path, axis=0).T))])
    keep = s <= laps * lap_length + 1e-9
    path, s = path[keep], s[keep]
    heading = np.unwrap(np.arctan2(np.gradient(path[:, 1]), np.gradient(path[:, 0])))
    return Route(s / speed, np.column_stack([path, heading]))
