"""LiDAR boundary cells (paper Sec. III-B, Eq. 5).

Each boundary cell has a receptive field centred at ``(d_i, alpha_i)`` in the robot's egocentric
polar frame. The fields lie on concentric rings (the paper's Fig. 2): every ring holds the same
number of cells, evenly spaced in angle, with cell 0 of every ring facing forward. Cell ``k`` of
ring ``r`` is element ``r * cells_per_ring + k`` of the activity vector ``B``.

The activity of one scan is the sum of Eq. 5 over all valid endpoints. Two choices the paper
leaves open, documented here:

* Truncation: a field is evaluated for a point only when the point lies within
  ``cutoff_sigmas`` widths of it in distance and in angle; beyond 2 widths a Gaussian of the
  form ``exp(-(x/sigma)^2)`` is below 1.8 % of its peak (1.3e-4 beyond 3). Place recognition
  measured the same with 2 as with 3 (``benchmarks/bench_views.py``: precision 99.5 %,
  recall 86.6 vs 86.5 %, the same tolerance to offsets) and B costs 28 % less.
* Beam-density weighting: a plain sum over endpoints grows with the number of beams, so the
  same room gives a 4x larger ``B`` to a 0.25 deg scanner than to a 1 deg one, and the view
  thresholds of Eq. 6-9 would have to be retuned per sensor. Each endpoint is therefore weighted
  by ``beam_spacing / reference_beam_spacing`` (default reference 1 deg), which leaves Eq. 5
  exactly as printed for a 1 deg scanner and makes ``B`` an angular integral otherwise.
  Set ``weight_by_beam_spacing=False`` for the paper's unweighted sum.
* Distance gain (a deviation, on by default): after the sum, cell ``i`` is multiplied by its
  ring distance ``d_i``. Eq. 5's ``1/d`` makes a wall at 0.7 m fire ten times more than one at
  7 m, so the mean squared difference of Eq. 8 only sees the nearest walls: a corridor looks
  the same wherever one stands in it, and a view matched scans up to 2.5 m away on the
  simulated maze. With the gain every ring weighs alike in Eq. 8 while each ring keeps Eq. 5's
  shape; matches beyond 0.5 m along a corridor all but vanished. ``distance_gain=False`` gives
  Eq. 5 exactly.

Cells whose field lies outside the sensor's field of view (or beyond its range) receive no
endpoints and stay silent, so 180, 240, 270 and 360 deg scanners all share one layout.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numba import njit
from numpy.typing import NDArray

from bioslam.compiled import wrap_scalar
from bioslam.geometry import wrap_angle
from bioslam.scan import LaserScan

FloatArray = NDArray[np.float64]


def geometric_rings(first: float, last: float, count: int) -> tuple[float, ...]:
    """``count`` ring distances from ``first`` to ``last`` metres, evenly spaced in log-distance.

    With the field width linear in distance (Eq. 5), log spacing makes neighbouring rings overlap
    by the same fraction at every distance.
    """
    if not (0.0 < first < last) or count < 2:
        raise ValueError(f"need 0 < first < last and count >= 2, got {first}, {last}, {count}")
    return tuple(float(d) for d in np.geomspace(first, last, count))


def linear_rings(first: float, last: float, spacing: float) -> tuple[float, ...]:
    """Ring distances from ``first`` to ``last`` metres (inclusive), ``spacing`` apart."""
    if not (0.0 < first <= last) or spacing <= 0.0:
        raise ValueError(f"need 0 < first <= last and spacing > 0, got {first}, {last}, {spacing}")
    count = math.floor((last - first) / spacing + 1e-9) + 1
    return tuple(float(first + k * spacing) for k in range(count))


@dataclass(frozen=True)
class BoundaryCellConfig:
    """Layout and tuning of the boundary cells.

    Attributes:
        ring_distances: ring radii ``d_i`` in metres. Default: 28 rings every 0.5 m from 1.5 m
            to 15 m. 15 m is the scale of rooms and corridors that tell places apart (the
            paper's maze is 16.8 m x 12.6 m) and within the 30 m of a UTM-30LX; a short-range
            sensor (5.6 m URG-04LX) simply leaves the outer rings silent. Evenly spaced rings
            resolve the distance to a corridor's end as finely at 10 m as at 2 m, which is
            what tells places along a corridor apart; log-spaced rings did worse on the maze.
            No rings nearer than 1.5 m: the walls beside the robot say little about where it
            is, yet their cells change fastest when it moves, and with rings at 0.5 m and
            1 m they made up 90 % of ``S`` for a 5 cm sideways offset, so a place was
            recognised only within 2 cm of where its view was learned. Without them it is
            recognised 5 cm sideways in 86 % of cases (0 % before) at the same precision
            (``benchmarks/bench_views.py``, section 5).
        cells_per_ring: cells per ring; sets the angular spacing ``2 pi / cells_per_ring``.
            Default 36 (10 deg): fine enough to separate corridor openings, coarse enough that
            a view is still recognised a few degrees off (72 did no better on the maze).
        sigma_d_ratio, sigma_d_offset: ``sigma_{d_i} = sigma_d_offset + sigma_d_ratio * d_i``,
            linear in ``d_i`` as the paper asks. Defaults 0.1 and 0.1 m: 0.15 m at the first
            ring and 1.6 m at the last. A wall midway between the first two rings still drives
            a cell at 0.21 of its on-ring peak (0.02 without the offset), and further out the
            rings overlap more and more.
        sigma_alpha_scale: ``sigma_alpha = sigma_alpha_scale * 2 pi / cells_per_ring`` (the
            paper: set by the number of cells per ring). Default 1.0: neighbouring cells overlap
            at ``exp(-1)`` of the peak, so activity moves smoothly as the robot turns.
        cutoff_sigmas: fields are evaluated only within this many widths of a point (see the
            module docstring). Default 2.
        min_distance: endpoints closer than this (metres) are ignored; they are robot-body hits
            and would dominate through the ``1/d`` factor. Default 0.1 m.
        weight_by_beam_spacing: weight endpoints by their beam spacing (module docstring).
        reference_beam_spacing: the spacing, radians, whose weight is 1. Default 1 deg.
        distance_gain: multiply cell ``i`` by ``d_i`` (module docstring); False is Eq. 5.
    """

    ring_distances: tuple[float, ...] = field(default_factory=lambda: linear_rings(1.5, 15.0, 0.5))
    cells_per_ring: int = 36
    sigma_d_ratio: float = 0.1
    sigma_d_offset: float = 0.1
    sigma_alpha_scale: float = 1.0
    cutoff_sigmas: float = 2.0
    min_distance: float = 0.1
    weight_by_beam_spacing: bool = True
    reference_beam_spacing: float = math.radians(1.0)
    distance_gain: bool = True

    def __post_init__(self) -> None:
        d = np.asarray(self.ring_distances, dtype=np.float64)
        if d.ndim != 1 or d.size == 0 or np.any(d <= 0) or np.any(np.diff(d) <= 0):
            raise ValueError(f"ring_distances must be positive and increasing, got {d}")
        if self.cells_per_ring < 1:
            raise ValueError(f"cells_per_ring must be >= 1, got {self.cells_per_ring}")
        for name in ("sigma_d_ratio", "sigma_alpha_scale", "cutoff_sigmas"):
            if getattr(self, name) <= 0:
                raise ValueError(f"{name} must be positive, got {getattr(self, name)}")
        if self.sigma_d_offset < 0:
            raise ValueError(f"sigma_d_offset must be >= 0, got {self.sigma_d_offset}")
        if self.reference_beam_spacing <= 0:
            raise ValueError("reference_beam_spacing must be positive")

    @property
    def num_cells(self) -> int:
        """``M`` of Eq. 6 and Eq. 8."""
        return len(self.ring_distances) * self.cells_per_ring

    @property
    def sigma_alpha(self) -> float:
        return self.sigma_alpha_scale * 2.0 * math.pi / self.cells_per_ring

    def sigma_d(self) -> FloatArray:
        d = np.asarray(self.ring_distances, dtype=np.float64)
        return self.sigma_d_offset + self.sigma_d_ratio * d

    def cell_angles(self) -> FloatArray:
        """Receptive-field centre angles of one ring, radians in ``(-pi, pi]``."""
        a = 2.0 * np.pi * np.arange(self.cells_per_ring) / self.cells_per_ring
        return wrap_angle(a)

    def cell_centres(self) -> tuple[FloatArray, FloatArray]:
        """``(d_i, alpha_i)`` of every cell, in activity-vector order."""
        d = np.repeat(np.asarray(self.ring_distances, dtype=np.float64), self.cells_per_ring)
        a = np.tile(self.cell_angles(), len(self.ring_distances))
        return d, a


@njit(cache=True)
def boundary_cell_update(
    d: float, alpha: float, d_i: float, alpha_i: float, sigma_d: float, sigma_alpha: float
) -> float:
    """Eq. 5: activity update of the cell centred at ``(d_i, alpha_i)`` from one endpoint.

    ``1/d * exp(-((d - d_i)/sigma_d)^2) * exp(-((alpha - alpha_i)/sigma_alpha)^2)``, with the
    angle difference wrapped to ``(-pi, pi]`` so that fields straddling the rear are continuous.
    """
    rd = (d - d_i) / sigma_d
    ra = wrap_scalar(alpha - alpha_i) / sigma_alpha
    return math.exp(-rd * rd - ra * ra) / d


@njit(cache=True, fastmath=True)
def _accumulate(
    d: FloatArray,
    alpha: FloatArray,
    weight: float,
    rings: FloatArray,
    sigma_d: FloatArray,
    n_cells: int,
    sigma_alpha: float,
    cutoff: float,
    reach_lo: FloatArray,
    reach_hi: FloatArray,
    sorted_reach: bool,
) -> FloatArray:
    # Eq. 5 is a product of a radial and an angular Gaussian, so each factor is computed once
    # per point (one exp per ring and one per cell offset) instead of once per cell; the
    # tests check this against boundary_cell_update summed over every cell.
    n_rings = rings.size
    out = np.zeros(n_rings * n_cells)
    step = 2.0 * math.pi / n_cells
    half = math.ceil(cutoff * sigma_alpha / step)
    lo_k, hi_k = -half, half
    if 2 * half + 1 > n_cells:
        # A window wider than the ring would visit cells twice.
        lo_k = -((n_cells - 1) // 2)
        hi_k = lo_k + n_cells - 1
    ang = np.empty(hi_k - lo_k + 1)
    idx = np.empty(hi_k - lo_k + 1, dtype=np.int64)
    for p in range(d.size):
        dp = d[p]
        centre = round(alpha[p] / step)
        # |offset| <= step/2 + half*step < pi, so no wrapping is needed below.
        offset = wrap_scalar(alpha[p] - centre * step)
        for k in range(lo_k, hi_k + 1):
            ra = (offset - k * step) / sigma_alpha
            ang[k - lo_k] = math.exp(-ra * ra)
            idx[k - lo_k] = (centre + k) % n_cells
        scale = weight / dp
        # Rings within reach form one run: the reach edges d_i -+ cutoff * sigma_i increase
        # with i whenever sigma_d_ratio * cutoff < 1, which the caller checks.
        if sorted_reach:
            r_lo = np.searchsorted(reach_hi, dp)
            r_hi = np.searchsorted(reach_lo, dp, side="right")
        else:
            r_lo, r_hi = 0, n_rings
        for r in range(r_lo, r_hi):
            if abs(dp - rings[r]) > cutoff * sigma_d[r]:
                continue
            rd = (dp - rings[r]) / sigma_d[r]
            radial = scale * math.exp(-rd * rd)
            base = r * n_cells
            for k in range(lo_k, hi_k + 1):
                out[base + idx[k - lo_k]] += radial * ang[k - lo_k]
    return out


def _beam_spacing(angles: FloatArray) -> float:
    # Scans are evenly spaced (ROS angle_increment; every reader builds them so), and the
    # endpoints' spacing needs no median: this runs on every scan.
    if angles.size < 2:
        return 0.0
    return float(abs(angles[-1] - angles[0]) / (angles.size - 1))


class BoundaryCells:
    """Boundary cells on concentric rings; ``activity(scan)`` gives ``B`` (Eq. 5)."""

    def __init__(self, config: BoundaryCellConfig | None = None) -> None:
        self.config = config or BoundaryCellConfig()
        self._rings = np.asarray(self.config.ring_distances, dtype=np.float64)
        self._sigma_d = self.config.sigma_d()
        reach = self.config.cutoff_sigmas * self._sigma_d
        self._reach_lo = self._rings - reach
        self._reach_hi = self._rings + reach
        self._sorted_reach = bool(
            np.all(np.diff(self._reach_lo) >= 0) and np.all(np.diff(self._reach_hi) >= 0)
        )
        self._coverage_key: tuple[float, float] | None = None
        self._coverage = np.ones(self.config.cells_per_ring, dtype=bool)
        self._gain = (
            np.repeat(self._rings, self.config.cells_per_ring)
            if self.config.distance_gain
            else None
        )

    @property
    def num_cells(self) -> int:
        return self.config.num_cells

    def activity(self, scan: LaserScan, turn: float = 0.0) -> FloatArray:
        """Activity ``B`` (shape ``(M,)``) of one scan: Eq. 5 summed over its endpoints.

        ``turn`` (radians) is added to every endpoint's bearing: the activity the scan would
        give with the rings turned by ``-turn``, a fraction of a bin that lines its cells up
        with those of a view learned at another heading
        (:meth:`bioslam.views.ViewCells.observe`'s ``turned``)."""
        r, a = scan.valid_polar()
        return self.activity_polar(r, a + turn if turn else a, _beam_spacing(scan.angles))

    def coverage(self, scan: LaserScan) -> NDArray[np.bool_]:
        """Which angular bins of a ring the scan's field of view covers (a bin whose centre
        lies within the span of its beams): the sectors two views can be compared over."""
        return self.coverage_span(*scan.sweep)

    def coverage_span(self, first: float, last: float) -> NDArray[np.bool_]:
        """``coverage`` for beams swept from ``first`` to ``last`` radians (counter-clockwise)."""
        if self._coverage_key == (first, last):
            return self._coverage  # the same scanner at every look
        cover = self._coverage_of(first, last)
        cover.flags.writeable = False
        self._coverage_key, self._coverage = (first, last), cover
        return cover

    def _coverage_of(self, first: float, last: float) -> NDArray[np.bool_]:
        span = last - first
        if not np.isfinite(span) or span >= 2.0 * math.pi - self.config.sigma_alpha:
            return np.ones(self.config.cells_per_ring, dtype=bool)
        offset = np.mod(self.config.cell_angles() - first, 2.0 * math.pi)
        margin = 0.5 * self.config.sigma_alpha
        return (offset >= margin) & (offset <= span - margin)

    def activity_polar(
        self, ranges: FloatArray, angles: FloatArray, beam_spacing: float = 0.0
    ) -> FloatArray:
        """``B`` from valid endpoints in polar form (sensor frame).

        ``beam_spacing`` (radians) sets the endpoint weight when ``weight_by_beam_spacing``;
        0 means unknown and gives weight 1.
        """
        cfg = self.config
        d = np.asarray(ranges, dtype=np.float64)
        a = np.asarray(angles, dtype=np.float64)
        keep = d >= cfg.min_distance
        weight = 1.0
        if cfg.weight_by_beam_spacing and beam_spacing > 0.0:
            weight = beam_spacing / cfg.reference_beam_spacing
        b = _accumulate(
            np.ascontiguousarray(d[keep]),
            np.ascontiguousarray(a[keep]),
            weight,
            self._rings,
            self._sigma_d,
            cfg.cells_per_ring,
            cfg.sigma_alpha,
            cfg.cutoff_sigmas,
            self._reach_lo,
            self._reach_hi,
            self._sorted_reach,
        )
        if self._gain is not None:
            b *= self._gain
        return b
