"""An open-plan office of identical cubicles as a map_server map (PGM + YAML), a world none of
the defaults were tuned on and one that invites false loop closures in two dimensions at
once: a 30 m x 22 m hall holding a 7 x 5 grid of identical cubicles on a 4 m pitch, each a
2.4 m U of 8 cm partitions open to the south, split down the middle, with a desk in each
half. Every aisle crossing looks like every other, and the partitions are thin enough that
both faces of one fall within a cell of the registration's map.

    python benchmarks/cubicles_floor_plan.py OUT_DIR   # writes OUT_DIR/cubicles.{pgm,yaml}
    bioslam sim --world OUT_DIR/cubicles.yaml ...

The benchmarks README ("An unseen open-plan office of identical cubicles") runs routes on it.
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

WIDTH, HEIGHT = 30.0, 22.0
PITCH = 4.0
CUBICLE = 2.4
PARTITION = 0.08
DESK = 0.6


def floor_plan() -> np.ndarray:
    """The occupancy image, row 0 at the top (y = ``HEIGHT``)."""
    x, y = pixel_centres(WIDTH, HEIGHT)
    img = np.full(x.shape, FREE, np.uint8)
    box = partial(box_mask, x, y)
    img[~box(0.3, 0.3, WIDTH - 0.3, HEIGHT - 0.3)] = OCCUPIED
    for cx in np.arange(2.5, WIDTH - 3.0, PITCH):
        for cy in np.arange(2.5, HEIGHT - 3.0, PITCH):
            top = cy + CUBICLE
            img[box(cx, cy, cx + PARTITION, top)] = OCCUPIED  # west side
            img[box(cx + CUBICLE - PARTITION, cy, cx + CUBICLE, top)] = OCCUPIED  # east side
            img[box(cx, top - PARTITION, cx + CUBICLE, top)] = OCCUPIED  # back
            middle = cx + CUBICLE / 2
            img[box(middle - PARTITION / 2, cy + 0.9, middle + PARTITION / 2, top)] = OCCUPIED
            for left in (cx + 0.3, cx + CUBICLE - 0.3 - DESK):
                img[box(left, top - 0.1 - DESK, left + DESK, top - 0.1)] = OCCUPIED
    return img[::-1]


def write_cubicles(folder: Path) -> Path:
    """Write ``cubicles.pgm`` and ``cubicles.yaml`` into ``folder``; the YAML's path."""
    return write_floor_plan(folder, "cubicles", floor_plan(), RESOLUTION)


if __name__ == "__main__":
    floor_plan_cli(__doc__, write_cubicles)
