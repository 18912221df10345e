"""Tiny analytic ray caster for the boundary/view tests (walls as line segments)."""

from __future__ import annotations

import numpy as np

from bioslam.scan import LaserScan


def box(x0: float, y0: float, x1: float, y1: float) -> list[tuple[float, float, float, float]]:
    return [(x0, y0, x1, y0), (x1, y0, x1, y1), (x1, y1, x0, y1), (x0, y1, x0, y0)]


def cast(
    walls: list[tuple[float, float, float, float]],
    pose: tuple[float, float, float],
    fov_deg: float = 270.0,
    beams: int = 1081,
    range_max: float = 30.0,
) -> LaserScan:
    """Exact ranges from ``pose`` to the nearest wall along each beam (NaN when none in range)."""
    half = np.radians(fov_deg) / 2.0
    closed = np.isclose(fov_deg, 360.0)
    angles = np.linspace(-half, half, beams, endpoint=not closed)
    x, y, th = pose
    dx, dy = np.cos(angles + th), np.sin(angles + th)
    seg = np.asarray(walls, dtype=np.float64)
    ax, ay = seg[:, 0] - x, seg[:, 1] - y
    ex, ey = seg[:, 2] - seg[:, 0], seg[:, 3] - seg[:, 1]
    # Solve t * dir = a + u * e for every beam/segment pair.
    den = dx[:, None] * ey[None, :] - dy[:, None] * ex[None, :]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (ax[None, :] * ey[None, :] - ay[None, :] * ex[None, :]) / den
        u = (ax[None, :] * dy[:, None] - ay[None, :] * dx[:, None]) / den
    hit = (np.abs(den) > 1e-12) & (t > 0) & (u >= 0) & (u <= 1)
    t = np.where(hit, t, np.inf).min(axis=1)
    t[t > range_max] = np.nan
    return LaserScan(0.0, t, angles, 0.05, range_max)
