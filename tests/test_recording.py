"""Watching a run: the pipeline's per-scan observer, the MCAP recorder and the live server."""

from __future__ import annotations

import numpy as np
import pytest
from loop_world import ring_route, ring_world

from bioslam.pipeline import RunOptions, run_slam
from bioslam.sim import LIDAR_PRESETS, simulate_scans


@pytest.fixture(scope="module")
def ring_scans():
    """Two laps of the ring corridor: a run that makes experiences and closes loops."""
    route = ring_route(laps=2.0)
    pairs = simulate_scans(ring_world(), LIDAR_PRESETS["urg04lx"], route, seed=3)
    return [scan for scan, _ in pairs]


def test_observer_sees_every_scan_in_order_with_the_pose_process_returned(ring_scans):
    scans = ring_scans[:80]
    seen: list[tuple[float, np.ndarray, np.ndarray]] = []

    def observer(scan, pose, system):
        seen.append((scan.stamp, np.asarray(pose, dtype=float), system.self_motion.pose.copy()))

    result = run_slam(scans, options=RunOptions(progress=False, warm_up=False), observer=observer)
    assert [s for s, _, _ in seen] == [scan.stamp for scan in scans]
    odometry = result.system.odometry_trajectory()
    np.testing.assert_allclose(np.array([o for _, _, o in seen]), odometry.poses)
    # the last pose seen is the system's estimate at the last scan
    np.testing.assert_allclose(seen[-1][1], result.system.trajectory().poses[-1], atol=1e-9)
