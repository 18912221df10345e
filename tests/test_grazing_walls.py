"""Walls the beams graze: their endpoints lie metres apart, the map holds them as the dots the
last fused scans' beams left, and matched they pull the pose back to where those scans were
taken. Along a corridor longer than the range the pose then stops while the robot drives on.
"""

import math

import numpy as np
import pytest
from _scan_world import box, make_scan

from bioslam.matching.gauss_newton import _cheaper_start, grid_args
from bioslam.matching.registration import grazing_endpoints
from bioslam.occupancy_grid import LogOddsConfig, MapPyramid
from bioslam.odometry import LidarOdometry, OdometryConfig
from bioslam.scan import LaserScan


def _points(scan):
    return np.ascontiguousarray(scan.endpoints())


def test_a_wall_seen_at_a_shallow_angle_is_grazed_and_one_seen_across_is_not():
    wall_alongside = np.array([((-50.0, 1.0), (50.0, 1.0))])
    scan = make_scan(wall_alongside, (0.0, 0.0, 0.0), beams=181, fov=math.pi)
    pts = _points(scan)
    grazed = grazing_endpoints(pts, 4.0, 0.1)
    bearing = np.degrees(np.arctan2(pts[:, 1], pts[:, 0]))
    # beams within 14 deg of the wall (bearings below ~14 deg: hits > 4 m ahead) are grazing;
    # the first endpoint's missing neighbour counts as a gap
    assert grazed[(bearing > 1.5) & (bearing < 10.0)].all()
    assert not grazed[bearing > 20.0].any()

    wall_ahead = np.array([((5.0, -50.0), (5.0, 50.0))])
    pts = _points(make_scan(wall_ahead, (0.0, 0.0, 0.0), beams=181, fov=math.radians(90.0)))
    assert not grazing_endpoints(pts, 4.0, 0.1)[1:-1].any()


def test_the_wall_seen_between_a_persons_legs_is_no_grazed_wall():
    # two legs 1 m ahead, the wall 3 m ahead between them: both gaps long and sparse, but the
    # second turns back on the first
    pts = np.array([[1.0, -0.12], [1.0, -0.1], [3.0, 0.0], [1.0, 0.1], [1.0, 0.12]])
    assert not grazing_endpoints(pts, 4.0, 0.5)[2]
    # points in a line, a wall seen along from 1 m off it: grazed
    line = np.array([[3.0, 1.0], [6.0, 1.0], [10.0, 1.0], [15.0, 1.0], [21.0, 1.0]])
    assert grazing_endpoints(line, 4.0, 0.5)[1:4].all()


def test_beams_without_a_return_do_not_make_a_wall_seen_across_look_sparse():
    wall_ahead = np.array([((5.0, -50.0), (5.0, 50.0))])
    scan = make_scan(wall_ahead, (0.0, 0.0, 0.0), beams=181, fov=math.radians(90.0))
    ranges = scan.ranges.copy()
    ranges[::3] = np.inf  # two in three beams return, the gaps twice as long
    pts = _points(LaserScan(0.0, ranges, scan.angles, 0.05, 30.0))
    assert not grazing_endpoints(pts, 4.0, 0.1)[1:-1].any()


def _corridor(width: float, period: float) -> np.ndarray:
    """A corridor ``2 * width`` wide from x = -20 to 120, a 1 m door niche 0.3 m deep every
    ``period`` metres along its left wall, the right wall bare."""
    segs, x = [], -20.0
    back = width + 0.3
    for n in np.arange(2.0, 110.0, period):
        segs += [((x, width), (n, width)), ((n, width), (n, back)), ((n, back), (n + 1.0, back)),
                 ((n + 1.0, back), (n + 1.0, width))]  # fmt: skip
        x = n + 1.0
    return np.array([*segs, ((x, width), (120.0, width)), ((-20.0, -width), (120.0, -width))])


def _drive(config: OdometryConfig, width: float, period: float) -> float:
    """A 181-beam 180° scanner (30 m, 1 cm noise) at 10 Hz, 40 m along the corridor at
    0.5 m/s weaving 10 cm about its centre line: how far the pose ends behind the robot."""
    segs = _corridor(width, period)
    rng = np.random.default_rng(0)
    odo = LidarOdometry(config)
    for k in range(801):
        x = 0.05 * k
        pose = (x, 0.1 * math.sin(x / 3.0), 0.0)
        odo.update(make_scan(segs, pose, stamp=0.1 * k, beams=181, fov=math.pi, sigma=0.01,
                             rng=rng, max_range=30.0))  # fmt: skip
    return x - float(odo.pose[0])


def test_the_pose_keeps_up_along_a_corridor_longer_than_the_range():
    # with every endpoint matched the pose falls metres behind: 4.4 m and 9.7 m here
    every = OdometryConfig(grazing_ratio=None)
    assert _drive(every, 1.0, 4.0) > 2.0
    assert abs(_drive(OdometryConfig(), 1.0, 4.0)) < 0.2
    assert abs(_drive(OdometryConfig(), 1.5, 6.0)) < 0.1 * _drive(every, 1.5, 6.0)


def test_the_finest_level_restarts_from_the_cheaper_of_the_start_and_the_prior():
    room = np.array(box(-6, -4, 6, 4) + box(1.0, 1.0, 2.0, 1.5), dtype=float)
    truth = np.array([0.3, -0.2, 0.1])
    pyramid = MapPyramid(0.05, 24.0, 3, LogOddsConfig(), origin=None)
    pyramid.recenter(0.0, 0.0)
    for _ in range(3):
        scan = make_scan(room, truth, beams=361)
        pyramid.insert_scan(truth, scan.endpoints(), 30.0)
    finest = grid_args(pyramid.finest, 1.0)
    pts = _points(make_scan(room, truth, beams=361))
    facing = np.zeros((0, 2))
    off = truth + np.array([0.25, 0.0, 0.05])
    chosen = _cheaper_start(finest, pts, facing, (off, truth), 1e9)
    assert chosen is truth
    # neither start beats where the descent ended: no restart
    assert _cheaper_start(finest, pts, facing, (off, truth), 0.0) is None


def test_grazed_walls_are_left_out_only_where_the_scan_leaves_a_direction_weak():
    # a corridor: the walls far ahead, grazed, are left out of the match
    segs = _corridor(1.0, 4.0)
    rng = np.random.default_rng(1)
    odo = LidarOdometry(OdometryConfig())
    for k in range(40):
        scan = make_scan(segs, (0.05 * k, 0.0, 0.0), stamp=0.1 * k, beams=181, fov=math.pi,
                         sigma=0.01, rng=rng, max_range=30.0)  # fmt: skip
        odo.update(scan)
    pts = odo._sensor_points(scan)
    matched, _ = odo._matched(pts, np.ones(pts.shape[0], dtype=bool), scan)
    grazed = grazing_endpoints(pts, 4.0, 1.0)
    assert odo.last_report.condition < OdometryConfig().grazing_condition and grazed.sum() >= 3
    assert matched.shape[0] <= pts.shape[0] - grazed.sum()
    # the same scan after a match that pinned every direction: every endpoint in range matched
    odo.last_report.condition = 0.5
    kept, _ = odo._matched(pts, np.ones(pts.shape[0], dtype=bool), scan)
    assert kept.shape[0] > matched.shape[0]
    near = np.hypot(pts[:, 0], pts[:, 1]) <= 30.0 - OdometryConfig().matched_range_margin
    assert kept.shape[0] == near.sum()


def test_grazing_settings_out_of_range_are_refused():
    for bad in ({"grazing_ratio": 0.5}, {"grazing_gap": -1.0}, {"grazing_condition": -0.1}):
        with pytest.raises(ValueError, match="grazing_"):
            OdometryConfig(**bad)
    assert OdometryConfig(grazing_ratio=None).grazing_ratio is None
