"""A robot that stops in a corridor whose ends are out of range, then turns on the spot: nothing
in the scans tells the stop (the corridor is featureless along its axis), but while it turns,
moving on along the axis would be a sideways slip of its wheels, which the scans do see (no
motion across the axis). With ``sideways_noise`` the pose stands still once the turn is under
way; carried on, the speed slid it along the corridor for the whole turn (the simulated
URG-04LX hall's adversarial route, seed 2: 2.6 m off)."""

import math

import numpy as np
from _scan_world import make_scan

from bioslam.odometry import LidarOdometry, OdometryConfig


def _wall_with_niches(side: float, niches: list[float], width: float = 0.8,
                      depth: float = 0.4) -> list:  # fmt: skip
    """A wall at y = ``side`` from x = -30 to 60 with a niche ``width`` wide and ``depth``
    deep starting at each x of ``niches``."""
    segs, x = [], -30.0
    back = side * (1.0 + depth)
    for n in sorted(niches):
        segs += [((x, side), (n, side)), ((n, side), (n, back)), ((n, back), (n + width, back)),
                 ((n + width, back), (n + width, side))]  # fmt: skip
        x = n + width
    return [*segs, ((x, side), (60.0, side))]


# 2 m wide: niches near the start tell the speed, then 5 m of bare corridor beyond a 5.6 m range
SEGS = np.array(
    _wall_with_niches(1.0, [-6.0, -1.0, 4.0]) + _wall_with_niches(-1.0, [-3.5, 1.5]), dtype=float
)


def stop_and_turn(dt: float = 0.1) -> np.ndarray:
    """Rows (t, x, y, heading): from rest at x = -8 up to 1 m/s past the niches, on to x = 9,
    a stop in 0.5 s, then half a turn on the spot at 1.5 rad/s, and standing still."""
    rows, t, x, v, heading, phase = [], 0.0, -8.0, 0.0, 0.0, "go"
    while t < 21.0:
        rows.append((t, x, 0.0, heading))
        if phase == "go":
            v = min(v + dt, 1.0)
            phase = "stop" if x > 9.0 else phase
        elif phase == "stop":
            v = max(v - 2.0 * dt, 0.0)
            phase = "turn" if v == 0.0 else phase
        else:
            heading = min(heading + 1.5 * dt, math.pi)
        x += v * dt
        t += dt
    return np.array(rows)


def _run(config: OdometryConfig) -> tuple[np.ndarray, np.ndarray]:
    """URG-04LX-like scans (240 degrees, 682 beams, 5.6 m, 1 cm noise) at 10 Hz: the route
    and the estimated poses."""
    route = stop_and_turn()
    rng = np.random.default_rng(0)
    odo = LidarOdometry(config, initial_pose=route[0, 1:])
    poses = []
    for t, x, y, heading in route:
        scan = make_scan(SEGS, (x, y, heading), stamp=t, beams=682, fov=math.radians(240.0),
                         sigma=0.01, rng=rng, max_range=5.6)  # fmt: skip
        odo.update(scan)
        poses.append(odo.pose.copy())
    return route, np.array(poses)


def test_a_robot_turning_on_the_spot_in_a_featureless_corridor_stands_still():
    route, poses = _run(OdometryConfig(sideways_noise=0.1))
    turning = np.flatnonzero(np.diff(route[:, 3]) > 0)
    start, end = turning[0], turning[-1] + 1
    # up to the turn the pose keeps up (the stop itself is seen by nothing: an overshoot)
    assert np.hypot(*(poses[start, :2] - route[start, 1:3])) < 0.6
    # a second into the turn the pose stands still, as the robot does
    late = poses[start + 10 : end + 1, :2]
    assert np.hypot(*(late[-1] - late[0])) < 0.05
    assert np.hypot(*(poses[-1, :2] - route[-1, 1:3])) < 1.0
    assert abs(poses[-1, 2] - math.pi) < 0.05
