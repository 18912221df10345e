"""An office floor plan as a map_server map (PNG + YAML), a world none of the odometry's or
the loop closure's defaults were tuned on: a 36 m x 24 m floor with a lobby of pillars, a
corridor 2.4 m wide with doors into ten rooms of desks, and a cross corridor.

    python benchmarks/office_floor_plan.py OUT_DIR   # writes OUT_DIR/office.{pgm,yaml}
    bioslam sim --world OUT_DIR/office.yaml ...

``bench_odometry.py --only office`` and ``bench_loops.py --cases <dir>/office.yaml-sick-tour``
run on it.
"""

from __future__ import annotations

import argparse
import itertools
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np

RESOLUTION = 0.05  # metres per pixel
WIDTH, HEIGHT = 36.0, 24.0
WALL = 0.15  # partition thickness
FREE, OCCUPIED = 254, 0
CORRIDOR = (10.0, 12.4)  # the main corridor's south and north walls (y)
CROSS = (18.0, 20.4)  # the cross corridor's west and east walls (x)
ROOM_EDGES = (8.0, 12.5, CROSS[0] - WALL, CROSS[1] + WALL, 25.0, 29.5, WIDTH - 0.2)


def floor_plan(seed: int = 0) -> np.ndarray:
    """The occupancy image, row 0 at the top (y = HEIGHT)."""
    img = np.full((round(HEIGHT / RESOLUTION), round(WIDTH / RESOLUTION)), FREE, np.uint8)

    def fill(x0: float, y0: float, x1: float, y1: float, value: int = OCCUPIED) -> None:
        rows = slice(round(y0 / RESOLUTION), round(y1 / RESOLUTION))
        img[rows, round(x0 / RESOLUTION) : round(x1 / RESOLUTION)] = value

    south, north = CORRIDOR
    for x0, y0, x1, y1 in ((0, 0, WIDTH, 0.2), (0, HEIGHT - 0.2, WIDTH, HEIGHT),
                           (0, 0, 0.2, HEIGHT), (WIDTH - 0.2, 0, WIDTH, HEIGHT)):  # fmt: skip
        fill(x0, y0, x1, y1)
    fill(8.0, south - WALL, WIDTH - 0.2, south)
    fill(8.0, north, WIDTH - 0.2, north + WALL)
    for y0, y1 in ((0.2, south), (north, HEIGHT - 0.2)):
        fill(CROSS[0] - WALL, y0, CROSS[0], y1)
        fill(CROSS[1], y0, CROSS[1] + WALL, y1)
    fill(CROSS[0], south - WALL, CROSS[1], south, FREE)
    fill(CROSS[0], north, CROSS[1], north + WALL, FREE)
    rng = np.random.default_rng(seed)
    for a, b in itertools.pairwise(ROOM_EDGES):
        if a == CROSS[0] - WALL:
            continue  # the cross corridor
        if b < WIDTH - 0.3 and b != CROSS[0] - WALL:
            fill(b - WALL, 0.2, b, south - WALL)
            fill(b - WALL, north + WALL, b, HEIGHT - 0.2)
        door = 0.5 * (a + b)
        fill(door - 0.6, south - WALL, door + 0.6, south, FREE)
        fill(door - 0.6, north, door + 0.6, north + WALL, FREE)
        for y0, y1 in ((1.0, 8.5), (13.5, 23.0)):  # a desk in each room
            x, y = rng.uniform(a + 0.9, b - 2.6), rng.uniform(y0 + 0.5, y1 - 2.0)
            fill(x, y, x + 1.6, y + 0.8)
    for px in (3.0, 5.5):  # the lobby's pillars
        for py in (5.0, 11.2, 17.5):
            fill(px - 0.2, py - 0.2, px + 0.2, py + 0.2)
    fill(8.0 - WALL, 0.2, 8.0, south - WALL)  # the lobby's wall, with two openings
    fill(8.0 - WALL, north + WALL, 8.0, HEIGHT - 0.2)
    fill(8.0 - WALL, 4.0, 8.0, 5.2, FREE)
    fill(8.0 - WALL, 18.0, 8.0, 19.2, FREE)
    return img[::-1]


def write_floor_plan(folder: Path, name: str, image: np.ndarray, resolution: float) -> Path:
    """Write a floor plan's occupancy ``image`` (``FREE`` / ``OCCUPIED`` pixels, row 0 at the
    top) as the map_server map ``<name>.pgm`` + ``<name>.yaml`` into ``folder``, origin at
    its lower-left corner; the YAML's path."""
    from bioslam.io.mapfile import OccupancyImage, write_map

    folder.mkdir(parents=True, exist_ok=True)
    occupancy = np.where(image[::-1] == OCCUPIED, 1.0, 0.0)
    return write_map(folder, OccupancyImage(occupancy, resolution), name=name)[1]


def pixel_centres(
    width: float, height: float, resolution: float = RESOLUTION
) -> tuple[np.ndarray, np.ndarray]:
    """x and y (metres) of the centre of every pixel of a ``width`` x ``height`` floor, row 0
    at y = 0 (the image is flipped to row 0 at the top before it is written)."""
    rows, cols = round(height / resolution), round(width / resolution)
    y, x = (np.mgrid[0:rows, 0:cols] + 0.5) * resolution
    return x, y


def box_mask(
    x: np.ndarray, y: np.ndarray, x0: float, y0: float, x1: float, y1: float
) -> np.ndarray:
    """The pixels (centres ``x``, ``y``, :func:`pixel_centres`) inside [x0, x1) x [y0, y1)."""
    return (x >= x0) & (x < x1) & (y >= y0) & (y < y1)


def floor_plan_cli(doc: str, write: Callable[[Path], Path]) -> None:
    """A floor plan script's command line: ``write`` the floor into the folder given (default
    the current one) and print the YAML's path; ``doc`` the script's docstring, whose first
    paragraph is the help."""
    parser = argparse.ArgumentParser(description=doc.split("\n\n")[0])
    parser.add_argument("out", nargs="?", default=".", help="folder to write into")
    print(write(Path(parser.parse_args().out)))


def write_office(folder: Path) -> Path:
    """Write ``office.pgm`` and ``office.yaml`` into ``folder``; the YAML's path."""
    return write_floor_plan(folder, "office", floor_plan(), RESOLUTION)


if __name__ == "__main__":
    print(write_office(Path(sys.argv[1] if len(sys.argv) > 1 else ".")))
