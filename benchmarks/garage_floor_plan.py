"""A parking garage as a map_server map (PGM + YAML), a world none of the defaults were tuned
on and one that invites false loop closures: a 48 m x 32 m hall whose only features are
thirty identical 0.5 m pillars on a 7.5 m x 5.5 m grid, cars parked beside about a third of
them, and a stair core. Away from the outer walls a short-range scanner sees pillars alone,
and every bay looks like every other.

    python benchmarks/garage_floor_plan.py OUT_DIR   # writes OUT_DIR/garage.{pgm,yaml}
    bioslam sim --world OUT_DIR/garage.yaml ...

The benchmarks README ("Unseen floors: a garage of pillars, curved corridors") runs routes
on it.
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

WIDTH, HEIGHT = 48.0, 32.0
PILLAR = 0.5
PITCH = (7.5, 5.5)
PARKED = 0.35  # the share of pillars with a car beside them
CAR = (1.8, 2.5)
STAIRS = (20.0, 14.0, 28.0, 18.0)


def floor_plan(seed: int = 3) -> np.ndarray:
    """The occupancy image, row 0 at the top (y = ``HEIGHT``)."""
    x, y = pixel_centres(WIDTH, HEIGHT)
    img = np.full(x.shape, FREE, np.uint8)
    box = partial(box_mask, x, y)
    img[~box(0.3, 0.3, WIDTH - 0.3, HEIGHT - 0.3)] = OCCUPIED
    rng = np.random.default_rng(seed)
    for px in np.arange(6.0, WIDTH - 3.0, PITCH[0]):
        for py in np.arange(5.0, HEIGHT - 3.0, PITCH[1]):
            img[box(px, py, px + PILLAR, py + PILLAR)] = OCCUPIED
            if rng.random() < PARKED:
                cx = px + 1.2 + rng.uniform(0.0, 1.0)
                img[box(cx, py - 1.0, cx + CAR[0], py - 1.0 + CAR[1])] = OCCUPIED
    img[box(*STAIRS)] = OCCUPIED
    return img[::-1]


def write_garage(folder: Path) -> Path:
    """Write ``garage.pgm`` and ``garage.yaml`` into ``folder``; the YAML's path."""
    return write_floor_plan(folder, "garage", floor_plan(), RESOLUTION)


if __name__ == "__main__":
    floor_plan_cli(__doc__, write_garage)
