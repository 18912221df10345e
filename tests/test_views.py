import math

import numpy as np
import pytest
from _views_world import box, cast

from bioslam.boundary import BoundaryCells
from bioslam.scan import LaserScan
from bioslam.views import (
    ViewCellConfig,
    ViewCells,
    ViewMatch,
    coarse_view_feature,
    view_cell_activity,
    view_similarity,
)

# Two corridors of different shape joined by a hall, with a side room off the first.
WORLD = [
    *box(0.0, 0.0, 20.0, 12.0),
    (0.0, 2.0, 4.0, 2.0),  # corridor A: y in [0, 2], open to the hall at x > 14
    (8.0, 2.0, 14.0, 2.0),
    (4.0, 2.0, 4.0, 5.0),  # side room above corridor A
    (8.0, 2.0, 8.0, 5.0),
    (4.0, 5.0, 6.0, 5.0),
    (0.0, 9.0, 11.0, 9.0),  # corridor B: y in [9, 12]
    (11.0, 9.0, 11.0, 7.0),
    (16.0, 5.0, 18.0, 7.0),
]
POSE_A = (2.0, 1.0, 0.0)
POSE_B = (2.0, 10.5, 0.0)


@pytest.fixture(scope="module")
def bc() -> BoundaryCells:
    return BoundaryCells()


def _b(bc: BoundaryCells, pose: tuple[float, float, float]) -> np.ndarray:
    return bc.activity(cast(WORLD, pose))


def test_eq6_coarse_feature_hand_computed():
    b = np.array([100.0, 20.0, 3.4])
    assert coarse_view_feature(b, 1.0) == 12
    assert coarse_view_feature(b, 0.0) == 123
    assert coarse_view_feature(b, -1.0) == 1234
    assert coarse_view_feature(b, 0.5) == math.floor(123.4 / math.sqrt(10.0))


def test_eq8_similarity_hand_computed():
    assert view_similarity([1.0, 2.0, 3.0], [1.0, 0.0, 3.0]) == pytest.approx(4.0 / 3.0)
    assert view_similarity([0.5, 0.5], [0.5, 0.5]) == 0.0
    with pytest.raises(ValueError, match="differ in size"):
        view_similarity([1.0], [1.0, 2.0])


def test_eq9_activity_hand_computed():
    assert view_cell_activity(0.0, 0.2) == 1.0
    assert view_cell_activity(0.05, 0.2) == pytest.approx(0.75)
    assert np.allclose(view_cell_activity([0.1, 0.2, 5.0], 0.2), [0.5, 0.0, 0.0])


def test_same_scan_matches_itself(bc):
    vc = ViewCells()
    b = _b(bc, POSE_A)
    first = vc.observe(b)
    assert first.is_new and first.view_id == 0 and first.activity == 1.0
    assert first.similarity == math.inf
    again = vc.observe(b.copy())
    assert again == ViewMatch(0, 1.0, False, 0.0)
    assert vc.num_views == 1


def test_scan_a_few_centimetres_away_matches(bc):
    vc = ViewCells()
    vc.observe(_b(bc, POSE_A))
    for dx, dy, dth in [(0.03, 0.0, 0.0), (0.0, 0.01, 0.0), (0.02, -0.01, math.radians(0.5))]:
        m = vc.observe(_b(bc, (POSE_A[0] + dx, POSE_A[1] + dy, POSE_A[2] + dth)))
        assert not m.is_new and m.view_id == 0
        assert 0.0 < m.activity < 1.0
        assert m.activity == pytest.approx(view_cell_activity(m.similarity, vc.config.s_t))


def test_scan_from_a_different_corridor_does_not_match(bc):
    vc = ViewCells()
    vc.observe(_b(bc, POSE_A))
    m = vc.observe(_b(bc, POSE_B))
    assert m.is_new and m.view_id == 1
    assert vc.activities()[0] == 0.0


def test_scan_far_along_the_same_corridor_does_not_match(bc):
    vc = ViewCells()
    vc.observe(_b(bc, POSE_A))
    assert vc.observe(_b(bc, (POSE_A[0] + 1.0, POSE_A[1], POSE_A[2]))).is_new


def test_turned_around_does_not_match(bc):
    vc = ViewCells()
    vc.observe(_b(bc, (7.0, 1.0, 0.0)))
    assert vc.observe(_b(bc, (7.0, 1.0, math.pi))).is_new


def test_neighbouring_bucket_recovers_a_split_match():
    # Sums 9.99 and 10.01 fall in buckets 9 and 10 with ds = 0 though S is tiny.
    b1 = np.full(10, 0.999)
    b2 = np.full(10, 1.001)
    paper = ViewCells(ViewCellConfig(ds=0.0, s_t=0.01, neighbour_buckets=0))
    fixed = ViewCells(ViewCellConfig(ds=0.0, s_t=0.01, neighbour_buckets=1))
    for vc in (paper, fixed):
        vc.observe(b1)
    assert paper.observe(b2).is_new
    m = fixed.observe(b2)
    assert not m.is_new and m.view_id == 0
    # the views hold float32 activities (VIEW_DTYPE): S is that of the rounded cells
    assert m.similarity == pytest.approx(float(np.float32(1.001) - np.float32(0.999)) ** 2)


def test_prematch_gives_the_brute_force_answer(bc):
    rng = np.random.default_rng(3)
    poses = [(rng.uniform(1, 19), rng.uniform(0.5, 1.5), rng.uniform(-0.3, 0.3)) for _ in range(30)]
    fast, brute = ViewCells(), ViewCells(ViewCellConfig(prematch=False))
    for p in poses:
        b = _b(bc, p)
        mf, mb = fast.observe(b), brute.observe(b)
        assert (mf.view_id, mf.is_new) == (mb.view_id, mb.is_new)
        assert mf.activity == pytest.approx(mb.activity)
    assert fast.num_views == brute.num_views
    assert np.allclose(fast.activities(), brute.activities())


def test_activity_vector_and_payloads():
    vc = ViewCells(ViewCellConfig(ds=3.0, s_t=1.0))
    vc.observe(np.zeros(4), payload="first")
    vc.observe(np.full(4, 3.0), payload={"points": np.ones((2, 2))})
    m = vc.observe(np.full(4, 0.5))
    assert (m.view_id, m.is_new) == (0, False)
    assert np.allclose(vc.activities(), [0.75, 0.0])
    ids, v = vc.active_views()
    assert ids.tolist() == [0] and np.allclose(v, [0.75])
    assert vc.payload(0) == "first"
    assert vc.payload(1)["points"].shape == (2, 2)
    assert vc.view(1).h == 0 and np.array_equal(vc.view(1).B, np.full(4, 3.0))
    with pytest.raises(IndexError):
        vc.payload(2)
    with pytest.raises(ValueError, match="4"):
        vc.observe(np.zeros(5))
    with pytest.raises(ValueError, match="s_t"):
        ViewCellConfig(s_t=0.0)
    for bad in ({"turn_steps": 0}, {"turn_reach": -1}, {"turn_candidates": 0},
                {"turn_screen": 0.0}):
        with pytest.raises(ValueError, match="turn_"):
            ViewCellConfig(**bad)


def test_heading_gate_rejects_a_view_learned_facing_another_way():
    b = np.linspace(0.0, 1.0, 8)
    vc = ViewCells(ViewCellConfig(heading_gate=math.radians(45.0)))
    assert vc.observe(b, heading=0.0).is_new
    # Same egocentric view, but the robot heads 90 deg elsewhere: a rotated twin.
    assert vc.observe(b, heading=math.pi / 2).is_new
    # Within the gate (and across the +-pi wrap for the second view) it matches.
    assert vc.observe(b, heading=math.radians(30.0)) == ViewMatch(0, 1.0, False, 0.0)
    assert vc.observe(b, heading=math.radians(100.0)).view_id == 1
    # Without a heading every stored view is a candidate: the paper's matching.
    assert not vc.observe(b).is_new


def test_similarities_above_threshold_are_skipped_but_matches_are_exact():
    rng = np.random.default_rng(7)
    stored = rng.random((200, 72))
    vc = ViewCells(ViewCellConfig(prematch=False, s_t=0.05, bound_block=10))
    for row in stored:
        vc.learn(row)
    query = stored[17] + rng.normal(0.0, 0.05, 72)
    m = vc.observe(query)
    exact = np.array([view_similarity(row, query) for row in stored])
    assert m.view_id == int(np.argmin(exact)) == 17
    assert m.similarity == pytest.approx(exact.min())
    assert np.allclose(vc.activities(), view_cell_activity(exact, 0.05))


def test_a_scanner_whose_angles_count_down_recognises_its_views(bc):
    """A scanner that reports its beams clockwise (a negative ROS ``angle_increment``, as one
    mounted upside down does) covers the same sector: its views are compared over it and a
    place seen again is recognised. Its coverage was read as empty, and every look learned a
    new view (simulated maze, 200 s: no view cue at all)."""
    up = cast(WORLD, POSE_A, fov_deg=240.0, beams=683)
    down = LaserScan(0.0, up.ranges[::-1].copy(), up.angles[::-1].copy(), 0.05, 30.0)
    assert np.array_equal(bc.coverage(down), bc.coverage(up)) and bc.coverage(up).any()
    vc = ViewCells(cells_per_ring=bc.config.cells_per_ring)
    first = vc.observe(bc.activity(down), coverage=bc.coverage(down))
    again = vc.observe(bc.activity(down), coverage=bc.coverage(down))
    assert first.is_new and not again.is_new and again.view_id == first.view_id


@pytest.mark.parametrize("steps, reach", [(4, 1), (4, 0), (3, 2), (8, 1)])
def test_a_turn_plan_tries_each_views_rounded_fraction_and_its_neighbours_as_few_turns(
    steps, reach
):
    from bioslam.views import _turn_plan

    left_over = np.array([-0.5, -0.3, -0.125, 0.0, 0.2, 0.375, 0.49])
    whole, step, turns, which = _turn_plan(left_over, steps, reach)
    tried = np.round(left_over * steps).astype(np.int64)[:, None] + np.arange(-reach, reach + 1)
    # each try turns by whole bins and a step no bigger than half a bin either way
    np.testing.assert_array_equal(whole * steps + step, tried)
    assert np.all((step >= -(steps // 2)) & (step < steps - steps // 2))
    # each distinct turn once, in order, and every try points at its own
    np.testing.assert_array_equal(turns, np.unique(step))
    np.testing.assert_array_equal(turns[which], step)


def test_shift_windows_centre_on_each_views_heading_and_span_the_ring_without_one():
    from bioslam.views import _shift_windows

    cols, reach = 36, 2
    centre = np.array([0.3, -4.6, 17.5, np.nan, 18.5])
    lo, hi, left_over = _shift_windows(centre, reach, cols)
    np.testing.assert_array_equal(lo, [-2, -7, 16, 0, 16])
    np.testing.assert_array_equal(hi, [2, -3, 20, cols - 1, 20])
    np.testing.assert_allclose(left_over, [0.3, 0.4, -0.5, 0.0, 0.5])
    # a reach past half the ring compares each shift once
    lo, hi, _ = _shift_windows(np.array([3.0]), cols, cols)
    assert hi[0] - lo[0] == cols - 1
