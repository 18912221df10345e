"""End-to-end: the whole system on a short simulated drive that must close a loop."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from loop_world import ring_route, ring_world

from bioslam.config import SLAMConfig, config_from_dict
from bioslam.evaluation import ate
from bioslam.sim import LIDAR_PRESETS, simulate_scans
from bioslam.slam import BioSLAM, thin_points
from bioslam.trajectory import Trajectory


@pytest.fixture(scope="module")
def ring_drive() -> tuple[list, Trajectory]:
    route = ring_route(laps=2.0)
    scans, poses = [], []
    for scan, pose in simulate_scans(ring_world(), LIDAR_PRESETS["urg04lx"], route, seed=3):
        scans.append(scan)
        poses.append(pose)
    return scans, Trajectory(np.array([s.stamp for s in scans]), np.array(poses))


def run(scans: list, config: SLAMConfig) -> BioSLAM:
    slam = BioSLAM(config)
    for scan in scans:
        slam.process(scan)
    slam.finish()
    return slam


def test_loop_closes_and_pulls_injected_drift_back(ring_drive):
    scans, gt = ring_drive
    # A gyro-like heading bias makes the odometry drift by ~6° per lap, so the second lap
    # arrives visibly off the first; recognising the places must pull it back.
    config = dataclasses.replace(SLAMConfig(), heading_bias=0.002)
    slam = run(scans, config)
    summary = slam.summary()
    assert summary["loop_closures"] >= 1
    full = ate(slam.trajectory(), gt)["rmse"]
    odometry = ate(slam.odometry_trajectory(), gt)["rmse"]
    assert odometry > 0.1, "the injected drift should be large"
    assert full < 0.5 * odometry
    assert len(slam.trajectory()) == len(scans)
    # Closures make experiences too (the robot's pose, linked to the recognised one): the
    # travel at which each was made must be known, in order, for the closure cues' searches.
    made_at = slam._made_at[: summary["experiences"]]
    assert np.all(np.isfinite(made_at)) and np.all(np.diff(made_at) >= 0.0)


def test_drift_free_run_stays_accurate(ring_drive):
    scans, gt = ring_drive
    slam = run(scans, SLAMConfig())
    assert ate(slam.trajectory(), gt)["rmse"] < 0.05
    records = slam.records
    assert records[0].view_is_new and records[0].event == "new"
    # The second lap re-recognises views learned on the first.
    revisits = [r for r in records[len(records) // 2 + 50 :] if not r.view_is_new]
    assert len(revisits) > 0.3 * (len(records) // 2 - 50)


def test_config_overrides_are_checked():
    cfg = config_from_dict({"loop_closure": {"min_score": 0.9}, "heading_bias": 0.001})
    assert cfg.loop_closure.min_score == 0.9 and cfg.heading_bias == 0.001
    with pytest.raises(ValueError, match=r"unknown setting 'views\.nope'"):
        config_from_dict({"views": {"nope": 1}})


def test_thin_points_keeps_one_point_per_cell():
    pts = np.array([[0.01, 0.01], [0.02, 0.03], [0.06, 0.0], [1.0, 1.0]])
    kept = thin_points(pts, 0.05)
    assert kept.shape == (3, 2)
    assert np.allclose(kept[0], pts[0])


def test_step_records_are_a_sequence_of_the_records_appended():
    from bioslam.slam import StepRecord, StepRecords

    made = [StepRecord(0.5 * k, k % 3, k % 2 == 0, StepRecords.EVENTS[k % 4], k - 1)
            for k in range(2000)]  # fmt: skip
    records = StepRecords()
    for record in made:
        records.append(record)
    assert len(records) == 2000 and list(records) == made
    assert records[-1] == made[-1] and records[10:13] == made[10:13]
    np.testing.assert_array_equal(records.view_ids.view(), [r.view_id for r in made])
    with pytest.raises(IndexError):
        records[2000]
