"""Wide-basin scan matching: an exhaustive-equivalent search of a wide (x, y, theta) window by
branch and bound over max-pooled grids, with the best *distinct* rival.

Olson's real-time correlative matching (2009) scores a scan at every pose of a lattice
against a rasterised map; Hess et al. (2016, Cartographer) find the same optimum without
visiting every pose: a node stands for a square of ``2^h x 2^h`` lattice translations at
one heading, and its upper bound is the scan's summed value on the grid whose cells hold the
maximum of the ``2^h x 2^h`` cells ahead of them (precomputed once per map). A node whose
bound cannot beat the best pose found is cut with all its children; the answer is exactly
the lattice optimum of a brute-force search (:func:`brute_force_scores`).

A look-alike place (an aisle among identical aisles, a corridor along its axis) scores as
well as the true one. So the search also returns the best *rival*: the best lattice pose
that is a local maximum of the score and lies farther than ``rival_distance`` or
``rival_angle`` from the winner. ``rival_score / score`` (:attr:`WideMatch.ambiguity`)
near 1 says the scan cannot tell the places apart; a caller then keeps its prior.

API (both the odometry and loop-closure verification use it)::

    matcher = WideBasinMatcher(WideBasinConfig(distance=1.5, angle=math.pi / 4))
    matcher.set_map(grid)                        # an OccupancyGrid (e.g. a submap); once per map
    found = matcher.search(points, centre)       # sensor-frame (N, 2) endpoints, centre (3,)
    found.pose, found.score                      # best lattice pose, mean map value in [0, 1]
    found.rival_pose, found.rival_score          # None / 0.0 when no rival scores at least
    found.ambiguity                              #   min_rival_ratio * score
    matcher.score_at(points, pose)               # the same score at any other pose
    refined, report = refine(pyramid, found.pose, points)   # Gauss-Newton (Eq. 3) from it

``set_map(grid, box=...)`` builds only the part of the grid a search can reach
(``reach_box(points, windows, resolution)``: the cells the lattices of the windows to be
searched put the scan's endpoints in, which the odometry passes); ``set_map`` with no box
covers the whole grid. The map
value is the grid's occupancy probability of cells ever hit (0 elsewhere), spread to the
neighbouring cells with a Gaussian of ``blur`` cells (a sparse scan's endpoints on a wall
fall between another scan's).

Speed: the whole search is one compiled call. The endpoints' cells are computed once per
heading of the lattice (a table of flat indices into the pooled grids, so a bound is a
gather-and-sum without bounds checks for the endpoints that stay inside the crop; a node's
four children are bounded in one pass). Nodes are expanded best first from a heap, so only
nodes whose bound beats the optimum are expanded, and the rival search goes on from the same
heap instead of starting again from the roots.

Memory: the pooled grids (``depth + 1`` float32 copies of the reachable part of the grid,
kept in one buffer grown to the largest crop seen and reused by later searches; a level's
cells are read at ``row * buffer width + column``), and per search the heading table (an
int32 per endpoint and heading, two int64 more for those near the crop's edge) and the heap
(about 50 bytes a node bounded). No file or terminal I/O here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numba
import numpy as np
from numpy.typing import ArrayLike

from bioslam.geometry import unit
from bioslam.matching.gauss_newton import (
    FloatArray,
    MatchReport,
    match_scan_to_map,
    matched_normals,
    points_per_level,
)
from bioslam.occupancy_grid import MapPyramid, OccupancyGrid, subsample_by_spacing


@dataclass(frozen=True)
class WideBasinConfig:
    """Parameters of :class:`WideBasinMatcher`.

    Attributes:
        distance: half-width of the window in x and in y, metres (Cartographer's
            ``linear_search_window``; a thinned log's scans are up to a metre apart).
        angle: half-width of the window in heading, radians (up to 80° of turn between the
            scans of thinned CARMEN logs; ±45° covers most, a second search the rest).
        angular_step: heading step, radians; ``None`` takes the angle that moves an endpoint
            at the scan's 90th-percentile range by ``angular_cells`` cells (Cartographer uses
            one cell at the maximum range).
        angular_cells: see ``angular_step``.
        depth: pooling levels above the lattice (a top node spans ``2^depth`` cells a
            side); ``None`` spans the whole window with one node (Cartographer). Fewer
            levels cost less to pool and bound more tightly at the top, at the price of more
            top nodes: with the best-first search 4 (1.6 m at 10 cm cells) and one node per
            window search the warehouse equally fast, 3 twice as slowly
            (``benchmarks/bench_matcher.py``); 4 pools one level less.
        blur: cells over which a hit cell's value spreads (Gaussian, sigma one cell); 0
            scores only the cells hit.
        rival_distance, rival_angle: a rival must be farther than this from the winner in
            position (metres) or in heading (radians): nearer poses are the winner's own peak.
        min_rival_ratio: rivals scoring below this fraction of the winner are not searched
            for (the search then stays fast on a distinctive scan); ``rival_score`` is 0.
    """

    distance: float = 1.5
    angle: float = math.pi / 4
    angular_step: float | None = None
    angular_cells: float = 1.0
    depth: int | None = 4
    blur: int = 1
    rival_distance: float = 0.5
    rival_angle: float = math.radians(20.0)
    min_rival_ratio: float = 0.5

    def __post_init__(self) -> None:
        if not (self.distance >= 0 and self.angle >= 0 and self.blur >= 0):
            raise ValueError(
                f"window distance, angle and blur must be non-negative, got {self.distance}, "
                f"{self.angle}, {self.blur}"
            )
        if self.angular_step is not None and not self.angular_step > 0:
            raise ValueError(f"angular_step must be positive, got {self.angular_step}")
        if self.depth is not None and self.depth < 0:
            raise ValueError(f"depth must be non-negative, got {self.depth}")
        if not 0.0 <= self.min_rival_ratio <= 1.0:
            raise ValueError(f"min_rival_ratio must be in [0, 1], got {self.min_rival_ratio}")


@dataclass
class WideMatch:
    """The result of :meth:`WideBasinMatcher.search`.

    Attributes:
        pose: the best lattice pose (x, y, theta) in the map frame; among poses scoring
            exactly alike the first in (heading, x, y) order, as a brute force's first
            maximum (the rival, defined relative to it, then does not depend on the order
            the search met them in).
        score: its mean map value over the endpoints (1: every endpoint on a certain wall).
        rival_pose: the best local maximum farther than the rival distance/angle from
            ``pose``, or ``None`` when none scores at least ``min_rival_ratio * score``, or
            when nothing in the window scores above 0 (then ``pose`` is the window's first
            lattice pose).
        rival_score: its mean map value (0 without a rival).
        nodes: search nodes whose bound was computed (the cost; brute force visits every
            lattice pose).
        lattice: (headings, positions per axis) of the window's lattice.
        leaves: the best and the rival as the search found them, rows of (summed score,
            heading, x, y) on the lattice (a score of -1: none), for a search of a wider
            window around the same centre (:meth:`WideBasinMatcher.search`'s ``known``).
    """

    pose: FloatArray
    score: float
    rival_pose: FloatArray | None
    rival_score: float
    nodes: int
    lattice: tuple[int, int]
    leaves: FloatArray = field(default_factory=lambda: np.full((2, 4), -1.0), repr=False)

    @property
    def ambiguity(self) -> float:
        """``rival_score / score``: near 1 the scan fits a distinct place as well."""
        return self.rival_score / self.score if self.score > 0 else 0.0


# --------------------------------------------------------------------------------------------
# Numba kernels


@numba.njit(cache=True)
def _fill_levels(weights, r0, c0, rows, cols, blur, levels):
    """Level 0: the crop ``rows x cols`` of ``weights`` from cell (r0, c0), each cell the
    maximum of its neighbours' values (within ``blur`` cells) times a Gaussian of their
    distance; level h: the maximum of level 0 over the ``2^h x 2^h`` cells from each cell
    on (cells past the crop count as 0). Separable: a row pass, then a column pass."""
    grows, gcols = weights.shape
    kernel = np.empty(2 * blur + 1)
    for d in range(-blur, blur + 1):
        kernel[d + blur] = math.exp(-0.5 * d * d)
    levels[0, :rows, :cols] = 0.0
    # scattered from the hit cells (few in a map): each raises its neighbours
    first = max(c0 - blur, 0)
    width = max(min(c0 + cols + blur, gcols) - first, 0)
    for r in range(max(r0 - blur, 0), min(r0 + rows + blur, grows)):
        line = weights[r, first : first + width]
        for i in range(width):
            w = line[i]
            if w == 0.0:
                continue
            c = first + i
            for dr in range(-blur, blur + 1):
                rr = r - r0 + dr
                if rr < 0 or rr >= rows:
                    continue
                for dc in range(-blur, blur + 1):
                    cc = c - c0 + dc
                    if cc < 0 or cc >= cols:
                        continue
                    v = w * kernel[dr + blur] * kernel[dc + blur]
                    if v > levels[0, rr, cc]:
                        levels[0, rr, cc] = v
    for h in range(1, levels.shape[0]):
        s = 1 << (h - 1)
        # Row r's maximum with the cell s to its right, then row r - s's with row r (still
        # only that row's): one sweep whose rows are still in cache. The loops index slices
        # from 0 (no index arithmetic, which Numba checks for negatives), so they run on
        # vector registers; a maximum of float32 is exact.
        inside = max(cols - s, 0)
        for r in range(rows):
            here = levels[h - 1, r, :inside]
            right = levels[h - 1, r, s : s + inside]
            out = levels[h, r, :inside]
            for c in range(inside):
                out[c] = max(here[c], right[c])
            for c in range(inside, cols):  # a loop, not a slice copy (see _copy_into)
                levels[h, r, c] = levels[h - 1, r, c]
            if r >= s:
                done = levels[h, r - s, :cols]
                row = levels[h, r, :cols]
                for c in range(cols):
                    done[c] = max(done[c], row[c])


@numba.njit(cache=True)
def _discretize(pts, theta, x, y, ox, oy, res, out):
    """Row and column (of the crop whose lower-left corner is ``ox, oy``) of every endpoint
    placed by (x, y, theta); lattice translations then only add whole cells."""
    c = math.cos(theta)
    s = math.sin(theta)
    for k in range(pts.shape[0]):
        wx = c * pts[k, 0] - s * pts[k, 1] + x
        wy = s * pts[k, 0] + c * pts[k, 1] + y
        out[k, 0] = math.floor((wy - oy) / res)
        out[k, 1] = math.floor((wx - ox) / res)


@numba.njit(cache=True)
def _bound(levels, h, cells, ix, iy, rows, cols):
    """Σ over endpoints of level ``h`` at their cell shifted by (ix, iy): the score of the
    lattice pose at h = 0, an upper bound of the ``2^h x 2^h`` translations from (ix, iy)
    above. A window reaching in from below or left reads the first cell (whose window
    covers its part inside); one wholly outside the crop adds 0."""
    size = 1 << h
    total = 0.0
    for k in range(cells.shape[0]):
        r = cells[k, 0] + iy
        c = cells[k, 1] + ix
        if r >= rows or c >= cols or r + size <= 0 or c + size <= 0:
            continue
        total += levels[h, max(r, 0), max(c, 0)]
    return total


@numba.njit(cache=True)
def _in_zone(j, ix, iy, span, zone, strip):
    """Whether all translations of the node (j, ix, iy) of ``span`` cells lie in the
    winner's zone. ``zone``: (winner j, ix, iy, radius in cells, half-width in headings).
    ``strip``: a unit direction (x, y) along which the zone has no end (a strip of the
    radius either side of the line through the winner), or (0, 0) for a disc."""
    if abs(j - zone[0]) > zone[4]:
        return False
    if strip[0] == 0.0 and strip[1] == 0.0:
        dx = max(abs(ix - zone[1]), abs(ix + span - 1 - zone[1]))
        dy = max(abs(iy - zone[2]), abs(iy + span - 1 - zone[2]))
        return dx * dx + dy * dy <= zone[3] * zone[3]
    # across the strip, the node's farthest corner (the distance is linear in the corner)
    across = 0.0
    for cx in (ix, ix + span - 1):
        for cy in (iy, iy + span - 1):
            across = max(across, abs(strip[0] * (cy - zone[2]) - strip[1] * (cx - zone[1])))
    return across <= zone[3]


@numba.njit(cache=True)
def _in_known(j, ix, iy, span, known):
    """Whether all translations of the node (j, ix, iy) of ``span`` cells lie in the window
    already searched, ``known`` = (headings, cells) either side of the centre (-1: none)."""
    return (
        abs(j) <= known[0]
        and ix >= -known[1]
        and iy >= -known[1]
        and ix + span - 1 <= known[1]
        and iy + span - 1 <= known[1]
    )


@numba.njit(cache=True)
def _heading_table(pts, args, nh, reach, span, rows, cols, stride):
    """The endpoints' cells at every heading ``-nh..nh`` of the lattice, computed once per
    search (the bounds then only add whole cells). A search reads cell (r + iy, c + ix) for
    node origins |ix|, |iy| <= ``reach``: an endpoint whose reads all fall inside the crop
    is kept as its flat index ``r * stride + c`` (no bounds checks when summed); one whose
    reads may fall outside keeps (r, c) for the checked sum; one no node of ``span`` cells
    can bring onto the crop is dropped (it adds 0 everywhere).

    Returns (flat, n_inner, edge rows, edge cols, n_edge), each row one heading."""
    x, y, th, step, ox, oy, res = args
    n = pts.shape[0]
    count = 2 * nh + 1
    flat = np.empty((count, n), dtype=np.int32)
    edge_r = np.empty((count, n), dtype=np.int64)
    edge_c = np.empty((count, n), dtype=np.int64)
    n_inner = np.zeros(count, dtype=np.int64)
    n_edge = np.zeros(count, dtype=np.int64)
    # Endpoints whose cell stays inside at every heading (those nearer the centre than
    # its distance to the crop's edge, the most) come first and are not tested per heading.
    row0 = math.floor((y - oy) / res)
    col0 = math.floor((x - ox) / res)
    room = min(row0, col0, rows - 1 - row0, cols - 1 - col0) - reach - 2
    order = np.empty(n, dtype=np.int64)
    n_sure = 0
    for k in range(n):
        if math.hypot(pts[k, 0], pts[k, 1]) / res < room:
            order[n_sure] = k
            n_sure += 1
    n_rest = n_sure
    for k in range(n):
        if not math.hypot(pts[k, 0], pts[k, 1]) / res < room:
            order[n_rest] = k
            n_rest += 1
    px = pts[order, 0]
    py = pts[order, 1]
    for jj in range(count):
        theta = th + (jj - nh) * step
        c = math.cos(theta)
        s = math.sin(theta)
        row = flat[jj]
        for k in range(n_sure):  # branch-free: vector registers
            r = math.floor((s * px[k] + c * py[k] + y - oy) / res)
            q = math.floor((c * px[k] - s * py[k] + x - ox) / res)
            row[k] = r * stride + q
        a = n_sure
        e = 0
        for k in range(n_sure, n):
            r = math.floor((s * px[k] + c * py[k] + y - oy) / res)
            q = math.floor((c * px[k] - s * py[k] + x - ox) / res)
            if r - reach >= rows or q - reach >= cols:
                continue
            if r + reach + span <= 0 or q + reach + span <= 0:
                continue
            if r - reach >= 0 and q - reach >= 0 and r + reach < rows and q + reach < cols:
                row[a] = r * stride + q
                a += 1
            else:
                edge_r[jj, e] = r
                edge_c[jj, e] = q
                e += 1
        n_inner[jj] = a
        n_edge[jj] = e
    return flat, n_inner, edge_r, edge_c, n_edge


@numba.njit(cache=True)
def _node_bound(levels, h, table, jj, ix, iy, rows, cols, stride):
    """Σ over the endpoints at heading row ``jj`` of ``table`` of pooled level ``h`` at
    their cell shifted by (ix, iy): the score of the lattice pose at h = 0, an upper bound
    of the ``2^h x 2^h`` translations from (ix, iy) above. ``levels`` is flat per level
    (row ``stride``). A window reaching in from below or left reads the first cell (whose
    window covers its part inside); one wholly outside the crop adds 0."""
    flat, n_inner, edge_r, edge_c, n_edge = table
    base = iy * stride + ix
    grid = levels[h]
    total = 0.0
    for k in range(n_inner[jj]):
        total += grid[flat[jj, k] + base]
    size = 1 << h
    for k in range(n_edge[jj]):
        r = edge_r[jj, k] + iy
        c = edge_c[jj, k] + ix
        if r >= rows or c >= cols or r + size <= 0 or c + size <= 0:
            continue
        total += grid[max(r, 0) * stride + max(c, 0)]
    return total


@numba.njit(cache=True)
def _node_bounds4(levels, h, table, jj, xs, ys, m, out, rows, cols, stride):
    """``out[t]`` = :func:`_node_bound` of the nodes (xs[t], ys[t]), t < m <= 4, at level
    ``h`` and heading row ``jj``, in one pass over the endpoints (the siblings' cells are
    near each other in memory); each sum in the same order, so the same to the last bit."""
    if m == 1:
        out[0] = _node_bound(levels, h, table, jj, xs[0], ys[0], rows, cols, stride)
        return
    flat, n_inner, edge_r, edge_c, n_edge = table
    grid = levels[h]
    o0 = ys[0] * stride + xs[0]
    o1 = ys[min(1, m - 1)] * stride + xs[min(1, m - 1)]
    o2 = ys[min(2, m - 1)] * stride + xs[min(2, m - 1)]
    o3 = ys[min(3, m - 1)] * stride + xs[min(3, m - 1)]
    a0 = 0.0
    a1 = 0.0
    a2 = 0.0
    a3 = 0.0
    for k in range(n_inner[jj]):
        f = flat[jj, k]
        a0 += grid[f + o0]
        a1 += grid[f + o1]
        a2 += grid[f + o2]
        a3 += grid[f + o3]
    out[0] = a0
    out[1] = a1
    out[2] = a2
    out[3] = a3
    size = 1 << h
    for k in range(n_edge[jj]):
        for t in range(m):
            r = edge_r[jj, k] + ys[t]
            c = edge_c[jj, k] + xs[t]
            if r >= rows or c >= cols or r + size <= 0 or c + size <= 0:
                continue
            out[t] += grid[max(r, 0) * stride + max(c, 0)]


@numba.njit(cache=True)
def _local_maximum(levels, table, jj, score, ix, iy, rows, cols, stride):
    """Whether no lattice neighbour of (ix, iy) at heading row ``jj`` (26 of them, past
    the window's edge too) scores higher than ``score``."""
    for dj in range(-1, 2):
        for dx in range(-1, 2):
            for dy in range(-1, 2):
                if dj == 0 and dx == 0 and dy == 0:
                    continue
                v = _node_bound(
                    levels, np.int64(0), table, jj + dj, ix + dx, iy + dy, rows, cols, stride
                )
                if v > score:
                    return False
    return True


@numba.njit(cache=True)
def _heap_push(heap_b, heap_n, n, bound, node):
    """Push ``node`` with key ``bound`` on the max-heap of ``n`` entries (room for one
    more); returns the new count."""
    i = n
    while i > 0:
        parent = (i - 1) >> 1
        if heap_b[parent] >= bound:
            break
        heap_b[i] = heap_b[parent]
        heap_n[i] = heap_n[parent]
        i = parent
    heap_b[i] = bound
    heap_n[i] = node
    return n + 1


@numba.njit(cache=True)
def _heap_pop(heap_b, heap_n, n):
    """Remove the top of the max-heap of ``n`` entries; returns its node (n - 1 remain)."""
    top = heap_n[0]
    n -= 1
    bound = heap_b[n]
    node = heap_n[n]
    i = 0
    while True:
        c = 2 * i + 1
        if c >= n:
            break
        if c + 1 < n and heap_b[c + 1] > heap_b[c]:
            c += 1
        if heap_b[c] <= bound:
            break
        heap_b[i] = heap_b[c]
        heap_n[i] = heap_n[c]
        i = c
    heap_b[i] = bound
    heap_n[i] = node
    return top


@numba.njit(cache=True)
def _store(pool_b, pool_k, n, bound, j, h, ix, iy):
    """Store node ``n`` (heading j, level h, origin ix, iy) with its bound in the pool (with
    room for it); returns n + 1."""
    pool_b[n] = bound
    pool_k[n, 0] = j
    pool_k[n, 1] = h
    pool_k[n, 2] = ix
    pool_k[n, 3] = iy
    return n + 1


@numba.njit(cache=True)
def _open(pool_b, pool_k, heap_b, heap_n, n, size, bound, j, h, ix, iy):
    """Store node ``n`` (:func:`_store`) and push it on the heap of ``size`` entries (with
    room for it); returns (n + 1, size + 1)."""
    _store(pool_b, pool_k, n, bound, j, h, ix, iy)
    return n + 1, _heap_push(heap_b, heap_n, size, bound, n)


@numba.njit(cache=True)
def _place(pool_b, pool_k, heap_b, heap_n, n, size, aside, n_aside, known, bound, j, h, ix, iy):
    """Store node ``n`` and push it on the heap (:func:`_open`), or, ``known`` (it lies in a
    window already searched), store it and set it aside; returns (aside, n_aside, n, size)."""
    if known:
        aside = _appended(aside, n_aside, n)
        return aside, n_aside + 1, _store(pool_b, pool_k, n, bound, j, h, ix, iy), size
    n, size = _open(pool_b, pool_k, heap_b, heap_n, n, size, bound, j, h, ix, iy)
    return aside, n_aside, n, size


@numba.njit(cache=True)
def _appended(items, count, item):
    """``items`` (grown when full) with ``item`` at index ``count``."""
    if count == items.shape[0]:
        more = np.empty(2 * count, dtype=np.int64)
        _copy_into(more, items)
        items = more
    items[count] = item
    return items


@numba.njit(cache=True)
def _copy_into(dst, src):
    """``dst[:len(src)] = src`` for 1-D or 2-D arrays, as a loop: Numba's slice assignment
    checks the shapes and compiles an error message formatter with it, a few seconds of a
    first run's compilation."""
    flat_dst = dst.reshape(-1)
    flat_src = src.reshape(-1)
    for i in range(flat_src.shape[0]):
        flat_dst[i] = flat_src[i]


@numba.njit(cache=True)
def _grown(pool_b, pool_k, heap_b, heap_n, need):
    """The node pool and heap with room for ``need`` nodes (doubled when short)."""
    if need <= pool_b.shape[0]:
        return pool_b, pool_k, heap_b, heap_n
    size = max(2 * pool_b.shape[0], need)
    nb = np.empty(size)
    nk = np.empty((size, 4), dtype=np.int64)
    hb = np.empty(size)
    hn = np.empty(size, dtype=np.int64)
    _copy_into(nb, pool_b)
    _copy_into(nk, pool_k)
    _copy_into(hb, heap_b)
    _copy_into(hn, heap_n)
    return nb, nk, hb, hn


@numba.njit(cache=True)
def _search(levels, pts, args, nt, nx, dims, rival, known, seeds):
    """The whole search in one call: the best lattice pose of headings -nt..nt and
    translations -nx..nx (cells), then its best distinct rival.

    Best first, where Hess et al. go depth first: a queue of all open nodes by bound
    expands only nodes whose bound beats the optimum, however good or bad the first leaves
    met are. The node of highest bound is taken from a heap and its children are bounded
    and pushed, until a leaf comes out on top: its score is at least every bound left, so
    it is the lattice optimum. The rival search goes on from the same heap (which with the
    winner covers the whole window): nodes wholly inside the winner's zone (``rival[0]``
    cells, ``rival[1]`` headings; a strip along the unit direction ``rival[3:5]`` unless it
    is (0, 0)) are dropped, and the first leaf on top that is a local
    maximum outside it is the best rival, if it scores more than the floor (``rival[2]``
    of the winner). Of leaves scoring exactly alike, each phase keeps the first in
    (j, ix, iy) order. Only leaves scoring above 0 are sought: where none does, the answer
    is score 0 at the first lattice pose, without a rival.

    ``known`` (headings, cells; -1 for none): a window within this one already searched,
    with the same rival settings and no slide, whose best and best rival are ``seeds``
    (rows of score, j, ix, iy; a score of -1: none). Its nodes can hold no leaf better than
    its best, which is pushed as a leaf instead: they are set aside, bounded, never expanded
    in the search for the best. If that best is the whole window's and the known rival lies
    outside this search's zone around it (or there is none), the known rival stands for the
    known window in the rival search, pushed as a leaf, and its nodes are dropped; otherwise
    (a rival inside a slide's strip) they are pushed back and searched for the rival as the
    whole window's search would.

    Returns (score, j, ix, iy, rival score, rj, rx, ry, nodes); rj is ``nt + 1`` without a
    rival."""
    rows, cols, stride = dims
    depth = levels.shape[0] - 1
    span = 1 << depth
    nh = nt + 1
    table = _heading_table(pts, args, nh, nx + 1, span, rows, cols, stride)
    per_axis = (2 * nx + span) // span
    per_heading = per_axis * per_axis
    n_roots = (2 * nt + 1) * per_heading
    cap = 4 * n_roots + 64
    pool_b = np.empty(cap)
    pool_k = np.empty((cap, 4), dtype=np.int64)
    heap_b = np.empty(cap)
    heap_n = np.empty(cap, dtype=np.int64)
    xs = np.empty(4, dtype=np.int64)
    ys = np.empty(4, dtype=np.int64)
    out = np.empty(4)
    # counts start as typed zeros, not literals: Numba would compile the kernels they are
    # passed to once more for the literal 0 (a first run's compilation time)
    n = np.int64(0)
    size = np.int64(0)
    aside = np.empty(16, dtype=np.int64)  # the known window's nodes, set aside
    n_aside = 0
    for j in range(-nt, nt + 1):
        for first in range(0, per_heading, 4):
            m = min(4, per_heading - first)
            for t in range(m):
                xs[t] = -nx + ((first + t) // per_axis) * span
                ys[t] = -nx + ((first + t) % per_axis) * span
            _node_bounds4(levels, depth, table, j + nh, xs, ys, m, out, rows, cols, stride)
            for t in range(m):
                aside, n_aside, n, size = _place(
                    pool_b, pool_k, heap_b, heap_n, n, size, aside, n_aside,
                    _in_known(j, xs[t], ys[t], span, known), out[t], j, depth, xs[t], ys[t],
                )  # fmt: skip
    nodes = n
    seed = -1  # the known best's leaf
    if seeds.shape[0]:
        seed = n
        n, size = _open(
            pool_b, pool_k, heap_b, heap_n, n, size, seeds[0, 0], int(seeds[0, 1]), 0,
            int(seeds[0, 2]), int(seeds[0, 3]),
        )  # fmt: skip
    skip = False  # whether the known window's nodes are dropped in the rival search
    zone = np.zeros(5, dtype=np.int64)
    strip = np.array([rival[3], rival[4]])
    found = np.full((2, 4), -1.0)  # (score, j, ix, iy) of the winner, then of the rival
    # Nodes bounded at 0 hold no leaf worth finding. Where nothing scores above it, every
    # pose ties at 0 and every node would be expanded to order the ties: a lost robot's
    # check against a submap out of its reach, 0.2-0.4 million nodes and 150-500 ms for a
    # verdict the score decides.
    floor = 0.0
    chosen = -1  # the leaf of the phase, the first in (j, ix, iy) order among its equals
    held = np.empty(16, dtype=np.int64)  # the winner's equals, pushed back for the rival
    n_held = 0
    phase = 0
    while phase < 2:
        if size == 0 or (chosen >= 0 and heap_b[0] < pool_b[chosen]) or heap_b[0] <= floor:
            # no node left can hold a leaf scoring as much as the chosen one
            if chosen >= 0:
                found[phase, 0] = pool_b[chosen]
                found[phase, 1] = pool_k[chosen, 0]
                found[phase, 2] = pool_k[chosen, 2]
                found[phase, 3] = pool_k[chosen, 3]
            if phase == 1 or chosen < 0:
                break
            for t in range(n_held):
                size = _heap_push(heap_b, heap_n, size, pool_b[held[t]], held[t])
            zone[0] = pool_k[chosen, 0]
            zone[1] = pool_k[chosen, 2]
            zone[2] = pool_k[chosen, 3]
            zone[3] = int(rival[0])
            zone[4] = int(rival[1])
            # The known rival is the best local maximum of its window outside a disc around
            # the same best: outside this zone, which holds that disc (a strip along a slide
            # holds it too), it is the window's best as well; none there, none here.
            rival_known = seeds.shape[0] > 1 and seeds[1, 0] >= 0.0
            skip = chosen == seed and not (
                rival_known
                and _in_zone(int(seeds[1, 1]), int(seeds[1, 2]), int(seeds[1, 3]), 1, zone, strip)
            )
            if skip and rival_known:
                pool_b, pool_k, heap_b, heap_n = _grown(pool_b, pool_k, heap_b, heap_n, n + 1)
                n, size = _open(
                    pool_b, pool_k, heap_b, heap_n, n, size, seeds[1, 0], int(seeds[1, 1]), 0,
                    int(seeds[1, 2]), int(seeds[1, 3]),
                )  # fmt: skip
            for t in range(0 if skip else n_aside):
                size = _heap_push(heap_b, heap_n, size, pool_b[aside[t]], aside[t])
            low = max(rival[2] * pool_b[chosen], 0.0)
            floor = np.nextafter(low, -np.inf) if low > 0 else -1.0
            chosen = -1
            phase = 1
            continue
        q = _heap_pop(heap_b, heap_n, size)
        size -= 1
        j = pool_k[q, 0]
        h = pool_k[q, 1]
        ix = pool_k[q, 2]
        iy = pool_k[q, 3]
        if phase == 1 and _in_zone(j, ix, iy, 1 << h, zone, strip):
            continue
        if h == 0:
            # a leaf on top scores at least every bound left: the best (or, outside the
            # winner's zone and a local maximum, the best rival); its equals still on the
            # heap are taken too, and the first in (j, ix, iy) order is kept, as a brute
            # force's first maximum, whatever order the search met them in
            if phase == 1 and not _local_maximum(
                levels, table, j + nh, pool_b[q], ix, iy, rows, cols, stride
            ):
                continue
            if chosen < 0 or (j, ix, iy) < (
                pool_k[chosen, 0],
                pool_k[chosen, 2],
                pool_k[chosen, 3],
            ):
                q, chosen = chosen, q
            if q >= 0 and phase == 0:
                held = _appended(held, n_held, q)
                n_held += 1
            continue
        half = 1 << (h - 1)
        m = np.int64(0)
        for a in range(2):
            for c in range(2):
                cx = ix + a * half
                cy = iy + c * half
                if cx > nx or cy > nx:
                    continue
                if phase == 1 and _in_zone(j, cx, cy, half, zone, strip):
                    continue
                if skip and _in_known(j, cx, cy, half, known):
                    continue
                xs[m] = cx
                ys[m] = cy
                m += 1
        if m == 0:
            continue
        _node_bounds4(levels, h - 1, table, j + nh, xs, ys, m, out, rows, cols, stride)
        nodes += m
        pool_b, pool_k, heap_b, heap_n = _grown(pool_b, pool_k, heap_b, heap_n, n + m)
        for t in range(m):
            if out[t] > floor:
                aside, n_aside, n, size = _place(
                    pool_b, pool_k, heap_b, heap_n, n, size, aside, n_aside,
                    phase == 0 and _in_known(j, xs[t], ys[t], half, known), out[t], j, h - 1,
                    xs[t], ys[t],
                )  # fmt: skip
    if found[0, 0] < 0.0:  # nothing above 0
        return 0.0, -nt, -nx, -nx, 0.0, nt + 1, 0, 0, nodes
    score, bj, bx, by = found[0, 0], int(found[0, 1]), int(found[0, 2]), int(found[0, 3])
    rival_score, rj, rx, ry = found[1, 0], int(found[1, 1]), int(found[1, 2]), int(found[1, 3])
    if rival_score < 0.0:
        rj = nt + 1
    return score, bj, bx, by, rival_score, rj, rx, ry, nodes


@numba.njit(cache=True)
def _brute_force(levels, pts, args, nt, nx, dims, pad):
    """Every lattice score, headings -nt-pad..nt+pad, translations -nx-pad..nx+pad (with
    the search's own sums: the same table for ``pad`` <= 1)."""
    rows, cols, stride = dims
    reach = max(pad, 1)
    span = 1 << (levels.shape[0] - 1)
    table = _heading_table(pts, args, nt + reach, nx + reach, span, rows, cols, stride)
    out = np.empty((2 * (nt + pad) + 1, 2 * (nx + pad) + 1, 2 * (nx + pad) + 1))
    for j in range(-nt - pad, nt + pad + 1):
        for ix in range(-nx - pad, nx + pad + 1):
            for iy in range(-nx - pad, nx + pad + 1):
                out[j + nt + pad, ix + nx + pad, iy + nx + pad] = _node_bound(
                    levels, np.int64(0), table, j + nt + reach, ix, iy, rows, cols, stride
                )
    return out


def _finite_points(points: ArrayLike) -> FloatArray:
    """Sensor-frame endpoints as a contiguous (N, 2) array, those with a non-finite
    coordinate left out."""
    pts = np.ascontiguousarray(np.asarray(points, dtype=np.float64).reshape(-1, 2))
    return pts[np.all(np.isfinite(pts), axis=1)]


def _percentile_90(values: FloatArray) -> float:
    """``np.percentile(values, 90)`` (its linear rule, to the bit) by a partial sort alone:
    NumPy's call costs 60 µs for its generality, on intel a hundredth of a scan's matching."""
    n = values.shape[0]
    virtual = (n - 1) * 0.9
    low = math.floor(virtual)
    high = min(low + 1, n - 1)
    part = np.partition(values, (low, high))
    a, b = float(part[low]), float(part[high])
    t = virtual - low
    return b - (b - a) * (1 - t) if t >= 0.5 else a + (b - a) * t


@numba.njit(cache=True)
def _arc_extent(pts, low, high):
    """(min x, min y, max x, max y) of sensor-frame ``pts`` turned by every angle from
    ``low`` to ``high``: each endpoint sweeps an arc, whose extreme along an axis is one of
    its ends or, where the arc crosses that axis's direction, its whole range."""
    full = high - low >= 2.0 * math.pi
    out = np.array([np.inf, np.inf, -np.inf, -np.inf])
    for k in range(pts.shape[0]):
        r = math.hypot(pts[k, 0], pts[k, 1])
        start = math.atan2(pts[k, 1], pts[k, 0]) + low
        end = start + (high - low)
        ends_x = (math.cos(start) * r, math.cos(end) * r)
        ends_y = (math.sin(start) * r, math.sin(end) * r)
        extremes = (
            -r if full or _crosses(start, end, math.pi) else min(ends_x),
            -r if full or _crosses(start, end, -0.5 * math.pi) else min(ends_y),
            r if full or _crosses(start, end, 0.0) else max(ends_x),
            r if full or _crosses(start, end, 0.5 * math.pi) else max(ends_y),
        )
        for i in range(2):
            out[i] = min(out[i], extremes[i])
            out[i + 2] = max(out[i + 2], extremes[i + 2])
    return out


@numba.njit(cache=True)
def _crosses(start, end, direction):
    """Whether the angles from ``start`` to ``end`` (less than a turn apart) pass
    ``direction`` or one of its turns."""
    lap = math.ceil((start - direction) / (2.0 * math.pi))
    return direction + 2.0 * math.pi * lap <= end


# --------------------------------------------------------------------------------------------
# The matcher

#: A known window (:meth:`WideBasinMatcher.search`) is reused when it holds at least this
#: share of the lattice searched: one of tens of centimetres under a rival window of metres
#: (freiburg-079's checks, 0.2 % of the lattice) spares nothing, and the slowest of those
#: searches cost 10-50 % more with it, the same nodes bounded (``benchmarks/README.md``).
KNOWN_SHARE = 0.05


def _poses(lattice: tuple[int, int]) -> int:
    """Poses in a lattice of (headings, positions per axis)."""
    return lattice[0] * lattice[1] ** 2


#: no window searched before (:func:`_search`'s ``known`` and ``seeds``)
_NOTHING_KNOWN = np.array([-1, -1], dtype=np.int64)
_NO_SEEDS = np.zeros((0, 4))


class WideBasinMatcher:
    """Branch-and-bound search of a wide window against one map (see the module docstring).

    The pooled grids are kept between searches: ``set_map`` again when the map changed
    (the odometry does so before each search, the cost is a few passes over the reachable
    cells)."""

    def __init__(self, config: WideBasinConfig | None = None) -> None:
        self.config = config or WideBasinConfig()
        self._levels = np.zeros((1, 0, 0), dtype=np.float32)
        self._shape = (0, 0)
        self._origin = np.zeros(2)
        self._resolution = 0.0
        self._depth = 0

    @property
    def resolution(self) -> float:
        """Cell size of the map searched, metres (the lattice's translation step)."""
        return self._resolution

    def depth_for(self, resolution: float) -> int:
        """Pooling levels above the finest: the top node spans the whole window."""
        cells = 2 * int(self.config.distance / resolution) + 1
        full = max(math.ceil(math.log2(cells)), 0)
        return full if self.config.depth is None else min(self.config.depth, full)

    def set_map(
        self, grid: OccupancyGrid, box: tuple[float, float, float, float] | None = None
    ) -> None:
        """Pool the part of ``grid`` within ``box`` (xmin, ymin, xmax, ymax; the whole grid
        by default) for searches. Endpoints that a searched pose puts outside it score 0,
        as outside the map."""
        res = grid.resolution
        rows_all, cols_all = grid.shape
        if box is None:
            r0, c0, r1, c1 = 0, 0, rows_all, cols_all
        else:
            ox, oy = grid.origin
            c0 = max(math.floor((box[0] - ox) / res), 0)
            r0 = max(math.floor((box[1] - oy) / res), 0)
            c1 = min(math.floor((box[2] - ox) / res) + 1, cols_all)
            r1 = min(math.floor((box[3] - oy) / res) + 1, rows_all)
        rows, cols = max(r1 - r0, 1), max(c1 - c0, 1)
        depth = self.depth_for(res)
        need = (depth + 1, rows, cols)
        have = self._levels.shape
        if have[0] < need[0] or have[1] < rows or have[2] < cols:
            # grown to the largest crop seen, then reused
            self._levels = np.zeros(
                (need[0], max(have[1], rows), max(have[2], cols)), dtype=np.float32
            )
        # the whole (C-contiguous) buffer: its rows are contiguous, so the kernel's loops
        # over them run on vector registers
        _fill_levels(grid.weights, r0, c0, rows, cols, self.config.blur, self._levels[: depth + 1])
        self._shape = (rows, cols)
        self._origin = grid.origin + res * np.array([c0, r0], dtype=np.float64)
        self._resolution = res
        self._depth = depth

    def _angular_step(self, pts: FloatArray, resolution: float) -> float:
        """The lattice's heading step for endpoints ``pts`` on a grid of ``resolution``."""
        c = self.config
        if c.angular_step is not None:
            return c.angular_step
        reach = _percentile_90(np.hypot(pts[:, 0], pts[:, 1])) if len(pts) else 1.0
        return c.angular_cells * resolution / max(reach, resolution)

    def reach_box(
        self, points: ArrayLike, windows: list[tuple[ArrayLike, float, float]], resolution: float
    ) -> tuple[float, float, float, float]:
        """The box (xmin, ymin, xmax, ymax) that holds every cell the lattice of each window
        (centre (x, y, theta), half-widths in metres and radians; searched on a grid of
        ``resolution``) puts one of the sensor-frame ``points`` in, a lattice step beyond
        the window too (the rival's local-maximum test looks there). Searches of those
        windows against ``set_map(grid, box)`` find what they find against the whole grid:
        no endpoint of theirs lands outside it, and a coarser level's bound, cut at the
        box's edge, still bounds every pose inside. A 180° scanner's endpoints turned
        ±45° leave a quarter of the square around its reach empty, and the pooling, a
        tenth of a thinned log's scan, then covers two thirds of the cells it would."""
        pts = _finite_points(points)
        if len(pts) == 0:
            x, y = (float(v) for v in np.asarray(windows[0][0], dtype=np.float64)[:2])
            return (x, y, x, y)
        step = self._angular_step(pts, resolution)
        boxes = []
        for centre, distance, angle in windows:
            x, y, theta = (float(v) for v in np.asarray(centre, dtype=np.float64).reshape(3))
            turn = (int(angle / step) + 2) * step
            slack = (int(distance / resolution) + 2) * resolution
            x0, y0, x1, y1 = _arc_extent(pts, theta - turn, theta + turn)
            boxes.append((x + x0 - slack, y + y0 - slack, x + x1 + slack, y + y1 + slack))
        b = np.array(boxes)
        return (float(b[:, 0].min()), float(b[:, 1].min()), float(b[:, 2].max()),
                float(b[:, 3].max()))  # fmt: skip

    def _lattice(self, pts: FloatArray, centre: FloatArray) -> tuple[int, int, tuple]:
        c = self.config
        res = self._resolution
        step = self._angular_step(pts, res)
        nt = int(c.angle / step)
        nx = int(c.distance / res)
        args = (float(centre[0]), float(centre[1]), float(centre[2]), float(step),
                float(self._origin[0]), float(self._origin[1]), float(res))  # fmt: skip
        return nt, nx, args

    def _prepare(self, points: ArrayLike, centre: ArrayLike) -> tuple[FloatArray, FloatArray]:
        if self._resolution == 0.0:
            raise RuntimeError("WideBasinMatcher.search needs set_map first")
        return _finite_points(points), np.asarray(centre, dtype=np.float64).reshape(3)

    def _pose(self, args: tuple, j: int, ix: int, iy: int) -> FloatArray:
        x, y, th, step, _, _, res = args
        return np.array([x + ix * res, y + iy * res, th + j * step])

    def _flat_levels(self) -> tuple[FloatArray, tuple[int, int, int]]:
        """The pooled levels the window of :attr:`config` needs, one flat row each (row
        stride: the buffer's width), and (rows, cols, stride) of the crop in it. A map pooled
        for a wider window serves a narrower one with its first levels (each level pools
        level 0 alone), so one pooling serves searches of several windows; a deeper window
        than pooled is searched from more top nodes, to the same answer."""
        buffer = self._levels
        depth = min(self.depth_for(self._resolution), self._depth)
        flat = buffer.reshape(buffer.shape[0], -1)[: depth + 1]
        return flat, (*self._shape, buffer.shape[2])

    def search(
        self,
        points: ArrayLike,
        centre: ArrayLike,
        hint: ArrayLike | None = None,
        slide: ArrayLike | None = None,
        known: WideMatch | None = None,
    ) -> WideMatch:
        """The best lattice pose of sensor-frame ``points`` (N, 2) within the window around
        ``centre`` (x, y, theta; map frame), and its best distinct rival. ``hint`` (a pose
        believed good) is accepted for callers that have one; the best-first search needs
        none (it expands the same nodes whatever it meets first), so it is not used.
        ``slide``: a direction (map frame) along which the scan is known not to pin the
        pose (a corridor's axis): the rival must then lie farther than ``rival_distance``
        across it, not merely along it (a corridor is one plateau; a rival on it is the
        winner's own).

        ``known``: this matcher's search of a window within this one, around the same
        ``centre``, of the same ``points``, with the same rival settings and no ``slide``
        (a closure check's own window, before the wider one its rival is sought in). Its
        best stands for its lattice in the search for the best, and, where that best is the
        whole window's, its rival in the search for the rival unless, across a ``slide``
        given here, that rival lies in the best's strip: its lattice is then not searched
        again. The answer is the one the whole window's search gives (the known best is the
        first maximum of its window, the known rival the best local maximum there outside
        the best's zone)."""
        pts, centre = self._prepare(points, centre)
        nt, nx, args = self._lattice(pts, centre)
        lattice = (2 * nt + 1, 2 * nx + 1)
        n = max(len(pts), 1)
        if len(pts) == 0:
            return WideMatch(centre.copy(), 0.0, None, 0.0, 0, lattice)
        levels, dims = self._flat_levels()
        c = self.config
        along = np.zeros(2) if slide is None else unit(slide)
        rival = (
            int(c.rival_distance / args[6]), int(c.rival_angle / args[3]), c.min_rival_ratio,
            float(along[0]), float(along[1]),
        )  # fmt: skip
        inner, seeds = _NOTHING_KNOWN, _NO_SEEDS
        if known is not None and known.leaves[0, 0] > 0.0 and (
            _poses(known.lattice) >= KNOWN_SHARE * _poses(lattice)
        ):
            inner = np.array([(known.lattice[0] - 1) // 2, (known.lattice[1] - 1) // 2])
            seeds = known.leaves
        best, j, ix, iy, score, rj, rx, ry, nodes = _search(
            levels, pts, args, nt, nx, dims, rival, inner, seeds
        )
        found = rj <= nt
        return WideMatch(
            pose=self._pose(args, j, ix, iy),
            score=best / n,
            rival_pose=self._pose(args, rj, rx, ry) if found else None,
            rival_score=score / n if found else 0.0,
            nodes=int(nodes),
            lattice=lattice,
            leaves=np.array([[best, j, ix, iy], [score if found else -1.0, rj, rx, ry]]),
        )

    def score_at(self, points: ArrayLike, pose: ArrayLike) -> float:
        """The mean map value of sensor-frame ``points`` placed by ``pose`` (any pose, not
        only the lattice's): the score :meth:`search` maximises, to compare other poses
        with its winner on the same scale."""
        pts, pose = self._prepare(points, pose)
        if len(pts) == 0:
            return 0.0
        levels = self._levels[: self._depth + 1, : self._shape[0], : self._shape[1]]
        cells = np.empty((len(pts), 2), dtype=np.int64)
        ox, oy = self._origin
        _discretize(pts, pose[2], pose[0], pose[1], ox, oy, self._resolution, cells)
        return _bound(levels, 0, cells, 0, 0, *self._shape) / len(pts)

    def brute_force_scores(self, points: ArrayLike, centre: ArrayLike, pad: int = 0):
        """Every lattice pose's mean map value, as (headings, x, y) with ``pad`` extra
        poses around the window, and the lattice's (x, y, theta, step, ...) arguments: the
        reference the branch and bound must equal (tests, benchmark)."""
        pts, centre = self._prepare(points, centre)
        nt, nx, args = self._lattice(pts, centre)
        levels, dims = self._flat_levels()
        scores = _brute_force(levels, pts, args, nt, nx, dims, pad)
        return scores / max(len(pts), 1), args


def refine(
    pyramid: MapPyramid,
    start: ArrayLike,
    points: ArrayLike,
    max_iterations: tuple[int, ...] | None = None,
    spacing: float | None = None,
    subcell_sigma: float | None = 1.0,
) -> tuple[FloatArray, MatchReport]:
    """Gauss-Newton (Eq. 3) from a search's pose down ``pyramid`` for sensor-frame
    ``points``: the sub-cell pose the lattice only brackets. ``spacing`` (default the finest
    cell) thins the points per level as the odometry does."""
    pts = np.ascontiguousarray(np.asarray(points, dtype=np.float64).reshape(-1, 2))
    levels = len(pyramid.grids)
    spacing = pyramid.finest.resolution if spacing is None else spacing
    keep = subsample_by_spacing(pts, spacing)
    level_pts = points_per_level(pts, spacing, levels, keep)
    iterations = max_iterations or (10,) * levels
    return match_scan_to_map(
        pyramid, level_pts, start, iterations, subcell_sigma=subcell_sigma,
        normals=matched_normals(level_pts),
    )  # fmt: skip


__all__ = ["WideBasinConfig", "WideBasinMatcher", "WideMatch", "refine"]
