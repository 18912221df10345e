"""A short-range scanner in a corridor longer than its range: only the motion model carries the
pose along it, and it must carry it at the robot's speed, not stall."""

import numpy as np
import pytest
from _scan_world import make_scan, pose_error

from bioslam.matching.gauss_newton import (
    geometric_conditioning,
    mapped_conditioning,
    matched_normals,
    points_per_level,
)
from bioslam.occupancy_grid import LogOddsConfig, MapPyramid, subsample_by_spacing
from bioslam.odometry import LidarOdometry

URG_FOV = np.radians(240.0)
URG_RANGE = 5.6

# A closed corridor 2 m wide and 24 m long, a door niche near each end: from x = 3 to 17 the
# scanner (5.6 m, 240 degrees, so it never sees the end behind it) sees two parallel walls only.
CLOSED_CORRIDOR = np.array(
    [
        ((-1, -1), (18, -1)), ((18, -1), (18, -1.5)), ((18, -1.5), (19, -1.5)),
        ((19, -1.5), (19, -1)), ((19, -1), (23, -1)), ((23, -1), (23, 1)), ((-1, 1), (-1, -1)),
        ((-1, 1), (1, 1)), ((1, 1), (1, 1.5)), ((1, 1.5), (2, 1.5)), ((2, 1.5), (2, 1)),
        ((2, 1), (23, 1)),
    ],
    dtype=float,
)  # fmt: skip


def out_and_back(y: float, speed: float = 0.5, accel: float = 0.5, rate: float = 10.0):
    """Poses at ``rate`` Hz: off the centre-line by ``y``, speed up to ``speed`` beside the first
    niche, drive to x = 20 and brake with the far end in view, turn on the spot beside the
    second niche, and drive back to x = 1."""
    dt = 1.0 / rate
    x, v, th = 0.0, 0.0, 0.0
    poses = [(x, y, th)]
    while x < 20.0 - v * v / (2 * accel) or v == 0.0:
        v = min(speed, v + accel * dt)
        x += v * dt
        poses.append((x, y, th))
    while v > 0.0:
        v = max(0.0, v - accel * dt)
        x += v * dt
        poses.append((x, y, th))
    while th < np.pi:
        th = min(np.pi, th + dt)
        poses.append((x, y, th))
    while x > 1.0:
        v = min(speed, v + accel * dt)
        x -= v * dt
        poses.append((x, y, th))
    return np.array(poses)


@pytest.mark.parametrize("y", [0.3, -0.4])
def test_a_corridor_longer_than_the_range_is_driven_through_and_back(y):
    poses = out_and_back(y)
    rng = np.random.default_rng(4)
    odo = LidarOdometry(initial_pose=poses[0])
    errors = []
    for k, pose in enumerate(poses):
        scan = make_scan(CLOSED_CORRIDOR, pose, stamp=0.1 * k, beams=682, fov=URG_FOV,
                         sigma=0.01, rng=rng, max_range=URG_RANGE)  # fmt: skip
        odo.update(scan)
        errors.append(pose_error(odo.pose, pose)[0])
        # never a step the robot cannot make (the speed is 0.5 m/s)
    # 14 m each way along nothing but two walls: the speed learned beside the niches carries
    # the pose (stalled, the estimate fell 16-18 m behind)
    assert max(errors) < 1.0
    # back at the start, with the near end and the niche in view again
    assert errors[-1] < 0.3


def _corridor_map(segs, pose):
    rng = np.random.default_rng(1)
    scan = make_scan(segs, pose, beams=682, fov=URG_FOV, sigma=0.01, rng=rng, max_range=5.6)
    pyramid = MapPyramid(0.05, 24.0, 3, LogOddsConfig(), origin=(-12.0, -12.0))
    pyramid.insert_scan(np.asarray(pose, float), scan.endpoints(), 5.6)
    return pyramid


def test_a_surface_the_map_does_not_hold_does_not_count_as_constraining():
    """A corridor's end coming into range is not yet in the map: against the map it fixes
    nothing, and counted, it hid that the position along the corridor was unconstrained."""
    walls = np.array([((-12, -1), (12, -1)), ((-12, 1), (12, 1))], dtype=float)
    pyramid = _corridor_map(walls, (0.0, 0.0, 0.0))
    ended = np.vstack([walls, [((4.5, -1), (4.5, 1))]])
    scan = make_scan(ended, (0.2, 0.0, 0.0), beams=682, fov=URG_FOV, sigma=0.01,
                     rng=np.random.default_rng(2), max_range=5.6)  # fmt: skip
    pts = scan.endpoints()
    level_pts = points_per_level(pts, 0.05, 3, subsample_by_spacing(pts, 0.05))
    normals = matched_normals(level_pts)
    condition, _ = geometric_conditioning(level_pts[0], normals, 3.0)
    assert condition > 0.05  # the end wall pins the position down ...
    mapped, weakest = mapped_conditioning(
        pyramid.finest, level_pts[0], normals, (0.2, 0.0, 0.0), 0.0, 3.0
    )
    # ... but not against this map (what is left is the end wall's corners, next to the
    # side walls the map holds)
    assert mapped < 0.2 * condition and abs(weakest[0]) > 0.99
