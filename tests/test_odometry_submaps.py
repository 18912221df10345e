"""Sparse scans: a wrong step must not spoil the map for every later scan."""

from __future__ import annotations

import math

import numpy as np
from _scan_world import box, make_scan

from bioslam.geometry import between, compose
from bioslam.odometry import LidarOdometry, OdometryConfig

# A corridor 2.5 m wide around a block (a loop of 42 m), with door frames along its walls
LOOP = np.array(
    box(-8, -5, 8, 5)
    + box(-5.5, -2.5, 5.5, 2.5)
    + [((x, -5.0), (x, -4.6)) for x in (-6.0, -2.5, 1.0, 4.5)]
    + [((x, 5.0), (x, 4.6)) for x in (-5.0, -1.0, 2.5, 6.0)]
    + [((-8.0, y), (-7.6, y)) for y in (-1.0, 2.0)]
    + [((8.0, y), (7.6, y)) for y in (-2.0, 1.5)],
    dtype=float,
)


def loop_path(laps: float, step: float) -> list[np.ndarray]:
    """Poses along the corridor's centre-line, ``step`` metres apart, turning on the spot
    in three steps at each corner (as a log thinned to a scan per metre or 30 degrees)."""
    corners = [(-6.75, -3.75), (6.75, -3.75), (6.75, 3.75), (-6.75, 3.75)]
    poses: list[np.ndarray] = []
    travelled, total = 0.0, laps * 42.0
    k = 0
    while travelled < total:
        a, b = np.array(corners[k % 4]), np.array(corners[(k + 1) % 4])
        heading = math.atan2(*(b - a)[::-1])
        if poses:
            turn = (heading - poses[-1][2] + math.pi) % (2 * math.pi) - math.pi
            poses += [np.array([*a, poses[-1][2] + turn * f]) for f in (1 / 3, 2 / 3)]
        n = int(np.linalg.norm(b - a) // step)
        poses += [np.array([*(a + (b - a) * j / n), heading]) for j in range(n)]
        travelled += np.linalg.norm(b - a)
        k += 1
    return poses


def run(config: OdometryConfig, path, dt: float, doubt_at: int | None = None,
        max_range: float = 30.0, shift: tuple = (0.0, 0.0, 0.0),
        ) -> tuple[LidarOdometry, np.ndarray]:  # fmt: skip
    """The odometry along ``path`` (a scan every ``dt`` seconds), with the match of scan
    ``doubt_at`` alone flagged ambiguous (as the odometry flags a look-alike it cannot
    rule out) and moved by ``shift`` (robot frame: a look-alike taken), and no other
    match flagged. Returns the odometry and each step's translation error."""
    rng = np.random.default_rng(0)
    odo = LidarOdometry(config, initial_pose=path[0])
    match = odo._match

    def doubted(*args, **kwargs):
        pose, report, searched = match(*args, **kwargs)
        report.ambiguous, report.broken = odo.num_scans - 1 == doubt_at, False
        if report.ambiguous:
            pose = compose(pose, np.asarray(shift, dtype=float))
        return pose, report, searched

    odo._match = doubted
    poses = []
    for k, true in enumerate(path):
        odo.update(make_scan(LOOP, true, stamp=dt * k, sigma=0.01, rng=rng, max_range=max_range))
        poses.append(odo.pose.copy())
    truth, est = np.array(path), np.array(poses)
    miss = between(between(truth[:-1], truth[1:]), between(est[:-1], est[1:]))
    return odo, np.hypot(miss[:, 0], miss[:, 1])


def start_walls_held(odo: LidarOdometry) -> float:
    """The largest log-odds the matched map holds on the first corridor's walls near the
    start (x from -7 to -4), which a 6 m scanner sees only near there."""
    grid = odo.pyramid.finest
    xs = np.arange(-7.0, -4.0, 0.05)
    walls = np.concatenate([np.column_stack([xs, np.full_like(xs, y)]) for y in (-5.0, -2.5)])
    rows, cols = grid.world_to_cell(walls).T
    inside = (rows >= 0) & (rows < grid.shape[0]) & (cols >= 0) & (cols < grid.shape[1])
    return float(grid.logodds[rows[inside], cols[inside]].max(initial=0.0))


def test_the_loop_path_stays_in_the_corridor():
    rng = np.random.default_rng(0)
    for pose in loop_path(1.0, 0.7)[::5]:
        r = make_scan(LOOP, pose, rng=rng).ranges
        assert np.min(r[np.isfinite(r)]) > 0.5


def test_a_wrong_step_the_recent_scans_contradict_replaces_the_map():
    """Sparse scans (a scan per 0.7 m, 3 s apart) of a 6 m scanner around the loop, one
    look-alike 0.3 m sideways taken (flagged ambiguous) and fused: the map of the recent
    scans puts that scan elsewhere, so the map matched against, which now holds the walls
    twice, is replaced by the recent scans' (the walls near the start, seen before, are
    gone from it) and the loop goes on with no other wrong step. The same look-alike at no
    distance (a doubted step that was right) leaves the map as it was: a log tracked well
    gains from its revisits."""
    path = loop_path(0.7, 0.7)
    config = OdometryConfig(submap_travel=10.0)
    wrong, errors = run(config, path, 3.0, doubt_at=21, max_range=6.0, shift=(0.0, 0.3, 0.0))
    assert wrong.num_submaps >= 1 and start_walls_held(wrong) == 0.0
    assert errors[20] > 0.25 and np.sum(errors > 0.1) <= 2, np.nonzero(errors > 0.1)
    right, errors = run(config, path, 3.0, doubt_at=21, max_range=6.0)
    assert right.num_submaps == 0 and start_walls_held(right) > 2.0
    assert np.max(errors) < 0.1


def test_dense_scans_keep_one_map():
    """At a scanner's own rate the scans are not sparse: one map, never replaced, even
    with a step in doubt; the run is the run without submaps."""
    path = [np.array([-6.75 + 0.02 * k, -3.75, 0.0]) for k in range(60)]
    odo, errors = run(OdometryConfig(submap_travel=0.5), path, 0.025, doubt_at=10)
    assert odo._young is None and odo.num_submaps == 0
    assert np.max(errors) < 0.02
    _, without = run(OdometryConfig(submap_travel=0.0), path, 0.025, doubt_at=10)
    np.testing.assert_array_equal(errors, without)
