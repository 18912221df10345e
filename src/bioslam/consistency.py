"""How well a trajectory makes a map agree with itself where the robot came back: a measure of
map quality that needs no reference.

An ATE against a log's "corrected" poses measures that reference's errors as much as the
estimate's (freiburg-079's own 1 m RPE is about twice bioslam's odometry's, by a three-cornered
hat). Where the robot passed a place twice, though, the scans of the two passes see the same
walls: placed by a trajectory that is right, their endpoints fall on one another; placed by
one that is off between the passes, they stand apart by its error. So for scans at a revisit
the median distance from their endpoints to the nearest endpoint of the other pass's scans
says how consistent the trajectory is there, and two trajectories compared on the same scans
say which of them the scans themselves agree with better (the 2D analogue of the mean map
entropy of Razlaw et al. 2015, for point clouds).

The revisits are chosen once, from one trajectory (a reference when there is one), and every
trajectory is judged on the same scans.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from bioslam.geometry import transform_points

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.intp]


@dataclass(frozen=True)
class RevisitConfig:
    """Which scans are judged and against what.

    min_gap_s: another pass is a scan at least this many seconds away (the scans just before
        and after belong to the same pass, and agree whatever the trajectory's error).
    radius_m: ... whose pose is at most this far from the judged scan's.
    max_range_m: the judged scan's endpoints within this range (far ones are sparse, and a small
        heading error moves them far).
    every: judge every n-th scan.
    max_partners: at most this many scans of the other passes, evenly chosen.
    min_points: a scan with fewer endpoints in range is not judged.
    """

    min_gap_s: float = 30.0
    radius_m: float = 3.0
    max_range_m: float = 8.0
    every: int = 5
    max_partners: int = 20
    min_points: int = 30

    def __post_init__(self) -> None:
        if self.every < 1 or self.max_partners < 1:
            raise ValueError("every and max_partners must be at least 1")
        if not (self.radius_m > 0.0 and self.max_range_m > 0.0 and self.min_gap_s >= 0.0):
            raise ValueError("radius_m and max_range_m must be positive, min_gap_s not negative")


@dataclass(frozen=True)
class Revisit:
    """A judged scan and the scans of other passes it is compared with (indices)."""

    scan: int
    partners: IntArray


def _ceil_div(a: int, b: int) -> int:
    return -(-a // b)


def _evenly(items: IntArray, most: int) -> IntArray:
    """At most ``most`` of ``items``, evenly chosen (every n-th, from the first)."""
    return items[:: _ceil_div(items.size, most)]


def find_revisits(
    poses: ArrayLike, stamps: ArrayLike, config: RevisitConfig | None = None
) -> list[Revisit]:
    """The scans (every ``config.every``-th) that have scans of another pass near them, with
    those scans: ``poses`` (N, 3) and ``stamps`` (N,) place and time each scan."""
    cfg = config or RevisitConfig()
    xy = np.asarray(poses, dtype=np.float64).reshape(-1, 3)[:, :2]
    t = np.asarray(stamps, dtype=np.float64).reshape(-1)
    if len(t) != len(xy):
        raise ValueError(f"poses and stamps differ in length: {len(xy)}, {len(t)}")
    found = []
    for i in range(0, len(t), cfg.every):
        near = np.hypot(*(xy - xy[i]).T) <= cfg.radius_m
        other = np.flatnonzero(near & (np.abs(t - t[i]) >= cfg.min_gap_s))
        if other.size:
            found.append(Revisit(i, _evenly(other, cfg.max_partners)))
    return found


def revisit_residuals(
    endpoints: Sequence[ArrayLike] | Mapping[int, ArrayLike],
    poses: ArrayLike,
    revisits: Sequence[Revisit],
    config: RevisitConfig | None = None,
) -> FloatArray:
    """For each revisit, the median distance (m) from the judged scan's endpoints (robot frame,
    ``endpoints[i]`` (M, 2); a mapping may hold only the scans the revisits name) to the
    nearest endpoint of its partners, every scan placed by ``poses`` (N, 3); NaN where the
    scan has too few endpoints in range."""
    from scipy.spatial import cKDTree

    cfg = config or RevisitConfig()
    placed = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
    out = np.full(len(revisits), np.nan)
    # a scan is the partner of many judged ones: placed once
    partner_points: dict[int, FloatArray] = {}

    def partner(j: int) -> FloatArray:
        if j not in partner_points:
            points = np.asarray(endpoints[j], dtype=np.float64).reshape(-1, 2)
            partner_points[j] = transform_points(placed[j], points)
        return partner_points[j]

    for k, revisit in enumerate(revisits):
        own = np.asarray(endpoints[revisit.scan], dtype=np.float64).reshape(-1, 2)
        own = own[np.hypot(own[:, 0], own[:, 1]) <= cfg.max_range_m]
        if len(own) < cfg.min_points:
            continue
        others = [o for o in (partner(int(j)) for j in revisit.partners) if len(o)]
        if not others:
            continue
        distances, _ = cKDTree(np.vstack(others)).query(transform_points(placed[revisit.scan], own))
        out[k] = float(np.median(distances))
    return out


def merge_revisits(*found: Sequence[Revisit], max_partners: int) -> list[Revisit]:
    """The revisits of several :func:`find_revisits` calls (e.g. on two trajectories of the
    same scans) as one list, each judged scan once with the partners any of them gave it (at
    most ``max_partners``, evenly chosen): two trajectories compared on the revisits one of
    them alone finds are judged where that one brought the passes together."""
    partners: dict[int, set[int]] = {}
    for revisits in found:
        for revisit in revisits:
            partners.setdefault(revisit.scan, set()).update(int(j) for j in revisit.partners)
    merged = []
    for scan in sorted(partners):
        merged.append(Revisit(scan, _evenly(np.array(sorted(partners[scan]), dtype=np.intp),
                                            max_partners)))
    return merged


@dataclass(frozen=True)
class SharpnessComparison:
    """Two placements of the same scans judged at their revisits: the median residual (m) of
    each, the revisits judged, and the one-sided p-value of the Wilcoxon signed-rank test
    that the second places them sharper (1 where the two never differ)."""

    median_first: float
    median_second: float
    judged: int
    p_second_sharper: float


def compare_sharpness(
    endpoints: Sequence[ArrayLike] | Mapping[int, ArrayLike],
    stamps: ArrayLike,
    first: ArrayLike,
    second: ArrayLike,
    config: RevisitConfig | None = None,
    max_judged: int = 400,
) -> SharpnessComparison:
    """Whether the scans (``endpoints``, at ``stamps``) agree better placed by the poses
    ``second`` than by ``first`` (each (N, 3)), on the revisits either placement finds
    (:func:`merge_revisits`), at most about ``max_judged`` of them (every n-th scan judged
    as needed: the test's cost grows with them, its power hardly past a few hundred)."""
    from scipy.stats import wilcoxon

    cfg = config or RevisitConfig()
    t = np.asarray(stamps, dtype=np.float64).reshape(-1)
    cfg = replace(cfg, every=max(cfg.every, _ceil_div(t.size, max(max_judged, 1))))
    revisits = merge_revisits(
        find_revisits(first, t, cfg), find_revisits(second, t, cfg),
        max_partners=cfg.max_partners,
    )  # fmt: skip
    a = revisit_residuals(endpoints, first, revisits, cfg)
    b = revisit_residuals(endpoints, second, revisits, cfg)
    both = ~(np.isnan(a) | np.isnan(b))
    a, b = a[both], b[both]
    if not a.size:
        return SharpnessComparison(math.nan, math.nan, 0, 1.0)
    differ = a != b
    p = 1.0
    if differ.any():
        p = float(wilcoxon(a[differ] - b[differ], alternative="greater").pvalue)
    return SharpnessComparison(float(np.median(a)), float(np.median(b)), int(a.size), p)
