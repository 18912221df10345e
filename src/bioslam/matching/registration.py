"""Pairwise scan registration (loop-closure refinement): one scan against a map made of
another, by a lattice search then Gauss-Newton (Eq. 3-4)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from bioslam.geometry import transform_points, wrap_angle
from bioslam.matching.correlative import lattice_search
from bioslam.matching.gauss_newton import (
    FloatArray,
    match_scan_to_map,
    matched_normals,
    points_per_level,
)
from bioslam.occupancy_grid import (
    NORMAL_MAX_GAP,
    LogOddsConfig,
    MapPyramid,
    OccupancyGrid,
    subsample_by_spacing,
)


@dataclass
class RegistrationQuality:
    """How trustworthy a :func:`register_scans` result is; ``float(q)`` is ``q.score``.

    Attributes:
        score: fraction of query points (inside the reference map) that land within about a
            cell of ``RegistrationConfig.score_level`` of the reference scan after
            convergence: the sub-cell map function (kernel one cell wide) is at least
            ``hit_level`` there. The reference is densified along its surfaces first
            (:func:`densify_scan`). Points in space the reference never saw count as
            misses. In the tests a correct registration scores above 0.9 and a
            registration of two different places below 0.6.
        mean_value: mean of that map function over those points.
        overlap: fraction of query points that fall inside the reference map at all.
        converged: the finest level stopped on a small step before its iteration limit.
        degenerate: some direction was unconstrained (corridor): ``rel`` is then only
            reliable across that direction.
        condition: smallest / largest scaled curvature.
        iterations: Gauss-Newton iterations summed over the levels.
    """

    score: float
    mean_value: float
    overlap: float
    converged: bool
    degenerate: bool
    condition: float
    iterations: int

    def __float__(self) -> float:
        return float(self.score)


@dataclass(frozen=True)
class RegistrationConfig:
    """Parameters of :func:`register_scans`.

    Attributes:
        resolution, levels: the reference map pyramid (as :class:`OdometryConfig`).
        search_distance, search_angle: half-widths of the exhaustive search on the coarsest
            level around the initial guess (metres, radians); they set the convergence basin
            (a view cell's place match can be half a metre and tens of degrees off).
        max_range: reference/query endpoints beyond this are ignored, metres.
        max_iterations, step_tolerance, length_scale, degeneracy_ratio, subcell_sigma: as in
            OdometryConfig.
        hit_level: map function value at or above which a query point counts as landing on
            the reference scan (0.5: about one cell from a reference endpoint).
        score_level: the pyramid level whose cells that is judged on. Default 1 (10 cm):
            a point lands within about 10 cm of the reference scan. On the finest level
            (5 cm) range noise alone fails a correct registration: two scans with 3 cm noise
            (a low-cost 360° LiDAR) differ by more than 5 cm for a fifth of their points,
            and correct registrations scored 0.66-0.76, so the noisy sensor never closed a
            loop (0 of 336 registrations on a 600 s maze route; 73 on level 1).
    """

    resolution: float = 0.05
    levels: int = 3
    search_distance: float = 0.6
    search_angle: float = math.radians(25.0)
    max_range: float = 30.0
    max_iterations: tuple[int, ...] = (10, 10, 20)
    step_tolerance: float = 0.01
    length_scale: float = 3.0
    degeneracy_ratio: float = 0.01
    subcell_sigma: float | None = 1.0
    hit_level: float = 0.5
    score_level: int = 1


def straight_gaps(
    points: FloatArray, max_gap: float, angle: float, reach: int = 1, ratio: float = 3.0,
    longest: float = 2.0, tolerance: float | None = None,
) -> NDArray[np.bool_]:
    """Which gaps between consecutive endpoints (scan order) cross no opening: those up to
    ``max_gap``, and longer ones (up to ``longest`` metres) inside a straight run: the
    ``reach`` gaps either side each turn by at most ``angle`` radians from the one before,
    and the gaps next to it are at least ``1 / ratio`` of its length. A 1 deg scanner
    looking along a wall at 10 m hits it a metre apart, beam after beam in a line whose
    gaps grow steadily; a depth jump (a door frame, an obstacle's edge) leaves that line,
    and an opening in it is a gap several times its neighbours'. With ``tolerance``, a gap
    up to ``max_gap`` must also continue a neighbour's line (:func:`_in_line`)."""
    step = np.diff(points, axis=0)
    gap = np.hypot(step[:, 0], step[:, 1])
    near = gap <= max_gap
    if tolerance is not None:
        near &= _in_line(points, step, gap, near, tolerance)
    n = gap.size
    if angle <= 0.0 or n <= 2 * reach:
        return near
    bent = _turns(step) > angle  # turn k: gap k -> k + 1
    bends = np.concatenate([[0], np.cumsum(bent)])
    inner = np.arange(reach, n - reach)
    ok = np.zeros(n, dtype=bool)
    ok[inner] = (
        (bends[inner + reach] - bends[inner - reach] == 0)  # turns inner-reach .. inner+reach-1
        & (ratio * gap[inner - 1] >= gap[inner])
        & (ratio * gap[inner + 1] >= gap[inner])
        & (gap[inner] <= longest)
    )
    return near | ok


def _turns(step: FloatArray) -> FloatArray:
    """How far (radians) each gap between consecutive endpoints (the rows of ``step``) turns
    from the one before: entry k from gap k to gap k + 1."""
    return np.abs(wrap_angle(np.diff(np.arctan2(step[:, 1], step[:, 0]))))


# The largest turn (radians) between an endpoint's two gaps for it to be a sample of one wall
GRAZED_TURN = 0.2


def grazing_endpoints(points: FloatArray, ratio: float, min_gap: float) -> NDArray[np.bool_]:
    """Endpoints (sensor frame, scan order) whose gaps to both neighbours are longer than
    ``min_gap`` and than ``ratio`` times the arc the two beams span at the nearer one's
    range, and turn by less than ``GRAZED_TURN`` from one to the other: on a flat surface
    that is a beam meeting it within asin(1 / ``ratio``) of grazing (9.6° at 6), one sample
    of a wall the scan sees metres apart. The first and last endpoints count their missing
    neighbour as such a gap. The arc is taken between the two endpoints' own bearings, so
    beams without a return between them do not make a gap look sparse; and a point seen
    between two nearer ones (the wall behind a person's legs, two depth steps) turns back
    on itself: the legs of a person close to the scanner, so left out, cost freiburg-079 a
    step of 0.7 m."""
    n = points.shape[0]
    if n < 2:
        return np.ones(n, dtype=bool)
    step = np.diff(points, axis=0)
    gap = np.hypot(step[:, 0], step[:, 1])
    ranges = np.hypot(points[:, 0], points[:, 1])
    bearing = np.arctan2(points[:, 1], points[:, 0])
    arc = np.minimum(ranges[:-1], ranges[1:]) * np.abs(wrap_angle(np.diff(bearing)))
    sparse = (gap > min_gap) & (gap > ratio * arc)
    straight = _turns(step) < GRAZED_TURN
    return np.r_[True, sparse] & np.r_[sparse, True] & np.r_[True, straight, True]


def _in_line(
    points: FloatArray, step: FloatArray, gap: FloatArray, near: NDArray[np.bool_],
    tolerance: float,
) -> NDArray[np.bool_]:
    """Gaps that continue a surface (``points`` in the sensor frame): the endpoint before
    them or the one after, joined to the gap by a ``near`` gap, lies within ``tolerance``
    of the line through the gap's own two. A gap around a corner or down a depth step
    leaves both neighbours' lines. A pair of endpoints with no joined neighbour (a post's
    face, or a door jamb's corner seen past the wall it ends) is taken as a face when its
    gap lies more across the beams than along them: a corner cut or a depth step between
    two beams runs along them."""
    unit = step / np.maximum(gap, 1e-12)[:, None]
    before = np.zeros(gap.size, dtype=bool)
    after = np.zeros(gap.size, dtype=bool)
    joined = before.copy()
    # p[k-1] against the line p[k] p[k+1], p[k+2] against the same line
    before[1:] = near[:-1] & (_off_line(unit[1:], points[:-2] - points[1:-1]) <= tolerance)
    after[:-1] = near[1:] & (_off_line(unit[:-1], points[2:] - points[:-2]) <= tolerance)
    joined[1:] = near[:-1]
    joined[:-1] |= near[1:]
    mid = points[:-1] + 0.5 * step
    across = _off_line(unit, mid) >= math.sqrt(0.5) * np.hypot(mid[:, 0], mid[:, 1])
    return before | after | (~joined & across)


def _off_line(unit: FloatArray, offset: FloatArray) -> FloatArray:
    """Distances of ``offset`` (from a point on each line) across lines of direction
    ``unit``."""
    return np.abs(unit[:, 0] * offset[:, 1] - unit[:, 1] * offset[:, 0])


def densify_scan(
    points: FloatArray, spacing: float, max_gap: float, straight_angle: float = 0.0,
    tolerance: float | None = None,
) -> FloatArray:
    """Endpoints in scan order with points added every ``spacing`` metres between neighbours
    on the same surface (:func:`straight_gaps`: closer than ``max_gap``, or, with
    ``straight_angle`` > 0, farther but on a straight run): a sparse scan (1 deg beams reach
    10 cm apart at 6 m, a metre apart along a wall 10 m ahead) would otherwise leave empty
    cells between its points on a wall, where the other scan's points of that wall find
    nothing to land on, and a map made of a few such scans is densest near where they were
    taken: a pose moved back towards there scores better than the true one."""
    return densify_with_mask(points, spacing, max_gap, straight_angle, tolerance=tolerance)[0]


def densify_with_mask(
    points: FloatArray, spacing: float, max_gap: float, straight_angle: float = 0.0,
    filled_angle: float | None = None, tolerance: float | None = None,
) -> tuple[FloatArray, NDArray[np.bool_]]:
    """:func:`densify_scan` and which of its points were added (not endpoints); with
    ``filled_angle``, the gaps that densifying with that ``straight_angle`` fills are left
    as they are (the points were added before)."""
    if points.shape[0] < 2:
        return points, np.zeros(points.shape[0], dtype=bool)
    step = np.diff(points, axis=0)
    gap = np.hypot(step[:, 0], step[:, 1])
    fill = straight_gaps(points, max_gap, straight_angle, tolerance=tolerance)
    if filled_angle is not None:
        fill &= ~straight_gaps(points, max_gap, filled_angle, tolerance=tolerance)
    extra = np.where(fill, np.floor(gap / spacing).astype(np.int64), 0)
    counts = np.append(extra + 1, 1)
    start = np.repeat(np.arange(points.shape[0]), counts)
    offset = np.arange(start.size) - np.repeat(np.cumsum(counts) - counts, counts)
    frac = offset / np.repeat(counts, counts)
    ahead = np.minimum(start + 1, points.shape[0] - 1)
    return points[start] + frac[:, None] * (points[ahead] - points[start]), offset > 0


def _check_points(points: ArrayLike, name: str) -> FloatArray:
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 2:
        raise ValueError(f"{name} must have shape (N, 2), got {pts.shape}")
    return pts[np.all(np.isfinite(pts), axis=1)]


def register_scans(
    reference_points: ArrayLike,
    query_points: ArrayLike,
    initial_guess: ArrayLike = (0.0, 0.0, 0.0),
    config: RegistrationConfig | None = None,
) -> tuple[FloatArray, RegistrationQuality]:
    """The pose of the query scan's frame in the reference scan's frame.

    Both point sets are ``(N, 2)`` endpoints in their own sensor frames. The reference scan is
    fused into a small map pyramid; the query is placed by an exhaustive search of the Eq. 3
    objective on the coarsest level around ``initial_guess`` followed by Gauss-Newton (Eq. 3-4)
    down the pyramid. See :class:`RegistrationQuality` for how to reject a bad result.
    """
    c = config or RegistrationConfig()
    ref = _check_points(reference_points, "reference_points")
    qry = _check_points(query_points, "query_points")
    ref = ref[np.hypot(ref[:, 0], ref[:, 1]) <= c.max_range]
    qry = np.ascontiguousarray(qry[np.hypot(qry[:, 0], qry[:, 1]) <= c.max_range])
    guess = np.asarray(initial_guess, dtype=np.float64).reshape(3)
    if ref.shape[0] < 3 or qry.shape[0] < 3:
        raise ValueError(
            f"register_scans needs at least 3 finite points in each scan, got "
            f"{ref.shape[0]} reference and {qry.shape[0]} query points"
        )
    # The map covers the reference's bounding box (a square around the sensor would be
    # mostly empty, and zeroing it cost a fifth of a registration on a 30 m scanner); query
    # points beyond it still count as misses in the score: they fall where the reference
    # saw nothing, and the map function is 0 outside the map.
    lo = ref.min(axis=0) - 1.0
    hi = ref.max(axis=0) + 1.0
    pyramid = MapPyramid(c.resolution, tuple(hi - lo), c.levels, LogOddsConfig(), origin=lo)
    pyramid.insert_scan(np.zeros(3), densify_scan(ref, 0.5 * c.resolution, NORMAL_MAX_GAP))
    keep = subsample_by_spacing(qry, c.resolution)
    level_pts = points_per_level(qry, c.resolution, c.levels, keep)
    top = pyramid.grids[-1]
    # Lattice steps of one coarse cell, in angle at the range of most points: Gauss-Newton
    # on the coarse level converges from anywhere within a cell, so a finer lattice (half a
    # cell at the farthest point) only multiplied the cost, by 20 on a 30 m scanner.
    radius = float(np.percentile(np.hypot(qry[:, 0], qry[:, 1]), 90))
    seed = lattice_search(
        top, None, level_pts[-1], guess, c.search_distance, c.search_angle, top.resolution, radius
    )[0]
    rel, report = match_scan_to_map(
        pyramid, level_pts, seed, c.max_iterations, c.step_tolerance, c.length_scale,
        c.degeneracy_ratio, c.subcell_sigma, matched_normals(level_pts),
    )  # fmt: skip
    reach = float(np.max(np.abs(ref))) + 1.0
    score, mean_value, n_in = map_hits(
        pyramid.grids[c.score_level], transform_points(rel, qry), (-reach, -reach, reach, reach),
        c.hit_level,
    )
    quality = RegistrationQuality(
        score=score,
        mean_value=mean_value,
        overlap=n_in / qry.shape[0],
        converged=report.converged,
        degenerate=report.degenerate,
        condition=report.condition,
        iterations=report.iterations,
    )
    return rel, quality


def map_hits(
    judge: OccupancyGrid, world: FloatArray, extent: tuple[float, float, float, float],
    level: float,
) -> tuple[float, float, int]:
    """The registration score of points already placed in the map's frame: of those at least
    a cell inside ``extent`` (xmin, ymin, xmax, ymax), the share whose map function on
    ``judge`` is at least ``level`` (within about a cell of a wall), their mean map value, and
    how many were inside."""
    values, inside = _placed_values(judge, world, extent)
    n_in = int(inside.sum())
    if not n_in:
        return 0.0, 0.0, 0
    return float(np.mean(values[inside] >= level)), float(np.mean(values[inside])), n_in


def _placed_values(
    judge: OccupancyGrid, world: FloatArray, extent: tuple[float, float, float, float]
) -> tuple[FloatArray, NDArray[np.bool_]]:
    """The sub-cell map function on ``judge`` at points already placed in its frame, and
    which of them lie at least a cell inside ``extent``."""
    values, _ = judge.value_and_gradient(world, subcell_sigma=1.0)
    return values, _inside(extent, judge.resolution, world)


def _inside(
    extent: tuple[float, float, float, float], margin: float, world: FloatArray
) -> NDArray[np.bool_]:
    """Points at least ``margin`` inside ``extent`` (xmin, ymin, xmax, ymax)."""
    xmin, ymin, xmax, ymax = extent
    half = margin
    return (
        (world[:, 0] >= xmin + half)
        & (world[:, 0] < xmax - half)
        & (world[:, 1] >= ymin + half)
        & (world[:, 1] < ymax - half)
    )
