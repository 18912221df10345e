"""The odometry's per-scan covariance (``MatchReport.covariance``) and its CSV file: large along
a corridor's axis, small and round in a closed room."""

from __future__ import annotations

import math

import numpy as np
import pytest
from _scan_world import CORRIDOR, ROOM, make_scan

from bioslam.io.uncertainty import read_uncertainty, weakest_horizontal, write_uncertainty
from bioslam.odometry import LidarOdometry
from bioslam.slam import MatchUncertainty


def _drive(world, heading: float, steps: int = 40) -> MatchUncertainty:
    """0.5 m/s along x at a fixed ``heading`` (the map frame is the first scan's, so the
    world's x axis lies at ``-heading`` in it), with 1 cm range noise."""
    rng = np.random.default_rng(4)
    odo = LidarOdometry()
    table = MatchUncertainty()
    for k in range(steps):
        pose = (-2.0 + 0.05 * k, 0.3, heading)
        odo.update(make_scan(world, pose, stamp=0.1 * k, sigma=0.01, rng=rng))
        table.append(odo.last_report)
    return table


def _smallest_std(cov: np.ndarray) -> np.ndarray:
    """The smaller principal standard deviation of each (x, y) block."""
    xx, xy, yy = cov[:, 0], cov[:, 1], cov[:, 3]
    return np.sqrt(0.5 * (xx + yy) - np.hypot(0.5 * (xx - yy), xy))


def _axis_error(angle_deg: float, expected_deg: float) -> float:
    return abs((angle_deg - expected_deg + 90.0) % 180.0 - 90.0)


@pytest.mark.parametrize("heading", [0.0, 0.5])
def test_a_corridor_reports_its_axis_as_the_weakest_direction(heading):
    table = _drive(CORRIDOR, heading)
    covariances, flags = table.arrays()
    cov = covariances[-10:]
    assert np.all(flags[-10:] & 1)  # degenerate
    angle, std = weakest_horizontal(cov)
    assert np.all([_axis_error(a, -math.degrees(heading)) < 3.0 for a in angle]), angle
    across = _smallest_std(cov)
    assert np.all(across < 0.01), across
    assert np.all(std > 5.0 * across), (std, across)


def test_a_closed_room_is_pinned_down_in_every_direction():
    table = _drive(ROOM, 0.2)
    covariances, flags = table.arrays()
    cov = covariances[1:]  # the first scan only starts the map
    assert not np.any(flags[1:])
    assert np.all(np.isnan(covariances[0]))
    small = _smallest_std(cov)
    _, large = weakest_horizontal(cov)
    assert np.all(large < 0.003), large
    assert np.all(large < 2.0 * small), (large, small)
    assert np.all(np.sqrt(cov[:, 5]) < math.radians(0.5))
    assert np.all(np.isfinite(cov))


def test_the_file_has_a_row_per_scan_and_reads_back(tmp_path):
    table = _drive(CORRIDOR, 0.0, steps=12)
    covariances, flags = table.arrays()
    stamps = 0.1 * np.arange(12)
    write_uncertainty(tmp_path / "u.csv", stamps, covariances, flags)
    rows = read_uncertainty(tmp_path / "u.csv")
    assert rows.shape == (12, 12)
    np.testing.assert_allclose(rows[:, 0], stamps)
    np.testing.assert_allclose(rows[1:, 1:7], covariances[1:], rtol=5e-3)
    assert np.array_equal(rows[:, 9:].astype(int), (flags[:, None] >> np.arange(3)) & 1)
    # ~100 bytes a scan at most
    assert (tmp_path / "u.csv").stat().st_size < 100 * 13
