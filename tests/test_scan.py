import numpy as np

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
