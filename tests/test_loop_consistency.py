"""The loop-consistency measures for logs without a reference (benchmarks/loop_consistency.py):
the return misfit must tell a trajectory that drifted from one that came back to another
place than it started."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest
from loop_world import ring_route, ring_world

from bioslam.geometry import compose
from bioslam.sim import LIDAR_PRESETS, simulate_scans
from bioslam.trajectory import Trajectory

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from loop_consistency import loop_gap, return_misfit


@pytest.fixture(scope="module")
def once_round():
    """Most of a lap of the ring corridor: scans and the true poses, the route ending 0.7 m
    short of where it started (a handheld scanner brought back near, not onto, its start)."""
    world = ring_world()
    pairs = list(simulate_scans(world, LIDAR_PRESETS["utm30lx"], ring_route(laps=0.97), seed=3))
    scans = [scan for scan, _ in pairs]
    truth = Trajectory(np.array([s.stamp for s in scans]), np.array([p for _, p in pairs]))
    return scans, truth


def test_a_true_trajectory_has_no_return_misfit_though_its_loop_gap_is_not_zero(once_round):
    scans, truth = once_round
    misfit = return_misfit(truth, scans)
    assert misfit["misfit_m"] < 0.03 and misfit["misfit_deg"] < 1.0
    assert loop_gap(truth)["loop_gap_m"] > 0.5


def test_a_drift_at_the_return_is_measured_as_such(once_round):
    scans, truth = once_round
    # the last quarter of the lap displaced by 0.3 m and 4 deg, as a drifting odometry would
    poses = truth.poses.copy()
    bend = np.array([0.0, 0.3, math.radians(4.0)])
    late = np.arange(len(poses)) >= 3 * len(poses) // 4
    poses[late] = [compose(bend, p) for p in poses[late]]
    misfit = return_misfit(Trajectory(truth.stamps, poses), scans)
    # the bend is about the map origin; what the return sees is its effect at the return pose
    j = int(np.argmin(np.hypot(*(poses[late, :2] - poses[0, :2]).T)))
    shift = np.hypot(*(poses[late][j, :2] - truth.poses[late][j, :2]))
    assert abs(misfit["misfit_m"] - shift) < 0.05
    assert abs(misfit["misfit_deg"] - 4.0) < 1.0
