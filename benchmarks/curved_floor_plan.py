"""A floor of curved corridors as a map_server map (PGM + YAML), a world none of the defaults
were tuned on: a 2.4 m corridor round an ellipse of 34 m x 26 m (radius of curvature 10-22 m,
so that no stretch of it is straight), a corridor cut through the middle at 20° to the axes
with eight rooms off it (a cabinet in each, where it falls) and a round hall of 7 m with a
pillar at its centre off the east side. Along the curved corridor a scan constrains the
motion along it only through the walls' curvature: the pose can slide along the corridor by
turning with it, the degenerate direction a straight corridor has, bent.

    python benchmarks/curved_floor_plan.py OUT_DIR   # writes OUT_DIR/curved.{pgm,yaml}
    bioslam sim --world OUT_DIR/curved.yaml ...

The benchmarks README ("Unseen floors: a garage of pillars, curved corridors") runs routes
on it.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from office_floor_plan import (
    FREE,
    OCCUPIED,
    RESOLUTION,
    floor_plan_cli,
    pixel_centres,
    write_floor_plan,
)

WIDTH, HEIGHT = 44.0, 36.0
CENTRE = (22.0, 18.0)
SEMI_AXES = (17.0, 13.0)  # of the corridor's centre line
CORRIDOR = 2.4
MIDDLE_TURN = math.radians(20.0)
HALL = (40.0, 18.0, 3.5)  # centre and radius


def floor_plan(seed: int = 5) -> np.ndarray:
    """The occupancy image, row 0 at the top (y = ``HEIGHT``)."""
    x, y = pixel_centres(WIDTH, HEIGHT)
    img = np.full(x.shape, OCCUPIED, np.uint8)
    dx, dy = x - CENTRE[0], y - CENTRE[1]
    # the ellipse's normalised radius; its width there is about CORRIDOR metres
    radius = np.hypot(dx / SEMI_AXES[0], dy / SEMI_AXES[1])
    half = CORRIDOR / 2 / np.mean(SEMI_AXES)
    img[np.abs(radius - 1.0) < half] = FREE
    along = dx * math.cos(MIDDLE_TURN) + dy * math.sin(MIDDLE_TURN)
    across = -dx * math.sin(MIDDLE_TURN) + dy * math.cos(MIDDLE_TURN)
    img[(np.abs(across) < 1.1) & (np.abs(along) < SEMI_AXES[0] - 0.5)] = FREE
    rng = np.random.default_rng(seed)
    for start in np.arange(-10.0, 10.0, 5.0):
        for side in (1.0, -1.0):
            depth = rng.uniform(2.5, 4.0)
            inside = (along > start) & (along < start + 4.0)
            off = side * across
            img[inside & (off > 1.25) & (off < 1.25 + depth)] = FREE
            img[(along > start + 1.5) & (along < start + 2.6) & (off > 1.0) & (off < 1.3)] = FREE
            u, v = start + rng.uniform(0.5, 3.0), rng.uniform(1.8, 0.45 + depth)
            img[(along > u) & (along < u + 0.5) & (off > v) & (off < v + 0.5)] = OCCUPIED
    hx, hy, hr = HALL
    img[np.hypot(x - hx, y - hy) < hr] = FREE
    img[np.hypot(x - hx, y - hy) < 0.4] = OCCUPIED
    img[(np.abs(y - hy) < 1.1) & (x > hx - 2.0) & (x < hx)] = FREE
    return img[::-1]


def write_curved(folder: Path) -> Path:
    """Write ``curved.pgm`` and ``curved.yaml`` into ``folder``; the YAML's path."""
    return write_floor_plan(folder, "curved", floor_plan(), RESOLUTION)


if __name__ == "__main__":
    floor_plan_cli(__doc__, write_curved)
