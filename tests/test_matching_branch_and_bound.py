import math

import numpy as np
import pytest
from _scan_world import CORRIDOR, ROOM, box, make_scan, pose_error
from scipy import ndimage

from bioslam.geometry import compose
from bioslam.matching.branch_and_bound import (
    KNOWN_SHARE,
    WideBasinConfig,
    WideBasinMatcher,
    refine,
)
from bioslam.occupancy_grid import MapPyramid, OccupancyGrid, subsample_by_spacing
from bioslam.sim.warehouse import aisle_centres, warehouse_world


def _brute_force_reference(matcher, points, centre, with_pose=False, slide=None):
    """The lattice optimum and the best distinct local maximum, from every lattice score
    (and the optimum's pose: the first maximum in (heading, x, y) order); with a ``slide``,
    distinct across it."""
    cfg = matcher.config
    scores, (x, y, th, step, _, _, res) = matcher.brute_force_scores(points, centre, pad=1)
    # a rival must be a local maximum among all 26 neighbours, also those past the window
    local = scores >= ndimage.maximum_filter(scores, size=3, mode="constant", cval=-1.0)
    inner = scores[1:-1, 1:-1, 1:-1]
    local = local[1:-1, 1:-1, 1:-1]
    nt, nx = (inner.shape[0] - 1) // 2, (inner.shape[1] - 1) // 2
    j, ix, iy = np.meshgrid(
        np.arange(-nt, nt + 1), np.arange(-nx, nx + 1), np.arange(-nx, nx + 1), indexing="ij"
    )
    best = np.unravel_index(np.argmax(inner), inner.shape)
    bj, bx, by = best[0] - nt, best[1] - nx, best[2] - nx
    zone_cells = int(cfg.rival_distance / res)
    if slide is None:
        near = (ix - bx) ** 2 + (iy - by) ** 2 <= zone_cells**2
    else:
        fx, fy = np.asarray(slide, dtype=np.float64) / math.hypot(*slide)
        near = np.abs(fx * (iy - by) - fy * (ix - bx)) <= zone_cells
    zone = (np.abs(j - bj) <= int(cfg.rival_angle / step)) & near
    rivals = local & ~zone & (inner >= cfg.min_rival_ratio * inner.max())
    found = inner.max(), (inner[rivals].max() if rivals.any() else 0.0)
    return (*found, np.array([x + bx * res, y + by * res, th + bj * step])) if with_pose else found


def _random_grid(rng: np.random.Generator, resolution: float, size: float) -> OccupancyGrid:
    """Random cells of random occupancy: the adversarial case for the bounds, no structure to
    prune on and many near-ties."""
    grid = OccupancyGrid(resolution, size)
    mask = rng.random(grid.shape) < rng.uniform(0.01, 0.1)
    grid.weights[mask] = rng.random(int(mask.sum())).astype(np.float32)
    return grid


def test_branch_and_bound_equals_brute_force_on_random_maps_and_windows():
    # Random cells of random occupancy are the adversarial case for the bounds: no structure
    # to prune on, many near-ties. Best and rival must be the brute force's to the last bit.
    rng = np.random.default_rng(7)
    for _ in range(16):
        res = rng.choice([0.05, 0.1, 0.2])
        grid = _random_grid(rng, res, 12.0)
        points = rng.uniform(-5, 5, (int(rng.integers(5, 80)), 2))
        centre = np.array([*rng.uniform(-2, 2, 2), rng.uniform(-math.pi, math.pi)])
        cfg = WideBasinConfig(
            distance=rng.uniform(0.1, 1.0), angle=rng.uniform(0.02, 0.6),
            rival_distance=rng.uniform(0.1, 0.6), rival_angle=rng.uniform(0.02, 0.3),
            min_rival_ratio=rng.uniform(0.0, 0.9), blur=int(rng.integers(0, 3)),
            depth=[None, 0, 1, 2, 4][int(rng.integers(0, 5))],
        )  # fmt: skip
        matcher = WideBasinMatcher(cfg)
        # the whole grid, or a crop of it whose edges cut through the map and the scan: the
        # bounds of endpoints that a node's translations move across the crop's edge
        half = rng.uniform(1.0, 5.0, 2)
        crop = (*(centre[:2] - half), *(centre[:2] + half[::-1]))
        matcher.set_map(grid, crop if rng.random() < 0.5 else None)
        found = matcher.search(points, centre)
        best, rival, pose = _brute_force_reference(matcher, points, centre, with_pose=True)
        assert found.score == best and np.array_equal(found.pose, pose)
        assert found.rival_score == rival
        assert (found.rival_pose is None) == (rival == 0.0)
        # a hint (a pose believed good) does not change the answer
        hint = centre + np.array([*rng.uniform(-0.3, 0.3, 2), rng.uniform(-0.1, 0.1)])
        hinted = matcher.search(points, centre, hint)
        assert hinted.score == found.score and np.array_equal(hinted.pose, found.pose)
        assert hinted.rival_score == found.rival_score
        # a rival sought across a slide: the winner's zone a strip along it
        slide = (math.cos(a := rng.uniform(-math.pi, math.pi)), math.sin(a))
        across = matcher.search(points, centre, slide=slide)
        best, rival = _brute_force_reference(matcher, points, centre, slide=slide)
        assert across.score == best and np.array_equal(across.pose, found.pose)
        assert across.rival_score == rival and (across.rival_pose is None) == (rival == 0.0)


def test_a_map_pooled_for_a_wide_window_answers_a_narrower_windows_search_as_its_own():
    """One pooling serves a loop closure's check and the wider search for a rival outside it:
    a narrower window, which needs fewer pooling levels than were pooled, finds against that
    map the best pose, rival and scores a matcher pooled for it alone finds."""
    rng = np.random.default_rng(5)
    for _ in range(16):
        res = rng.choice([0.05, 0.1])
        grid = _random_grid(rng, res, 16.0)
        points = rng.uniform(-5, 5, (int(rng.integers(5, 80)), 2))
        centre = np.array([*rng.uniform(-1, 1, 2), rng.uniform(-math.pi, math.pi)])
        ratio = rng.uniform(0.0, 0.9)
        wide = WideBasinConfig(distance=rng.uniform(1.0, 2.5), angle=1.0, min_rival_ratio=ratio)
        narrow = WideBasinConfig(
            distance=rng.uniform(0.5, 3.4) * res, angle=rng.uniform(0.02, 0.5),
            min_rival_ratio=ratio,
        )
        shared, own = WideBasinMatcher(wide), WideBasinMatcher(narrow)
        shared.set_map(grid, shared.reach_box(points, [(centre, wide.distance, wide.angle)], res))
        own.set_map(grid)
        assert own.depth_for(res) < shared.depth_for(res)  # the narrow one pools fewer levels
        shared.config = narrow
        a, b = shared.search(points, centre), own.search(points, centre)
        assert a.score == b.score and np.array_equal(a.pose, b.pose)
        assert a.rival_score == b.rival_score
        assert (a.rival_pose is None) == (b.rival_pose is None)


def test_a_wider_windows_search_given_a_narrower_ones_answer_finds_the_whole_windows():
    """A closure check's rival outside its window is sought by searching a wider window
    around the same prediction; given the check's own search (``known``), that lattice is
    not searched again. The answer is the one a search of the whole wider window gives
    (best, rival, scores, to the pose), on random maps where the best lies inside the
    narrower window or outside it, its rival sought as there or across a slide, and the
    search costs fewer nodes when the best lies inside and the rival is sought as there."""
    rng = np.random.default_rng(11)
    inside = 0
    for _ in range(40):
        res = rng.choice([0.05, 0.1])
        grid = _random_grid(rng, res, 14.0)
        points = rng.uniform(-5, 5, (int(rng.integers(5, 80)), 2))
        centre = np.array([*rng.uniform(-1, 1, 2), rng.uniform(-math.pi, math.pi)])
        rivals = dict(
            rival_distance=rng.uniform(0.1, 0.6), rival_angle=rng.uniform(0.02, 0.3),
            min_rival_ratio=rng.uniform(0.0, 0.95), blur=int(rng.integers(0, 3)),
        )  # fmt: skip
        narrow = WideBasinConfig(
            distance=rng.uniform(0.2, 1.2), angle=rng.uniform(0.05, 0.5), **rivals
        )
        wide = WideBasinConfig(
            distance=narrow.distance * rng.choice([1.0, rng.uniform(1.0, 2.0)]),
            angle=narrow.angle * rng.uniform(1.0, 2.5), **rivals,
        )  # fmt: skip
        matcher = WideBasinMatcher(wide)
        matcher.set_map(grid, matcher.reach_box(points, [(centre, wide.distance, wide.angle)], res))
        matcher.config = narrow
        known = matcher.search(points, centre)
        matcher.config = wide
        # the rival sought as in the known window, or across a slide (a strip around the
        # best where the known search sought it around a disc)
        slide = (math.cos(a := rng.uniform(-math.pi, math.pi)), math.sin(a))
        for across in (None, slide):
            whole = matcher.search(points, centre, slide=across)
            reused = matcher.search(points, centre, slide=across, known=known)
            assert np.array_equal(reused.pose, whole.pose)
            assert reused.score == pytest.approx(whole.score, rel=1e-12)
            assert (reused.rival_pose is None) == (whole.rival_pose is None)
            if whole.rival_pose is not None:
                assert np.array_equal(reused.rival_pose, whole.rival_pose)
                assert reused.rival_score == pytest.approx(whole.rival_score, rel=1e-12)
            if across is None and np.array_equal(known.pose, whole.pose):
                inside += 1
                assert reused.nodes < whole.nodes
    assert 5 <= inside <= 35  # both cases met


def test_a_known_window_with_nothing_on_it_or_a_sliver_of_the_lattice_is_searched_in_full():
    """A known window where nothing scored above 0 stands for nothing, and one holding less
    than ``KNOWN_SHARE`` of the lattice spares too little to be worth its bookkeeping: the
    wider window is searched whole (the same nodes), one holding more is not."""
    rng = np.random.default_rng(3)
    points = rng.uniform(-4, 4, (40, 2))
    centre = np.array([0.2, -0.3, 0.4])
    wide = WideBasinConfig(distance=1.5, angle=0.6)
    empty = WideBasinMatcher(wide)
    empty.set_map(OccupancyGrid(0.1, 12.0))
    nothing = empty.search(points, centre)
    assert nothing.score == 0.0
    assert empty.search(points, centre, known=nothing).nodes == nothing.nodes
    matcher = WideBasinMatcher(wide)
    matcher.set_map(_random_grid(rng, 0.1, 12.0))
    whole = matcher.search(points, centre)
    for distance, reused in ((0.2, False), (1.0, True)):
        matcher.config = WideBasinConfig(distance=distance, angle=0.3)
        known = matcher.search(points, centre)
        (nt, nx), (wt, wx) = known.lattice, whole.lattice
        assert (nt * nx**2 >= KNOWN_SHARE * wt * wx**2) is reused
        matcher.config = wide
        again = matcher.search(points, centre, known=known)
        assert (again.nodes < whole.nodes) is reused
        assert np.array_equal(again.pose, whole.pose)


def test_a_map_pooled_over_the_reach_box_alone_gives_the_whole_maps_answers():
    """Searches of the windows a reach box was made for find, against the map pooled over
    that box, the best pose, rival and scores they find against the whole map pooled: no
    lattice pose (nor its neighbour past the window's edge) puts an endpoint outside it.
    Scans of every field of view, windows turned up to a whole turn, one window or two."""
    rng = np.random.default_rng(11)
    for _ in range(24):
        res = rng.choice([0.05, 0.1])
        grid = _random_grid(rng, res, 16.0)
        fov = rng.uniform(0.3, 2 * math.pi)
        bearing = rng.uniform(-fov / 2, fov / 2, int(rng.integers(5, 120)))
        ranges = rng.uniform(0.3, 6.0, bearing.size)
        points = np.column_stack([ranges * np.cos(bearing), ranges * np.sin(bearing)])
        windows = [
            (np.array([*rng.uniform(-1, 1, 2), rng.uniform(-math.pi, math.pi)]),
             rng.uniform(0.1, 1.0), rng.uniform(0.02, 3.2))
            for _ in range(int(rng.integers(1, 3)))
        ]  # fmt: skip
        cfg = WideBasinConfig(min_rival_ratio=rng.uniform(0.0, 0.9), depth=4)
        whole, boxed = WideBasinMatcher(cfg), WideBasinMatcher(cfg)
        whole.set_map(grid)
        box = boxed.reach_box(points, windows, res)
        for centre, distance, angle in windows:  # the lattice's edge, and a step past it
            step = boxed._angular_step(points, res)
            nt, nx = int(angle / step) + 1, int(distance / res) + 1
            for j in range(-nt, nt + 1):
                for ix, iy in ((-nx, -nx), (-nx, nx), (nx, -nx), (nx, nx), (0, 0)):
                    pose = centre + np.array([ix * res, iy * res, j * step])
                    placed = compose(pose, np.column_stack([points, np.zeros(len(points))]))
                    assert np.all(placed[:, 0] >= box[0]) and np.all(placed[:, 0] <= box[2])
                    assert np.all(placed[:, 1] >= box[1]) and np.all(placed[:, 1] <= box[3])
        boxed.set_map(grid, box)
        assert boxed._shape[0] * boxed._shape[1] < whole._shape[0] * whole._shape[1]
        for centre, distance, angle in windows:
            window = WideBasinConfig(
                distance=distance, angle=angle, min_rival_ratio=cfg.min_rival_ratio, depth=4
            )
            whole.config = boxed.config = window
            a, b = whole.search(points, centre), boxed.search(points, centre)
            assert a.score == b.score and np.array_equal(a.pose, b.pose)
            assert a.rival_score == b.rival_score
            assert (a.rival_pose is None) == (b.rival_pose is None)
            if a.rival_pose is not None:
                assert np.array_equal(a.rival_pose, b.rival_pose)


@pytest.mark.parametrize(("beams", "fov"), [(1081, 1.5 * np.pi), (181, np.pi)])
def test_branch_and_bound_equals_brute_force_in_a_repetitive_warehouse(beams, fov):
    # Identical aisles whose view repeats every 2.8 m: many near-equal maxima, little to
    # prune. A dense scanner (1081 beams) and a sparse one (181), the odometry's window
    # (±1.5 m, ±45°) and its crop of the map around the search (endpoints near the crop's
    # edge are summed with bounds checks, the others without): best and rival must be the
    # brute force's to the last bit, with and without pooling to a single top node.
    segs = warehouse_world().segments.reshape(-1, 2, 2)
    y = aisle_centres()[2]
    truth = np.array([16.1, y + 0.2, 0.07])
    rng = np.random.default_rng(3)
    pyramid = MapPyramid(0.05, 40.0, 3)
    pyramid.recenter(truth[0], truth[1])
    for x in (12.0, 14.5, 18.0):
        pose = np.array([x, y, rng.uniform(-0.2, 0.2)])
        scan = make_scan(segs, pose, beams=beams, fov=fov, sigma=0.01, rng=rng)
        pyramid.insert_scan(pose, scan.endpoints())
    scan = make_scan(segs, truth, beams=beams, fov=fov, sigma=0.01, rng=rng).endpoints()
    points = scan[subsample_by_spacing(scan, 0.1)]
    start = compose(truth, (0.8, -0.6, math.radians(30)))
    reach = float(np.max(np.hypot(*points.T))) + 2.5
    crop = (start[0] - reach, start[1] - reach, start[0] + reach, start[1] + reach)
    for depth in (4, None):
        matcher = WideBasinMatcher(WideBasinConfig(depth=depth, angular_cells=2.0))
        matcher.set_map(pyramid.grids[1], crop)
        found = matcher.search(points, start)
        best, rival = _brute_force_reference(matcher, points, start)
        assert found.score == best and found.rival_score == rival
        assert found.rival_pose is not None and found.ambiguity > 0.8  # look-alikes
        assert found.nodes < 0.2 * np.prod(found.lattice) * found.lattice[1]
        hinted = matcher.search(points, start, truth)
        assert hinted.score == best and hinted.rival_score == rival


def test_equal_scores_give_the_brute_force_first_maximum_and_its_rival():
    # A plateau: uniform wall blocks and no blur, so that many poses score exactly alike.
    # Which of them wins decides where the rival may be; the search keeps the first in
    # (heading, x, y) order, as a brute force's first maximum, whatever order it met them in.
    rng = np.random.default_rng(11)
    for _ in range(30):
        grid = OccupancyGrid(0.1, 8.0)
        for _ in range(int(rng.integers(1, 4))):
            r, c = rng.integers(0, 70, 2)
            grid.weights[r : r + rng.integers(2, 10), c : c + rng.integers(2, 10)] = 0.5
        points = rng.uniform(-2, 2, (int(rng.integers(1, 12)), 2))
        centre = np.array([*rng.uniform(-1, 1, 2), rng.uniform(-math.pi, math.pi)])
        cfg = WideBasinConfig(
            distance=rng.uniform(0.1, 0.6), angle=rng.uniform(0.0, 0.4), blur=0,
            rival_distance=rng.uniform(0.0, 0.4), rival_angle=rng.uniform(0.0, 0.2),
            min_rival_ratio=rng.uniform(0.0, 0.9), depth=int(rng.integers(0, 4)),
        )  # fmt: skip
        matcher = WideBasinMatcher(cfg)
        matcher.set_map(grid)
        found = matcher.search(points, centre)
        best, rival, pose = _brute_force_reference(matcher, points, centre, with_pose=True)
        assert found.score == best and np.array_equal(found.pose, pose)
        assert found.rival_score == rival


def _mapped(world, poses, beams=361, fov=1.5 * np.pi, size=24.0):
    """A map pyramid (5 cm finest) made from noisy scans of ``world`` at ``poses``."""
    rng = np.random.default_rng(0)
    pyramid = MapPyramid(0.05, size, 3)
    for pose in poses:
        scan = make_scan(world, pose, beams=beams, fov=fov, sigma=0.01, rng=rng)
        pyramid.insert_scan(pose, scan.endpoints())
    return pyramid


def _query(world, pose, beams=181, fov=np.pi):
    scan = make_scan(world, pose, beams=beams, fov=fov, sigma=0.01, rng=np.random.default_rng(1))
    return scan.endpoints()


def test_finds_an_offset_of_a_metre_and_30_degrees_in_a_distinctive_room():
    truth = np.array([0.5, 0.3, 0.4])
    pyramid = _mapped(ROOM, [truth])
    matcher = WideBasinMatcher()  # ±1.5 m, ±45°
    matcher.set_map(pyramid.grids[1])
    points = _query(ROOM, truth)
    guess = compose(truth, (-0.8, 0.6, math.radians(30)))  # 1 m and 30° off
    found = matcher.search(points, guess)
    dist, ang = pose_error(found.pose, truth)
    assert dist < 0.1 and ang < math.radians(2)
    assert found.ambiguity < 0.8  # nothing else in the room looks like it
    pose, _ = refine(pyramid, found.pose, points)
    dist, ang = pose_error(pose, truth)
    assert dist < 0.02 and ang < math.radians(0.5)


def test_a_featureless_corridor_is_ambiguous_along_its_axis():
    truth = np.array([0.0, 0.2, 0.05])
    pyramid = _mapped(CORRIDOR, [(-3, 0, 0), (0, 0, 0), (3, 0, 0)], size=40.0)
    matcher = WideBasinMatcher(WideBasinConfig(angle=math.radians(20)))
    matcher.set_map(pyramid.grids[1])
    points = _query(CORRIDOR, truth, fov=np.radians(270.0))
    found = matcher.search(points, truth)
    assert found.rival_pose is not None and found.ambiguity > 0.95
    # the look-alike is along the axis; across it both sit on the walls
    apart = found.rival_pose - found.pose
    assert abs(apart[0]) > 0.5 and abs(apart[1]) < 0.1 and abs(apart[2]) < 0.03
    # sought across the axis, the corridor's own plateau is no rival: nothing beside it fits
    across = matcher.search(points, truth, slide=(1.0, 0.0))
    assert np.array_equal(across.pose, found.pose)
    assert across.rival_pose is None or abs(across.rival_pose[1] - found.pose[1]) > 0.5


def test_two_identical_rooms_are_told_apart_only_as_ambiguous():
    # two closed 2 m x 2.6 m rooms with the same furniture, 2.4 m apart; a search window
    # centred between them holds both
    def room(x0):
        return box(x0, 0, x0 + 2.0, 2.6) + box(x0 + 0.3, 0.3, x0 + 0.8, 0.6)

    world = np.array(room(0.0) + room(2.4), dtype=float)
    truth = np.array([1.2, 1.5, 0.3])
    other = truth + np.array([2.4, 0, 0])
    pyramid = _mapped(world, [truth, other], beams=721, fov=2 * np.pi, size=12.0)
    matcher = WideBasinMatcher(WideBasinConfig(distance=1.5, angle=math.radians(15)))
    matcher.set_map(pyramid.grids[1])
    points = _query(world, truth, beams=361, fov=2 * np.pi)
    found = matcher.search(points, truth + np.array([1.2, 0.0, 0.0]))
    assert found.rival_pose is not None and found.ambiguity > 0.9
    places = sorted([found.pose[0], found.rival_pose[0]])
    assert places[0] == pytest.approx(1.2, abs=0.1) and places[1] == pytest.approx(3.6, abs=0.1)
    # the same scan searched around one room alone is unambiguous
    alone = matcher.search(points, truth + np.array([0.3, 0.0, 0.0]))
    assert alone.ambiguity < 0.8 or alone.rival_pose is None


def test_search_needs_a_map_and_checks_its_window():
    with pytest.raises(RuntimeError, match="set_map"):
        WideBasinMatcher().search(np.zeros((3, 2)), np.zeros(3))
    with pytest.raises(ValueError, match="non-negative"):
        WideBasinConfig(distance=-1.0)


def test_a_window_where_nothing_lands_scores_zero_without_expanding_its_nodes():
    # A check against a submap out of the scan's reach: every pose ties at 0. The answer is
    # the brute force's (score 0 at the window's first lattice pose) and no rival, found from
    # the top nodes' bounds alone, not by expanding every node to order the ties.
    grid = OccupancyGrid(0.1, 16.0)
    grid.weights[5:9, 5:60] = 0.8  # a wall far from where the scan can land
    points = np.random.default_rng(3).uniform(-1.0, 1.0, (40, 2))
    centre = np.array([4.0, 4.0, 0.3])
    matcher = WideBasinMatcher(WideBasinConfig(distance=1.5, angle=math.radians(45.0)))
    matcher.set_map(grid)
    found = matcher.search(points, centre)
    best, _, pose = _brute_force_reference(matcher, points, centre, with_pose=True)
    assert best == 0.0 and found.score == 0.0
    assert np.array_equal(found.pose, pose)
    assert found.rival_pose is None and found.ambiguity == 0.0
    headings, positions = found.lattice
    assert found.nodes < headings * positions**2 / 50
