import math

import numpy as np
from _scan_world import CORRIDOR, ROOM, make_scan, pose_error

from bioslam.geometry import compose
from bioslam.odometry import LidarOdometry
from bioslam.odometry.body_hits import RELEASE, BodyHits
from bioslam.odometry_config import OdometryConfig
from bioslam.scan import LaserScan

FULL = 2.0 * math.pi
POSTS = np.radians([45.0, 135.0, -135.0, -45.0])  # a deck's four posts round a 360° scanner


def _posts(scan: LaserScan, rng: np.random.Generator, at: float = 0.22) -> LaserScan:
    """``scan`` with the beams within 2.5° of each post returning the post, 1 cm noise."""
    off = np.angle(np.exp(1j * (scan.angles[:, None] - POSTS[None, :])))
    blocked = (np.abs(off) < np.radians(2.5)).any(axis=1)
    ranges = np.array(scan.ranges, dtype=np.float64)
    ranges[blocked] = at + rng.normal(0.0, 0.01, int(blocked.sum()))
    return LaserScan(scan.stamp, ranges, scan.angles, scan.range_min, scan.range_max)


def _heading(t: float) -> float:
    return 2.0 * math.sin(0.5 * t)  # 115° left, then back and 115° right


def _turning(t: float) -> np.ndarray:
    """A robot in the room, weaving: it turns left, then right, as it drives."""
    return np.array([-1.0 + 0.3 * t, 0.4 * math.sin(0.5 * t), _heading(t)])


def test_the_directions_the_body_blocks_are_learned_once_the_robot_has_turned_both_ways():
    rng = np.random.default_rng(1)
    body = BodyHits(reach=1.0, turn=math.pi)
    for k in range(90):  # 0.1 s apart
        t = 0.1 * k
        scan = _posts(make_scan(ROOM, _turning(t), beams=720, fov=FULL), rng)
        hidden = np.isnan(body.without(scan).ranges)
        body.observe(scan, heading=_heading(t))
        if t < math.pi or _heading(t) > 2.0 - 0.5 * math.pi:  # not yet 90° each way
            assert not hidden.any()
    # every post's direction, and nothing more than a bin either side of them
    hidden = np.isnan(body.without(scan).ranges)
    near_post = (np.abs(np.angle(np.exp(1j * (scan.angles[:, None] - POSTS)))) < np.radians(4))
    assert hidden.sum() >= 16 and not (hidden & ~near_post.any(axis=1)).any()


def test_a_wall_beside_a_corridor_is_no_body_however_long_the_robot_drives_along_it():
    body = BodyHits(reach=1.5, turn=math.pi)
    rng = np.random.default_rng(2)
    heading = 0.0
    for k in range(400):  # 40 m straight on, the side walls 1 m away, heading jitter 0.5°
        wobble = math.radians(0.5) * rng.standard_normal()
        scan = make_scan(CORRIDOR, (0.1 * k, 0.0, wobble), beams=720, fov=FULL, sigma=0.01, rng=rng)
        body.observe(scan, heading=heading + wobble)
    assert not body.blocked.any()


def test_a_blocked_direction_that_reads_other_ranges_is_free_again():
    body = BodyHits(reach=1.0, turn=math.pi)
    angles = np.radians(np.arange(-180.0, 180.0, 1.0))
    near = np.where(np.abs(angles) < 0.05, 0.3, 5.0)  # something 0.3 m ahead, turning with it
    for k in range(80):  # a turn of 2 rad left, then back
        body.observe(LaserScan(0.1 * k, near, angles), heading=2.0 - abs(2.0 - 0.05 * k))
        assert body.blocked.any() == (k >= 72)  # back 1.6 rad: 90° each way
    far = np.full(angles.size, 5.0)  # a person who walked alongside through the turns, gone
    for k in range(RELEASE):
        assert body.blocked.any()
        body.observe(LaserScan(8.0 + 0.1 * k, far, angles), heading=0.0)
    assert not body.blocked.any()


def test_a_corner_the_robot_turns_round_is_no_body():
    """Turning left round a wall's corner, the robot keeps the corner at one range and
    bearing for the whole turn: a turn one way only is no proof of a body."""
    body = BodyHits(reach=1.0, turn=math.pi)
    angles = np.radians(np.arange(-180.0, 180.0, 1.0))
    for k in range(40):
        heading = 0.05 * k  # 2 rad left, the corner 0.9 m to the left all along
        ranges = np.where(np.abs(angles - 0.5 * math.pi) < 0.03, 0.9, 3.0 + 0.05 * k)
        body.observe(LaserScan(0.1 * k, ranges, angles), heading=heading)
    assert not body.blocked.any()


def test_a_turn_the_scans_did_not_make_blocks_nothing():
    """An odometry that jumped a turn the robot never made (a lost match) sees every near
    direction hold its range through the turn: no body blocks that much of a scan."""
    body = BodyHits(reach=1.0, turn=math.pi)
    angles = np.radians(np.arange(-180.0, 180.0, 1.0))
    still = 0.8 + 0.1 * np.cos(angles)  # standing in a small round room
    for k in range(120):  # "turning" 2 rad left and right, the scans never changing
        heading = 2.0 * math.sin(0.1 * k)
        body.observe(LaserScan(0.1 * k, still, angles), heading=heading)
    assert not body.blocked.any()


def test_a_few_scans_far_apart_that_read_alike_are_no_body():
    """On a thinned log the robot turns far between scans: a direction that happened to read
    alike on a few of them, turned both ways, is no body (the body is in every scan)."""
    body = BodyHits(reach=1.0, turn=math.pi)
    angles = np.radians(np.arange(-180.0, 180.0, 1.0))
    near = np.where(np.abs(angles) < 0.05, 0.5, 5.0)
    for k, heading in enumerate([0.0, 1.7, 0.0, -1.7, 0.0, 1.7, 0.0]):
        body.observe(LaserScan(3.0 * k, near, angles), heading=heading)
    assert not body.blocked.any()


def test_the_odometry_leaves_out_the_posts_of_its_own_deck():
    """A 360° scanner between four posts 0.22 m away, on a robot that turns about the room:
    once it has turned a quarter of a turn the posts give no endpoints, and the pose is
    tracked at least as well as by an odometry that keeps them."""
    poses = [_turning(0.1 * k) for k in range(80)]
    runs = {}
    for reach in (0.0, 1.0):
        rng = np.random.default_rng(3)  # the same noise for both
        odo = LidarOdometry(OdometryConfig(body_reach=reach))
        for k, pose in enumerate(poses):
            scan = make_scan(ROOM, pose, stamp=0.1 * k, beams=720, fov=FULL, sigma=0.01, rng=rng)
            odo.update(_posts(scan, rng))
        error = pose_error(poses[-1], compose(poses[0], odo.pose))
        runs[reach] = (error, np.hypot(*odo.last_points.T).min())
    assert runs[0.0][1] < 0.3 < runs[1.0][1]  # kept, the posts are endpoints; learned, none
    (kept, _), (learned, _) = runs[0.0], runs[1.0]
    assert learned[0] < kept[0] + 0.005 and learned[1] < kept[1] + math.radians(0.2)
