"""The growing arrays behind per-scan bookkeeping and the output map's kept scans."""

import numpy as np

from bioslam.growing import GrowingArray
from bioslam.pipeline import KeyframeScans


def test_rows_survive_growth_in_order() -> None:
    rows = GrowingArray(np.float64, 3, capacity=2)
    expected = np.random.default_rng(0).normal(size=(37, 3))
    for row in expected[:20]:
        rows.append(row)
    rows.extend(expected[20:])
    assert len(rows) == 37
    np.testing.assert_array_equal(rows.view(), expected)
    np.testing.assert_array_equal(np.asarray(rows), expected)
    assert rows.nbytes == 64 * 3 * 8  # doubled from 2, no more


def test_copy_outlives_later_appends_and_scalars_keep_dtype() -> None:
    ids = GrowingArray(np.int64, capacity=1)
    ids.append(-1)
    ids.append(5)
    kept = ids.array()
    ids.extend(np.arange(10))
    ids.append(7)
    assert kept.tolist() == [-1, 5]
    assert ids.view().dtype == np.int64 and ids[-1] == 7 and len(ids) == 13


def test_keyframe_scans_give_back_each_scan_exactly() -> None:
    rng = np.random.default_rng(1)
    assert KeyframeScans().points() == []
    scans = [rng.uniform(-30, 30, size=(n, 2)) for n in (5, 0, 70000, 3)]
    store = KeyframeScans()
    for k, pts in enumerate(scans):
        store.add(10 * k, pts)
    assert store.index.view().tolist() == [0, 10, 20, 30]
    back = store.points()
    assert [len(p) for p in back] == [5, 0, 70000, 3]
    for got, want in zip(back, scans, strict=True):
        np.testing.assert_array_equal(got, want.astype(np.float32))
