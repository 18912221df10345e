"""TUM trajectory files: ``t x y z qx qy qz qw`` per line, as evo and most tools read them."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from bioslam.geometry import quaternion_to_yaw, yaw_to_quaternion
from bioslam.io.jsonio import atomic_path
from bioslam.trajectory import Trajectory


def write_tum(path: str | Path, trajectory: Trajectory) -> None:
    """Write one line per pose (z = 0, rotation about +z), atomically: a full disk or an
    interruption leaves the previous file or none, never a truncated one."""
    q = yaw_to_quaternion(trajectory.poses[:, 2]).reshape(-1, 4)
    table = np.column_stack(
        [trajectory.stamps, trajectory.poses[:, :2], np.zeros(len(trajectory)), q]
    )
    with atomic_path(path) as tmp:
        np.savetxt(tmp, table, fmt=["%.9f"] + ["%.6f"] * 3 + ["%.9f"] * 4)


def read_tum(path: str | Path) -> Trajectory:
    """Read a TUM file; ``#`` comments and blank lines are ignored.

    Raises ``ValueError`` naming the file and line for a malformed row, a value that is not
    finite (NaN, inf) or a stamp not later than the previous one: evaluation against such a
    trajectory would be meaningless, and the line number is what the user needs to fix it.
    """
    path = Path(path)
    rows: list[list[float]] = []
    previous = (-math.inf, 0)
    with path.open(encoding="latin-1") as fh:
        for lineno, line in enumerate(fh, start=1):
            text = line.strip()
            if not text or text.startswith("#"):
                continue
            row = _parse_row(text, f"{path}:{lineno}")
            if not row[0] > previous[0]:
                raise ValueError(
                    f"{path}:{lineno}: stamp {row[0]:.9f} s is not later than "
                    f"{previous[0]:.9f} s on line {previous[1]}"
                )
            previous = (row[0], lineno)
            rows.append(row)
    if not rows:
        return Trajectory.empty()
    table = np.asarray(rows)
    yaw = quaternion_to_yaw(table[:, 4:8])
    return Trajectory(table[:, 0], np.column_stack([table[:, 1:3], yaw]))


def _parse_row(text: str, where: str) -> list[float]:
    fields = text.replace(",", " ").split()
    if len(fields) != 8:
        raise ValueError(f"{where}: expected 8 fields in a TUM line, got {len(fields)}")
    try:
        row = [float(f) for f in fields]
    except ValueError as exc:
        raise ValueError(f"{where}: {exc}") from None
    if not all(math.isfinite(v) for v in row):
        raise ValueError(f"{where}: value not finite (NaN or inf) in {text[:80]!r}")
    if not any(row[4:8]):
        raise ValueError(f"{where}: zero quaternion (no rotation can be read from it)")
    return row
