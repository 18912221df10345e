"""Trajectory: interpolation at other stamps."""

from __future__ import annotations

import numpy as np
import pytest

from bioslam.trajectory import Trajectory


def test_at_interpolates_position_and_turns_the_short_way_across_pi():
    traj = Trajectory(
        np.array([0.0, 1.0, 2.0]),
        np.array([[0.0, 0.0, 3.0], [1.0, 2.0, -3.0], [3.0, 2.0, -2.5]]),
    )
    mid = traj.at(np.array([0.5, 1.5, -1.0, 9.0]))
    assert mid.poses[0, :2] == pytest.approx([0.5, 1.0])
    # from 3.0 to -3.0 rad is 0.28 rad through pi, not 6 rad through zero
    assert abs(mid.poses[0, 2]) == pytest.approx(np.pi, abs=1e-9)
    assert mid.poses[1] == pytest.approx([2.0, 2.0, -2.75])
    assert mid.poses[2] == pytest.approx(traj.poses[0])
    assert mid.poses[3] == pytest.approx(traj.poses[2])
    with pytest.raises(ValueError, match="empty"):
        Trajectory.empty().at(np.array([0.0]))
