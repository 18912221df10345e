"""A run that starts in a corridor: its scans pin the pose along the corridor only by the few
beams that reach its far end, and the motion model has measured no velocity along it yet. The
prediction there is the start's standstill, which no scan measured; held to it with the full
motion prior, the pose stood still while the robot drove off (a 180° scanner facing
backwards on a toothed corridor loop, its corridor's end 12 m behind: 5.1 m short after 8 s).
Until a scan has measured that velocity the prior weighs as after a gap, and the end wall's
beams carry the pose."""

import math

import numpy as np
from _scan_world import make_scan

from bioslam.motion_model import ConstantVelocityModel
from bioslam.odometry import LidarOdometry, OdometryConfig

# a 3.2 m corridor closed at x = 0, open 40 m on
SEGS = np.array(
    [((0.0, -1.6), (40.0, -1.6)), ((0.0, 1.6), (40.0, 1.6)), ((0.0, -1.6), (0.0, 1.6))],
    dtype=float,
)


def drive_off(dt: float = 0.5, seconds: float = 10.0) -> np.ndarray:
    """Rows (t, x, y, heading) of the scanner: 12.5 m from the end wall and 0.5 m from a
    side wall, facing the end wall (mounted backwards) while the robot drives away from it
    from rest, up to 0.5 m/s in a second."""
    rows, x, v = [], 12.5, 0.0
    for k in range(int(seconds / dt) + 1):
        rows.append((k * dt, x, 1.1, math.pi))
        v = min(v + 0.5 * dt, 0.5)
        x += v * dt
    return np.array(rows)


def _run(config: OdometryConfig) -> tuple[np.ndarray, np.ndarray, LidarOdometry]:
    """A SICK-like scanner (180°, 181 beams, 1 cm noise) at 2 Hz: the route, the poses."""
    route = drive_off()
    rng = np.random.default_rng(0)
    odo = LidarOdometry(config, initial_pose=route[0, 1:])
    poses = []
    for t, x, y, heading in route:
        scan = make_scan(SEGS, (x, y, heading), stamp=t, beams=181, fov=math.pi, sigma=0.01,
                         rng=rng, max_range=80.0)  # fmt: skip
        odo.update(scan)
        poses.append(odo.pose.copy())
    return route, np.array(poses), odo


def test_a_run_starting_in_a_corridor_follows_the_end_wall_not_the_standstill():
    route, poses, odo = _run(OdometryConfig())
    assert odo.num_degenerate >= len(route) - 3  # the corridor leaves the axis weak throughout
    travelled = route[-1, 1] - route[0, 1]
    assert travelled > 4.0
    # the pose keeps up with the robot: within 10 cm of the truth at every scan
    assert np.max(np.abs(poses[:, 0] - route[:, 1])) < 0.1
    assert np.max(np.abs(poses[:, 1] - route[:, 2])) < 0.05


def test_the_velocity_along_the_weak_direction_is_measured_only_by_a_scan_that_constrains_it():
    model = ConstantVelocityModel(0.1, 3, 3.0, 0.01, 0.1, 0.5, 0.05, 0.1)
    weakest = np.array([1.0, 0.0, 0.0])
    model.update(0.0, [0.0, 0.0, 0.0], 0.005, weakest)
    model.update(0.5, [0.01, 0.0, 0.0], 0.005, weakest)
    assert not model.weak_measured  # degenerate: the twist carried, not measured
    assert model.twist[0] == 0.0
    model.update(1.0, [0.03, 0.0, 0.0], 0.05, weakest)  # partly constrained
    assert model.weak_measured
    assert model.twist[0] > 0.0
