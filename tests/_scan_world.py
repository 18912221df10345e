"""A tiny analytic 2D world for scan-matching tests: wall segments and exact ray casting."""

import numpy as np

from bioslam.geometry import between, compose
from bioslam.matching.deskew import se2_exp
from bioslam.scan import LaserScan


def box(x0, y0, x1, y1):
    c = [(x0, y0), (x1, y0), (x1, y1), (x0, y1)]
    return [(c[i], c[(i + 1) % 4]) for i in range(4)]


ROOM = np.array(
    box(-6, -4, 6, 4)
    + box(-3, -2, -2, -1.2)
    + box(2, 1, 3.5, 1.6)
    + box(0.5, -3, 1.1, -2.2)
    + [((-6, 2.5), (-4.5, 2.5)), ((4.0, -4), (4.0, -2.5)), ((-1.0, 4.0), (-0.4, 3.1))],
    dtype=float,
)
# 200 m corridor, 2 m wide, no features at all, its ends out of a 30 m range
CORRIDOR = np.array([((-100, -1), (100, -1)), ((-100, 1), (100, 1))], dtype=float)
# Every scan below has 1 cm range noise, as real sensors do: noise-free hits on a wall that
# lies exactly on a cell boundary all fall into one cell, the worst case of any grid map.


def cast(segs, origins, directions, max_range=30.0):
    """Distance along each ray (origins, directions: (B, 2)) to the nearest segment."""
    a, e = segs[:, 0], segs[:, 1] - segs[:, 0]
    d = directions[:, None, :]
    denom = d[..., 0] * e[None, :, 1] - d[..., 1] * e[None, :, 0]
    ap = a[None] - origins[:, None, :]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (ap[..., 0] * e[None, :, 1] - ap[..., 1] * e[None, :, 0]) / denom
        u = (ap[..., 0] * d[..., 1] - ap[..., 1] * d[..., 0]) / denom
    t = np.where((t > 1e-9) & (u >= 0) & (u <= 1), t, np.inf).min(axis=1)
    t[t > max_range] = np.inf
    return t


FOV = np.radians(270.0)


def make_scan(segs, pose, stamp=0.0, beams=541, fov=FOV, sigma=0.0, rng=None,
              twist=None, time_increment=0.0, max_range=30.0):  # fmt: skip
    """A scan from ``pose``; with ``twist`` the robot moves during the sweep (beam k at
    ``stamp + k * time_increment``), as a rotating-mirror scanner does; returns beyond
    ``max_range`` are invalid (inf)."""
    angles = -fov / 2 + fov * np.arange(beams) / (beams - 1)
    poses = np.broadcast_to(np.asarray(pose, float), (beams, 3))
    if twist is not None:
        poses = compose(poses, se2_exp(twist, np.arange(beams) * time_increment))
    heading = poses[:, 2] + angles
    r = cast(segs, poses[:, :2], np.column_stack([np.cos(heading), np.sin(heading)]), max_range)
    if sigma:
        r = r + rng.normal(0.0, sigma, r.shape)
    return LaserScan(stamp, r, angles, 0.05, max_range, time_increment)


def pose_error(a, b):
    d = between(a, b)
    return float(np.hypot(d[0], d[1])), float(abs(d[2]))

