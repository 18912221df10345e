"""A library floor as a map_server map (PGM + YAML), a world none of the defaults were tuned
on and one that invites false closures: a 34 m x 24 m hall with two blocks of seven identical
bookshelf stacks (6 m long, 1.2 m aisles), a reading room of fourteen identical square tables
4 m apart behind a partition with three doors, a colonnade of pillars 3 m apart along the
south wall, and a few book carts where they were left.

    python benchmarks/library_floor_plan.py OUT_DIR   # writes OUT_DIR/library.{pgm,yaml}
    bioslam sim --world OUT_DIR/library.yaml ...

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

WIDTH, HEIGHT = 34.0, 24.0
STACK_PITCH = 1.7  # a 0.5 m stack and a 1.2 m aisle
PARTITION_Y = 14.0  # the reading room's south wall
TABLE_PITCH = 4.0


def floor_plan(seed: int = 3) -> np.ndarray:
    """The occupancy image, row 0 at the top (y = ``HEIGHT``)."""
    x, y = pixel_centres(WIDTH, HEIGHT)
    img = np.full(x.shape, OCCUPIED, np.uint8)
    box = partial(box_mask, x, y)
    img[box(0.3, 0.3, WIDTH - 0.3, HEIGHT - 0.3)] = FREE
    for block in (3.0, 19.0):
        for k in range(7):
            img[box(block + k * STACK_PITCH, 4.0, block + k * STACK_PITCH + 0.5, 10.0)] = OCCUPIED
    img[box(0.3, PARTITION_Y, WIDTH - 0.3, PARTITION_Y + 0.15)] = OCCUPIED
    for door in (5.0, 16.0, 27.0):
        img[box(door, PARTITION_Y - 0.1, door + 1.4, PARTITION_Y + 0.3)] = FREE
    for tx in np.arange(3.0, WIDTH - 3.0, TABLE_PITCH):
        for ty in (16.5, 20.0):
            img[box(tx, ty, tx + 1.2, ty + 1.2)] = OCCUPIED
    for px in np.arange(2.0, WIDTH - 1.0, 3.0):
        img[box(px, 1.8, px + 0.4, 2.2)] = OCCUPIED
    rng = np.random.default_rng(seed)
    for _ in range(6):
        cx, cy = rng.uniform(2.0, WIDTH - 3.0), rng.uniform(11.0, 13.0)
        img[box(cx, cy, cx + 0.5, cy + 0.3)] = OCCUPIED
    return img[::-1]


def write_library(folder: Path) -> Path:
    """Write ``library.pgm`` and ``library.yaml`` into ``folder``; the YAML's path."""
    return write_floor_plan(folder, "library", floor_plan(), RESOLUTION)


if __name__ == "__main__":
    floor_plan_cli(__doc__, write_library)
