"""The built-in ``hall``: an open 30 m x 20 m hall with a regular grid of pillars, a place
with no corridors to follow where every pillar has identical neighbours (a car park, a
factory floor). Routes drive the lanes between the pillars."""

from __future__ import annotations

from bioslam.sim.world import FloorPlan, World

HALL_SIZE = (30.0, 20.0)
PITCH = 5.0  # pillar to pillar, metres
PILLAR = 0.4
_STEP = 0.1


def hall_world() -> World:
    """The built-in pillar hall and its roadmap: a grid of lanes halfway between pillars."""
    width, height = HALL_SIZE
    plan = FloorPlan(width, height, _STEP)
    plan.carve(0.0, 0.0, width, height)
    nx, ny = round(width / PITCH), round(height / PITCH)
    half = 0.5 * PILLAR
    for i in range(1, nx):
        for j in range(1, ny):
            plan.fill(i * PITCH - half, j * PITCH - half, i * PITCH + half, j * PITCH + half)
    xs = [(i + 0.5) * PITCH for i in range(nx)]
    ys = [(j + 0.5) * PITCH for j in range(ny)]
    nodes = [[x, y] for x in xs for y in ys]
    edges = [[i * ny + j, i * ny + j + 1] for i in range(nx) for j in range(ny - 1)]
    edges += [[i * ny + j, (i + 1) * ny + j] for i in range(nx - 1) for j in range(ny)]
    return plan.world("hall", nodes, edges)
