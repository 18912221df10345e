"""Loop-closure candidates and their verification against local submaps (Sec. III-C).

The paper closes a loop when a view cell fires for a place the pose cells agree with. Two
things make that fragile on real robots, and this module is where they are handled:

* **Candidates from two cues.** A boundary view is recognised only within a limited offset of
  where it was learned, while a hand-driven robot returns half a metre off. As an animal's
  path integration says "I am near where I was", the map proposes the nearest experience
  within the odometry's drift bound of the robot's map pose (:func:`nearest_experience`),
  beside the view cells' own candidate. Experiences the robot has just left, or that a short
  chain of links already joins to the current one, are not loops and are not proposed.
* **Verification that look-alikes cannot fool.** A candidate is accepted only after the
  current scan is registered against a *submap* fused from the scans of the experiences
  around the candidate on its own pass (:func:`fuse_submap`): one scan sees a corridor's
  walls but not its end, several scans a metre apart see the doors that tell it from its
  twin. The registration must fit (score), be constrained in every direction (not
  degenerate), stay within what the odometry can have drifted, and be unambiguous (no
  distinct rival pose nearly as good, when the matcher reports one).

No I/O here; :class:`bioslam.slam.BioSLAM` calls these once per look.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from bioslam.geometry import between, transform_points
from bioslam.odometry import RegistrationConfig, register_scans

FloatArray = NDArray[np.float64]


def thin_points(points: FloatArray, spacing: float) -> NDArray[np.float32]:
    """Keep one point per ``spacing``-sized grid cell: a compact scan to store with a place."""
    if points.shape[0] == 0 or spacing <= 0.0:
        return points.astype(np.float32)
    cells = np.floor(points / spacing).astype(np.int64)
    # One integer key per cell (a 1-D unique is far cheaper than a row-wise one).
    keys = (cells[:, 0] << 32) + (cells[:, 1] & 0xFFFFFFFF)
    _, first = np.unique(keys, return_index=True)
    return points[np.sort(first)].astype(np.float32)


def pass_neighbours(
    travelled: FloatArray, anchor: int, reach: float, step: float, before: float
) -> list[int]:
    """The experiences whose scans make ``anchor``'s submap: on its own pass (ids are in
    creation order, ``travelled`` the odometry distance at which each was made,
    non-decreasing), the one nearest each multiple of ``step`` metres of travel within
    ``reach`` of it, made no later than ``before`` metres of travel; ``anchor`` always."""
    centre = travelled[anchor]
    k = int(reach // step) if step > 0 else 0
    targets = centre + step * np.arange(-k, k + 1)
    targets = targets[targets <= before]
    picks = np.clip(np.searchsorted(travelled, targets), 0, travelled.size - 1)
    near = [int(i) for i in picks if abs(travelled[i] - centre) <= reach and travelled[i] <= before]
    return sorted({anchor, *near})


def fuse_submap(
    poses: FloatArray,
    payloads: Sequence[FloatArray | None],
    anchor: int,
    members: Sequence[int],
    spacing: float,
) -> NDArray[np.float32]:
    """The scans stored with ``members`` fused into ``anchor``'s frame, thinned to one point
    per ``spacing`` cell. Members of one pass are related by the odometry over a few metres,
    so their relative map poses are good to the odometry's local accuracy."""
    parts = []
    for m in members:
        scan = payloads[m]
        if scan is None or len(scan) == 0:
            continue
        rel = between(poses[anchor], poses[m])
        parts.append(transform_points(rel, np.asarray(scan, dtype=np.float64)))
    if not parts:
        return np.zeros((0, 2), dtype=np.float32)
    return thin_points(np.concatenate(parts), spacing)


def nearest_experience(
    poses: FloatArray,
    travelled: FloatArray,
    position: FloatArray,
    now: float,
    radius: float,
    min_travel: float,
) -> int | None:
    """The experience nearest ``position`` (map frame) within ``radius`` metres among those
    made at least ``min_travel`` metres of travel ago (a place just left is no loop), or None.
    """
    old = int(np.searchsorted(travelled, now - min_travel, side="right"))
    if old == 0:
        return None
    d = np.hypot(poses[:old, 0] - position[0], poses[:old, 1] - position[1])
    best = int(np.argmin(d))
    return best if d[best] <= radius else None


@dataclass(frozen=True)
class Check:
    """One verification as the system ran it: when (``stamp``), of which experience (and
    when that was made), with which cue ('view' or 'proximity'), and its verdict."""

    stamp: float
    experience: int
    experience_stamp: float
    cue: str
    verdict: Verdict


@dataclass(frozen=True)
class Verdict:
    """The outcome of verifying one candidate: ``pose`` is the robot in the candidate
    experience's frame; ``reason`` says why a candidate was refused ('' when accepted)."""

    accepted: bool
    pose: FloatArray
    score: float
    rival_score: float
    reason: str = ""


def verify(
    reference: FloatArray,
    query: FloatArray,
    predicted: FloatArray,
    window: tuple[float, float],
    min_score: float,
    reject_degenerate: bool,
    registration: RegistrationConfig,
) -> Verdict:
    """Register ``query`` (the current scan, robot frame) against ``reference`` (a submap in
    a candidate experience's frame) around ``predicted`` within ``window`` (m, rad), and judge
    the result: a good score, constrained in every direction, and within the window (a pose
    farther than the odometry can have drifted is a look-alike place)."""
    distance, angle = window
    config = dataclasses.replace(
        registration,
        search_distance=min(registration.search_distance, distance),
        search_angle=min(registration.search_angle, angle),
    )
    pose, quality = register_scans(reference, query, predicted, config)
    correction = between(predicted, pose)
    reason = ""
    if quality.score < min_score:
        reason = "score"
    elif reject_degenerate and quality.degenerate:
        reason = "degenerate"
    elif not within(correction, distance, angle):
        reason = "beyond drift"
    return Verdict(not reason, pose, quality.score, float("nan"), reason)


def within(correction: FloatArray, distance: float, angle: float) -> bool:
    """Whether a pose correction moves by at most ``distance`` metres and ``angle`` radians."""
    return bool(np.hypot(correction[0], correction[1]) <= distance and abs(correction[2]) <= angle)
