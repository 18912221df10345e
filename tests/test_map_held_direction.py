"""The direction the map leaves a match free: where the scan sees a corridor's far end but the
map does not hold it yet, the scan's own geometry is sound while the walls the map holds pin
nothing along the corridor (:func:`bioslam.matching.gauss_newton.mapped_conditioning`, which
:meth:`bioslam.odometry.LidarOdometry._slid` slides sparse scans' matches along)."""

import numpy as np
import pytest
from _scan_world import make_scan

from bioslam.matching.gauss_newton import (
    mapped_conditioning,
    match_scan_to_map,
    matched_normals,
    points_per_level,
)
from bioslam.occupancy_grid import MapPyramid, subsample_by_spacing, thinned_normals
from bioslam.odometry_config import OdometryConfig

# a corridor 1.4 m wide along x, closed at x = 6
CORRIDOR_END = np.array(
    [((-20, -0.7), (6, -0.7)), ((-20, 0.7), (6, 0.7)), ((6, -0.7), (6, 0.7))], dtype=float
)
DEGENERACY_RATIO = OdometryConfig().degeneracy_ratio


def _matched_corridor(map_range: float):
    """The corridor mapped from five poses along it by a 180° scanner (181 beams, 1 cm noise)
    reaching ``map_range``, then a 30 m scan from x = 1 matched from 0.1 m short of it:
    (pose, report, the finest level's endpoints and normals, pyramid)."""
    rng = np.random.default_rng(1)
    pyramid = MapPyramid(0.05, 24.0, 3)
    sick = {"beams": 181, "fov": np.pi, "sigma": 0.01, "rng": rng}
    for x in np.linspace(0.0, 0.6, 5):
        pose = np.array([x, 0.0, 0.0])
        pts = make_scan(CORRIDOR_END, pose, max_range=map_range, **sick).endpoints()
        pyramid.insert_scan(pose, pts, normals=thinned_normals(pts))
    points = make_scan(CORRIDOR_END, (1.0, 0.0, 0.0), **sick).endpoints()
    levels = points_per_level(points, 0.05, 3, subsample_by_spacing(points, 0.05))
    normals = matched_normals(levels)
    pose, report = match_scan_to_map(
        pyramid, levels, (0.9, 0.0, 0.0), (10, 10, 15), 0.05, 3.0, DEGENERACY_RATIO, 1.0,
        normals, 0.0005,
    )  # fmt: skip
    return pose, report, levels[0], normals, pyramid


@pytest.mark.parametrize("at_truth", [False, True])
def test_a_corridor_end_the_map_lacks_leaves_its_walls_free_along_the_corridor(at_truth):
    pose, report, points, normals, pyramid = _matched_corridor(map_range=3.0)
    assert not report.degenerate  # the scan sees the end wall: its own geometry is sound
    assert pose[0] < 0.7  # and the match slid half a metre back along the walls
    at = np.array([1.0, 0.0, 0.0]) if at_truth else pose
    condition, weakest = mapped_conditioning(pyramid.finest, points, normals, at, 0.0, 3.0)
    assert condition < DEGENERACY_RATIO
    assert abs(weakest[0]) > 0.99, weakest  # along the corridor (sensor frame: heading 0)


def test_a_corridor_end_the_map_holds_pins_the_match():
    pose, report, points, normals, pyramid = _matched_corridor(map_range=30.0)
    assert not report.degenerate
    assert abs(pose[0] - 1.0) < 0.03
    condition, _ = mapped_conditioning(pyramid.finest, points, normals, pose, 0.0, 3.0)
    assert condition > 2 * DEGENERACY_RATIO
