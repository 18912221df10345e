"""A ring-corridor floor as a map_server map (PGM + YAML), a world none of the defaults were
tuned on: a 40 m x 28 m floor whose 2.2 m corridor runs round a solid core, sixteen identical
offices off its long sides (a cabinet at the same place in each, a chair where it falls), a
2 m corridor cut diagonally through the core at 28° (off the axes the others run along, its
walls a staircase of 5 cm pixels), and a lab of pillars off its west side. ``--width`` and
``--height`` stretch it (a 110 m x 40 m floor has corridors longer than a SICK's 30 m of
matched range, with an office door every 4 m: the benchmarks README's "Long corridors").

    python benchmarks/ring_floor_plan.py OUT_DIR   # writes OUT_DIR/ring.{pgm,yaml}
    python benchmarks/ring_floor_plan.py OUT_DIR --width 110 --height 40   # ring110x40.*
    bioslam sim --world OUT_DIR/ring.yaml ...

The benchmarks README ("Where the map is surest") runs thinned and dense routes on it.
"""

from __future__ import annotations

import argparse
import math
from functools import partial
from pathlib import Path

import numpy as np
from office_floor_plan import (
    FREE,
    OCCUPIED,
    RESOLUTION,
    box_mask,
    pixel_centres,
    write_floor_plan,
)

WIDTH, HEIGHT = 40.0, 28.0
RING = (5.0, 5.0, 35.0, 23.0)  # the corridor's outer edge (x0, y0, x1, y1)
CORE = (7.2, 7.2, 32.8, 20.8)  # its inner edge
OFFICE = 4.0  # office pitch along the corridor; 3.85 m inside
DIAGONAL_WIDTH = 2.0


def floor_plan(seed: int = 7, width: float = WIDTH, height: float = HEIGHT) -> np.ndarray:
    """The occupancy image, row 0 at the top (y = ``height``); the corridor keeps its 5 m
    from the floor's edges, the core its 2.2 m from the corridor's."""
    ring = (RING[0], RING[1], width - (WIDTH - RING[2]), height - (HEIGHT - RING[3]))
    core = (CORE[0], CORE[1], width - (WIDTH - CORE[2]), height - (HEIGHT - CORE[3]))
    x, y = pixel_centres(width, height)
    img = np.full(x.shape, OCCUPIED, np.uint8)
    box = partial(box_mask, x, y)
    img[box(*ring) & ~box(*core)] = FREE
    rng = np.random.default_rng(seed)
    sides = (
        (0.3, 4.85, (4.84, 5.01)),
        (height - 4.85, height - 0.3, (height - 5.01, height - 4.84)),
    )
    for x0 in np.arange(ring[0] + 0.2, ring[2] - 1.0, OFFICE):
        for y0, y1, door in sides:
            img[box(x0, y0, x0 + 3.85, y1)] = FREE
            img[box(x0 + 1.4, door[0], x0 + 2.5, door[1])] = FREE
            cabinet = y0 + 0.3 if y0 < ring[1] else y1 - 0.9
            img[box(x0 + 0.2, cabinet, x0 + 1.2, cabinet + 0.6)] = OCCUPIED
            cx, cy = rng.uniform(x0 + 1.5, x0 + 3.2), rng.uniform(y0 + 1.2, y1 - 1.2)
            img[box(cx, cy, cx + 0.45, cy + 0.45)] = OCCUPIED
    dx, dy = core[2] - core[0], core[3] - core[1]
    length = math.hypot(dx, dy)
    along = ((x - core[0]) * dx + (y - core[1]) * dy) / length
    across = (-(x - core[0]) * dy + (y - core[1]) * dx) / length
    diagonal = (np.abs(across) < DIAGONAL_WIDTH / 2) & (along > -1.0) & (along < length + 1.0)
    img[diagonal & box(*ring)] = FREE
    img[box(0.3, 7.5, ring[0] + 0.01, height - 7.5)] = FREE  # the lab, open on the corridor
    for py in np.arange(9.5, height - 9.0, 3.0):
        img[box(2.3, py, 2.7, py + 0.4)] = OCCUPIED
    return img[::-1]


def write_ring(folder: Path, width: float = WIDTH, height: float = HEIGHT) -> Path:
    """Write ``ring.pgm`` and ``ring.yaml`` (``ring<width>x<height>.*`` when stretched) into
    ``folder``; the YAML's path."""
    if width < WIDTH or height < HEIGHT:
        raise ValueError(f"the floor is at least {WIDTH:g} m x {HEIGHT:g} m")
    name = "ring" if (width, height) == (WIDTH, HEIGHT) else f"ring{width:g}x{height:g}"
    return write_floor_plan(folder, name, floor_plan(width=width, height=height), RESOLUTION)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("out", nargs="?", default=".", help="folder to write into")
    parser.add_argument("--width", type=float, default=WIDTH, help="metres (default 40)")
    parser.add_argument("--height", type=float, default=HEIGHT, help="metres (default 28)")
    args = parser.parse_args()
    print(write_ring(Path(args.out), args.width, args.height))


if __name__ == "__main__":
    main()
