"""A parking deck as a map_server map (PGM + YAML), a world none of the defaults were tuned on:
a 38 m x 24 m deck with four rows of cars parked nose-in (4.6 m x 1.9 m on a 2.5 m pitch, a
fifth of the bays empty), 2 m lanes between the rows and round them, and three pillars
between the middle rows. A short-range scanner in a lane sees the cars' flanks and the gaps
between them, and one stretch of lane looks like the next.

    python benchmarks/parking_floor_plan.py OUT_DIR   # writes OUT_DIR/parking.{pgm,yaml}
    bioslam sim --world OUT_DIR/parking.yaml ...

The benchmarks README ("Three more unseen floors") runs routes on it.
"""

from __future__ import annotations

from functools import partial
from pathlib import Path

import numpy as np
import office_floor_plan as plan

WIDTH, HEIGHT = 40.0, 26.0
ROWS = (2.0, 8.6, 13.8, 20.4)  # the south edge (y) of each row of cars
CAR = (1.9, 4.6)  # width (x), length (y)
PITCH = 2.5
PILLARS = (10.0, 20.0, 30.0)  # x, between the middle rows


def floor_plan(seed: int = 7) -> np.ndarray:
    """The occupancy image, row 0 at the top (y = ``HEIGHT``)."""
    x, y = plan.pixel_centres(WIDTH, HEIGHT)
    img = np.full(x.shape, plan.OCCUPIED, np.uint8)
    box = partial(plan.box_mask, x, y)
    img[box(1.0, 1.0, WIDTH - 1.0, HEIGHT - 1.0)] = plan.FREE
    rng = np.random.default_rng(seed)
    for row in ROWS:
        for bay in np.arange(3.0, 37.0, PITCH):
            if rng.random() < 0.2:
                continue  # an empty bay
            img[box(bay + 0.3, row, bay + 0.3 + CAR[0], row + CAR[1])] = plan.OCCUPIED
    for px in PILLARS:
        img[box(px - 0.3, 13.2, px + 0.3, 13.8)] = plan.OCCUPIED
    return img[::-1]


def write_parking(folder: Path) -> Path:
    """Write ``parking.pgm`` and ``parking.yaml`` into ``folder``; the YAML's path."""
    return plan.write_floor_plan(folder, "parking", floor_plan(), plan.RESOLUTION)


if __name__ == "__main__":
    plan.floor_plan_cli(__doc__, write_parking)
