"""The built-in ``warehouse``: long identical aisles between pallet racks, the layout that
makes a scan matcher slide along an aisle or jump to the next one.

A 36.1 m x 20.2 m hall. Racks run along x between two 4 m cross aisles; every aisle is 2.4 m
wide and flanked on both sides by the same rack face: an upright (0.1 m post) every 2.8 m, and
0.3 m behind the face the rack's solid back (the goods, or the wall for the racks along the
side walls). So every aisle looks the same from the same place in it, and along an aisle the
view repeats every 2.8 m. The aisles are 28 m long: from one end a 30 m scanner looking down
the aisle sees no end wall. One loading bay in the east wall breaks the hall's symmetry (else a
half turn maps the hall onto itself).
"""

from __future__ import annotations

from bioslam.sim.world import FloorPlan, World

AISLES = 6
AISLE_WIDTH = 2.4
CROSS_AISLE = 4.0
BAYS = 10
BAY = 2.8  # upright to upright along a rack, metres
UPRIGHT = 0.1  # post size, metres
BAY_DEPTH = 0.3  # rack face to the rack's solid back
SPINE = 0.2  # a double rack's solid middle
_STEP = 0.1

RACK_LENGTH = BAYS * BAY + UPRIGHT
WALL_RACK = BAY_DEPTH + UPRIGHT
DOUBLE_RACK = 2 * (UPRIGHT + BAY_DEPTH) + SPINE
WAREHOUSE_SIZE = (
    2 * CROSS_AISLE + RACK_LENGTH,
    2 * WALL_RACK + AISLES * AISLE_WIDTH + (AISLES - 1) * DOUBLE_RACK,
)
#: The loading bay, a 3 m x 1 m recess in the east wall: x0, y0, x1, y1.
LOADING_BAY = (WAREHOUSE_SIZE[0], 3.0, WAREHOUSE_SIZE[0] + 1.0, 6.0)


def aisle_centres() -> list[float]:
    """The y of each aisle's centre-line, south to north."""
    first = WALL_RACK + 0.5 * AISLE_WIDTH
    return [first + k * (AISLE_WIDTH + DOUBLE_RACK) for k in range(AISLES)]


def _uprights(plan: FloorPlan, y0: float) -> None:
    """A row of posts whose south side is at ``y0``, along the racks' length."""
    for k in range(BAYS + 1):
        x = CROSS_AISLE + k * BAY
        plan.fill(x, y0, x + UPRIGHT, y0 + UPRIGHT)


def _floor_plan() -> FloorPlan:
    width, height = WAREHOUSE_SIZE
    plan = FloorPlan(LOADING_BAY[2], height, _STEP)
    plan.carve(0.0, 0.0, width, height)
    x0, x1 = CROSS_AISLE, CROSS_AISLE + RACK_LENGTH
    _uprights(plan, BAY_DEPTH)  # the racks along the south wall
    _uprights(plan, height - WALL_RACK)  # and along the north wall
    for k in range(AISLES - 1):
        south = WALL_RACK + (k + 1) * AISLE_WIDTH + k * DOUBLE_RACK
        _uprights(plan, south)
        back = south + UPRIGHT + BAY_DEPTH
        plan.fill(x0, back, x1, back + SPINE)
        _uprights(plan, back + SPINE + BAY_DEPTH)
    plan.carve(*LOADING_BAY)
    return plan


def warehouse_world() -> World:
    """The built-in warehouse (see the module): walls, racks, and a roadmap along the aisle
    and cross-aisle centre-lines (a ladder: every aisle can be driven both ways)."""
    width, _ = WAREHOUSE_SIZE
    xs = (0.5 * CROSS_AISLE, width - 0.5 * CROSS_AISLE)
    ys = aisle_centres()
    nodes = [[x, y] for x in xs for y in ys]
    n = len(ys)
    edges = [[k, n + k] for k in range(n)]  # down each aisle
    edges += [[c * n + k, c * n + k + 1] for c in range(2) for k in range(n - 1)]
    return _floor_plan().world("warehouse", nodes, edges)
