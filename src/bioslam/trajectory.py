"""A timestamped sequence of SE(2) poses: what readers, the simulator, the pipeline and the
evaluation exchange."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from bioslam.geometry import wrap_angle


@dataclass
class Trajectory:
    """``stamps`` (N,) in seconds, strictly increasing; ``poses`` (N, 3) as (x, y, theta)."""

    stamps: NDArray[np.float64]
    poses: NDArray[np.float64]

    def __post_init__(self) -> None:
        self.stamps = np.asarray(self.stamps, dtype=np.float64).reshape(-1)
        self.poses = np.asarray(self.poses, dtype=np.float64).reshape(-1, 3)
        if self.stamps.shape[0] != self.poses.shape[0]:
            raise ValueError(
                f"{self.stamps.shape[0]} stamps but {self.poses.shape[0]} poses in a trajectory"
            )

    def __len__(self) -> int:
        return int(self.stamps.shape[0])

    @classmethod
    def empty(cls) -> Trajectory:
        return cls(np.zeros(0), np.zeros((0, 3)))

    def path_length(self) -> float:
        """Distance travelled along the positions, metres."""
        if len(self) < 2:
            return 0.0
        return float(np.sum(np.hypot(*np.diff(self.poses[:, :2], axis=0).T)))

    def at(self, stamps: NDArray[np.float64]) -> Trajectory:
        """The poses at ``stamps``, linearly interpolated (the heading the short way round);
        stamps outside the trajectory's span get its first or last pose. For a trajectory on
        its own clock, such as wheel odometry, to be compared pose by pose with the scans'."""
        if len(self) == 0:
            raise ValueError("cannot interpolate an empty trajectory")
        stamps = np.asarray(stamps, dtype=np.float64).reshape(-1)
        heading = np.unwrap(self.poses[:, 2])
        columns = [np.interp(stamps, self.stamps, c) for c in (*self.poses[:, :2].T, heading)]
        columns[2] = wrap_angle(columns[2])
        return Trajectory(stamps, np.column_stack(columns))
