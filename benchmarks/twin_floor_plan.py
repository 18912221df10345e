"""A floor that is its own image turned half round, as a map_server map (PGM + YAML): every
place has a twin across the floor's centre that looks exactly the same the other way round,
so a rotation-tolerant place recogniser meets a perfect look-alike of wherever it stands.
A 30 m x 20 m floor: a 2.2 m corridor round a core, a cross corridor through the core, a
short corridor from the cross corridor to the ring in each half, a room of pillars and a desk
off the ring, and niches along it, each with its twin turned 180° about the centre.

    python benchmarks/twin_floor_plan.py OUT_DIR   # writes OUT_DIR/twin.{pgm,yaml}
    bioslam sim --world OUT_DIR/twin.yaml ...

The benchmarks README ("A floor that is its own twin") runs routes on it.
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

WIDTH, HEIGHT = 30.0, 20.0
RING = (3.0, 3.0, 27.0, 17.0)  # the corridor's outer edge (x0, y0, x1, y1)
CORRIDOR = 2.2
CROSS = (8.9, 11.1)  # the cross corridor's south and north edges (y)
SPUR = (9.0, 11.0)  # the short corridor from the cross corridor north to the ring (x)
ROOM = (5.5, 17.0, 12.5, 19.6)  # off the ring's north side, its door below
NICHES = (14.0, 17.5, 22.0)  # along the ring's north wall (x of their west edges)


def floor_plan() -> np.ndarray:
    """The occupancy image, row 0 at the top (y = ``HEIGHT``): every box drawn twice, as
    given and turned half round about the floor's centre."""
    x, y = pixel_centres(WIDTH, HEIGHT)
    img = np.full(x.shape, OCCUPIED, np.uint8)
    inside = partial(box_mask, x, y)

    def fill(x0: float, y0: float, x1: float, y1: float, value: int) -> None:
        img[inside(x0, y0, x1, y1)] = value
        img[inside(WIDTH - x1, HEIGHT - y1, WIDTH - x0, HEIGHT - y0)] = value

    x0, y0, x1, y1 = RING
    fill(x0, y0, x1, y1, FREE)
    fill(x0 + CORRIDOR, y0 + CORRIDOR, x1 - CORRIDOR, y1 - CORRIDOR, OCCUPIED)
    fill(x0 + CORRIDOR, CROSS[0], x1 - CORRIDOR, CROSS[1], FREE)
    fill(SPUR[0], CROSS[1], SPUR[1], y1 - CORRIDOR, FREE)
    rx0, ry0, rx1, ry1 = ROOM
    fill(rx0, ry0 + 0.15, rx1, ry1, FREE)
    fill(rx0 + 1.0, ry0, rx0 + 2.2, ry0 + 0.15, FREE)  # the door
    for px in (rx0 + 3.0, rx0 + 5.0):
        fill(px - 0.2, ry0 + 1.1, px + 0.2, ry0 + 1.5, OCCUPIED)
    fill(rx1 - 1.0, ry1 - 0.9, rx1 - 0.2, ry1 - 0.3, OCCUPIED)  # a desk
    for niche in NICHES:
        fill(niche, y1, niche + 0.8, y1 + 0.3, FREE)
    fill(x0 + 0.6, y0 + 0.6, x0 + 1.0, y0 + 1.0, OCCUPIED)  # a post in one corner
    return img[::-1]


def write_twin(folder: Path) -> Path:
    """Write ``twin.pgm`` and ``twin.yaml`` into ``folder``; the YAML's path."""
    return write_floor_plan(folder, "twin", floor_plan(), RESOLUTION)


if __name__ == "__main__":
    floor_plan_cli(__doc__, write_twin)
