"""The first scan at a scanner's own rate: the map is then that one scan, and a 1° scanner's
endpoints on walls 7-15 m away lie 0.1-0.5 m apart. Fused as dots, each next scan's beams land
on them exactly when placed back where the first was taken, so standing still outscores every
step on: the pose stayed at the start while the robot drove 15 m down a hall."""

import math

import numpy as np
from _scan_world import box, make_scan

from bioslam.odometry import LidarOdometry

SICK_FOV = math.pi  # 180°, 181 beams: a SICK LMS 200/291


def pillared_hall() -> np.ndarray:
    """A 30 m x 20 m hall with 0.3 m pillars on a 5 m grid; the robot starts 7.5 m from one
    side wall, 27.5 m from the end wall ahead (outside the local map at first)."""
    segs = [((0.0, 0.0), (30.0, 0.0)), ((30.0, 0.0), (30.0, 20.0)),
            ((30.0, 20.0), (0.0, 20.0)), ((0.0, 20.0), (0.0, 0.0))]  # fmt: skip
    for x in (5.0, 10.0, 15.0, 20.0, 25.0):
        for y in (5.0, 10.0, 15.0):
            segs += box(x - 0.15, y - 0.15, x + 0.15, y + 0.15)
    return np.array(segs, dtype=float)


def test_a_sparse_scanners_first_scan_does_not_hold_the_pose_at_the_start():
    rate, speed, accel = 10.0, 0.5, 0.5
    t = np.arange(0.0, 8.0, 1.0 / rate)
    travel = np.where(t < speed / accel, 0.5 * accel * t**2, speed * t - speed**2 / (2 * accel))
    poses = np.column_stack([2.5 + travel, np.full_like(t, 7.5), np.zeros_like(t)])
    segs = pillared_hall()
    rng = np.random.default_rng(0)
    odo = LidarOdometry(initial_pose=poses[0])
    for stamp, pose in zip(t, poses, strict=True):
        scan = make_scan(segs, pose, stamp=stamp, beams=181, fov=SICK_FOV, sigma=0.01, rng=rng,
                         max_range=80.0)  # fmt: skip
        odo.update(scan)
    assert travel[-1] > 3.0  # the case is what it claims to be
    assert math.hypot(*(odo.pose[:2] - poses[-1, :2])) < 0.1


def test_a_log_that_starts_with_the_robot_moving_is_not_read_as_standing_still():
    """A log cut from a longer recording starts at speed (1.2 m/s, a SICK in its 361-beam
    mode at 5 Hz: 0.24 m between the first two scans). The motion model knows no velocity
    yet, so its prior pulled the first match to standing still, and along the hall only the
    pillars tell otherwise: the pose stood at the start while the robot drove off."""
    rate, speed = 5.0, 1.2
    t = np.arange(0.0, 3.0, 1.0 / rate)
    poses = np.column_stack([3.0 + speed * t, np.full_like(t, 2.5), np.zeros_like(t)])
    segs = pillared_hall()
    rng = np.random.default_rng(0)
    odo = LidarOdometry(initial_pose=poses[0])
    errors = []
    for stamp, pose in zip(t, poses, strict=True):
        scan = make_scan(segs, pose, stamp=stamp, beams=361, fov=SICK_FOV, sigma=0.01, rng=rng,
                         max_range=80.0)  # fmt: skip
        odo.update(scan)
        errors.append(math.hypot(*(odo.pose[:2] - pose[:2])))
    assert max(errors) < 0.1
