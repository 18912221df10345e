import math

import numpy as np
import pytest

from bioslam.scan import LaserScan


def test_invalid_returns_are_dropped():
    ranges = np.array([1.0, np.nan, np.inf, 0.0, 0.05, 40.0, 2.0])
    scan = LaserScan.from_angle_min(0.0, ranges, -0.3, 0.1, range_min=0.1, range_max=30.0)
    r, a = scan.valid_polar()
    assert np.allclose(r, [1.0, 2.0])
    assert np.allclose(a, [-0.3, 0.3])
    pts = scan.endpoints()
    assert np.allclose(pts[0], [np.cos(-0.3), np.sin(-0.3)])
    assert np.allclose(np.hypot(pts[:, 0], pts[:, 1]), r)


def test_empty_scan_has_no_endpoints():
    scan = LaserScan.from_angle_min(0.0, np.full(10, np.nan), 0.0, 0.1)
    assert scan.endpoints().shape == (0, 2)


def test_beam_times_follow_time_increment():
    scan = LaserScan.from_angle_min(
        5.0, np.array([1.0, np.nan, 1.0]), 0.0, 0.1, time_increment=0.01
    )
    assert np.allclose(scan.beam_times(), [0.0, 0.02])
    assert scan.fov == 0.2 and scan.num_beams == 3


def test_the_sweep_is_the_same_sector_whichever_way_the_beams_count():
    up = LaserScan.from_angle_min(0.0, np.ones(271), -2.0, math.radians(1.0))
    down = LaserScan(0.0, up.ranges[::-1].copy(), up.angles[::-1].copy())
    assert up.sweep == pytest.approx((-2.0, -2.0 + math.radians(270.0)))
    assert down.sweep == pytest.approx(up.sweep)
    assert down.fov == pytest.approx(up.fov)
    # angles wrapped into [-pi, pi): a 240° scanner facing backwards jumps by a turn
    wrapped = np.mod(math.pi - math.radians(120.0) + np.radians(np.arange(241.0)), 2 * math.pi)
    wrapped = np.where(wrapped >= math.pi, wrapped - 2 * math.pi, wrapped)
    back = LaserScan(0.0, np.ones(241), wrapped)
    first, last = back.sweep
    assert first == pytest.approx(math.radians(60.0))
    assert last - first == pytest.approx(math.radians(240.0))
    assert back.fov == pytest.approx(math.radians(240.0))


def test_a_beam_reported_at_the_maximum_range_is_no_return():
    """Loggers and drivers that do not use +inf report a beam that met nothing as the
    scanner's maximum range (a float32 of it rounds just below); a wall exactly there is a
    set of measure zero. Taken for hits, those beams draw an arc round the robot."""
    ranges = np.array([1.0, 5.6, np.float32(5.6), 5.59, np.inf, 6.0])
    scan = LaserScan.from_angle_min(0.0, ranges, -0.3, 0.1, range_min=0.02, range_max=5.6)
    assert scan.valid_mask.tolist() == [True, False, False, True, False, False]
    assert LaserScan.from_angle_min(0.0, ranges, -0.3, 0.1).valid_mask.sum() == 5  # no maximum
