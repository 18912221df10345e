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
    store = ViewStore(RINGS * COLS, RINGS, COLS, RINGS)
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
    store = ViewStore(RINGS * COLS, RINGS, COLS, RINGS)
    for row in _sparse_views(n, 0.3, seed=2):
        store.append(row, np.zeros(RINGS), np.ones(COLS, dtype=bool), np.zeros(RINGS))
    per_view = store.resident_bytes / n
    assert per_view < 0.3 * 4032 + 800  # values, bits, ring starts, sums, keys, coverage
    assert per_view < 0.5 * 4032


def test_growth_adds_a_chunk_and_copies_nothing() -> None:
    """Past a full chunk, the next view costs one new chunk: nothing already stored is
    copied (a doubling array would briefly hold the old and the new copy)."""
    store = ViewStore(RINGS * COLS, RINGS, COLS, RINGS)
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


def _mapped_rss(directory) -> int | None:
    """Resident bytes of this process's mappings of files in ``directory`` (None without
    ``/proc``)."""
    try:
        with open("/proc/self/smaps") as fh:
            lines = fh.read().splitlines()
    except OSError:
        return None
    total, inside = 0, False
    for line in lines:
        head = line.split()
        if head and "-" in head[0] and len(head) >= 5 and not line.startswith(("Rss", "Size")):
            inside = len(head) >= 6 and head[5].startswith(str(directory))
        elif inside and line.startswith("Rss:"):
            total += int(head[1]) * 1024
    return total


def test_views_in_a_file_come_back_bit_for_bit_and_leave_memory_when_dropped(tmp_path) -> None:
    """The zero bits and values in a mapped file (spill_dir): what the process holds for a
    view is its value start, sums, coverage and key, a third of the in-memory store at the
    warehouse's 30 % nonzero cells; the pages written or read leave the process when
    dropped, and the views are still there, bit for bit."""
    n = 2 * CHUNK_VIEWS + 5
    rows = _sparse_views(n, 0.3, seed=7)
    extra = (np.zeros(RINGS), np.ones(COLS, dtype=bool), np.zeros(RINGS))
    in_memory = ViewStore(RINGS * COLS, RINGS, COLS, RINGS)
    in_file = ViewStore(RINGS * COLS, RINGS, COLS, RINGS, spill_dir=tmp_path)
    for row in rows:
        in_memory.append(row, *extra)
        in_file.append(row, *extra)
    assert in_file.in_file == n and in_file.file_value_count == in_file.value_count
    assert in_file.resident_bytes < 0.35 * in_memory.resident_bytes
    # three chunks of value starts, sums, coverage and keys
    assert in_file.resident_bytes == 3 * CHUNK_VIEWS * (4 + 2 * RINGS * 8 + COLS)
    written = _mapped_rss(tmp_path)
    in_file.drop_pages()
    dropped = _mapped_rss(tmp_path)
    for k in (0, CHUNK_VIEWS - 1, CHUNK_VIEWS, n - 1):
        assert np.array_equal(in_file.row(k), rows[k])
    if written is not None:
        assert written >= 0.9 * in_file.value_count * 4  # the values were resident ...
        assert dropped == 0  # ... and are no longer
        assert 0 < _mapped_rss(tmp_path) <= 4 * 2 * 64 * 1024  # the four read back (and neighbours)


def test_a_full_disk_keeps_the_next_chunks_in_memory(tmp_path, monkeypatch) -> None:
    """The file refuses its second chunk (no space): that chunk and the later ones are held
    in memory, nothing is lost and the kernels read both kinds."""
    import os

    reserve = os.posix_fallocate
    calls = []

    def refusing(fd: int, offset: int, size: int) -> None:
        calls.append(offset)
        if len(calls) > 1:
            raise OSError(28, "No space left on device")
        reserve(fd, offset, size)

    monkeypatch.setattr(os, "posix_fallocate", refusing)
    rows = _sparse_views(3 * CHUNK_VIEWS, 0.3, seed=8)
    vc = ViewCells(ViewCellConfig(partial_candidates=4000), cells_per_ring=COLS, spill_dir=tmp_path)
    for row in rows:
        vc.learn(row)
    store = vc._store
    assert store is not None and store.in_file == CHUNK_VIEWS and len(calls) == 2
    for k in (1, CHUNK_VIEWS + 1, 3 * CHUNK_VIEWS - 1):
        assert np.array_equal(store.row(k), rows[k])
        m = vc.observe(rows[k])
        assert (m.view_id, m.is_new, m.similarity) == (k, False, 0.0)


@pytest.mark.parametrize("heading", [None, 0.3])
def test_views_in_a_file_match_as_in_memory(tmp_path, heading: float | None) -> None:
    """The same looks against views in memory and in a file, its pages dropped every few
    looks: every match, S and heading offset the same, and a scan matches its own view."""
    import bioslam.views as views

    rows = _sparse_views(CHUNK_VIEWS + 300, 0.3, seed=9)
    cover = np.ones(COLS, dtype=bool)
    cover[:9] = False
    made = [
        ViewCells(ViewCellConfig(), cells_per_ring=COLS, spill_dir=d) for d in (None, tmp_path)
    ]
    for vc in made:
        for row in rows[: CHUNK_VIEWS + 200]:
            vc.learn(row, heading=0.3, coverage=cover)
    rng = np.random.default_rng(10)
    picks = rng.integers(0, rows.shape[0], 3 * views.DROP_PAGES_EVERY)
    for k in picks:
        query = rows[k] + rng.normal(0.0, 0.05, rows.shape[1]) * (rows[k] > 0)
        got = [vc.observe(query, heading=heading, coverage=cover) for vc in made]
        assert got[0] == got[1]
    own = [vc.observe(rows[7], heading=0.3, coverage=cover) for vc in made]
    assert own[0] == own[1] and (own[1].view_id, own[1].similarity) == (7, 0.0)
