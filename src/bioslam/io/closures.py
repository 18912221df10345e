"""``closures.csv``: every loop-closure verification a run made, accepted or refused.

One row per check (:class:`bioslam.closure.Check`), in the order they ran: ``stamp`` (s),
the ``experience`` checked and when it was made (``experience_stamp``), the ``cue`` that
proposed it (``view`` or ``proximity``), ``accepted`` (1/0), the ``reason`` for a refusal
(``score``, ``degenerate``, ``ambiguous``, ``slid``, ``beyond drift``, ``odometry broke``,
``unconfirmed``; empty when accepted), the registration's ``score`` (share of the scan's
points on the place's submap; empty for a check refused before it registered) and
``ambiguity`` (the best distinct rival's score over the best's), and the measured pose of the
robot in the experience's frame (``x``, ``y`` in m, ``theta_deg``). With a reference
trajectory two columns say how far that measurement is from the reference's relative pose
between the two stamps (``reference_error_m``, ``reference_error_deg``; empty where the
reference has no pose near a stamp): a closure far off it is a false one, or the reference's
own error. Two more say the same of the run's odometry between the same two stamps
(``odometry_reference_error_m``, ``odometry_reference_error_deg``), the odometry's own relative
pose judged as the closure is: where both are off alike, it is the reference that is (a
corrected log's poses carry their own centimetres, and a closure cannot be judged below
them).
"""

from __future__ import annotations

import csv
import math
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from bioslam.io.jsonio import atomic_path

if TYPE_CHECKING:
    from bioslam.closure import Check

HEADER = (
    "stamp", "experience", "experience_stamp", "cue", "accepted", "reason", "score",
    "ambiguity", "x", "y", "theta_deg",
)  # fmt: skip
REFERENCE_COLUMNS = ("reference_error_m", "reference_error_deg")
ODOMETRY_COLUMNS = ("odometry_reference_error_m", "odometry_reference_error_deg")


def _number(value: float, digits: int) -> str:
    return "" if not math.isfinite(value) else f"{value:.{digits}f}"


def check_row(check: Check) -> list[str]:
    """One check's columns of :data:`HEADER`."""
    v = check.verdict
    x, y, theta = (float(c) for c in np.asarray(v.pose, dtype=np.float64).reshape(3))
    return [
        f"{check.stamp:.6f}", str(check.experience), f"{check.experience_stamp:.6f}",
        check.cue, str(int(v.accepted)), v.reason, _number(v.score, 4),
        _number(v.ambiguity, 4), _number(x, 4), _number(y, 4),
        _number(math.degrees(theta), 3),
    ]  # fmt: skip


def write_closures(
    path: str | Path,
    checks: Sequence[Check],
    reference_errors: NDArray | None = None,
    odometry_errors: NDArray | None = None,
) -> None:
    """Write the table (atomically, like the trajectories); ``reference_errors`` (N, 2: m,
    degrees, :func:`bioslam.evaluation.relative_pose_errors`) adds the reference columns, and
    ``odometry_errors`` (the same of the odometry's relative poses between each check's two
    stamps) the odometry's beside them."""
    columns = [errors for errors in (reference_errors, odometry_errors) if errors is not None]
    header = HEADER + (REFERENCE_COLUMNS if reference_errors is not None else ())
    header += ODOMETRY_COLUMNS if odometry_errors is not None else ()
    with atomic_path(path) as tmp, open(tmp, "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(header)
        for k, check in enumerate(checks):
            row = check_row(check)
            for errors in columns:
                metres, degrees = (float(e) for e in errors[k])
                row += [_number(metres, 4), _number(degrees, 3)]
            writer.writerow(row)


def read_closures(path: str | Path) -> list[dict[str, str]]:
    """The table's rows, as the strings written."""
    with open(path, newline="") as f:
        return list(csv.DictReader(f))
