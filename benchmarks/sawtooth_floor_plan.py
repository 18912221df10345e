"""A corridor loop with a toothed wall as a map_server map (PGM + YAML), a world none of the
defaults were tuned on: a 3.2 m corridor round a 21.6 m x 11.6 m block, its outer wall along
the two long sides cut into 45° teeth 0.6 m deep every 1.2 m, the short sides plain. Along the
long sides the scan is pinned, but every tooth looks like the next; along the short sides a
short-range scanner sees two parallel walls and nothing else.

    python benchmarks/sawtooth_floor_plan.py OUT_DIR   # writes OUT_DIR/sawtooth.{pgm,yaml}
    bioslam sim --world OUT_DIR/sawtooth.yaml ...

The benchmarks README ("Three more unseen floors") runs routes on it.
"""

from __future__ import annotations

from functools import partial
from pathlib import Path

import numpy as np
import office_floor_plan as plan

WIDTH, HEIGHT = 30.0, 20.0
OUTER = (1.0, 1.0, 29.0, 19.0)  # the corridor's outer edge (x0, y0, x1, y1)
CORRIDOR = 3.2
PITCH, DEPTH = 1.2, 0.6


def floor_plan() -> np.ndarray:
    """The occupancy image, row 0 at the top (y = ``HEIGHT``)."""
    x, y = plan.pixel_centres(WIDTH, HEIGHT)
    img = np.full(x.shape, plan.OCCUPIED, np.uint8)
    box = partial(plan.box_mask, x, y)
    x0, y0, x1, y1 = OUTER
    img[box(x0, y0, x1, y1)] = plan.FREE
    img[box(x0 + CORRIDOR, y0 + CORRIDOR, x1 - CORRIDOR, y1 - CORRIDOR)] = plan.OCCUPIED
    # a tooth rises from the wall DEPTH deep and falls back to it over half a pitch, a pixel
    # column at a time
    phase = (x - x0) % PITCH
    steps = np.floor(phase / plan.RESOLUTION) * plan.RESOLUTION
    depth = np.where(phase < DEPTH, DEPTH - steps, 0.0)
    img[(y >= y0) & (y < y0 + depth)] = plan.OCCUPIED
    img[(y < y1) & (y >= y1 - depth)] = plan.OCCUPIED
    return img[::-1]


def write_sawtooth(folder: Path) -> Path:
    """Write ``sawtooth.pgm`` and ``sawtooth.yaml`` into ``folder``; the YAML's path."""
    return plan.write_floor_plan(folder, "sawtooth", floor_plan(), plan.RESOLUTION)


if __name__ == "__main__":
    plan.floor_plan_cli(__doc__, write_sawtooth)
