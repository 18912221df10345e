"""Exhaustive correlative search of the Eq. 3 objective on a regular (x, y, theta) lattice.

Used where the search window is small (pairwise registration seeds); the wide windows of a
scan with no trustworthy prediction go to :mod:`bioslam.matching.branch_and_bound`, which
finds the same optimum without visiting every lattice pose.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from bioslam.matching.gauss_newton import NO_FACING, FloatArray, grid_args, summed_map
from bioslam.occupancy_grid import OccupancyGrid


def neighbourhood_max(values: FloatArray) -> FloatArray:
    """The largest value of each element's 3 x 3 (x 3 ...) neighbourhood, edges repeated
    outwards: SciPy's ``maximum_filter(size=3, mode="nearest")``, one axis at a time (a
    maximum is exact in any order), without importing SciPy for it. On booleans it is a
    dilation by one cell (SciPy's ``binary_dilation`` with a 3 x 3 structure)."""
    out = values
    for axis in range(values.ndim):
        n = values.shape[axis]
        padded = np.concatenate(
            [out.take([0], axis=axis), out, out.take([n - 1], axis=axis)], axis=axis
        )
        left, mid, right = (padded.take(np.arange(k, k + n), axis=axis) for k in range(3))
        out = np.maximum(np.maximum(left, mid), right)
    return out


@numba.njit(cache=True)
def _correlative_scores(g, pts, pose, nt, nx, step_xy, step_th):
    """The Eq. 3 objective (summed M*) on the (theta, x, y) lattice of ``2 nt + 1`` headings
    and ``(2 nx + 1)^2`` positions around ``pose``."""
    out = np.empty((2 * nt + 1, 2 * nx + 1, 2 * nx + 1))
    for it in range(-nt, nt + 1):
        th = pose[2] + it * step_th
        c = math.cos(th)
        s = math.sin(th)
        for ix in range(-nx, nx + 1):
            for iy in range(-nx, nx + 1):
                tx = pose[0] + ix * step_xy
                ty = pose[1] + iy * step_xy
                score = summed_map(g, pts, NO_FACING, c, s, tx, ty, np.bool_(False))
                out[it + nt, ix + nx, iy + nx] = score
    return out


def lattice_search(
    grid: OccupancyGrid,
    subcell_sigma: float | None,
    points: FloatArray,
    guess: FloatArray,
    distance: float,
    angle: float,
    step: float,
    radius: float,
    peaks: int = 1,
) -> FloatArray:
    """Exhaustive search of the Eq. 3 objective on ``grid`` within ``distance`` m and
    ``angle`` rad of ``guess``, ``step`` m apart in position and, in heading, by the angle
    that moves a point at ``radius`` m (at least one cell) by ``step``. Returns the poses
    ``(K, 3)`` of the ``peaks`` best local maxima of the lattice, best first."""
    step_th = step / max(radius, grid.resolution)
    nt, nx = int(angle / step_th), int(distance / step)
    scores = _correlative_scores(
        grid_args(grid, subcell_sigma), points, guess, nt, nx, step, step_th
    )
    if peaks == 1:
        best = np.array([np.argmax(scores)])
    else:
        local = scores == neighbourhood_max(scores)
        flat = np.flatnonzero(local)
        best = flat[np.argsort(-scores.ravel()[flat], kind="stable")[:peaks]]
    it, ix, iy = np.unravel_index(best, scores.shape)
    offsets = np.column_stack([(ix - nx) * step, (iy - nx) * step, (it - nt) * step_th])
    return guess + offsets

