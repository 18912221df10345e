"""The built-in ``rooms``: a corridor with identical rooms off both sides, the office floor
where every door opens on the same room.

A 42.2 m x 10.4 m floor. A 2 m corridor runs along x; eight rooms on each side, 4.8 m x 4 m,
each with the same two 1 m doors at the same places and the same cabinet against its back wall
(north rooms are the mirror image of south ones). Routes enter a room by one door and leave by
the other, so every room is a loop off the corridor.
"""

from __future__ import annotations

from bioslam.sim.world import FloorPlan, World

ROOMS_PER_SIDE = 8
ROOM = (4.8, 4.0)  # inside width along the corridor, depth
WALL = 0.2
CORRIDOR = 2.0
END = 1.0  # corridor beyond the last rooms, metres
DOORS = ((0.6, 1.6), (3.2, 4.2))  # door extents from a room's west wall
CABINET = (2.0, 3.0, 0.6)  # x from the west wall, x to, depth from the back wall
_STEP = 0.1

ROOMS_SIZE = (
    2 * END + ROOMS_PER_SIDE * (ROOM[0] + WALL) + WALL,
    2 * (ROOM[1] + WALL) + CORRIDOR,
)
CORRIDOR_Y = (ROOM[1] + WALL, ROOM[1] + WALL + CORRIDOR)


def room_origins() -> list[float]:
    """The x of each room's west inner wall (the same for the south and north room)."""
    return [END + WALL + k * (ROOM[0] + WALL) for k in range(ROOMS_PER_SIDE)]


def _floor_plan() -> FloorPlan:
    width, height = ROOMS_SIZE
    plan = FloorPlan(width, height, _STEP)
    plan.carve(0.0, CORRIDOR_Y[0], width, CORRIDOR_Y[1])
    room_w, depth = ROOM
    cx0, cx1, cdepth = CABINET
    for x in room_origins():
        plan.carve(x, 0.0, x + room_w, depth)  # south room
        plan.carve(x, height - depth, x + room_w, height)  # north room
        for d0, d1 in DOORS:
            plan.carve(x + d0, depth, x + d1, CORRIDOR_Y[0])
            plan.carve(x + d0, CORRIDOR_Y[1], x + d1, height - depth)
        plan.fill(x + cx0, 0.0, x + cx1, cdepth)
        plan.fill(x + cx0, height - cdepth, x + cx1, height)
    return plan


def rooms_world() -> World:
    """The built-in corridor with identical rooms (see the module) and its roadmap: the
    corridor centre-line, and through each room from one door to the other."""
    _, height = ROOMS_SIZE
    mid = 0.5 * (CORRIDOR_Y[0] + CORRIDOR_Y[1])
    inside = (0.5 * ROOM[1], height - 0.5 * ROOM[1])
    nodes: list[list[float]] = []
    edges: list[list[int]] = []
    previous = -1  # the corridor node at the previous room's east door
    for x in room_origins():
        doors = [x + 0.5 * (d0 + d1) for d0, d1 in DOORS]
        corridor = [len(nodes), len(nodes) + 1]
        nodes += [[dx, mid] for dx in doors]
        if previous >= 0:
            edges.append([previous, corridor[0]])
        edges.append(corridor)
        previous = corridor[1]
        for y in inside:
            first = len(nodes)
            nodes += [[dx, y] for dx in doors]
            edges += [[corridor[0], first], [first, first + 1], [first + 1, corridor[1]]]
    return _floor_plan().world("rooms", nodes, edges)
