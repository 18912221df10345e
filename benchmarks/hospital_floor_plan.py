"""A hospital ward as a map_server map (PGM + YAML), a world none of the defaults were tuned
on: two parallel 44 m corridors, 2 m wide and 10 m apart, joined at both ends and in the middle,
with identical 3.2 m rooms opening off both sides of each corridor through 1 m doors every
3.5 m (none beside the middle cross corridor). Every door looks like the next, along a
corridor and across to the other one.

    python benchmarks/hospital_floor_plan.py OUT_DIR   # writes OUT_DIR/hospital.{pgm,yaml}
    bioslam sim --world OUT_DIR/hospital.yaml ...

The benchmarks README ("Three more unseen floors") runs routes on it.
"""

from __future__ import annotations

from functools import partial
from pathlib import Path

import numpy as np
import office_floor_plan as plan

WIDTH, HEIGHT = 46.0, 20.0
CORRIDORS = (4.0, 14.0)  # centre lines (y) of the two long corridors
HALF = 1.0  # half a corridor's width
CROSS = (2.0, 23.0, 44.0)  # centre lines (x) of the cross corridors, 2 m wide
ROOM_PITCH, ROOM_DEPTH = 3.5, 2.8
DOOR = (1.2, 2.2)  # a door's sides, from its room's west edge (m)


def floor_plan() -> np.ndarray:
    """The occupancy image, row 0 at the top (y = ``HEIGHT``)."""
    x, y = plan.pixel_centres(WIDTH, HEIGHT)
    img = np.full(x.shape, plan.OCCUPIED, np.uint8)
    box = partial(plan.box_mask, x, y)
    for yc in CORRIDORS:
        img[box(1.0, yc - HALF, WIDTH - 1.0, yc + HALF)] = plan.FREE
    for xc in CROSS:
        img[box(xc - HALF, CORRIDORS[0], xc + HALF, CORRIDORS[1])] = plan.FREE
    for yc in CORRIDORS:
        for x0 in np.arange(4.0, 42.0, ROOM_PITCH):
            if abs(x0 + 1.5 - CROSS[1]) < 2.5:
                continue  # the middle cross corridor
            for side in (-1.0, 1.0):
                wall = yc + side * HALF  # the corridor's wall the room opens through
                near, far = wall + side * 0.15, wall + side * ROOM_DEPTH
                img[box(x0 + 0.15, min(near, far), x0 + 3.35, max(near, far))] = plan.FREE
                img[box(x0 + DOOR[0], min(wall, near) - 0.05, x0 + DOOR[1],
                        max(wall, near) + 0.05)] = plan.FREE  # fmt: skip
    return img[::-1]


def write_hospital(folder: Path) -> Path:
    """Write ``hospital.pgm`` and ``hospital.yaml`` into ``folder``; the YAML's path."""
    return plan.write_floor_plan(folder, "hospital", floor_plan(), plan.RESOLUTION)


if __name__ == "__main__":
    plan.floor_plan_cli(__doc__, write_hospital)
