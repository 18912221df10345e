"""TUM trajectory files: ``t x y z qx qy qz qw`` per line, as evo and most tools read them."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bioslam.geometry import quaternion_to_yaw, yaw_to_quaternion
from bioslam.trajectory import Trajectory


def write_tum(path: str | Path, trajectory: Trajectory) -> None:
    """Write one line per pose (z = 0, rotation about +z)."""
    q = yaw_to_quaternion(trajectory.poses[:, 2]).reshape(-1, 4)
    table = np.column_stack(
        [trajectory.stamps, trajectory.poses[:, :2], np.zeros(len(trajectory)), q]
    )
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    np.savetxt(path, table, fmt=["%.9f"] + ["%.6f"] * 3 + ["%.9f"] * 4)


def read_tum(path: str | Path) -> Trajectory:
    """Read a TUM file; ``#`` comments and blank lines are ignored.

    Raises ``ValueError`` naming the file and line for a malformed row.
    """
    path = Path(path)
    rows: list[list[float]] = []
    with path.open() as fh:
        for lineno, line in enumerate(fh, start=1):
            text = line.strip()
            if not text or text.startswith("#"):
                continue
            fields = text.replace(",", " ").split()
            if len(fields) != 8:
                raise ValueError(
                    f"{path}:{lineno}: expected 8 fields in a TUM line, got {len(fields)}"
                )
            try:
                rows.append([float(f) for f in fields])
            except ValueError as exc:
                raise ValueError(f"{path}:{lineno}: {exc}") from None
    if not rows:
        return Trajectory.empty()
    table = np.asarray(rows)
    yaw = quaternion_to_yaw(table[:, 4:8])
    return Trajectory(table[:, 0], np.column_stack([table[:, 1:3], yaw]))
