"""Point-to-line polishing of accepted registrations (:mod:`bioslam.matching.point_to_line`,
:func:`bioslam.closure.polish_on_lines`)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from _views_world import box
from test_closure import HALL, _offset, _points, _submap

from bioslam.closure import _submap_pyramid, polish_on_lines, refine_where_seen
from bioslam.config import LoopClosureConfig
from bioslam.geometry import between, compose
from bioslam.matching.gauss_newton import levels_up_to
from bioslam.matching.point_to_line import LineMap, local_lines, refine_point_to_line
from bioslam.occupancy_grid import NORMAL_RADIUS

# a corridor far longer than the scanner reaches: nothing pins a pose along it
LONG_CORRIDOR = [(-200.0, 0.0, 200.0, 0.0), (-200.0, 2.0, 200.0, 2.0)]


def _position_error(truth: np.ndarray, pose: np.ndarray) -> float:
    return math.hypot(*between(truth, pose)[:2])


def _hall_revisit(lateral: float, turn: float, seed: int = 0):
    """The hall's submap around a pass facing east (5 scans 0.5 m apart, 270 deg), the robot
    back ``lateral`` m aside and turned ``turn`` rad: its true pose in the submap's frame and
    its scan."""
    around = [(3.0 + 0.5 * k, 1.5, 0.0) for k in range(5)]
    submap, seen = _submap(HALL, 2, around)
    robot = _offset(around[2], lateral, turn)
    truth = np.array(between(around[2], robot))
    return submap, seen, truth, _points(HALL, robot, seed=seed)


def test_a_straight_wall_gets_its_normal_and_a_corner_none():
    wall = np.column_stack([np.arange(0.0, 1.0, 0.03), np.full(34, 2.0)])
    corner = np.array([[1.0, 2.0]])
    across = np.column_stack([np.full(10, 1.0), 2.0 - np.arange(1, 11) * 0.03])
    points = np.concatenate([wall, corner, across])
    lines = LineMap.build(points)
    on_wall = lines.normals[5:25]
    assert np.allclose(np.abs(on_wall[:, 1]), 1.0) and np.allclose(on_wall[:, 0], 0.0)
    assert np.all(lines.normals[34] == 0.0)
    assert np.all(local_lines(points[:2], NORMAL_RADIUS)[1] == 0.0)


@pytest.mark.parametrize(
    ("lateral", "turn", "seed"), [(0.0, 0.0, 1), (0.3, 0.35, 2), (-0.4, -0.2, 3)]
)
def test_lines_recover_the_pose_the_grid_leaves_a_fraction_of_a_cell_off(lateral, turn, seed):
    submap, seen, truth, query = _hall_revisit(lateral, turn, seed)
    config = LoopClosureConfig()
    pyramid = _submap_pyramid(submap, config.registration)
    start = compose(truth, (0.02, -0.015, math.radians(0.5)))
    iterations = levels_up_to(config.registration.max_iterations, config.search_level)
    on_grid, _ = refine_where_seen(pyramid, start, query, iterations, seen)
    fit = refine_point_to_line(LineMap.build(submap), on_grid, query, 0.1, 0.02)
    polished = fit.pose
    assert fit.matched > 0.5 * query.shape[0]
    # the scan's 1 cm of range noise, seen across the walls
    assert 0.003 < fit.spread < 0.015
    assert _position_error(truth, polished) < 0.003
    assert abs(between(truth, polished)[2]) < math.radians(0.1)
    assert _position_error(truth, polished) < 0.5 * _position_error(truth, on_grid)


def test_along_a_corridor_the_lines_keep_the_start_and_correct_only_across():
    around = [(0.5 * k, 1.0, 0.0) for k in range(5)]
    submap, _ = _submap(LONG_CORRIDOR, 2, around)
    truth = np.array([0.1, 0.3, 0.2])
    query = _points(LONG_CORRIDOR, compose(around[2], truth), seed=4)
    start = compose(truth, (0.08, 0.02, 0.01))
    polished = refine_point_to_line(LineMap.build(submap), start, query, 0.1, 0.02).pose
    # across (y) and the heading come back; along (x) stays where it started
    assert abs(polished[1] - truth[1]) < 0.003
    assert abs(polished[2] - truth[2]) < math.radians(0.1)
    assert abs(polished[0] - start[0]) < 0.005


def test_the_lines_pin_a_position_along_a_corridor_only_where_a_wall_crosses_it():
    # Down a long corridor nothing pins the position along it: its standard deviation there
    # is infinite, across it the scanner's centimetre over the square root of the points
    # matched. A wall across the corridor (a door frame, an aisle's end) pins it too.
    around = [(0.5 * k, 1.0, 0.0) for k in range(5)]
    truth = np.array([0.1, 0.3, 0.0])
    submap, _ = _submap(LONG_CORRIDOR, 2, around)
    query = _points(LONG_CORRIDOR, compose(around[2], truth), seed=4)
    fit = refine_point_to_line(LineMap.build(submap), truth, query, 0.1, 0.02)
    assert fit.position_sigma((1.0, 0.0)) == math.inf
    across = fit.position_sigma((0.0, 1.0))
    assert 0.2 * fit.spread / math.sqrt(fit.matched) < across < 5.0 * fit.spread / math.sqrt(
        fit.matched
    )
    closed = [*LONG_CORRIDOR, (4.0, 0.0, 4.0, 2.0)]
    submap, _ = _submap(closed, 2, around)
    query = _points(closed, compose(around[2], truth), seed=4)
    fit = refine_point_to_line(LineMap.build(submap), truth, query, 0.1, 0.02)
    along = fit.position_sigma((1.0, 0.0))
    assert across < along < 0.005
    # the same fit with no spread measured pins nothing
    unmeasured = dataclasses.replace(fit, spread=math.inf)
    assert unmeasured.position_sigma((0.0, 1.0)) == math.inf


def test_a_polish_that_would_move_the_pose_beyond_its_reach_is_not_kept():
    submap, seen, truth, query = _hall_revisit(0.2, 0.1, seed=5)
    lines = LineMap.build(submap)
    config = LoopClosureConfig()
    near = compose(truth, (0.015, 0.01, 0.004))
    polished, fit = polish_on_lines(lines, near, query, seen, config)
    assert _position_error(truth, polished) < 0.003
    assert fit is not None and np.array_equal(fit.pose, polished)
    far = compose(truth, (0.07, -0.05, 0.0))
    assert polish_on_lines(lines, far, query, seen, config) == (far, None)


def test_a_box_room_polished_from_every_side_lands_on_its_walls():
    # a plain room, every wall seen: the pose comes back whatever the start's direction off
    room = box(0.0, 0.0, 5.0, 4.0)
    around = [(2.5, 2.0, 0.0)]
    submap, _ = _submap(room, 0, around, fov=360.0)
    lines = LineMap.build(submap)
    truth = np.array([0.4, -0.3, 0.5])
    query = _points(room, compose(around[0], truth), fov=360.0, seed=6)
    for angle in np.linspace(0.0, 2.0 * math.pi, 8, endpoint=False):
        start = compose(truth, (0.03 * math.cos(angle), 0.03 * math.sin(angle), -0.01))
        polished = refine_point_to_line(lines, start, query, 0.1, 0.02).pose
        assert _position_error(truth, polished) < 0.003


def test_points_that_scatter_more_than_the_grid_blurs_are_not_polished():
    submap, seen, truth, _ = _hall_revisit(0.2, 0.1)
    lines = LineMap.build(submap)
    start = compose(truth, (0.015, 0.01, 0.004))
    config = LoopClosureConfig()
    robot = compose(np.array([4.0, 1.5, 0.0]), truth)
    precise = _points(HALL, robot, noise=0.005, seed=7)
    assert _position_error(truth, polish_on_lines(lines, start, precise, seen, config)[0]) < 0.004
    # a low-cost scanner's 3 cm: its lines are no better than the grid's blur
    noisy = _points(HALL, robot, noise=0.03, seed=7)
    assert refine_point_to_line(lines, start, noisy, 0.1, 0.02).spread > config.line_max_spread
    assert polish_on_lines(lines, start, noisy, seen, config) == (start, None)


def test_the_point_index_finds_what_a_search_of_every_point_finds():
    # The nearest point within a radius, and the nearest 8 within it (nearest first), from
    # the cells the index keeps, against every point's distance; clustered and spread points,
    # query points inside and outside the points' box, radii under and over a cell.
    from bioslam.matching.point_to_line import PointIndex, _nearest_k

    rng = np.random.default_rng(4)
    for _ in range(20):
        points = np.concatenate([rng.normal(0.0, 0.3, (200, 2)), rng.uniform(-3, 3, (100, 2))])
        index = PointIndex.build(points, float(rng.choice([0.1, 0.25, 0.5])))
        for query in rng.uniform(-3.5, 3.5, (30, 2)):
            radius = float(rng.uniform(0.05, 0.8))
            d2 = np.sum((points - query) ** 2, axis=1)
            within = np.flatnonzero(d2 < radius * radius)
            found, dist2 = np.empty(1, dtype=np.int64), np.empty(1)
            count = _nearest_k(points, index.arrays(), query[0], query[1], radius, found, dist2)
            assert count == min(within.size, 1)
            if count:
                assert d2[found[0]] == d2[within].min()
            found, dist2 = np.empty(8, dtype=np.int64), np.empty(8)
            count = _nearest_k(points, index.arrays(), query[0], query[1], radius, found, dist2)
            expected = within[np.argsort(d2[within], kind="stable")][:8]
            assert count == expected.size
            assert np.array_equal(np.sort(d2[found[:count]]), d2[expected])
            assert np.all(np.diff(dist2[:count]) >= 0.0)
