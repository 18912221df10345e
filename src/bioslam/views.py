"""Boundary views and view cells: two-stage boundary-view matching (paper Sec. III-B, Eq. 6-9).

A view ``v = <h, B>`` (Eq. 7) pairs the boundary-cell activity ``B`` with its coarse feature
``h`` (Eq. 6), used as a hash key. Matching a new ``B``:

1. pre-match: only stored views whose ``h`` is within ``neighbour_buckets`` of the current
   ``h`` are compared;
2. for those, the mean squared difference ``S`` (Eq. 8) gives the view-cell activity
   ``V_i = 1 - min(s_t, S)/s_t`` (Eq. 9). The candidate with the smallest ``S`` is the active
   view if ``S < s_t``; otherwise ``B`` is learned as a new view (``V`` is extended).

Deviations from the paper, each measured by ``benchmarks/bench_views.py``:

* Neighbouring buckets. The paper compares only views with *equal* ``h``. ``h`` is the floor
  of a continuous sum, so two near-identical views whose sums straddle a bucket boundary land
  in neighbouring buckets and the match is lost, however small their difference. Looking also
  in ``h - 1`` and ``h + 1`` (``neighbour_buckets=1``, the default) recovers every pair whose
  sums differ by less than one bucket width ``10^ds``. ``neighbour_buckets=0`` is the paper.
* Head-direction gate. Boundary views are egocentric, so two corridors that look alike but
  run in different directions give the same ``B``; in a maze this is the main source of false
  matches (on the simulated maze, nearly all false matches were such rotated twins). When the
  caller passes its heading estimate (the pose cells' head-direction dimension, or odometry)
  to ``observe``, a view only matches if it was learned within ``heading_gate`` of that
  heading. Without a heading, matching is the paper's.
* Rotation search (Scan Context style, when the view cells know the ring layout,
  ``cells_per_ring``). A robot back at a place facing another way sees the same boundary-cell
  rings circularly shifted. Eq. 8 is then evaluated for each circular shift ``m`` of the
  stored view's angular bins within the heading window, over the angular sectors both scans
  cover (a 180 or 270 deg scanner compares what its fields of view share, at least
  ``min_shared`` of a ring), and the smallest ``S`` wins; ``ViewMatch.heading_offset``
  (``m`` bins) is the current heading minus the view's, which seeds the registration that
  verifies the place. With a heading estimate, the shifts are those within ``heading_gate``
  of the heading difference it implies, so a corridor driven the other way is compared
  turned round (and matches), while a rotated twin (a corridor running elsewhere that looks
  alike when turned) is not compared at all. Without a heading every shift is tried. Eq. 6's
  sum is then taken per covered sector (``sum(B) * cells_per_ring / covered``); it is
  rotation-invariant for a 360 deg scanner only (a turned 270 deg scanner's sum changed by
  13 % at the median, 37 % at the 90th percentile for 30 deg on the maze), so a scanner that
  sees part of each ring skips the hash; instead the ``partial_candidates`` views whose mean
  activity per ring (over the bins each scan covers) is nearest are compared. Measured in
  ``benchmarks/bench_views.py`` section 5: a place is recognised 30 deg off its learned
  heading (0 % before).
* Turned activity (with a heading and the scan, ``observe``'s ``turned``). Whole shifts line
  the bins up only for turns that are whole bins: turned by 5°, 15° or 25° on the maze, no
  place was recognised (a field 10° wide sampled every 10° is no line between bins, so
  interpolating the shift does not recover it). Each view is compared instead with the
  scan's activity recomputed with its bearings turned by the fraction of a bin its heading
  difference leaves over, to a quarter of a bin, and by a quarter either side for the
  heading estimate's error: 100 % at every turn measured, with the estimate 3° off too.
* ``S`` values at or above ``s_t`` are not computed exactly: they give ``V = 0`` whatever
  their value, so a candidate is dropped as soon as a lower bound on ``S`` reaches ``s_t``
  (reported as ``inf``). Matches and ``V`` are exactly those of the full computation.

Views not compared in a step (other buckets, other headings) have ``V = 0``; only the compared
candidates are kept, so a step's cost does not grow with the views outside the pre-match.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
from numba import njit
from numpy.typing import ArrayLike, NDArray

from bioslam.geometry import wrap_angle
from bioslam.growing import GrowingArray
from bioslam.view_store import CHUNK_MASK, CHUNK_SHIFT, VIEW_DTYPE, ViewStore, decode_cells

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

#: With the views' cells in a file, the pages read are handed back every this many looks.
DROP_PAGES_EVERY = 64

#: Whole-bin shifts are screened against this multiple of ``s_t`` before the fractional one.
_COARSE_SLACK = 4.0


def coarse_view_feature(B: ArrayLike, ds: float) -> int:
    """Eq. 6: ``h = floor(10^-ds * sum_i b_i)``, the coarse view feature (hash key)."""
    return math.floor(10.0 ** (-ds) * float(np.sum(B)))


def view_similarity(B1: ArrayLike, B2: ArrayLike) -> float:
    """Eq. 8: ``S(B1, B2)``, the mean squared difference of two boundary views."""
    a = np.asarray(B1, dtype=np.float64)
    b = np.asarray(B2, dtype=np.float64)
    if a.shape != b.shape:
        raise ValueError(f"boundary views differ in size: {a.shape} vs {b.shape}")
    return float(np.mean((a - b) ** 2))


def view_cell_activity(S: ArrayLike, s_t: float) -> FloatArray | float:
    """Eq. 9: ``V_i = 1 - min(s_t, S_i) / s_t``, clamped and inverted into ``[0, 1]``."""
    # S >= 0, but the closed-form fractional shift can leave -1e-16 for an exact repeat
    v = 1.0 - np.clip(np.asarray(S, dtype=np.float64), 0.0, s_t) / s_t
    return float(v) if v.ndim == 0 else v


def _first(ids: IntArray) -> IntArray:
    """Every candidate compared with the first row of the activity stack."""
    return np.zeros(ids.size, dtype=np.int64)


def block_sums(B: FloatArray, block: int) -> FloatArray:
    """Sums of ``B`` over consecutive blocks of ``block`` cells (the last may be shorter)."""
    edges = np.arange(0, B.shape[-1], block)
    return np.add.reduceat(B, edges, axis=-1)


@njit(cache=True)
def _similarities(
    chunks: Any, idx: IntArray, B: FloatArray, b_sums: FloatArray, block: int, limit: float
) -> FloatArray:
    # Eq. 8 for many stored views (bioslam.view_store chunks), decoding each view's cells
    # only as far as they are read. Values at or above ``limit`` are not needed exactly
    # (they give V = 0), so a view is dropped as soon as a lower bound reaches it: first
    # Cauchy-Schwarz over block sums, sum_k (sum_{i in k} diff_i)^2 / |k| <= sum_i diff_i^2,
    # which costs one operation per block instead of per cell, then the running sum itself.
    # Dropped views get inf.
    m = B.size
    n_blocks = b_sums.size
    budget = limit * m
    out = np.full(idx.size, np.inf)
    row = np.empty(m)
    for n in range(idx.size):
        v = idx[n]
        bits, starts, sums, _, _, values = chunks[v >> CHUNK_SHIFT]
        at = v & CHUNK_MASK
        bound = 0.0
        for k in range(n_blocks):
            size = min(block, m - k * block)
            diff = sums[at, k] - b_sums[k]
            bound += diff * diff / size
        if bound >= budget:
            continue
        pos = starts[at]
        acc = 0.0
        for k in range(n_blocks):
            stop = min(m, (k + 1) * block)
            pos = decode_cells(bits[at], values, pos, k * block, stop - k * block, row)
            for i in range(k * block, stop):
                diff = row[i] - B[i]
                acc += diff * diff
            if acc >= budget:
                break
        if acc < budget:
            out[n] = acc / m
    return out


@njit(cache=True)
def _shift_similarities(
    chunks: Any,
    idx: IntArray,
    lo: IntArray,
    hi: IntArray,
    stack: FloatArray,
    which: IntArray,
    b_cover: NDArray[np.bool_],
    stack_ring_sums: FloatArray,
    cols: int,
    limit: float,
    min_cols: int,
) -> tuple[FloatArray, IntArray]:
    # Eq. 8 between B (row ``which[n]`` of ``stack`` for candidate n: the scan's activity,
    # or turned) and each stored view circularly shifted by m bins (m in lo..hi),
    # over the sectors both cover: B[r, c] against view[r, (c + m) % cols]. Per candidate the
    # smallest S below ``limit`` and its shift; inf when none. When both views cover the whole
    # ring, the ring sums do not change with the shift and bound every shift at once
    # (Cauchy-Schwarz, as in _similarities); a running sum that reaches the best so far stops.
    # A view's rings are decoded (bioslam.view_store) the first time a shift reads them: a
    # shift reads rings in order, so the next ring to decode is always the one after the
    # last decoded.
    rings = stack.shape[1] // cols
    out = np.full(idx.size, np.inf)
    shift = np.zeros(idx.size, dtype=np.int64)
    row = np.empty(stack.shape[1])
    b_full = np.all(b_cover)
    for n in range(idx.size):
        v = idx[n]
        B = stack[which[n]]
        bits, starts, ring_sums, cover, _, values = chunks[v >> CHUNK_SHIFT]
        at = v & CHUNK_MASK
        if b_full and np.all(cover[at]):
            gap = _ring_sum_gap(ring_sums[at], stack_ring_sums[which[n]], cols)
            if gap >= limit * rings * cols:
                continue
        decoded = 0
        pos = starts[at]
        best = limit
        for m in range(lo[n], hi[n] + 1):
            mm = m % cols
            count = 0
            for c in range(cols):
                if b_cover[c] and cover[at, (c + mm) % cols]:
                    count += 1
            if count < min_cols:
                continue
            budget = best * rings * count
            acc = 0.0
            for r in range(rings):
                base = r * cols
                if r == decoded:
                    pos = decode_cells(bits[at], values, pos, base, cols, row)
                    decoded += 1
                for c in range(cols):
                    k = (c + mm) % cols
                    if b_cover[c] and cover[at, k]:
                        diff = B[base + c] - row[base + k]
                        acc += diff * diff
                if acc >= budget:
                    break
            if acc < budget:
                best = acc / (rings * count)
                out[n] = best
                shift[n] = mm
    return out, shift


@njit(cache=True)
def _ring_sum_gap(ring_sums: Any, b_ring_sums: FloatArray, cols: int) -> float:
    # sum over the rings of (view's ring sum - scan's)^2 / cols: where both cover the whole
    # ring, a lower bound on rings * cols * S at any shift or turn, which change neither sum
    # (Cauchy-Schwarz, as in _similarities)
    gap = 0.0
    for r in range(b_ring_sums.size):
        diff = ring_sums[r] - b_ring_sums[r]
        gap += diff * diff / cols
    return gap


@njit(cache=True)
def _ring_sum_bounds(chunks: Any, idx: IntArray, b_ring_sums: FloatArray, cols: int) -> FloatArray:
    # _ring_sum_gap as a lower bound on each stored view's S, for a scan that covers the
    # whole ring; 0 for a view that covers part of it.
    out = np.zeros(idx.size)
    for n in range(idx.size):
        v = idx[n]
        _, _, ring_sums, cover, _, _ = chunks[v >> CHUNK_SHIFT]
        at = v & CHUNK_MASK
        if np.all(cover[at]):
            out[n] = _ring_sum_gap(ring_sums[at], b_ring_sums, cols) / (b_ring_sums.size * cols)
    return out


@njit(cache=True)
def _fractional_shift(
    row: FloatArray,
    cover: NDArray[np.bool_],
    B: FloatArray,
    b_cover: NDArray[np.bool_],
    m: int,
    cols: int,
) -> tuple[float, float]:
    # Eq. 8 against the stored view shifted by m + f bins, f in [-1, 1], the shifted view
    # interpolated linearly between neighbouring bins: S(f) is quadratic in f on each side,
    # so its minimum is closed-form. A robot turned by half a bin would otherwise differ
    # from its view by as much as a neighbouring place does.
    rings = B.size // cols
    best_s = np.inf
    best_f = 0.0
    for side in (-1, 1):
        e0 = 0.0
        e1 = 0.0
        e2 = 0.0
        count = 0
        for c in range(cols):
            k0 = (c + m) % cols
            k1 = (c + m + side) % cols
            if not (b_cover[c] and cover[k0] and cover[k1]):
                continue
            count += 1
            for r in range(rings):
                a = B[r * cols + c] - row[r * cols + k0]
                d = row[r * cols + k1] - row[r * cols + k0]
                e0 += a * a
                e1 += a * d
                e2 += d * d
        if count == 0:
            continue
        f = min(max(e1 / e2, 0.0), 1.0) if e2 > 0.0 else 0.0
        value = (e0 - 2.0 * f * e1 + f * f * e2) / (rings * count)
        if value < best_s:
            best_s = value
            best_f = side * f
    return best_s, best_f


@njit(cache=True)
def _refine_shifts(
    chunks: Any,
    idx: IntArray,
    coarse: FloatArray,
    shift: IntArray,
    stack: FloatArray,
    which: IntArray,
    b_cover: NDArray[np.bool_],
    cols: int,
    s_t: float,
) -> tuple[FloatArray, FloatArray]:
    # The candidates the whole-bin search kept (finite ``coarse``) refined to their best
    # fractional shift (_fractional_shift): ``S`` (inf at or above ``s_t``) and the shift in
    # bins. Each view is decoded in float32, as it is stored (the shifted differences of its
    # cells are float32 arithmetic).
    S = np.full(idx.size, np.inf)
    offsets = shift.astype(np.float64)
    row = np.empty(stack.shape[1], dtype=np.float32)
    for n in range(idx.size):
        if not np.isfinite(coarse[n]):
            continue
        B = stack[which[n]]
        v = idx[n]
        bits, starts, _, cover, _, values = chunks[v >> CHUNK_SHIFT]
        at = v & CHUNK_MASK
        decode_cells(bits[at], values, starts[at], 0, B.size, row)
        value, frac = _fractional_shift(row, cover[at], B, b_cover, shift[n], cols)
        value = min(value, coarse[n])
        if value < s_t:
            S[n] = value
            offsets[n] = shift[n] + (frac if value < coarse[n] else 0.0)
    return S, offsets


@njit(cache=True)
def _one_bin_difference(b: FloatArray, cover: NDArray[np.bool_], cols: int) -> float:
    """Eq. 8 between the scan's activity ``b`` and itself shifted by one bin, over the bins
    both cover: the scale of the screen for the views worth turning the scan for
    (``ViewCellConfig.turn_screen``). A view learned at this place and turned between bins
    differs from the scan at a whole shift by about the scan's difference from itself turned
    by half a bin, which depends on the scene (walls near or far, bare or cluttered), not on
    ``s_t``, and is a steady share of the one-bin difference (0.25-0.31, 1st to 99th
    percentile, on four floors and scanners); the one-bin difference needs no activity
    recomputed."""
    # one pass, no temporaries: this runs at most looks of a partial scanner
    acc = 0.0
    count = 0
    for c in range(cols):
        k = (c + 1) % cols
        if not (cover[c] and cover[k]):
            continue
        count += 1
        for base in range(0, b.size, cols):
            diff = b[base + c] - b[base + k]
            acc += diff * diff
    return acc / (count * (b.size // cols)) if count else math.inf


@njit(cache=True)
def _shift_windows(
    centre: FloatArray, reach: int, cols: int
) -> tuple[IntArray, IntArray, FloatArray]:
    """The whole-bin shifts (``lo`` to ``hi``) each view is compared at, from the shift its
    learned heading gives (``centre``, in bins; NaN for a view learned without one): within
    ``reach`` bins of it, never more than a whole ring, every shift where it is NaN. And the
    fraction of a bin (``left_over``) it leaves over the nearest whole shift (0 where NaN).
    One pass: this runs at every look of the rotation search."""
    n = centre.size
    lo = np.zeros(n, dtype=np.int64)
    hi = np.full(n, cols - 1, dtype=np.int64)
    left_over = np.zeros(n)
    for k in range(n):
        if not math.isfinite(centre[k]):
            continue
        mid = np.round(centre[k])
        lo[k] = np.int64(mid) - reach
        hi[k] = min(np.int64(mid) + reach, np.int64(mid) - reach + cols - 1)
        left_over[k] = centre[k] - mid
    return lo, hi, left_over


@njit(cache=True)
def _turn_plan(
    left_over: FloatArray, steps: int, reach: int
) -> tuple[IntArray, IntArray, IntArray, IntArray]:
    """The turns of the scan each view is compared at (:meth:`ViewCells._turned_similarities`):
    its ``left_over`` fraction of a bin rounded to ``1 / steps`` of one, and ``reach`` steps
    either side. A turn of ``t`` steps is one of ``step`` steps (``-steps // 2`` up to
    ``steps - steps // 2 - 1``) with the shifts ``whole`` bins on. Returns ``whole`` and
    ``step`` (views x tries), the distinct ``turns`` in ascending order and ``which`` of
    them each try uses."""
    n, tries, half = left_over.size, 2 * reach + 1, steps // 2
    whole = np.empty((n, tries), dtype=np.int64)
    step = np.empty((n, tries), dtype=np.int64)
    used = np.zeros(steps, dtype=np.bool_)
    for k in range(n):
        first = np.int64(np.round(left_over[k] * steps)) - reach
        for j in range(tries):
            shifted = first + j + half
            whole[k, j] = shifted // steps  # floor division, as np.divmod
            step[k, j] = shifted - whole[k, j] * steps - half
            used[step[k, j] + half] = True
    index = np.full(steps, -1, dtype=np.int64)
    turns = np.empty(steps, dtype=np.int64)
    count = 0
    for t in range(steps):
        if used[t]:
            index[t], turns[count] = count, t - half
            count += 1
    which = np.empty((n, tries), dtype=np.int64)
    for k in range(n):
        for j in range(tries):
            which[k, j] = index[step[k, j] + half]
    return whole, step, turns[:count], which


@njit(cache=True)
def _key_distances(chunks: Any, n: int, key: FloatArray) -> FloatArray:
    # Squared distances of the first ``n`` views' ring keys to ``key``, without the
    # (n, rings) temporaries of the NumPy expression: this runs at every look of a partial
    # scanner over every view learned (0.14 ms at 3000 views in NumPy, a fifth of it here).
    out = np.empty(n)
    for first in range(0, n, CHUNK_MASK + 1):
        keys = chunks[first >> CHUNK_SHIFT][4]  # a chunk at a time: fetching one costs
        for at in range(min(n - first, CHUNK_MASK + 1)):
            acc = 0.0
            for r in range(key.size):
                diff = keys[at, r] - key[r]
                acc += diff * diff
            out[first + at] = acc
    return out


class View(NamedTuple):
    """Eq. 7: a learned boundary view ``<h, B>``."""

    h: int
    B: FloatArray


class ViewMatch(NamedTuple):
    """The output of one ``ViewCells.observe`` step, for the pose cells.

    Attributes:
        view_id: the active view: the best match, or the view just learned.
        activity: its ``V`` (Eq. 9); 1.0 for a newly learned view.
        is_new: True when no stored view matched and ``B`` was learned as ``view_id``.
        similarity: ``S`` (Eq. 8) of the active view; for a new view, ``inf`` (no candidate
            came below ``s_t``, and such ``S`` are not computed exactly).
        heading_offset: radians, the current heading minus the matched view's, from the
            circular shift that matched (rotation search); 0 for a new view or without it.
    """

    view_id: int
    activity: float
    is_new: bool
    similarity: float
    heading_offset: float = 0.0


@dataclass(frozen=True)
class ViewCellConfig:
    """Tuning of the two-stage matching.

    The defaults go with the default ``BoundaryCellConfig`` (beam-density weighted, distance-
    gained activity, so they hold for any sensor resolution) and were chosen on the simulated
    600 s maze run with ``benchmarks/bench_views.py``, which prints precision and recall.

    Attributes:
        ds: downscaling exponent of Eq. 6; buckets are ``10^ds`` wide in units of ``sum(B)``.
            Default 1 (width 10): on the maze, ``sum(B)`` spans about 290-680 and two scans
            that match differ in ``sum(B)`` by less than 10 in 99.9 % of cases, so ``h +- 1``
            finds virtually every match while comparing a fraction of the views.
        s_t: matching threshold on ``S`` (Eq. 8, 9). Default 0.02: the largest value that kept
            precision above 99 % on the maze (0.05 gives 98 %, 0.1 about 97 %). The price is a
            narrow tolerance: a place is re-recognised only within a few centimetres sideways
            and 1-2 deg of heading (benchmark section 5). The simulated route drives the same
            centre-lines on every pass, so it meets that; for a hand-driven robot 0.3 tolerates
            5 cm and 3 deg, at about 89 % precision on the maze.
        neighbour_buckets: also compare views whose ``h`` differs by up to this much (module
            docstring); 0 is the paper's rule.
        heading_gate: radians; with a heading given to ``observe``, views learned more than
            this far from it are not compared (with the rotation search: shifts more than
            this far from the heading difference it implies are not tried). Default 15 deg,
            the implied shift plus and minus one bin: every shift tried is another chance
            for a look-alike (at 45 deg, 36 % of the maze's view matches were true, 99.5 %
            with shift 0 alone), the odometry's heading is good to a degree or two between
            looks, and the map's own cue proposes the places a drifted heading misses.
        turn_steps, turn_reach: with the rotation search, a heading and ``observe``'s
            ``turned``, the activity is turned in steps of ``1 / turn_steps`` of a bin, and
            each view compared at the step nearest the fraction of a bin its heading
            difference leaves over and at ``turn_reach`` steps either side (module
            docstring). Defaults 4 and 1: a quarter of a bin (2.5°) and a quarter either
            side, for a heading estimate up to 3.75° off.
        turn_screen, turn_candidates: only when no view matched at a whole shift, the scan
            is turned for the ``turn_candidates`` views that came nearest at a whole shift,
            below ``turn_screen`` times the scan's difference from itself shifted by one bin
            (:meth:`ViewCells._nearest_at_whole_shifts`, :func:`_one_bin_difference`).
            Defaults 0.4 and 8. How far a place turned between bins is from its view at a
            whole shift depends on the scene: turned by 5° or 15°, 7-32 ``s_t`` on the maze
            (UTM-30LX, 200 places of a weaving route, 10th percentile to largest), 15-49 on
            a drawn office seen by a 180° SICK, where a fixed 40 ``s_t`` lost 14-22 % of the
            places. Against the scan's own one-bin difference it is steady: turned by 5°,
            15° or 25°, 0.27-0.28 of it at the median and 0.29-0.35 at the 99th percentile on
            six floors and scanners (``benchmarks/README.md``, "Turned views on a 180°
            scanner"). A looser screen turns the scan for more look-alikes: at 0.5, half
            of a thinned SICK 361 run's looks turned, and its ratio of medians to the
            odometry rose by 0.1.
        partial_candidates: with the rotation search, a scan that covers part of each ring is
            compared with this many views, those nearest in mean activity per ring (Eq. 6's
            sum changes as such a scanner turns; module docstring). Default 64.
        min_shared: with the rotation search, the least share of a ring that both views must
            cover for a shift to be compared (default 0.25: 90 deg; a 180 deg scanner turned
            by 90 deg still shares that much).
        bound_block: cells per block for the lower bound on ``S`` (any size is exact; the
            default 36 is one ring of the default layout).
        prematch: False compares every stored view (brute force, for benchmarks).
    """

    ds: float = 1.0
    s_t: float = 0.02
    neighbour_buckets: int = 1
    heading_gate: float = math.radians(15.0)
    min_shared: float = 0.25
    partial_candidates: int = 64
    turn_steps: int = 4
    turn_reach: int = 1
    turn_screen: float = 0.4
    turn_candidates: int = 8
    bound_block: int = 36
    prematch: bool = True

    def __post_init__(self) -> None:
        if self.s_t <= 0:
            raise ValueError(f"s_t must be positive, got {self.s_t}")
        if self.neighbour_buckets < 0:
            raise ValueError(f"neighbour_buckets must be >= 0, got {self.neighbour_buckets}")
        if self.bound_block < 1:
            raise ValueError(f"bound_block must be >= 1, got {self.bound_block}")
        if self.partial_candidates < 1:
            raise ValueError(f"partial_candidates must be >= 1, got {self.partial_candidates}")
        if self.turn_steps < 1 or self.turn_reach < 0 or self.turn_candidates < 1 or not (
            self.turn_screen > 0
        ):
            raise ValueError(
                "turn_steps and turn_candidates must be >= 1, turn_reach >= 0 and turn_screen "
                f"> 0, got {self.turn_steps}, {self.turn_candidates}, {self.turn_reach}, "
                f"{self.turn_screen}"
            )
        if not 0.0 < self.min_shared <= 1.0:
            raise ValueError(f"min_shared must be in (0, 1], got {self.min_shared}")


class ViewCells:
    """The learned boundary views and their activity ``V``.

    ``cells_per_ring``: the boundary cells' angular bins per ring (``B`` is ring after ring,
    as :class:`bioslam.boundary.BoundaryCells` lays it out). Given, views are compared over
    circular shifts (module docstring); None treats ``B`` as a plain vector (the paper).
    ``spill_dir``: keep the views' cells in an unlinked file there, of which the process
    holds only what the last ``DROP_PAGES_EVERY`` looks read (:mod:`bioslam.view_store`);
    None: in memory. The matches are the same either way.
    """

    def __init__(
        self, config: ViewCellConfig | None = None, cells_per_ring: int | None = None,
        spill_dir: str | Path | None = None,
    ) -> None:  # fmt: skip
        self.config = config or ViewCellConfig()
        self._spill_dir = spill_dir
        self._looks = 0
        if cells_per_ring is not None and cells_per_ring < 1:
            raise ValueError(f"cells_per_ring must be >= 1, got {cells_per_ring}")
        self.cells_per_ring = cells_per_ring
        # the views (bioslam.view_store), made at the first (it takes its size)
        self._store: ViewStore | None = None
        self._h: list[int] = []
        self._payloads: list[Any] = []
        self._headings = GrowingArray(np.float64, capacity=64)
        self._buckets: dict[int, list[int]] = {}
        self._bucket_arrays: dict[int, IntArray] = {}
        self._last_ids: IntArray = np.empty(0, dtype=np.int64)
        self._last_v: FloatArray = np.empty(0)

    @property
    def num_views(self) -> int:
        return len(self._h)

    def view(self, view_id: int) -> View:
        """The stored view ``<h, B>`` (Eq. 7)."""
        self._check_id(view_id)
        assert self._store is not None
        return View(self._h[view_id], self._store.row(view_id).astype(np.float64))

    def payload(self, view_id: int) -> Any:
        """Whatever the caller attached when ``view_id`` was learned (None if nothing)."""
        self._check_id(view_id)
        return self._payloads[view_id]

    def activities(self) -> FloatArray:
        """The view-cell vector ``V`` (Eq. 9) of the last step, one entry per view."""
        v = np.zeros(self.num_views)
        v[self._last_ids] = self._last_v
        return v

    def active_views(self) -> tuple[IntArray, FloatArray]:
        """``(ids, V)`` of the views with ``V > 0`` in the last step (sparse ``activities()``)."""
        keep = self._last_v > 0.0
        return self._last_ids[keep].copy(), self._last_v[keep].copy()

    def observe(
        self,
        B: ArrayLike,
        payload: Any = None,
        heading: float | None = None,
        coverage: ArrayLike | None = None,
        turned: Callable[[float], ArrayLike] | None = None,
    ) -> ViewMatch:
        """Match ``B`` against the stored views; learn it (with ``payload``) if none matches.

        ``heading``: the robot's current heading estimate in the map frame, radians (the
        head-direction state), if the caller has one. Stored views learned with a heading
        then match only within ``heading_gate`` of it (module docstring).
        ``coverage``: with the rotation search, which angular bins of a ring the scanner's
        field of view covers (:meth:`bioslam.boundary.BoundaryCells.coverage`); None = all.
        ``turned``: with the rotation search and a heading, the same scan's activity with
        every endpoint's bearing increased by a given angle
        (:meth:`bioslam.boundary.BoundaryCells.activity`'s ``turn``): each stored view is
        then compared with the activity turned by the fraction of a bin its heading
        difference leaves over whole shifts, to a ``1 / turn_steps`` of a bin
        (:meth:`_turned_similarities`).
        """
        b = self._checked(B)
        cover = self._coverage(coverage)
        h = self.coarse_feature(b, cover)
        self._looks += 1
        if self._store is not None and self._looks % DROP_PAGES_EVERY == 0:
            self._store.drop_pages()
        # Eq. 6's sum does not survive a turn of a scanner that sees part of each ring (what
        # leaves the field of view differs): such scans are compared with the views nearest
        # in mean activity per ring instead.
        # a partial scanner's ring key finds its candidates; a whole ring's is needed only
        # when the scan is learned
        key = None if cover.all() else self._ring_key(b, cover)
        ids = self._candidates(h) if key is None else self._nearest_keys(key)
        shifts = np.zeros(ids.size)
        if self.cells_per_ring is None:
            if heading is not None and ids.size:
                ids = self._gate(ids, float(heading))
            S = self._similarities(ids, b)
        else:
            S, shifts = self._shift_similarities(ids, b, cover, heading, turned)
        V = view_cell_activity(S, self.config.s_t)
        chosen = self._choose(S)
        if chosen >= 0:
            self._last_ids, self._last_v = ids, np.asarray(V)
            offset = float(wrap_angle(shifts[chosen] * self._bin_angle()))
            return ViewMatch(int(ids[chosen]), float(V[chosen]), False, float(S[chosen]), offset)
        new_id = self._learn(h, b, payload, heading, cover, key)
        self._last_ids = np.append(ids, new_id)
        self._last_v = np.append(V, 1.0)
        return ViewMatch(new_id, 1.0, True, math.inf)

    def _bin_angle(self) -> float:
        return 2.0 * math.pi / self.cells_per_ring if self.cells_per_ring else 0.0

    def _coverage(self, coverage: ArrayLike | None) -> NDArray[np.bool_]:
        cols = self.cells_per_ring or 1
        if coverage is None:
            return np.ones(cols, dtype=bool)
        # a copy: a caller's read-only array is another type to the compiled kernels, which
        # a first run would then compile again mid-run, after the warm-up
        cover = np.array(coverage, dtype=bool).reshape(-1)
        if cover.size != cols:
            raise ValueError(f"coverage has {cover.size} bins, a ring has {cols}")
        return cover

    def _ring_key(self, b: FloatArray, cover: NDArray[np.bool_]) -> FloatArray:
        """Mean activity of each ring over the covered bins: a summary that changes little as
        a partial scanner turns (unlike the sum, it does not grow with the bins seen)."""
        cols = self.cells_per_ring or b.size
        rings = b.reshape(-1, cols)[:, cover] if cover.size == cols else b.reshape(1, -1)
        return rings.mean(axis=1) if rings.shape[1] else np.zeros(rings.shape[0])

    def _nearest_keys(self, key: FloatArray) -> IntArray:
        """The ``partial_candidates`` views with the nearest ring keys (``key``: the scan's,
        :meth:`_ring_key`; a partial scanner)."""
        n = self.num_views
        if n == 0:
            return np.empty(0, dtype=np.int64)
        k = self.config.partial_candidates
        if n <= k:
            return np.arange(n, dtype=np.int64)
        assert self._store is not None
        d = _key_distances(self._store.chunks, n, key)
        return np.sort(np.argpartition(d, k)[:k]).astype(np.int64)

    def coarse_feature(self, b: FloatArray, cover: NDArray[np.bool_]) -> int:
        """Eq. 6, per covered sector when the scanner sees only part of each ring."""
        share = max(int(cover.sum()), 1) / cover.size
        return coarse_view_feature(b / share, self.config.ds)

    def _shift_similarities(
        self, ids: IntArray, b: FloatArray, cover: NDArray[np.bool_], heading: float | None,
        turned: Callable[[float], ArrayLike] | None = None,
    ) -> tuple[FloatArray, FloatArray]:
        """Eq. 8 over circular shifts (module docstring): best ``S`` and shift (bins, with a
        fraction) per candidate; ``inf`` at or above ``s_t``."""
        cols = int(self.cells_per_ring or 1)
        if ids.size == 0:
            return np.empty(0), np.empty(0)
        if heading is None:
            lo = np.zeros(ids.size, dtype=np.int64)
            hi = np.full(ids.size, cols - 1, dtype=np.int64)
            return self._whole_then_fraction(ids, lo, hi, b[None, :], _first(ids), cover)
        step = self._bin_angle()
        reach = math.floor(self.config.heading_gate / step + 1e-9)
        # wrapped in NumPy, as every other heading difference is, to the bit
        centre = wrap_angle(float(heading) - self._headings.view()[ids]) / step
        lo, hi, left_over = _shift_windows(np.asarray(centre, dtype=np.float64), reach, cols)
        found, shifts = self._whole_then_fraction(ids, lo, hi, b[None, :], _first(ids), cover)
        if turned is None or np.any(found < self.config.s_t):
            # a view matched at a whole shift is the match without turning (and cheaper)
            return found, shifts
        screen = self.config.turn_screen * _one_bin_difference(b, cover, cols)
        near = self._nearest_at_whole_shifts(ids, lo, hi, b, cover, screen)
        return self._turned_similarities(ids, near, lo, hi, left_over, b, cover, turned)

    def _nearest_at_whole_shifts(
        self, ids: IntArray, lo: IntArray, hi: IntArray, b: FloatArray,
        cover: NDArray[np.bool_], screen: float,
    ) -> IntArray:
        """Indices into ``ids`` of the ``turn_candidates`` views nearest the scan at a whole
        shift, below ``screen``: those worth turning the scan for. Of a
        scan that covers the whole ring only the ``4 * turn_candidates`` with the lowest
        ring-sum bound are compared that far (a partial scanner's candidates are
        ``partial_candidates`` at most): with 10,000 views stored, 760 candidates a look,
        comparing every one up to the screen cost 1.5 ms a look, a third of that so
        (``benchmarks/bench_views.py`` section 3)."""
        assert self._store is not None
        cols = int(self.cells_per_ring or 1)
        keep = 4 * self.config.turn_candidates
        chosen = np.arange(ids.size)
        if ids.size > keep and cover.all():
            bound = _ring_sum_bounds(self._store.chunks, ids, block_sums(b, cols), cols)
            chosen = np.argsort(bound, kind="stable")[:keep]
        coarse, _ = self._whole_shifts(
            ids[chosen], lo[chosen], hi[chosen], b[None, :], _first(chosen), cover, screen,
        )  # fmt: skip
        order = np.argsort(coarse, kind="stable")[: self.config.turn_candidates]
        return chosen[order[np.isfinite(coarse[order])]]

    def _turned_similarities(
        self, ids: IntArray, near: IntArray, lo: IntArray, hi: IntArray, left_over: FloatArray,
        b: FloatArray, cover: NDArray[np.bool_], turned: Callable[[float], ArrayLike],
    ) -> tuple[FloatArray, FloatArray]:
        """:meth:`_whole_then_fraction` for the views ``ids[near]``, each compared against the
        activity turned by the fraction of a bin (``left_over``, in bins) its heading
        difference leaves over whole shifts, rounded to ``1 / turn_steps`` of a bin, and by
        ``turn_reach`` steps either side; the others ``inf``. A turn of a whole bin or more
        is a turn of less with the shifts moved: at most ``turn_steps - 1`` turned
        activities a look, each computed once, all compared in one pass."""
        steps, reach = self.config.turn_steps, self.config.turn_reach
        S = np.full(ids.size, np.inf)
        shifts = np.zeros(ids.size)
        if not near.size:
            return S, shifts
        whole, step, turns, which = _turn_plan(left_over[near], steps, reach)
        stack = np.stack([
            b if t == 0 else self._checked(turned(t / steps * self._bin_angle())) for t in turns
        ])  # fmt: skip
        each = np.repeat(near, step.shape[1])
        found, offset = self._whole_then_fraction(
            ids[each], lo[each] + whole.ravel(), hi[each] + whole.ravel(), stack,
            which.ravel(), cover,
        )  # fmt: skip
        found = found.reshape(step.shape)
        offset = offset.reshape(step.shape) + step / steps
        best = np.argmin(found, axis=1)
        rows = np.arange(near.size)
        S[near] = found[rows, best]
        shifts[near] = offset[rows, best]
        return S, shifts

    def _whole_then_fraction(
        self, ids: IntArray, lo: IntArray, hi: IntArray, stack: FloatArray, which: IntArray,
        cover: NDArray[np.bool_],
    ) -> tuple[FloatArray, FloatArray]:
        """Best ``S`` and shift per candidate over the whole-bin shifts ``lo`` to ``hi`` of the
        activity ``stack[which]`` (the scan's, or turned), with a loose limit that prunes most
        views early, the few left refined to the best fractional shift."""
        coarse, shift = self._whole_shifts(
            ids, lo, hi, stack, which, cover, _COARSE_SLACK * self.config.s_t
        )
        assert self._store is not None
        return _refine_shifts(
            self._store.chunks, ids, coarse, shift, stack, which, cover,
            int(self.cells_per_ring or 1), self.config.s_t,
        )  # fmt: skip

    def _whole_shifts(
        self, ids: IntArray, lo: IntArray, hi: IntArray, stack: FloatArray, which: IntArray,
        cover: NDArray[np.bool_], limit: float,
    ) -> tuple[FloatArray, IntArray]:
        """Eq. 8 per candidate at its best whole-bin shift from ``lo`` to ``hi`` of the activity
        ``stack[which]`` and that shift; ``inf`` at or above ``limit``."""
        cols = int(self.cells_per_ring or 1)
        assert self._store is not None
        return _shift_similarities(
            self._store.chunks, ids, lo, hi, stack, which, cover, block_sums(stack, cols),
            cols, limit, max(1, math.ceil(self.config.min_shared * cols - 1e-9)),
        )  # fmt: skip

    def _similarities(self, ids: IntArray, b: FloatArray) -> FloatArray:
        if ids.size == 0:
            return np.empty(0)
        block = self.config.bound_block
        assert self._store is not None
        return _similarities(
            self._store.chunks, ids, b, block_sums(b, block), block, self.config.s_t
        )

    def _choose(self, sims: FloatArray) -> int:
        """Index of the best candidate below ``s_t``, or -1 to learn a new view."""
        if sims.size == 0:
            return -1
        best = int(np.argmin(sims))
        return best if sims[best] < self.config.s_t else -1

    def learn(
        self,
        B: ArrayLike,
        payload: Any = None,
        heading: float | None = None,
        coverage: ArrayLike | None = None,
    ) -> int:
        """Store ``B`` as a new view without matching it (e.g. to seed a map); its id."""
        b = self._checked(B)
        cover = self._coverage(coverage)
        return self._learn(self.coarse_feature(b, cover), b, payload, heading, cover)

    def _checked(self, B: ArrayLike) -> FloatArray:
        """``B`` as the views are stored (:data:`VIEW_DTYPE`), in float64 for the sums: a
        scan then matches its own view exactly (S = 0)."""
        b = np.asarray(B).astype(VIEW_DTYPE).astype(np.float64)
        if b.ndim != 1 or b.size == 0:
            raise ValueError(f"boundary activity must be a non-empty 1-D array, got {b.shape}")
        if self.cells_per_ring is not None and b.size % self.cells_per_ring:
            raise ValueError(
                f"boundary activity has {b.size} cells, not whole rings of {self.cells_per_ring}"
            )
        if self._store is not None and b.size != self._store.cells:
            raise ValueError(
                f"boundary activity has {b.size} cells, views have {self._store.cells}"
            )
        return b

    def _candidates(self, h: int) -> IntArray:
        if not self.config.prematch:
            return np.arange(self.num_views, dtype=np.int64)
        k = self.config.neighbour_buckets
        parts = [self._bucket(key) for key in range(h - k, h + k + 1)]
        parts = [p for p in parts if p.size]
        if not parts:
            return np.empty(0, dtype=np.int64)
        return parts[0] if len(parts) == 1 else np.concatenate(parts)

    def _bucket(self, h: int) -> IntArray:
        arr = self._bucket_arrays.get(h)
        if arr is None:
            arr = np.asarray(self._buckets.get(h, ()), dtype=np.int64)
            self._bucket_arrays[h] = arr
        return arr

    def _gate(self, ids: IntArray, heading: float) -> IntArray:
        """Drop views learned facing more than ``heading_gate`` away (NaN: no heading, kept)."""
        diff = np.abs(wrap_angle(self._headings.view()[ids] - heading))
        return ids[~(diff > self.config.heading_gate)]

    def _learn(
        self, h: int, b: FloatArray, payload: Any, heading: float | None,
        cover: NDArray[np.bool_], key: FloatArray | None = None,
    ) -> int:  # fmt: skip
        # Stored as float32 (``_checked`` rounded ``b`` to it; a cell moves by a relative
        # 6e-8, far below any S that matters), without its zeros (bioslam.view_store). Per
        # ring with the rotation search: ring sums do not change with a shift.
        sums = block_sums(b, self.cells_per_ring or self.config.bound_block)
        key = self._ring_key(b, cover) if key is None else key
        if self._store is None:
            self._store = ViewStore(b.size, sums.size, cover.size, key.size, self._spill_dir)
        new_id = self._store.append(b.astype(VIEW_DTYPE), sums, cover, key)
        self._headings.append(math.nan if heading is None else float(heading))
        self._h.append(h)
        self._payloads.append(payload)
        self._buckets.setdefault(h, []).append(new_id)
        self._bucket_arrays.pop(h, None)
        return new_id

    def _check_id(self, view_id: int) -> None:
        if not 0 <= view_id < self.num_views:
            raise IndexError(f"view id {view_id} out of range (have {self.num_views} views)")
