"""A large pillar hall as a map_server map (PGM + YAML), a world none of the defaults were tuned
on: a 64 m x 48 m hall, wider than a UTM-30LX's 30 m of matched range is long, with 0.5 m
pillars on an 8 m pitch and a few pallets and machines set down between them (the lanes kept
open). Few walls are in reach of a short-range scanner, and every lane crossing looks like the
next; a loop closure's submap spans tens of metres.

    python benchmarks/pillar_hall_floor_plan.py OUT_DIR   # writes OUT_DIR/pillar_hall.{pgm,yaml}
    bioslam sim --world OUT_DIR/pillar_hall.yaml ...

The benchmarks' loop-closure results (``results/loops.txt``) run the weaving route on it.
"""

from __future__ import annotations

from functools import partial
from pathlib import Path

import numpy as np
import office_floor_plan as plan

WIDTH, HEIGHT = 64.0, 48.0
PITCH = 8.0
PILLAR = 0.5
LANE = 1.8  # half-width kept clear either side of the lanes between pillars


def floor_plan(seed: int = 3) -> np.ndarray:
    """The occupancy image, row 0 at the top (y = ``HEIGHT``)."""
    x, y = plan.pixel_centres(WIDTH, HEIGHT)
    img = np.full(x.shape, plan.FREE, np.uint8)
    box = partial(plan.box_mask, x, y)
    img[~box(0.3, 0.3, WIDTH - 0.3, HEIGHT - 0.3)] = plan.OCCUPIED
    half = PILLAR / 2
    for cx in np.arange(PITCH, WIDTH - 4.0, PITCH):
        for cy in np.arange(PITCH, HEIGHT - 4.0, PITCH):
            img[box(cx - half, cy - half, cx + half, cy + half)] = plan.OCCUPIED
    rng = np.random.default_rng(seed)
    for _ in range(14):
        px, py = rng.uniform(3.0, WIDTH - 6.0), rng.uniform(3.0, HEIGHT - 6.0)
        w, h = rng.uniform(0.8, 2.5, 2)
        in_lane_x = abs((px + w / 2) % PITCH - PITCH / 2) < LANE
        in_lane_y = abs((py + h / 2) % PITCH - PITCH / 2) < LANE
        if in_lane_x and in_lane_y:
            continue  # a lane crossing stays open
        img[box(px, py, px + w, py + h)] = plan.OCCUPIED
    return img[::-1]


def write_pillar_hall(folder: Path) -> Path:
    """Write ``pillar_hall.pgm`` and ``pillar_hall.yaml`` into ``folder``; the YAML's path."""
    return plan.write_floor_plan(folder, "pillar_hall", floor_plan(), plan.RESOLUTION)


if __name__ == "__main__":
    plan.floor_plan_cli(__doc__, write_pillar_hall)
