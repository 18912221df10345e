"""A floor of identical city blocks as a map_server map (PGM + YAML), a world none of the
defaults were tuned on and one that repeats in both directions: twenty solid 4 m x 4 m blocks
on a 5.6 m grid, 1.6 m streets between them and round them, nothing else. Every crossing
looks like every other, one block's pitch away along either street, and halfway along a
block a scanner of short range sees two parallel walls and nothing to pin its position
along them.

    python benchmarks/blocks_floor_plan.py OUT_DIR   # writes OUT_DIR/blocks.{pgm,yaml}
    bioslam sim --world OUT_DIR/blocks.yaml ...

The benchmarks README ("A floor of identical blocks") runs routes on it.
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

BLOCKS = (5, 4)  # along x, along y
BLOCK, STREET = 4.0, 1.6
OUTER = 0.3  # the outer wall's thickness
WIDTH = 2 * OUTER + BLOCKS[0] * BLOCK + (BLOCKS[0] + 1) * STREET
HEIGHT = 2 * OUTER + BLOCKS[1] * BLOCK + (BLOCKS[1] + 1) * STREET


def floor_plan() -> np.ndarray:
    """The occupancy image, row 0 at the top (y = ``HEIGHT``)."""
    x, y = pixel_centres(WIDTH, HEIGHT)
    img = np.full(x.shape, FREE, np.uint8)
    box = partial(box_mask, x, y)
    img[~box(OUTER, OUTER, WIDTH - OUTER, HEIGHT - OUTER)] = OCCUPIED
    pitch = BLOCK + STREET
    for i in range(BLOCKS[0]):
        for j in range(BLOCKS[1]):
            west, south = OUTER + STREET + i * pitch, OUTER + STREET + j * pitch
            img[box(west, south, west + BLOCK, south + BLOCK)] = OCCUPIED
    return img[::-1]


def write_blocks(folder: Path) -> Path:
    """Write ``blocks.pgm`` and ``blocks.yaml`` into ``folder``; the YAML's path."""
    return write_floor_plan(folder, "blocks", floor_plan(), RESOLUTION)


if __name__ == "__main__":
    floor_plan_cli(__doc__, write_blocks)
