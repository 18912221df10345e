"""Tiny synthetic CARMEN logs for the command-line tests: a robot driving through a 10 m x 6 m
room with a pillar, 181-beam FLASER scans at 10 Hz, with chosen records spoiled."""

from __future__ import annotations

from pathlib import Path

import numpy as np

ROOM = (0.0, 0.0, 10.0, 6.0)
PILLAR = (4.8, 3.6, 5.4, 4.2)


def _box_distance(ox, oy, dx, dy, box, inside):
    """Distance along the rays to an axis-aligned box's boundary (inf where missed)."""
    x0, y0, x1, y1 = box
    with np.errstate(divide="ignore", invalid="ignore"):
        tx = np.stack([(x0 - ox) / dx, (x1 - ox) / dx])
        ty = np.stack([(y0 - oy) / dy, (y1 - oy) / dy])
    if inside:
        t = np.minimum(np.where(tx > 0, tx, np.inf).min(0), np.where(ty > 0, ty, np.inf).min(0))
        return t
    t_near = np.maximum(np.nanmin(tx, 0), np.nanmin(ty, 0))
    t_far = np.minimum(np.nanmax(tx, 0), np.nanmax(ty, 0))
    return np.where((t_near <= t_far) & (t_near > 0), t_near, np.inf)


def ranges_at(x: float, y: float, theta: float, beams: int = 181) -> np.ndarray:
    angles = theta + np.linspace(-np.pi / 2, np.pi / 2, beams)
    dx, dy = np.cos(angles), np.sin(angles)
    walls = _box_distance(x, y, dx, dy, ROOM, inside=True)
    pillar = _box_distance(x, y, dx, dy, PILLAR, inside=False)
    return np.minimum(walls, pillar)


def flaser_line(t: float, x: float, y: float, theta: float) -> str:
    r = ranges_at(x, y, theta)
    values = " ".join(f"{v:.3f}" for v in r)
    pose = f"{x:.4f} {y:.4f} {theta:.4f}"
    return f"FLASER {r.size} {values} {pose} {pose} {t:.6f} host {t:.6f}\n"


def write_carmen(path: Path, scans: int = 40, bad: set[int] = frozenset()) -> Path:
    """``scans`` FLASER records back and forth along the room (<= 0.05 m per scan); record
    ``k`` in ``bad`` is written cut short (a malformed record the reader skips)."""
    lines = []
    for k in range(scans):
        t = 100.0 + 0.1 * k
        x = 1.5 + 3.0 * (1.0 - np.cos(0.05 * k / 3.0))  # back and forth, 1.5 to 7.5 m
        y = 2.0 + 0.3 * np.sin(0.05 * k)
        theta = 0.1 * np.sin(0.03 * k)
        lines.append("FLASER 181 1.0 2.0 3.0\n" if k in bad else flaser_line(t, x, y, theta))
    path.write_text("".join(lines))
    return path
