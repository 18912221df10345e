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


def test_keyframe_scans_keep_points_to_a_millimetre_and_the_reach_exactly() -> None:
    rng = np.random.default_rng(1)
    scans = [rng.uniform(-40, 40, size=(n, 2)).astype(np.float32) for n in (5, 0, 70000, 3)]
    store = KeyframeScans(max_range=30.0)
    for k, pts in enumerate(scans):
        store.add(10 * k, pts)
    assert store.index.view().tolist() == [0, 10, 20, 30]
    assert store.nbytes < 70008 * 5  # 4 bytes a point and little else
    for k, pts in enumerate(scans):
        assert store.reach[k] == np.max(np.abs(pts), initial=0.0)
        within = pts[np.hypot(pts[:, 0], pts[:, 1]) <= 30.0]
        back = store.points(k)
        assert back.shape == within.shape
        # half a millimetre, plus float32 resolution at 30 m (4 µm) in the division
        np.testing.assert_allclose(back, within, atol=0.0005 + 4e-6, rtol=0)


def test_keyframe_scans_of_a_long_range_sensor_keep_their_far_points() -> None:
    store = KeyframeScans(max_range=80.0)
    store.add(0, np.array([[79.0, -1.0], [0.5, 0.25]], dtype=np.float32))
    np.testing.assert_allclose(store.points(0), [[79.0, -1.0], [0.5, 0.25]], atol=0.0013)
    unbounded = KeyframeScans(max_range=np.inf)
    unbounded.add(0, np.array([[1e3, 0.125]], dtype=np.float32))
    np.testing.assert_array_equal(unbounded.points(0), [[1e3, 0.125]])


def test_keyframe_scans_past_their_budget_double_the_spacing_and_keep_every_other_place():
    """A long run's kept scans stay within the budget: the spacing doubles and the scans
    already kept are thinned to it, each survivor's points untouched."""
    rng = np.random.default_rng(2)
    clouds = [rng.uniform(-5, 5, size=(200, 2)).astype(np.float32) for _ in range(60)]
    store = KeyframeScans(max_range=30.0, distance=0.125, angle=0.25, max_bytes=20000)
    offered = 0
    for k, cloud in enumerate(clouds):
        pose = np.array([0.125 * k, 0.0, 0.0])  # a straight drive, a scan every 12.5 cm
        if store.wants(pose):
            store.add(k, cloud, pose)
            offered += 1
    assert store.distance == 0.5 and offered < len(clouds)  # thinned twice
    kept = store.index.view()
    assert kept[0] == 0 and len(store) * 200 * 4 <= 20000
    assert np.all(np.diff(store.poses.view()[:, 0]) >= store.distance - 1e-9)
    for k, scan in enumerate(kept):
        np.testing.assert_allclose(store.points(k), clouds[scan], atol=0.0005 + 4e-6, rtol=0)


def test_keyframe_scans_thin_turns_by_the_doubled_angle():
    store = KeyframeScans(distance=0.125, angle=0.0625, max_bytes=10**9)
    for k in range(10):  # turning on the spot, the whole angle a scan
        store.add(k, np.ones((1, 2), dtype=np.float32), (0.0, 0.0, 0.0625 * k))
    store.thin()
    assert store.index.view().tolist() == [0, 2, 4, 6, 8]
    assert not store.wants(np.array([0.125, 0.0, 0.5 + 0.0625]))
    assert store.wants(np.array([0.0, 0.0, 0.5 + 0.125]))
