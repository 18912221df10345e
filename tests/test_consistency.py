"""Revisit sharpness: a trajectory judged by how well its map agrees with itself where the robot
came back, with no reference."""

import numpy as np
import pytest
from loop_world import ring_route, ring_world

from bioslam.consistency import RevisitConfig, find_revisits, revisit_residuals
from bioslam.geometry import compose
from bioslam.sim import LIDAR_PRESETS, simulate_scans


@pytest.fixture(scope="module")
def two_laps():
    """Scans and true poses of two laps of the ring corridor (about 53 s a lap)."""
    pairs = list(simulate_scans(ring_world(), LIDAR_PRESETS["urg04lx"], ring_route(laps=2.0),
                                seed=5))  # fmt: skip
    stamps = np.array([scan.stamp for scan, _ in pairs])
    return [scan.endpoints() for scan, _ in pairs], np.array([pose for _, pose in pairs]), stamps


def test_revisits_are_scans_near_another_pass_and_only_those():
    # out along x for 10 s, back for 10 s: only scans of the other leg, 5 s or more away, count
    t = np.arange(0.0, 20.0, 0.1)
    x = np.where(t < 10.0, t, 20.0 - t)
    poses = np.column_stack([x, np.zeros_like(t), np.zeros_like(t)])
    config = RevisitConfig(min_gap_s=5.0, radius_m=0.5, every=1, max_partners=4)
    revisits = find_revisits(poses, t, config)
    judged = {r.scan for r in revisits}
    assert 0 in judged and 190 in judged
    # the turn at 10 s: within 0.5 m of it lie only scans less than 5 s apart
    assert 100 not in judged
    for r in revisits:
        assert 1 <= len(r.partners) <= 4
        assert np.all(np.abs(t[r.partners] - t[r.scan]) >= 5.0)
        assert np.all(np.abs(x[r.partners] - x[r.scan]) <= 0.5)


def test_the_true_poses_make_a_sharper_map_than_a_trajectory_bent_between_the_laps(two_laps):
    endpoints, truth, stamps = two_laps
    revisits = find_revisits(truth, stamps, RevisitConfig(min_gap_s=10.0))
    assert len(revisits) > 50
    # the second lap turned by 2 degrees about the start: 4-31 cm off along the ring
    bent = truth.copy()
    second = stamps >= stamps[-1] / 2
    bent[second] = compose(np.array([0.0, 0.0, np.radians(2.0)]), truth[second])
    true_residual = revisit_residuals(endpoints, truth, revisits)
    bent_residual = revisit_residuals(endpoints, bent, revisits)
    assert np.nanmedian(true_residual) < 0.02  # the scanner's noise, 1-2 cm
    assert np.nanmedian(bent_residual) > 2.0 * np.nanmedian(true_residual)
    judged = ~np.isnan(true_residual)
    assert np.mean(true_residual[judged] < bent_residual[judged]) > 0.9


def test_a_scan_with_too_few_endpoints_in_range_is_not_judged(two_laps):
    endpoints, truth, stamps = two_laps
    revisits = find_revisits(truth, stamps, RevisitConfig(min_gap_s=10.0))
    first = revisits[0].scan
    emptied = list(endpoints)
    emptied[first] = np.zeros((0, 2))
    residual = revisit_residuals(emptied, truth, revisits)
    assert np.isnan(residual[0]) and not np.isnan(residual[1:]).all()


def test_poses_and_stamps_of_different_lengths_are_refused():
    with pytest.raises(ValueError, match="differ in length"):
        find_revisits(np.zeros((3, 3)), np.zeros(2))
