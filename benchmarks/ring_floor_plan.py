"""A ring-corridor floor as a map_server map (PGM + YAML), a world none of the defaults were
tuned on: a 40 m x 28 m floor whose 2.2 m corridor runs round a solid core, sixteen identical
offices off its long sides (a cabinet at the same place in each, a chair where it falls), a
2 m corridor cut diagonally through the core at 28° (off the axes the others run along, its
walls a staircase of 5 cm pixels), and a lab of pillars off its west side.

    python benchmarks/ring_floor_plan.py OUT_DIR   # writes OUT_DIR/ring.{pgm,yaml}
    bioslam sim --world OUT_DIR/ring.yaml ...

The benchmarks README ("Where the map is surest") runs thinned and dense routes on it.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
from office_floor_plan import FREE, OCCUPIED, write_floor_plan

RESOLUTION = 0.05  # metres per pixel
WIDTH, HEIGHT = 40.0, 28.0
RING = (5.0, 5.0, 35.0, 23.0)  # the corridor's outer edge (x0, y0, x1, y1)
CORE = (7.2, 7.2, 32.8, 20.8)  # its inner edge
OFFICE = 4.0  # office pitch along the corridor; 3.85 m inside
DIAGONAL_WIDTH = 2.0


def floor_plan(seed: int = 7) -> np.ndarray:
    """The occupancy image, row 0 at the top (y = HEIGHT)."""
    rows, cols = round(HEIGHT / RESOLUTION), round(WIDTH / RESOLUTION)
    img = np.full((rows, cols), OCCUPIED, np.uint8)
    y, x = (np.mgrid[0:rows, 0:cols] + 0.5) * RESOLUTION

    def box(x0: float, y0: float, x1: float, y1: float) -> np.ndarray:
        return (x >= x0) & (x < x1) & (y >= y0) & (y < y1)

    img[box(*RING) & ~box(*CORE)] = FREE
    rng = np.random.default_rng(seed)
    for x0 in np.arange(RING[0] + 0.2, RING[2] - 1.0, OFFICE):
        for y0, y1, door in ((0.3, 4.85, (4.84, 5.01)), (23.15, 27.7, (22.99, 23.16))):
            img[box(x0, y0, x0 + 3.85, y1)] = FREE
            img[box(x0 + 1.4, door[0], x0 + 2.5, door[1])] = FREE
            cabinet = y0 + 0.3 if y0 < RING[1] else y1 - 0.9
            img[box(x0 + 0.2, cabinet, x0 + 1.2, cabinet + 0.6)] = OCCUPIED
            cx, cy = rng.uniform(x0 + 1.5, x0 + 3.2), rng.uniform(y0 + 1.2, y1 - 1.2)
            img[box(cx, cy, cx + 0.45, cy + 0.45)] = OCCUPIED
    dx, dy = CORE[2] - CORE[0], CORE[3] - CORE[1]
    length = math.hypot(dx, dy)
    along = ((x - CORE[0]) * dx + (y - CORE[1]) * dy) / length
    across = (-(x - CORE[0]) * dy + (y - CORE[1]) * dx) / length
    diagonal = (np.abs(across) < DIAGONAL_WIDTH / 2) & (along > -1.0) & (along < length + 1.0)
    img[diagonal & box(*RING)] = FREE
    img[box(0.3, 7.5, RING[0] + 0.01, 20.5)] = FREE  # the lab, open on the corridor
    for py in (9.5, 12.5, 15.5, 18.5):
        img[box(2.3, py, 2.7, py + 0.4)] = OCCUPIED
    return img[::-1]


def write_ring(folder: Path) -> Path:
    """Write ``ring.pgm`` and ``ring.yaml`` into ``folder``; the YAML's path."""
    return write_floor_plan(folder, "ring", floor_plan(), RESOLUTION)


if __name__ == "__main__":
    print(write_ring(Path(sys.argv[1] if len(sys.argv) > 1 else ".")))
