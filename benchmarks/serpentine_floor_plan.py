"""A serpentine floor as a map_server map (PGM + YAML), a world none of the defaults were
tuned on, made of what a corridor-following odometry and a place recogniser find hardest: six
identical 24 m corridors 1.8 m wide joined by U-turns at alternate ends, three identical
niches at the same places along each (6 m apart), and a return corridor down the east side
with two pillars in it.

    python benchmarks/serpentine_floor_plan.py OUT_DIR   # writes OUT_DIR/serpentine.{pgm,yaml}
    bioslam sim --world OUT_DIR/serpentine.yaml ...

The benchmarks README ("Slides that add up past the search") runs routes on it.
"""

from __future__ import annotations

from functools import partial
from pathlib import Path

import numpy as np
from office_floor_plan import (
    FREE,
    OCCUPIED,
    RESOLUTION,
    box_mask,
    floor_plan_cli,
    pixel_centres,
    write_floor_plan,
)

WIDTH, HEIGHT = 32.0, 16.0
WEST, EAST = 2.0, 26.0  # the corridors' ends
CORRIDOR, PITCH = 1.8, 2.2  # a corridor's width; one corridor and the wall beside it
NICHES = (8.0, 14.0, 20.0)
RETURN_WIDTH = 1.8


def floor_plan() -> np.ndarray:
    """The occupancy image, row 0 at the top (y = ``HEIGHT``)."""
    x, y = pixel_centres(WIDTH, HEIGHT)
    img = np.full(x.shape, OCCUPIED, np.uint8)
    box = partial(box_mask, x, y)
    corridors = 6
    for k in range(corridors):
        south = 1.0 + k * PITCH
        img[box(WEST, south, EAST, south + CORRIDOR)] = FREE
        for niche in NICHES:
            img[box(niche, south + CORRIDOR, niche + 0.8, south + CORRIDOR + 0.3)] = FREE
        if k < corridors - 1:
            turn = EAST - CORRIDOR if k % 2 == 0 else WEST
            img[box(turn, south + CORRIDOR, turn + CORRIDOR, south + PITCH)] = FREE
    top = 1.0 + (corridors - 1) * PITCH
    for south in (1.0, top):  # the first and last corridors open onto the return corridor
        img[box(EAST, south, EAST + 0.5, south + CORRIDOR)] = FREE
    img[box(EAST + 0.5, 1.0, EAST + 0.5 + RETURN_WIDTH, top + CORRIDOR)] = FREE
    for py in (4.0, 8.0):
        img[box(EAST + 1.2, py, EAST + 1.6, py + 0.4)] = OCCUPIED
    return img[::-1]


def write_serpentine(folder: Path) -> Path:
    """Write ``serpentine.pgm`` and ``serpentine.yaml`` into ``folder``; the YAML's path."""
    return write_floor_plan(folder, "serpentine", floor_plan(), RESOLUTION)


if __name__ == "__main__":
    floor_plan_cli(__doc__, write_serpentine)
