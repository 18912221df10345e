"""Boundary views and view cells: two-stage boundary-view matching (paper Sec. III-B, Eq. 6-9).

A view ``v = <h, B>`` (Eq. 7) pairs the boundary-cell activity ``B`` with its coarse feature
``h`` (Eq. 6), used as a hash key. Matching a new ``B``:

1. pre-match: only stored views whose ``h`` is within ``neighbour_buckets`` of the current
   ``h`` are compared;
2. for those, the mean squared difference ``S`` (Eq. 8) gives the view-cell activity
   ``V_i = 1 - min(s_t, S)/s_t`` (Eq. 9). The candidate with the smallest ``S`` is the active
   view if ``S < s_t``; otherwise ``B`` is learned as a new view (``V`` is extended).

Deviation from the paper: the paper compares only views with *equal* ``h``. ``h`` is the floor
of a continuous sum, so two near-identical views whose sums straddle a bucket boundary land in
neighbouring buckets and the match is lost, however small their difference. Looking also in
``h - 1`` and ``h + 1`` (``neighbour_buckets=1``, the default) recovers every pair whose sums
differ by less than one bucket width ``10^ds``, at three times the pre-match cost. Set
``neighbour_buckets=0`` for the paper's rule. ``benchmarks/bench_views.py`` measures the loss.

Views not compared in a step (other buckets) have ``S >= s_t`` by construction of the
pre-match and so ``V = 0``; only the compared candidates are stored, which keeps a step's cost
independent of the number of views outside the pre-matched buckets.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
from numba import njit
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


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
    v = 1.0 - np.minimum(s_t, np.asarray(S, dtype=np.float64)) / s_t
    return float(v) if v.ndim == 0 else v


@njit(cache=True)
def _similarities(store: FloatArray, idx: IntArray, B: FloatArray) -> FloatArray:
    # Eq. 8 for many stored views, reading rows in place instead of gathering a copy.
    m = B.size
    out = np.empty(idx.size)
    for n in range(idx.size):
        row = store[idx[n]]
        acc = 0.0
        for i in range(m):
            diff = row[i] - B[i]
            acc += diff * diff
        out[n] = acc / m
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
        similarity: ``S`` (Eq. 8) of the best compared candidate; ``inf`` when the pre-match
            left no candidate.
    """

    view_id: int
    activity: float
    is_new: bool
    similarity: float


@dataclass(frozen=True)
class ViewCellConfig:
    """Tuning of the two-stage matching.

    The defaults go with the default ``BoundaryCellConfig`` (beam-density weighted activity, so
    they hold for any sensor resolution) and were chosen on the simulated maze with
    ``benchmarks/bench_views.py``; see its output for the measured precision and recall.

    Attributes:
        ds: downscaling exponent of Eq. 6; bucket width ``10^ds`` in units of ``sum(B)``.
        s_t: matching threshold on ``S`` (Eq. 8, 9).
        neighbour_buckets: also compare views whose ``h`` differs by up to this much (module
            docstring); 0 is the paper's rule.
        prematch: False compares every stored view (brute force, for benchmarks).
    """

    ds: float = 1.0
    s_t: float = 0.5
    neighbour_buckets: int = 1
    prematch: bool = True

    def __post_init__(self) -> None:
        if self.s_t <= 0:
            raise ValueError(f"s_t must be positive, got {self.s_t}")
        if self.neighbour_buckets < 0:
            raise ValueError(f"neighbour_buckets must be >= 0, got {self.neighbour_buckets}")


class ViewCells:
    """The learned boundary views and their activity ``V``."""

    def __init__(self, config: ViewCellConfig | None = None) -> None:
        self.config = config or ViewCellConfig()
        self._store = np.empty((0, 0))
        self._h: list[int] = []
        self._payloads: list[Any] = []
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
        return View(self._h[view_id], self._store[view_id].copy())

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

    def observe(self, B: ArrayLike, payload: Any = None) -> ViewMatch:
        """Match ``B`` against the stored views; learn it (with ``payload``) if none matches."""
        b = np.ascontiguousarray(B, dtype=np.float64)
        if b.ndim != 1 or b.size == 0:
            raise ValueError(f"boundary activity must be a non-empty 1-D array, got {b.shape}")
        if self.num_views and b.size != self._store.shape[1]:
            raise ValueError(f"boundary activity has {b.size} cells, views have "
                             f"{self._store.shape[1]}")
        h = coarse_view_feature(b, self.config.ds)
        ids = self._candidates(h)
        S = _similarities(self._store, ids, b) if ids.size else np.empty(0)
        V = view_cell_activity(S, self.config.s_t)
        best = int(np.argmin(S)) if S.size else -1
        best_s = float(S[best]) if best >= 0 else math.inf
        if best >= 0 and best_s < self.config.s_t:
            self._last_ids, self._last_v = ids, np.asarray(V)
            return ViewMatch(int(ids[best]), float(V[best]), False, best_s)
        new_id = self._learn(h, b, payload)
        self._last_ids = np.append(ids, new_id)
        self._last_v = np.append(V, 1.0)
        return ViewMatch(new_id, 1.0, True, best_s)

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

    def _learn(self, h: int, b: FloatArray, payload: Any) -> int:
        new_id = self.num_views
        if new_id == 0:
            self._store = np.empty((16, b.size))
        elif new_id == self._store.shape[0]:
            # Doubling keeps appends amortised O(1) as thousands of views accumulate.
            grown = np.empty((2 * new_id, b.size))
            grown[:new_id] = self._store[:new_id]
            self._store = grown
        self._store[new_id] = b
        self._h.append(h)
        self._payloads.append(payload)
        self._buckets.setdefault(h, []).append(new_id)
        self._bucket_arrays.pop(h, None)
        return new_id

    def _check_id(self, view_id: int) -> None:
        if not 0 <= view_id < self.num_views:
            raise IndexError(f"view id {view_id} out of range (have {self.num_views} views)")
