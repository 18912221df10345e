"""The view cells' compact store: exact templates, bounded memory, growth without copies."""

import math
import tracemalloc

import numpy as np
import pytest

from bioslam.view_store import CHUNK_VIEWS, VIEW_DTYPE, ViewStore
from bioslam.views import ViewCellConfig, ViewCells, view_similarity

RINGS, COLS = 28, 36


def _sparse_views(n: int, share: float, seed: int) -> np.ndarray:
    """``n`` views of the default layout with ``share`` of the cells nonzero, in runs along
    each ring as walls light them (values up to 17, as the distance gain gives)."""
    rng = np.random.default_rng(seed)
    views = np.zeros((n, RINGS, COLS), dtype=VIEW_DTYPE)
    for view in views:
        for ring in view:
            width = rng.binomial(COLS, share)
            start = rng.integers(COLS)
            cells = (start + np.arange(width)) % COLS
            ring[cells] = rng.uniform(0.01, 17.0, width)
    return views.reshape(n, -1)


def test_views_come_back_bit_for_bit_across_chunks() -> None:
    rows = _sparse_views(CHUNK_VIEWS + 40, 0.3, seed=1)
    rows[3] = 0.0  # nothing seen
    rows[CHUNK_VIEWS] = 1e-30  # every cell nonzero, the first of the second chunk
    store = ViewStore(RINGS * COLS, COLS, RINGS, COLS, RINGS)
    for row in rows:
        store.append(row, np.zeros(RINGS), np.ones(COLS, dtype=bool), np.zeros(RINGS))
    assert len(store) == rows.shape[0]
    for k in (0, 3, 17, CHUNK_VIEWS - 1, CHUNK_VIEWS, rows.shape[0] - 1):
        assert np.array_equal(store.row(k), rows[k])
    with pytest.raises(IndexError):
        store.row(rows.shape[0])


def test_memory_per_view_is_its_nonzero_cells_and_a_bit_for_each_zero() -> None:
    """30 % of the cells nonzero (the warehouse's median): the dense float32 store took
    4032 bytes a view (and up to twice that while its doubling array grew)."""
    n = 2 * CHUNK_VIEWS
    store = ViewStore(RINGS * COLS, COLS, RINGS, COLS, RINGS)
    for row in _sparse_views(n, 0.3, seed=2):
        store.append(row, np.zeros(RINGS), np.ones(COLS, dtype=bool), np.zeros(RINGS))
    per_view = store.resident_bytes / n
    assert per_view < 0.3 * 4032 + 800  # values, bits, ring starts, sums, keys, coverage
    assert per_view < 0.5 * 4032


def test_growth_adds_a_chunk_and_copies_nothing() -> None:
    """Past a full chunk, the next view costs one new chunk: nothing already stored is
    copied (a doubling array would briefly hold the old and the new copy)."""
    store = ViewStore(RINGS * COLS, COLS, RINGS, COLS, RINGS)
    rows = _sparse_views(CHUNK_VIEWS + 1, 0.3, seed=3)
    extra = (np.zeros(RINGS), np.ones(COLS, dtype=bool), np.zeros(RINGS))
    for row in rows[:CHUNK_VIEWS]:
        store.append(row, *extra)
    tracemalloc.start()
    try:
        before = tracemalloc.get_traced_memory()[0]
        store.append(rows[-1], *extra)
        peak = tracemalloc.get_traced_memory()[1] - before
    finally:
        tracemalloc.stop()
    chunk = CHUNK_VIEWS * (RINGS * COLS * 4 + (RINGS * COLS + 7) // 8 + RINGS * 4
                           + 2 * RINGS * 8 + COLS)  # fmt: skip
    assert peak < chunk * 1.05
    assert np.array_equal(store.row(CHUNK_VIEWS), rows[-1])


@pytest.mark.parametrize("heading", [None, 0.3])
def test_matches_in_every_chunk_are_the_exact_ones(heading: float | None) -> None:
    """Rotation search over views in three chunks, a 270 deg scanner's coverage: the match
    and its S are those of Eq. 8 computed densely on the stored float32 values."""
    rows = _sparse_views(2 * CHUNK_VIEWS + 100, 0.3, seed=4)
    cover = np.ones(COLS, dtype=bool)
    cover[:9] = False  # a 270 deg field of view
    vc = ViewCells(ViewCellConfig(partial_candidates=4000), cells_per_ring=COLS)
    for row in rows:
        vc.learn(row, heading=0.3, coverage=cover)
    rng = np.random.default_rng(5)
    for target in (5, CHUNK_VIEWS + 7, 2 * CHUNK_VIEWS + 99):
        query = rows[target] + rng.normal(0.0, 0.02, rows.shape[1]) * (rows[target] > 0)
        m = vc.observe(query, heading=heading, coverage=cover)
        assert (m.view_id, m.is_new) == (target, False)
        q = query.astype(VIEW_DTYPE).reshape(RINGS, COLS)[:, cover]
        exact = view_similarity(q, rows[target].reshape(RINGS, COLS)[:, cover])
        assert m.heading_offset == 0.0 or math.isclose(m.heading_offset, 0.0, abs_tol=0.2)
        assert m.similarity <= exact + 1e-12  # the fractional shift may only improve it
        assert m.similarity == pytest.approx(exact, rel=0.05)


def test_plain_vectors_match_exactly_across_chunks() -> None:
    """Without the ring layout (the paper's matching), views beyond the first chunk."""
    rng = np.random.default_rng(6)
    rows = np.where(rng.random((CHUNK_VIEWS + 50, 60)) < 0.3, rng.random((CHUNK_VIEWS + 50, 60)), 0)
    vc = ViewCells(ViewCellConfig(prematch=False, s_t=0.05, bound_block=8))
    for row in rows:
        vc.learn(row)
    query = rows[CHUNK_VIEWS + 20] + rng.normal(0.0, 0.02, 60)
    m = vc.observe(query)
    stored = rows.astype(VIEW_DTYPE).astype(np.float64)
    exact = np.array([view_similarity(r, query.astype(VIEW_DTYPE)) for r in stored])
    assert m.view_id == int(np.argmin(exact)) == CHUNK_VIEWS + 20
    assert m.similarity == pytest.approx(exact.min(), rel=1e-12)
    assert np.array_equal(vc.view(CHUNK_VIEWS + 20).B, stored[CHUNK_VIEWS + 20])
