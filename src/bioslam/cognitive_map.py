"""The cognitive map (Eq. 12-14): experience nodes, directed transition links, relaxation.

An experience ``e_i = <PC^i, V^i, p^i>`` (Eq. 12) stores the pose cell packet centre, the view
id and the map pose at which it was made. A link ``l_ij = <Δp^ij, Δt^ij>`` (Eq. 13) stores the
odometry from ``e_i`` to ``e_j`` in ``e_i``'s frame. The topological decisions follow
OpenRatSLAM's ``PosecellNetwork::get_action`` and ``ExperienceMap`` (Ball et al. 2013):

* a new view, or a known view whose experiences are all farther than ``match_threshold`` cells
  from the packet, creates an experience at ``p_current ⊕ odometry since`` and an ``odometry``
  link to it;
* a known view whose nearest experience is within the threshold and is not the current one
  moves the robot there; if there is no link from the current experience to it yet, this
  closes a loop and adds a ``loop`` link whose Δp is the odometry since the current experience;
  the map is then relaxed (Eq. 14).
* With a scan registration (``refine``) the move is a measurement instead: the robot's pose
  becomes an experience of its own chain and the registration a ``loop`` link from it to the
  recognised experience; the robot's pose keeps hanging off its own chain, so that a
  registration's error stays in that one link, where the relaxation can weigh it.

Relaxation (Eq. 14) — the choices the paper leaves open, written down:

* Eq. 14 sums every link's residual with the same weight. Here each residual is weighted by its
  link's information, the inverse of its covariance (:func:`information_of`): an odometry
  link's position variance grows with the distance it spans and its heading's is what its
  scans' matches measured; a loop link's is one registration's, shaped by its scan's
  geometry, or (``registration_covariance``) its registration's own covariance
  (:func:`measured_information`: along a corridor, where the match slides, it carries next to
  no weight) with a floor for what that covariance does not see. With equal weights a
  closure a few centimetres off is spread like an exact one and bends a loop whose odometry
  was better than the registration; weighted, a loop is corrected in proportion to how much
  its odometry can have drifted. How much the odometry drifts and how far a registration
  errs is learned from the closures themselves (:mod:`bioslam.link_noise`,
  :meth:`CognitiveMap.set_noise`): where the closures' residuals against the odometry do not
  grow with the loop, the odometry gets, while the run goes on, the largest drift they cannot
  rule out, and the closures bend it little but where it broke; the finished map is solved
  with the likeliest, the median of those they allow (:meth:`bioslam.slam.BioSLAM.finish`).
  A robust
  kernel (dynamic covariance scaling, :func:`robust_scale`) then demotes loop links that the
  solved map contradicts. With equal
  weights (all links alike) this is Eq. 14 as printed.

* Eq. 14 only names positions; headings are relaxed the same way (as OpenRatSLAM does), since a
  link's Δp is expressed in its source's frame and the compositions must stay consistent.
* The residuals use the consistent sign for both edge directions: outgoing
  ``p_j - (p_i ⊕ Δp_ij)`` and incoming ``(p_k ⊕ Δp_ki) - p_i`` (Eq. 14 prints ``- Δp^ki``).
* Sweeps update the nodes in place (Gauss-Seidel). The per-node gain is ``a = 0.5`` for nodes
  with one or two links — Eq. 14 exactly, and for the usual chain node the exact local minimum —
  and ``1 / (N_f + N_t)`` for nodes with more links: ``a`` times a sum over three or more edges
  overshoots (a Jacobi update with a = 0.5 also never damps the alternating mode of an even
  loop). With this normalisation every sweep decreases the squared residual, so repeated sweeps
  converge instead of oscillating.
* Experience 0 defines the map frame and stays fixed (Eq. 14 leaves the gauge free).
* Sweeps on a long loop converge slowly (the error diffuses ~one node per sweep), so after a loop
  closure ``relax`` jumps to the fixed point of Eq. 14 — the state where every node's
  correction Δp^i is zero — by solving that sparse linear system directly (headings, then
  positions with the headings fixed), on the junctions of the map's chains only
  (:mod:`bioslam.link_solve`: the experiences between two junctions follow from their
  links). Its cost is linear in the map; on long runs only the ``solve_window`` most recent
  experiences move, which bounds it. Between
  loop closures the map is consistent by construction (new links equal the odometry), so
  ``relax`` costs nothing.
"""

from __future__ import annotations

import heapq
import math
from array import array
from collections.abc import Callable, Iterator, MutableSequence, Sequence
from dataclasses import dataclass, field, replace
from typing import Any, Literal

import numpy as np
from numba import njit
from numpy.typing import ArrayLike, NDArray

from bioslam.compiled import wrap_scalar
from bioslam.consistency import SharpnessComparison, compare_sharpness
from bioslam.geometry import between, compose, inverse, unit, wrap_angle
from bioslam.growing import GrowingArray, IdRows
from bioslam.link_noise import LinkNoise
from bioslam.link_solve import solve_links
from bioslam.pose_cells import PoseCellConfig, wrapped_cell_distance

FloatArray = NDArray[np.float64]
EventKind = Literal["none", "new", "link", "loop"]
LinkKind = Literal["odometry", "loop"]


def _kind(loop: bool) -> LinkKind:
    """A link's kind from its loop flag."""
    return "loop" if loop else "odometry"


@dataclass
class CognitiveMapConfig:
    """Parameters of the cognitive map."""

    #: Packet distance, in pose cells (wrapped, x'/y'/θ' together), beyond which a known view
    #: makes a new experience instead of matching an old one. OpenRatSLAM
    #: exp_delta_pc_threshold (1.0 by default, 2.0 in its indoor configs).
    match_threshold: float = 2.0
    #: Correction factor a of Eq. 14 (paper: 0.5; OpenRatSLAM exp_correction = 0.5).
    correction: float = 0.5
    #: Gauss-Seidel sweeps of Eq. 14 per ``relax`` call while the map is not converged
    #: (OpenRatSLAM exp_loops = 20 sweeps every update; here only after loop closures).
    sweeps_per_update: int = 20
    #: The map counts as converged when a sweep moves no node by more than this (m) ...
    tolerance_m: float = 1e-4
    #: ... and turns none by more than this (rad).
    tolerance_rad: float = 1e-5
    #: After a loop closure, solve for the fixed point of Eq. 14 directly (sparse, O(map)) before
    #: sweeping; without it only bounded sweeps run and a long loop converges over many scans.
    solve_on_loop: bool = True
    #: Experiences (the most recent) that a loop closure's direct solve may move; older ones
    #: are held as fixed boundary conditions. This bounds the cost of a closure (~10-30 ms for
    #: 5,000 experiences on one core, see ``benchmarks/bench_pose_cells.py``) on long runs;
    #: ``None`` always frees the whole map.
    solve_window: int | None = 5000
    #: Eq. 14's link weights are the links' information (1 / variance). With ``learn_noise``
    #: (the default) the settings below that set them are the prior of a model the closures
    #: refine (:mod:`bioslam.link_noise`). An odometry link's
    #: position variance grows by this (m^2) per metre it spans, a random walk: 1e-4 is 1 cm
    #: after 1 m, 7 cm after 50 m. The LiDAR odometry registers each scan against a local
    #: map, so on the simulated worlds its error hardly grows with distance (2-10e-6 per
    #: metre measured on the maze, 6e-5 with a SICK scanner in the rooms); on freiburg-079
    #: against its corrected poses it is 3-5e-4, the reference's own error included. A model
    #: tighter than the real drift lets the robust kernel take true corrections for outliers
    #: on real logs, so the default sits between ...
    odometry_var_per_m: float = 1e-4
    #: ... and its heading variance by this (rad^2) per metre (0.7-3e-7 measured on the
    #: simulated worlds at 50 m, up to 1e-5 on freiburg-079 with the reference's error) ...
    odometry_heading_var_per_m: float = 1e-5
    #: ... and by this (rad^2) per radian it turns.
    odometry_heading_var_per_rad: float = 1e-4
    #: An odometry link's heading variance is the sum of its scans' own (each match's
    #: covariance, :meth:`CognitiveMap.integrate_odometry`) instead of the two settings
    #: above, which then serve only scans without a match. False: the model alone.
    scan_heading_variance: bool = True
    #: An odometry link's position variance also holds its degenerate scans' own (each such
    #: match's covariance, :meth:`CognitiveMap.integrate_odometry`): where the scans left a
    #: direction unconstrained the odometry may slide along it, and a loop closure then
    #: bends the map there rather than where the scans held it. Off by default: it helps
    #: where the odometry did slide (simulated floors with a 360° scanner of 3.5 m: ring
    #: 15.2 -> 5.7 cm, cubicles with people 21.9 -> 12.5, against odometries of 13.2 and
    #: 16.1), and costs where it did not, whatever the covariance said (a drift-free
    #: URG-04LX ring to 0.63 cm, above its odometry's 0.61; the maze's SICK tour s1 0.38 ->
    #: 0.47; intel 8.22 -> 8.39); the closures learned from cannot tell the two apart
    #: (``benchmarks/README.md``, "Where the odometry could slide").
    weak_step_variance: bool = False
    #: Variance (m^2, rad^2) every link has at least, so that a zero-length link is finite.
    #: Far below any link's own: at 1e-6 m² (and 1e-8 rad²) per link the floor alone, over
    #: the three links a metre of a simulated run makes, gave the odometry more variance
    #: than its learned drift, and closures bent loops the odometry had within millimetres.
    link_var_floor: tuple[float, float] = (1e-10, 1e-12)
    #: Standard deviation of a loop closure's measured relative pose beyond what its
    #: registration's covariance says (``registration_covariance``: the submap's own error;
    #: otherwise the whole of it): position (m; closures' errors measured on the simulated
    #: worlds 0.6-1 cm, with a tail to several centimetres; 1 cm instead of 2 moved the maze
    #: SICK routes by -0.3 and +0.3 cm, freiburg-079 by +0.1) ...
    closure_sigma_m: float = 0.02
    #: ... and heading (rad; measured 0.07-0.16 deg).
    closure_sigma_rad: float = 0.005
    #: Weigh a loop link by its registration's own covariance (:func:`measured_information`:
    #: the matcher's ``σ² H⁻¹`` against the submap, large along a corridor where the match
    #: slides), with ``closure_sigma_m`` / ``closure_sigma_rad`` added as the error that
    #: covariance does not see (the submap's own). False: ``closure_sigma_m`` shaped by the
    #: scan's geometry (:func:`registration_shape`), the default: with the odometry of
    #: dcc506d one closure 19 cm off along a corridor kept its weight under the
    #: covariance (maze, SICK scanner, weaving route: ATE 3.64 cm against 1.00 without and
    #: the odometry's 0.37), where on a796e9b's odometry it lowered 8 of 12 cases
    #: (``benchmarks/README.md``).
    registration_covariance: bool = False
    #: A registration's position information follows the scan's geometry
    #: (:func:`registration_shape`): ``closure_sigma_m`` along its best-constrained direction,
    #: up to this many times that variance along its weakest (along a corridor, where a
    #: registration slides); 1 makes every closure isotropic.
    closure_shape_ratio: float = 100.0
    #: The share of a whole closure's information a partial closure's position across its
    #: slide carries (:func:`free_along`). Its pose along the slide is the map's prediction,
    #: and a slide found a degree or two off the corridor's axis turns the prediction's error
    #: along it into centimetres across (warehouse, SICK, reversing route kept every third
    #: scan, seed 633: partial closures 1-3 cm off across their slides where the whole ones
    #: taught 1.3 mm, the prediction 39-56 cm off along them). A hundredth: a tenth of the
    #: standard deviation.
    partial_across_share: float = 0.01
    #: Robust kernel (dynamic covariance scaling): a loop link whose residual after the solve
    #: exceeds this many standard deviations has its weight scaled down until it does not,
    #: so that one closure inconsistent with the odometry and the other closures cannot bend
    #: the map. ``0`` turns the kernel off. At 3 it also demoted true closures where the
    #: odometry erred beyond its model (a one-scan jump of 20 cm on the SICK rooms route, whose
    #: closure 0.6 cm off the truth ended at 2 % of its weight: ATE 3.60 cm against the
    #: odometry's 3.45; 3.35 at 6; freiburg-079 6.67 and 6.51 cm), while the false closures
    #: that get through on intel (0.9 and 1.7 m off, χ² above 100) are demoted at either. The
    #: χ² is taken against the registration's best-direction accuracy, not its shape
    #: (``closure_shape_ratio``): a false closure slides along a corridor, where the shape
    #: excuses errors.
    robust_sigmas: float = 6.0
    #: Solves at most per relaxation while the kernel changes a loop link's weight.
    robust_iterations: int = 4
    #: Refine the link noise model (``odometry_var_per_m``, ``closure_sigma_m``, the scale of
    #: the odometry's heading variance and ``closure_sigma_rad``) from the accepted closures'
    #: residuals against the odometry (:mod:`bioslam.link_noise`); the settings above are
    #: then its prior. False: the settings as they are.
    learn_noise: bool = True
    #: The prior's standard deviation around the settings, in decades.
    noise_prior_decades: float = 1.0
    #: Accepted closures before the fitted model replaces the settings. The prior keeps a
    #: single closure from setting the model: its residual against the odometry decides
    #: only whether the odometry drifted more than a registration errs (a first closure
    #: 30 cm off after a loop is drift; one 5 mm off is not).
    noise_min_closures: int = 1
    #: Closures that must have taught the link noise for the finished map to be solved with
    #: the drift they make likeliest (:meth:`bioslam.link_noise.LinkNoise.likely`); with
    #: fewer, it is solved with the ``untaught_*`` model below. Only closures the odometry
    #: relates to their place without a break or a jump teach it, a selection that a
    #: handful of lucky ones can make: the hall's URG-04LX tour every 3rd scan
    #: (``benchmarks/README.md``, seeds 101-106) learned from 8 of its 49 closures, off the
    #: odometry by 0.1-2 cm, a drift of 8e-7 m² a metre and a closure good to 0.48 cm, where
    #: the closures erred by 1.9 cm at the median: 19.96 cm of ATE against the odometry's
    #: 9.96, 10.30 with the settings. Of 92 runs measured, the 24 taught by fewer than 10
    #: ended better on 5 and worse on 2 with the settings than with the fit, by at most
    #: 0.04 cm (both lost by their odometry).
    noise_min_closures_finished: int = 10
    #: The finished map's link noise when fewer than ``noise_min_closures_finished``
    #: closures taught it (:func:`untaught_noise`): an odometry position drift (m² a metre)
    #: and a scale of its matches' heading variance at the loosest the closures taught on
    #: the runs measured (drifts of 1e-8 to 2e-6 and scales of 6e-5 to 0.08 on the
    #: simulated floors; freiburg-079 8.9e-7 and 3.4e-4, intel 3.4e-8 and 2.6e-3), where the
    #: settings above, the run's prior, are cautious guesses decades looser; the
    #: registrations' own uncertainty stays the settings' ...
    untaught_odometry_var_per_m: float = 1e-6
    untaught_heading_scale: float = 0.01
    #: ... and the share of the variance the odometry's jumps put on their links that those
    #: links keep (:attr:`bioslam.link_noise.LinkNoise.jump_scale`; with
    #: ``weak_step_variance``, the degenerate steps' too): none. Few closures are taught
    #: where nearly every one spans a jump, and there the jumps are the odometry's routine
    #: (a 5 Hz scanner reversing, 0.2-0.3 m from its last step's motion, the step within
    #: 1-2 cm of the truth; every jump's link as free to turn as 21° a step, at the break
    #: thresholds of 0.2 s), not where it erred: on a floor of identical blocks the
    #: closures, each within 1-3 cm of the truth, bent the map at them to twice the
    #: odometry's error (``benchmarks/README.md``, "A floor of identical blocks").
    untaught_jump_scale: float = 0.0
    #: Where the finished map's model lets the jumps bend and its scans did not say to hold
    #: them all, it holds each jump's link that the map bends by at most this share of what
    #: the jumps added to it (position and heading, each as a standard deviation), as any
    #: other step, unless its scans agree better with them free
    #: (:meth:`CognitiveMap.hold_unbent_jumps`); 0: none. A jump the odometry made in error
    #: is taken back about whole by the closures across it; one bent by a small share of its
    #: allowance is no error taken back but the closures' own centimetres, which a free hinge
    #: gathers (a thinned SICK 361 reversing round a toothed corridor loop: a link carrying
    #: nine routine jumps, free by 1.5 m and 135°, bent 10.6 cm; the map 5.77 cm off against
    #: its odometry's 2.35, 2.29 held; ``benchmarks/README.md``, "Jumps the closures bend
    #: by a small share of their allowance").
    hold_unbent_jumps: float = 0.25
    #: The finished map holds the jumps' links as any other step where its model lets them
    #: bend, then takes the settings' weighing instead of the one the closures taught, and
    #: last lets its loop links weigh nothing, each where its own scans agree better so
    #: (:meth:`CognitiveMap.adopt_if_sharper`, :meth:`CognitiveMap.drop_closures_if_sharper`):
    #: three tests, each at a third of this significance (family-wise, Bonferroni); 0: none.
    #: The jumps held for being bent little (``hold_unbent_jumps``) are freed again where
    #: the scans agree better with them free at that third too.
    scan_test_significance: float = 0.05

    def __post_init__(self) -> None:
        if self.match_threshold <= 0.0:
            raise ValueError(f"match_threshold must be positive, got {self.match_threshold}")
        if not 0.0 <= self.hold_unbent_jumps <= 1.0:
            raise ValueError(f"hold_unbent_jumps must be in [0, 1], got {self.hold_unbent_jumps}")
        if not 0.0 < self.correction <= 1.0:
            raise ValueError(f"correction a must be in (0, 1], got {self.correction}")
        if self.sweeps_per_update < 0:
            raise ValueError("sweeps_per_update must be >= 0")
        if self.solve_window is not None and self.solve_window < 1:
            raise ValueError(f"solve_window must be >= 1 or None, got {self.solve_window}")
        variances = (
            self.odometry_var_per_m, self.odometry_heading_var_per_m,
            self.odometry_heading_var_per_rad, self.closure_sigma_m, self.closure_sigma_rad,
        )  # fmt: skip
        if min(variances) < 0.0 or min(self.link_var_floor) <= 0.0:
            raise ValueError("link uncertainties must be >= 0 and their floors > 0")
        if not 0.0 < self.partial_across_share <= 1.0:
            raise ValueError("partial_across_share must be in (0, 1]")
        if self.closure_shape_ratio < 1.0:
            raise ValueError(f"closure_shape_ratio must be >= 1, got {self.closure_shape_ratio}")
        if not 0.0 <= self.scan_test_significance < 1.0:
            raise ValueError("scan_test_significance must be in [0, 1)")
        if self.robust_sigmas < 0.0 or self.robust_iterations < 1:
            raise ValueError("robust_sigmas must be >= 0 and robust_iterations >= 1")
        if self.noise_prior_decades <= 0.0 or self.noise_min_closures < 1:
            raise ValueError("noise_prior_decades must be > 0 and noise_min_closures >= 1")
        if self.noise_min_closures_finished < 0:
            raise ValueError("noise_min_closures_finished must be >= 0")
        untaught = (
            self.untaught_odometry_var_per_m, self.untaught_heading_scale,
            self.untaught_jump_scale,
        )  # fmt: skip
        if min(untaught) < 0.0:
            raise ValueError("the untaught link noise model must be >= 0")


@dataclass
class Experience:
    """An experience node ``e_i = <PC^i, V^i, p^i>`` (Eq. 12); ``pose`` is the relaxed pose at
    the time the record was taken, ``pc_centre`` the packet centre (cells) it was made at."""

    id: int
    stamp: float
    pose: FloatArray
    view_id: int
    pc_centre: FloatArray
    payload: Any = None


@dataclass
class Link:
    """A directed link ``l_ij = <Δp^ij, Δt^ij>`` (Eq. 13), ``dp`` in the source's frame.
    ``free``: a partial loop link's slide (unit, the source's frame), along which it weighs
    nothing (:attr:`Measurement.partial`); None for any other."""

    source: int
    target: int
    dp: FloatArray
    dt: float
    stamp: float
    kind: LinkKind
    free: FloatArray | None = None


#: (xx, xy, yy) of an isotropic position information shape
ISOTROPIC = np.array([1.0, 0.0, 1.0])


@dataclass(frozen=True)
class NewLink:
    """A link as it enters the map: from ``source`` to ``target``, ``dp`` in the source's
    frame, made at ``stamp`` ``dt`` seconds after the source was entered, with the terms of
    its uncertainty ``terms`` (:func:`link_terms`, weighed by the map's noise model when it
    enters) and position information ``shape`` (xx, xy, yy) in the source's frame;
    ``doubted``: its odometry crossed a step the odometry doubted or broke
    (:meth:`CognitiveMap.integrate_odometry`). ``info``: a (position, heading) information
    fixed instead (a registration's own covariance, :func:`measured_information`), which the
    noise model then leaves as it is. ``partial``: a loop link free along its slide, the
    weakest direction of its shape (:attr:`Measurement.partial`); ``vouched``: False where it
    joins no chain of links (:attr:`Measurement.vouched`)."""

    source: int
    target: int
    dp: FloatArray
    stamp: float
    dt: float
    terms: FloatArray
    shape: FloatArray
    doubted: bool = False
    info: tuple[float, float] | None = None
    partial: bool = False
    vouched: bool = True


@dataclass(frozen=True)
class Measurement:
    """What a registration returns to :meth:`CognitiveMap.update`: the robot's ``pose`` in
    the recognised experience's frame, and the ``shape`` (xx, xy, yy) of its position
    information in the robot's frame (:func:`registration_shape`). ``doubted``: the
    registration was trusted only through earlier closures (its link then cannot vouch
    for later ones, :meth:`CognitiveMap.link_distance` with ``undoubted``). ``covariance``:
    the registration's own 3x3 covariance of the recognised experience's pose in the
    robot's frame (:func:`bioslam.closure.place_covariance`); when given (and finite) the
    loop link's information is its inverse (:func:`measured_information`) instead of
    ``closure_sigma_m`` shaped by ``shape``. ``partial``: the registration left the position
    free along its slide ``free`` (unit, the robot's frame; None: ``shape``'s weakest
    direction), which the link then neither pulls along nor is judged along by the robust
    kernel, and across which it weighs ``partial_across_share`` of ``shape``
    (:func:`free_along`). ``vouched``: False for
    a partial one whose pose along its slide, the map's prediction, the odometry did not
    vouch for: it may be metres off there, and its link joins the places by no chain of links
    (:meth:`CognitiveMap.link_distance`, the drift bound between places); any other link
    joins them by its own length."""

    pose: FloatArray
    shape: FloatArray = field(default_factory=ISOTROPIC.copy)
    doubted: bool = False
    covariance: FloatArray | None = None
    partial: bool = False
    vouched: bool = True
    free: FloatArray | None = None

    def link_shape(self, share: float) -> FloatArray:
        """The position information's shape (xx, xy, yy, the robot's frame) the loop link
        takes: ``shape``, or a partial one's free along its slide and ``share`` of it across
        (:func:`free_along`)."""
        shape = np.asarray(self.shape, dtype=np.float64)
        if not self.partial:
            return shape
        return free_along(shape, weakest(shape) if self.free is None else self.free, share)


@dataclass
class MapEvent:
    """What one ``update`` did: ``new`` experience, moved along an existing ``link``, closed a
    ``loop`` (new link to an old experience), or ``none``; ``experience`` is the current id
    afterwards. ``rejected`` is set when ``refine`` vetoed a loop closure."""

    kind: EventKind
    experience: int
    rejected: bool = False
    matched: int | None = None




@njit(cache=True)
def _relax_sweep(poses, src, dst, dps, weights, out_ptr, out_e, in_ptr, in_e, a):
    """One in-place sweep of the weighted Eq. 14 over nodes 1..N-1; returns the largest
    (move, turn). ``weights[e]`` is link e's (position, heading) information."""
    n = poses.shape[0]
    max_move = 0.0
    max_turn = 0.0
    for i in range(1, n):
        deg = (out_ptr[i + 1] - out_ptr[i]) + (in_ptr[i + 1] - in_ptr[i])
        if deg == 0:
            continue
        w_xy = 0.0
        w_th = 0.0
        for q in range(out_ptr[i], out_ptr[i + 1]):
            w_xy += weights[out_e[q], 0]
            w_th += weights[out_e[q], 1]
        for q in range(in_ptr[i], in_ptr[i + 1]):
            w_xy += weights[in_e[q], 0]
            w_th += weights[in_e[q], 1]
        # Eq. 14's a per unit of weight: equal weights give a (one or two links) or 1 / N.
        scale = a * deg if deg <= 2 else 1.0
        th_i = poses[i, 2]
        r_th = 0.0
        for q in range(out_ptr[i], out_ptr[i + 1]):
            e = out_e[q]
            r_th += weights[e, 1] * wrap_scalar(poses[dst[e], 2] - th_i - dps[e, 2])
        for q in range(in_ptr[i], in_ptr[i + 1]):
            e = in_e[q]
            r_th += weights[e, 1] * wrap_scalar(poses[src[e], 2] + dps[e, 2] - th_i)
        d_th = scale * r_th / w_th
        th_i = wrap_scalar(th_i + d_th)
        poses[i, 2] = th_i
        c = math.cos(th_i)
        s = math.sin(th_i)
        rx = 0.0
        ry = 0.0
        for q in range(out_ptr[i], out_ptr[i + 1]):
            e = out_e[q]
            j = dst[e]
            rx += weights[e, 0] * (poses[j, 0] - (poses[i, 0] + c * dps[e, 0] - s * dps[e, 1]))
            ry += weights[e, 0] * (poses[j, 1] - (poses[i, 1] + s * dps[e, 0] + c * dps[e, 1]))
        for q in range(in_ptr[i], in_ptr[i + 1]):
            e = in_e[q]
            k = src[e]
            ck = math.cos(poses[k, 2])
            sk = math.sin(poses[k, 2])
            rx += weights[e, 0] * (poses[k, 0] + ck * dps[e, 0] - sk * dps[e, 1] - poses[i, 0])
            ry += weights[e, 0] * (poses[k, 1] + sk * dps[e, 0] + ck * dps[e, 1] - poses[i, 1])
        dx = scale * rx / w_xy
        dy = scale * ry / w_xy
        poses[i, 0] += dx
        poses[i, 1] += dy
        max_move = max(max_move, math.hypot(dx, dy))
        max_turn = max(max_turn, abs(d_th))
    return max_move, max_turn


def _chain_headings(
    poses: FloatArray,
    ends: tuple[NDArray[np.int64], NDArray[np.int64]],
    ls: NDArray[np.int64],
    lt: NDArray[np.int64],
    turns: FloatArray,
    weights: FloatArray,
    lo: int,
) -> None:
    """Sets the headings of the free experiences, ``lo``.. (in place), to those composed
    along each one's most certain chain of links (least summed heading variance,
    ``1 / weights``) from the fixed experiences, the links' ``turns`` added up unwrapped.
    ``ends``: the links' source and target experiences; ``ls``, ``lt``: the same as the solve
    numbers them, the free ones from 0 and every fixed one as the last index, the ground.

    The heading solve is linear only once every cycle of the graph knows how many times it
    winds round: its residuals wrap at ±π, and a linear step leaves the sum of a cycle's
    wrapped residuals as it found it. From headings that a wrong closure bent by more than
    half a turn somewhere along a lap, that sum is a whole turn, which the solve then spreads
    round the lap (a map of a curved floor re-solved with every link true ended 17 m off).
    Along the chains each link's residual is zero, and a link off them is left with its
    cycle's own misclosure, the smallest winding; headings that were right come out as
    before, the solve being linear."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import dijkstra

    src, dst = ends
    ground = free = poses.shape[0] - lo
    usable = (ls != lt) & (weights > 0.0)
    cost = np.where(usable, 1.0 / np.maximum(weights, 1e-300), np.inf)
    # the most certain of parallel links, once per pair (a sparse matrix would add them up)
    pair = np.minimum(ls, lt) * (free + 1) + np.maximum(ls, lt)
    order = np.lexsort((cost, pair))
    order = order[usable[order]]
    _, first = np.unique(pair[order], return_index=True)
    edges = order[first]
    graph = coo_matrix((cost[edges], (ls[edges], lt[edges])), shape=(free + 1, free + 1))
    _, parent = dijkstra(graph.tocsr(), directed=False, indices=ground, return_predecessors=True)
    nodes = np.flatnonzero(parent[:free] >= 0)
    if nodes.size == 0:
        return
    up = parent[nodes]
    # the link each node was reached by (the kept pairs are sorted, as np.unique leaves them)
    via = edges[
        np.searchsorted(pair[edges], np.minimum(nodes, up) * (free + 1) + np.maximum(nodes, up))
    ]
    forwards = lt[via] == nodes  # the link runs from the parent to the node
    # a node's heading is its parent's plus its link's turn: a fixed parent's own heading is
    # folded into the link (the ground stands for all of them and counts as zero)
    offset = np.where(forwards, turns[via], -turns[via])
    fixed_end = np.where(forwards, src[via], dst[via])
    offset = offset + np.where(up == ground, poses[fixed_end, 2], 0.0)
    ancestor = np.full(free + 1, ground)
    ancestor[nodes] = up
    total = np.zeros(free + 1)
    total[nodes] = offset
    while (ancestor != ground).any():  # pointer jumping: each pass doubles the chain summed
        total = total + np.where(ancestor != ground, total[ancestor], 0.0)
        ancestor = np.where(ancestor != ground, ancestor[ancestor], ground)
    poses[lo + nodes, 2] = wrap_angle(total[nodes])


def _ground_numbered(nodes: NDArray[np.int64], lo: int, free: int) -> NDArray[np.int64]:
    """Experiences as the solve numbers them: the free ones, ``lo``.., from 0, and every
    fixed one as the ground (``free``, the last index), dropped from the system."""
    return np.where(nodes >= lo, nodes - lo, free)


def _solve_fixed_point(
    poses: FloatArray,
    src: NDArray[np.int64],
    dst: NDArray[np.int64],
    dps: FloatArray,
    weights: FloatArray,
    lo: int,
    shapes: FloatArray | None = None,
) -> None:
    """The weighted Eq. 14's fixed point for experiences ``lo``.. (in place), those before
    held fixed: headings by the weighted Laplacian of the heading residuals, then positions
    with the headings fixed (see :meth:`CognitiveMap.solve`). ``shapes`` ((E, 3): xx, xy, yy
    in each link's source frame) makes a link's position information anisotropic
    (:func:`registration_shape`); None = isotropic."""
    free = poses.shape[0] - lo
    ls, lt = _ground_numbered(src, lo, free), _ground_numbered(dst, lo, free)
    _chain_headings(poses, (src, dst), ls, lt, dps[:, 2], weights[:, 1], lo)
    r = wrap_angle(poses[src, 2] + dps[:, 2] - poses[dst, 2])
    step = solve_links(ls, lt, weights[:, 1], r, free + 1)
    poses[lo:, 2] = wrap_angle(poses[lo:, 2] + step)
    c, sn = np.cos(poses[src, 2]), np.sin(poses[src, 2])
    rel = np.stack([c * dps[:, 0] - sn * dps[:, 1], sn * dps[:, 0] + c * dps[:, 1]], 1)
    # Known positions of fixed ends move to the right-hand side.
    rel = rel + np.where(src < lo, 1.0, 0.0)[:, None] * poses[src, :2]
    rel = rel - np.where(dst < lo, 1.0, 0.0)[:, None] * poses[dst, :2]
    if shapes is None:
        for k in range(2):
            poses[lo:, k] = solve_links(ls, lt, weights[:, 0], rel[:, k], free + 1)
        return
    omega = _map_frame_information(weights[:, 0], shapes, c, sn)
    poses[lo:, :2] = solve_links(ls, lt, omega, rel, free + 1)


def _map_frame_information(
    weight: FloatArray, shapes: FloatArray, c: FloatArray, s: FloatArray
) -> FloatArray:
    """(E, 2, 2) each link's position information ``w R S Rᵀ`` in the map frame, from its
    shape ``S`` in its source's frame (rotation ``R`` = the source's heading), written out
    (a batch of 2x2 matrix products costs more than the arithmetic)."""
    xx, xy, yy = shapes[:, 0], shapes[:, 1], shapes[:, 2]
    cc, ss, cs = c * c, s * s, c * s
    out = np.empty((shapes.shape[0], 2, 2))
    out[:, 0, 0] = weight * (xx * cc - 2.0 * xy * cs + yy * ss)
    out[:, 0, 1] = out[:, 1, 0] = weight * ((xx - yy) * cs + xy * (cc - ss))
    out[:, 1, 1] = weight * (xx * ss + 2.0 * xy * cs + yy * cc)
    return out


def link_residuals(
    poses: FloatArray, src: NDArray[np.int64], dst: NDArray[np.int64], dps: FloatArray
) -> FloatArray:
    """(E, 3) each link's target pose in the frame of where its source and Δp put it: zero
    where the map agrees with the link."""
    return between(compose(poses[src], dps), poses[dst])


def _link_chi2(
    poses: FloatArray, src: NDArray[np.int64], dst: NDArray[np.int64], dps: FloatArray,
    info: FloatArray, shapes: FloatArray, partial: NDArray[np.bool_],
) -> FloatArray:
    """Each link's squared residual in units of its own (isotropic) variance (its χ²); a
    partial link's position residual only along what it pins (its shape, whose free
    direction weighs nothing)."""
    r = link_residuals(poses, src, dst, dps)
    position = r[:, 0] ** 2 + r[:, 1] ** 2
    if partial.any():
        # the residual is in the target's frame, the shape in the source's: turned by the
        # link's own heading change
        s = shapes[partial]
        turned = r[partial]
        c, sn = np.cos(dps[partial, 2]), np.sin(dps[partial, 2])
        x = c * turned[:, 0] - sn * turned[:, 1]
        y = sn * turned[:, 0] + c * turned[:, 1]
        position[partial] = s[:, 0] * x * x + 2.0 * s[:, 1] * x * y + s[:, 2] * y * y
    return position * info[:, 0] + wrap_angle(r[:, 2]) ** 2 * info[:, 1]


#: the columns of a link's uncertainty terms (:func:`link_terms`)
TERM_DISTANCE, TERM_REGISTRATIONS, TERM_EXTRA_XY, TERM_HEADING_VAR, TERM_EXTRA_TH = range(5)


def link_terms(
    distance: float,
    turned: float,
    registrations: int,
    config: CognitiveMapConfig,
    broken: ArrayLike = (0.0, 0.0),
    heading_var: float | None = None,
) -> FloatArray:
    """What a link's uncertainty is made of, before the noise model weighs it
    (:func:`information_of`): the metres of odometry it composes, its registrations, the
    position variance its odometry's breaks add (m²), the odometry's heading variance over
    it (rad²) and the heading variance the breaks add. Kept per link so that the map's
    weights follow the noise model as the closures refine it (:mod:`bioslam.link_noise`).

    A link's Δp composes the odometry since its source was entered (``distance`` metres
    travelled, ``turned`` radians turned) and ``registrations`` loop-closure registrations
    (one for a loop link, one more when the robot entered the source by a registration).
    The odometry's uncertainty grows with the distance travelled and the angle turned (a
    random walk), so a long link counts for less than a short one; a registration is as
    uncertain however far apart its experiences were made. With equal weights a closure's
    error would be spread like an exact one's over a loop of odometry that is often more
    precise than a single registration. ``broken`` (m², rad²): the variance of the
    odometry's breaks within the link: a jump to a look-alike is no random walk
    (:meth:`CognitiveMap.integrate_odometry`). ``heading_var`` (rad²): the odometry's
    heading variance over the link as its matches measured it, instead of the model's
    ``odometry_heading_var_per_m`` and ``odometry_heading_var_per_rad``."""
    extra_xy, extra_th = (float(v) for v in np.asarray(broken, dtype=np.float64).reshape(2))
    if heading_var is None:
        heading_var = modelled_heading_var(distance, turned, config)
    return np.array([distance, registrations, extra_xy, heading_var, extra_th], dtype=np.float64)


def information_of(
    terms: ArrayLike, noise: LinkNoise, floor: tuple[float, float]
) -> FloatArray:
    """Eq. 14's weights, the information (1 / variance) of each link's Δp ((..., 2):
    position m⁻², heading rad⁻²), of links with uncertainty ``terms`` (:func:`link_terms`,
    (..., 5)) under the link ``noise`` model (:func:`configured_noise` before the closures
    refine it), each variance at least ``floor`` (m², rad²) above zero."""
    t = np.asarray(terms, dtype=np.float64)
    var_xy = (
        noise.odometry_var_per_m * t[..., TERM_DISTANCE]
        + noise.closure_var * t[..., TERM_REGISTRATIONS]
        + noise.jump_scale * t[..., TERM_EXTRA_XY]
    )
    var_th = (
        noise.heading_scale * t[..., TERM_HEADING_VAR]
        + noise.closure_heading_var * t[..., TERM_REGISTRATIONS]
        + noise.jump_scale * t[..., TERM_EXTRA_TH]
    )
    return np.stack([1.0 / (floor[0] + var_xy), 1.0 / (floor[1] + var_th)], axis=-1)


def configured_noise(config: CognitiveMapConfig) -> LinkNoise:
    """The link noise model the settings give, before any closure refines it."""
    return LinkNoise(
        config.odometry_var_per_m, config.closure_sigma_m**2, 1.0, config.closure_sigma_rad**2
    )


def untaught_noise(config: CognitiveMapConfig) -> LinkNoise:
    """The link noise the finished map is solved with where too few closures taught one
    (``noise_min_closures_finished``): the ``untaught_*`` settings, the registrations'
    uncertainty the settings' (:func:`configured_noise`)."""
    return replace(
        configured_noise(config), odometry_var_per_m=config.untaught_odometry_var_per_m,
        heading_scale=config.untaught_heading_scale, jump_scale=config.untaught_jump_scale,
    )  # fmt: skip


def modelled_heading_var(distance: float, turned: float, config: CognitiveMapConfig) -> float:
    """The heading variance (rad²) the odometry model gives ``distance`` metres travelled
    and ``turned`` radians turned: where no match measured it (a scan without one, or
    ``scan_heading_variance`` off)."""
    return (
        config.odometry_heading_var_per_m * distance
        + config.odometry_heading_var_per_rad * turned
    )


def measured_information(
    info: tuple[float, float], covariance: ArrayLike, heading: float
) -> tuple[tuple[float, float], FloatArray]:
    """Eq. 14's weight of a loop link whose registration reports its own ``covariance``
    (3x3, x, y, θ of the recognised place in the robot's frame; the robot's frame is turned
    by ``heading`` from the link's source): ``info`` (:func:`information_of`: the odometry
    since the source and the floor of each registration) as variances, plus the
    registration's, inverted. Returns the (position, heading) information, the position's
    being its best direction's, and the position information's shape (xx, xy, yy; largest
    eigenvalue 1) in the source's frame.

    Information is the inverse of the covariance, in the same units as the odometry's: a
    closure whose match slides along a corridor (its covariance there tens of centimetres)
    carries next to no weight along it, so that its slide does not drag the map, while
    across the corridor it corrects as much as its fit allows."""
    cov = np.asarray(covariance, dtype=np.float64).reshape(3, 3)
    c, s = math.cos(heading), math.sin(heading)
    rot = np.array([[c, -s], [s, c]])
    position = rot @ cov[:2, :2] @ rot.T + np.eye(2) / info[0]
    w, v = np.linalg.eigh(0.5 * (position + position.T))
    strength = 1.0 / w  # the information's eigenvalues, along v's columns
    top = float(strength.max())
    shape = (v * (strength / top)) @ v.T
    heading_info = 1.0 / (1.0 / info[1] + max(float(cov[2, 2]), 0.0))
    return (top, heading_info), np.array([shape[0, 0], shape[0, 1], shape[1, 1]])


def registration_hessian(points: ArrayLike, normals: ArrayLike) -> FloatArray | None:
    """The point-to-line Gauss-Newton Hessian (3x3: x, y, θ) a scan's geometry gives its
    registration: each endpoint with a surface normal n constrains the motion along n and
    the rotation by ``p x n``; None with fewer than 3 normals."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    nrm = np.asarray(normals, dtype=np.float64).reshape(-1, 2)
    used = np.any(nrm != 0.0, axis=1)
    if np.count_nonzero(used) < 3:
        return None
    p, n = pts[used], nrm[used]
    jac = np.column_stack([n, p[:, 0] * n[:, 1] - p[:, 1] * n[:, 0]])
    hessian = jac.T @ jac
    return hessian + 1e-9 * np.trace(hessian) * np.eye(3)


def registration_shape(points: ArrayLike, normals: ArrayLike, max_ratio: float) -> FloatArray:
    """The shape (xx, xy, yy; largest eigenvalue 1) of a registration's position information
    in the scan's frame, from the scan's geometry: each endpoint with a surface normal n
    constrains the motion along n and the rotation by ``p x n`` (point-to-line, the
    Gauss-Newton Hessian's form); the heading is marginalised out. Along a corridor the
    walls pin the sideways position but hardly the position along it, where a registration
    slides: one isotropic variance would let such a closure drag the map along the
    corridor as hard as across it. Eigenvalues are clipped to at least ``1 / max_ratio``
    (a direction the scan does not constrain keeps some weight, as the verification has
    refused degenerate registrations); fewer than 3 normals give the isotropic shape."""
    hessian = registration_hessian(points, normals)
    if hessian is None:
        return ISOTROPIC.copy()
    position = np.linalg.inv(np.linalg.inv(hessian)[:2, :2])
    w, v = np.linalg.eigh(0.5 * (position + position.T))
    w = np.maximum(w / max(w[1], 1e-300), 1.0 / max_ratio)
    shape = (v * w) @ v.T
    return np.array([shape[0, 0], shape[0, 1], shape[1, 1]])


def weakest(shape: ArrayLike) -> FloatArray:
    """The unit direction ``shape`` (xx, xy, yy) pins least (a partial link's slide, which
    :func:`free_along` left weightless)."""
    xx, xy, yy = (float(v) for v in np.asarray(shape, dtype=np.float64).reshape(3))
    return np.linalg.eigh(np.array([[xx, xy], [xy, yy]]))[1][:, 0]


def free_along(shape: ArrayLike, free: ArrayLike, share: float = 1.0) -> FloatArray:
    """``shape`` (xx, xy, yy) with the unit direction ``free`` (same frame) left free
    (:data:`WEIGHTLESS`) and across it ``share`` of what ``shape`` pins there: a partial
    closure's, whose registration could not say where along its slide the robot is
    (:attr:`Measurement.partial`). The slide is the registration's own, not the shape's
    weakest direction: along a corridor both lie within a degree or two, but the map's
    prediction may be metres off along it, and every degree between them turns a metre of
    that into 1.7 cm across (``partial_across_share``)."""
    xx, xy, yy = (float(v) for v in np.asarray(shape, dtype=np.float64).reshape(3))
    f = unit(free)
    n = np.array([-f[1], f[0]])
    pinned = max(share * float(n @ np.array([[xx, xy], [xy, yy]]) @ n), WEIGHTLESS)
    out = pinned * np.outer(n, n) + WEIGHTLESS * np.outer(f, f)
    return np.array([out[0, 0], out[0, 1], out[1, 1]])


def rotate_shape(shape: FloatArray, angle: float) -> FloatArray:
    """``shape`` (xx, xy, yy) given in a frame turned by ``angle``, in the outer frame."""
    c, s = math.cos(angle), math.sin(angle)
    m = np.array([[shape[0], shape[1]], [shape[1], shape[2]]])
    r = np.array([[c, -s], [s, c]])
    out = r @ m @ r.T
    return np.array([out[0, 0], out[0, 1], out[1, 1]])


#: Two solutions of the map whose experiences lie within this (m) of each other everywhere
#: place every scan alike at the scans' own resolution: nothing for them to choose between.
SAME_MAP_M = 1e-3
#: The information a link that is to count for nothing is given (the solver needs a weight)
WEIGHTLESS = 1e-12


def _has_points(payload: Any) -> bool:
    """Whether a payload is points (n, 2) with some: what a scan test can place (a payload
    may be anything else a caller keeps with its experiences)."""
    return payload is not None and np.ndim(payload) == 2 and len(payload) > 0


class _Picked(Sequence[Any]):
    """Some items of a sequence, renumbered from 0, read only when asked for (a spilled
    store's scans stay on disk until a revisit needs them)."""

    def __init__(self, items: Sequence[Any], picked: Sequence[int]) -> None:
        self._items, self._picked = items, picked

    def __len__(self) -> int:
        return len(self._picked)

    def __getitem__(self, index: Any) -> Any:
        return self._items[self._picked[index]]


def robust_scale(chi2: FloatArray, sigmas: float) -> FloatArray:
    """Dynamic covariance scaling (Agarwal et al. 2013) of loop links: the factor
    ``s = min(1, 2Φ / (Φ + χ²))`` on a link's standard-deviation-normalised residual, with
    ``Φ = sigmas²``; the link's weight is multiplied by ``s²``. A link consistent with the
    rest of the map keeps its weight; one whose residual is k times the threshold keeps about
    ``4 / k⁴`` of it, so that it no longer bends the map. ``sigmas = 0``: no scaling."""
    chi2 = np.asarray(chi2, dtype=np.float64)
    if sigmas <= 0.0:
        return np.ones_like(chi2)
    phi = sigmas * sigmas
    return np.minimum(1.0, 2.0 * phi / (phi + chi2)) ** 2


def relaxation_correction(
    poses: ArrayLike,
    sources: ArrayLike,
    targets: ArrayLike,
    dps: ArrayLike,
    a: float = 0.5,
    weights: ArrayLike | None = None,
) -> FloatArray:
    """Eq. 14 for every node at once: ``Δp^i = a [Σ_out (p^j - p^i ⊕ Δp^ij) + Σ_in (p^k ⊕ Δp^ki
    - p^i)]`` (positions and, as OpenRatSLAM does, headings), without the gain normalisation;
    with ``weights`` ((E, 2): each link's position and heading weight) every residual is
    multiplied by its link's weight (the weighted Eq. 14 that ``CognitiveMap`` relaxes).

    ``CognitiveMap.relax`` applies it node by node in place; this vectorised form states the
    equation and measures how far a map is from its fixed point (all corrections zero).
    """
    p = np.asarray(poses, dtype=np.float64)
    s = np.asarray(sources, dtype=np.int64)
    t = np.asarray(targets, dtype=np.int64)
    predicted = compose(p[s], np.asarray(dps, dtype=np.float64))
    r = p[t] - predicted
    r[:, 2] = wrap_angle(r[:, 2])
    if weights is not None:
        w = np.asarray(weights, dtype=np.float64).reshape(-1, 2)
        r *= w[:, [0, 0, 1]]
    out = np.zeros_like(p)
    np.add.at(out, s, r)
    np.add.at(out, t, -r)
    return a * out


@njit(cache=True)
def _dijkstra(first, following, other, length, doubted, a, b, within, undoubted, best, came):
    """:meth:`Adjacency.shortest_chain` over its columns: (length, link ends walked), length
    -1 where no chain is at most ``within`` long. ``best`` (all infinite, as many as the
    nodes) and ``came`` are working arrays; ``best`` is left as it came."""
    nodes = first.size
    queue = [(0.0, a)]
    touched = [a]
    if a < nodes:
        best[a] = 0.0
    dist, found = -1.0, False
    while queue:
        reached_here, node = heapq.heappop(queue)
        if node == b:
            dist, found = reached_here, True
            break
        if node >= nodes or reached_here > best[node]:
            continue
        end = first[node]
        while end >= 0:
            if not (undoubted and doubted[end]):
                to = other[end]
                reached = reached_here + length[end]
                if reached <= within and reached < best[to]:
                    if best[to] == np.inf:
                        touched.append(to)
                    best[to] = reached
                    came[to, 0] = node
                    came[to, 1] = end
                    heapq.heappush(queue, (reached, to))
            end = following[end]
    walked = [np.int64(0) for _ in range(0)]
    if found:
        node = b
        while node != a:
            walked.append(came[node, 1])
            node = came[node, 0]
        walked.reverse()
    for node in touched:
        if node < nodes:
            best[node] = np.inf
    return dist, np.array(walked, dtype=np.int64)


class Adjacency:
    """The links at each experience, both directions, with their lengths: for the
    shortest chains of :meth:`CognitiveMap.link_distance`. Kept as linked lists in flat
    arrays (each node's first and last link end, each end's next), 48 bytes a link, instead
    of a list of tuples per node (about 330); a node's links come in the order they were
    added."""

    def __init__(self) -> None:
        self._first = array("q")
        self._last = array("q")
        self._next = array("q")
        self._other = array("q")
        self._length = array("d")
        self._doubted = array("b")
        # Dijkstra's working arrays, kept between searches: each search resets the nodes it
        # reached, not the whole map
        self._best = np.zeros(0)
        self._came = np.empty((0, 2), dtype=np.int64)

    def add(self, a: int, b: int, length: float, doubted: bool = False) -> None:
        """A link of ``length`` between nodes ``a`` and ``b`` (either direction); ``doubted``:
        its odometry crossed a step the odometry doubted or broke."""
        grow = max(a, b) + 1 - len(self._first)
        if grow > 0:
            self._first.extend([-1] * grow)
            self._last.extend([-1] * grow)
        self._end(a, b, length, doubted)
        self._end(b, a, length, doubted)

    def _end(self, node: int, other: int, length: float, doubted: bool) -> None:
        end = len(self._other)
        self._other.append(other)
        self._length.append(length)
        self._doubted.append(int(doubted))
        self._next.append(-1)
        if self._first[node] < 0:
            self._first[node] = end
        else:
            self._next[self._last[node]] = end
        self._last[node] = end

    def has_link(self, source: int, target: int) -> bool:
        """Whether a link from ``source`` to ``target`` was added (that direction: its end
        at ``source`` is the even one, :meth:`of`). A walk over ``source``'s links, instead
        of a set of every pair (80 bytes a link for the whole run)."""
        end = self._first[source] if 0 <= source < len(self._first) else -1
        other, following = self._other, self._next
        while end >= 0:
            if other[end] == target and not end & 1:
                return True
            end = following[end]
        return False

    def shortest_chain(
        self, a: int, b: int, within: float, undoubted: bool = False
    ) -> tuple[float, list[int]] | None:
        """Dijkstra from ``a`` to ``b`` over the links, either direction, stopped at
        ``within`` metres: the length and the link ends (:meth:`of`) walked, or None. In
        compiled code: a closure check asks it several times, over chains as long as the
        drift bound's horizon (on an unseen office floor 1.3 ms a check in Python)."""
        views = [
            np.frombuffer(column, dtype=dtype)
            for column, dtype in (
                (self._first, np.int64), (self._next, np.int64), (self._other, np.int64),
                (self._length, np.float64), (self._doubted, np.int8),
            )
        ]  # fmt: skip
        nodes = len(self._first)
        if self._best.size < nodes:
            self._best = np.full(max(nodes, 2 * self._best.size), np.inf)
            self._came = np.empty((self._best.size, 2), dtype=np.int64)
        dist, ends = _dijkstra(*views, a, b, within, undoubted, self._best, self._came)
        del views  # the arrays may grow again only once nothing holds their buffers
        return None if dist < 0.0 else (dist, ends.tolist())

    def of(self, node: int, undoubted: bool = False) -> Iterator[tuple[int, int, float]]:
        """``(end, other node, length)`` of each link at ``node``, oldest first (``undoubted``:
        only the links whose odometry the odometry never doubted). Link ``k``'s ends are
        ``2k`` (at its source) and ``2k + 1`` (at its target)."""
        end = self._first[node] if 0 <= node < len(self._first) else -1
        other, length, following, doubted = self._other, self._length, self._next, self._doubted
        while end >= 0:
            if not (undoubted and doubted[end]):
                yield end, other[end], length[end]
            end = following[end]


class CognitiveMap:
    """The topological-metric map of experiences (Eq. 12-14)."""

    def __init__(
        self,
        config: CognitiveMapConfig | None = None,
        cell_size: Sequence[float] | None = None,
        dims: Sequence[int] | None = None,
        payloads: MutableSequence[Any] | None = None,
    ) -> None:
        """``payloads``: where each experience's payload is appended (a list when None; an
        empty store such as :class:`bioslam.io.spill.SpilledScans` keeps the stored scans
        out of memory)."""
        self.config = config if config is not None else CognitiveMapConfig()
        pc_default = PoseCellConfig()
        self.cell_size = tuple(cell_size) if cell_size is not None else pc_default.cell_size
        self.dims: tuple[int, int, int] = tuple(int(d) for d in (dims or pc_default.dims))  # type: ignore[assignment]
        self._poses = GrowingArray(np.float64, 3, capacity=64)
        self._centres = GrowingArray(np.float64, 3, capacity=64)
        # per experience and per link for the whole run (about 30,000 of each an hour at
        # 40 Hz), so in arrays: 8 bytes a value rather than a Python object's 30-100
        self._stamps = GrowingArray(np.float64, capacity=64)
        self._view_ids = GrowingArray(np.int64, capacity=64)
        self._payloads: MutableSequence[Any] = payloads if payloads is not None else []
        # which experiences' payloads hold points (what the finished map's scan tests
        # judge), known when each is made: a spilled store's scans stay on disk until read
        self._scanned = GrowingArray(np.bool_, capacity=64)
        # the experiences of each view, oldest first, as linked lists in flat arrays (each
        # view's first and last experience, each experience's next): 16 bytes a view and 8
        # an experience instead of a dict entry and an array each (about 180 bytes a view)
        self._view_first = IdRows(np.int64)
        self._view_last = IdRows(np.int64)
        self._next_of_view = GrowingArray(np.int64, capacity=64)
        self._link_ends = GrowingArray(np.float64, 2, capacity=64)
        self._link_dp = GrowingArray(np.float64, 3, capacity=64)
        self._link_dt = GrowingArray(np.float64, capacity=64)
        self._link_stamp = GrowingArray(np.float64, capacity=64)
        # each link's kind, a flag per link: loop or odometry (the solve's robust kernel reads
        # the loops; a list of the kinds' names, scanned each solve, cost a fifth of a
        # millisecond on the demo maze's map)
        self._link_loop = GrowingArray(np.bool_, capacity=64)
        # Eq. 14's weights: each link's (position, heading) information, and the robust
        # kernel's factor on it (loop links; 1 = fully trusted)
        self._link_info = GrowingArray(np.float64, 2, capacity=64)
        # what each link's uncertainty is made of (link_terms; NaN for a fixed information),
        # to re-weigh the links as the noise model changes (set_noise)
        self._link_terms = GrowingArray(np.float64, 5, capacity=64)
        #: the noise model that weighs the links (:mod:`bioslam.link_noise`)
        self.noise = configured_noise(self.config)
        self._link_scale = GrowingArray(np.float64, capacity=64)
        # each link's position information shape in its source's frame (ISOTROPIC, or a
        # registration's: registration_shape)
        self._link_shape = GrowingArray(np.float64, 3, capacity=64)
        self._link_partial = GrowingArray(np.bool_, capacity=64)
        # undirected, with each link's length: for the odometry distance between two places
        self._neighbours = Adjacency()
        # the recognised place (topology) and the experience the robot's pose is composed from
        # (``_base ⊕ _offset``): the same, except after a measured loop closure, when the
        # robot is at the recognised place while its pose still hangs off its own chain
        self._current = -1
        self._base = -1
        self._offset = np.zeros(3)
        self._entered = 0.0
        self._last_stamp = 0.0
        self._dirty = False
        self._needs_solve = False
        # metres travelled and radians turned since the current experience was entered, and
        # whether it was entered by a registration (all part of the next link's uncertainty)
        self._travel = np.zeros(2)
        # the odometry's heading variance (rad²) since then (:meth:`integrate_odometry`)
        self._heading_var = 0.0
        # variance (m², rad²) the odometry's breaks since the current experience add, with
        # the position variance of its degenerate steps (``weak_var``)
        self._broken_var = np.zeros(2)
        # whether the odometry doubted or broke a step since then
        self._doubted = False
        self._entered_measured = False
        self._csr: tuple[NDArray[np.int64], ...] | None = None
        self.loop_closures = 0
        self.rejected_closures = 0
        #: whether the loop links weigh nothing: the finished map's scans agreed better
        #: without them (:meth:`drop_closures_if_sharper`)
        self.closures_dropped = False

    @classmethod
    def from_pose_cells(
        cls,
        config: CognitiveMapConfig | None,
        pc_config: PoseCellConfig,
        payloads: MutableSequence[Any] | None = None,
    ) -> CognitiveMap:
        """A map whose cell distances use the pose cell network's geometry."""
        return cls(config, cell_size=pc_config.cell_size, dims=pc_config.dims, payloads=payloads)

    # --- accessors -------------------------------------------------------------------------

    def __len__(self) -> int:
        return len(self._poses)

    @property
    def current(self) -> int:
        """Id of the current experience (-1 before the first one)."""
        return self._current

    @property
    def num_links(self) -> int:
        return len(self._link_ends)

    @property
    def experience_poses(self) -> FloatArray:
        """(N, 3) relaxed experience poses (a copy)."""
        return self._poses.view().copy()

    @property
    def experience_poses_view(self) -> FloatArray:
        """(N, 3) relaxed experience poses, read-only and without a copy (per-look queries)."""
        view = self._poses.view()
        view.flags.writeable = False
        return view

    @property
    def payloads(self) -> MutableSequence[Any]:
        """The payload stored with each experience, by id (the map's own store: do not edit)."""
        return self._payloads

    def link_distance(
        self, a: int, b: int, within: float, undoubted: bool = False
    ) -> float | None:
        """The length (m) of the shortest chain of links joining experiences ``a`` and ``b``,
        if one is at most ``within`` metres long, else None: how much odometry relates the
        two places in the map (Dijkstra over the links, either direction, stopped at
        ``within``). ``undoubted``: only through links whose odometry crossed no step the
        odometry doubted or broke (:meth:`integrate_odometry`), along which the drift bound
        holds."""
        found = self._neighbours.shortest_chain(a, b, within, undoubted)
        return None if found is None else found[0]

    def chain_pose(
        self, a: int, b: int, within: float, undoubted: bool = False
    ) -> tuple[float, FloatArray] | None:
        """The shortest chain of links joining ``a`` to ``b`` (as :meth:`link_distance`):
        its length and ``b``'s pose in ``a``'s frame composed from the links' own
        measurements (odometry and registrations), or None. The drift bound of a chain is a
        bound on this composition; the relaxed poses may differ from it by what other
        links, across doubted steps, pulled them."""
        found = self._neighbours.shortest_chain(a, b, within, undoubted)
        if found is None:
            return None
        length, ends = found
        pose = np.zeros(3)
        dps = self._link_dp.view()
        for end in ends:
            dp = dps[end // 2]
            pose = compose(pose, dp if end % 2 == 0 else inverse(dp))
        return length, pose

    def experience(self, eid: int) -> Experience:
        """A snapshot of experience ``eid``."""
        return Experience(
            id=eid,
            stamp=float(self._stamps[eid]),
            pose=self._poses.view()[eid].copy(),
            view_id=int(self._view_ids[eid]),
            pc_centre=self._centres.view()[eid].copy(),
            payload=self._payloads[eid],
        )

    @property
    def experiences(self) -> list[Experience]:
        """Snapshots of all experiences, O(N): for output, not for the per-scan loop."""
        return [self.experience(i) for i in range(len(self))]

    def link(self, index: int) -> Link:
        s, t = self._link_ends.view()[index]
        return Link(
            source=int(s),
            target=int(t),
            dp=self._link_dp.view()[index].copy(),
            dt=float(self._link_dt[index]),
            stamp=float(self._link_stamp[index]),
            kind=_kind(bool(self._link_loop[index])),
            free=weakest(self._link_shape.view()[index]) if self._link_partial[index] else None,
        )

    def link_table(self) -> tuple[NDArray[np.int64], list[LinkKind]]:
        """Every link's ``(source, target)`` (an (E, 2) array) and kind, without a
        :class:`Link` object each (an hour's map has 35,000 links: 15 MB of them)."""
        return self._link_ends.view().astype(np.int64), [_kind(v) for v in self._link_loop.view()]

    @property
    def links(self) -> list[Link]:
        """Snapshots of all links, O(E)."""
        return [self.link(i) for i in range(self.num_links)]

    def experiences_of_view(self, view_id: int) -> list[int]:
        """The experiences made with view ``view_id``, oldest first."""
        vid = int(view_id)
        eid = int(self._view_first[vid]) if vid in self._view_first else -1
        found, following = [], self._next_of_view.view()
        while eid >= 0:
            found.append(eid)
            eid = int(following[eid])
        return found

    # --- odometry and poses ----------------------------------------------------------------

    def integrate_odometry(
        self,
        dp: ArrayLike,
        stamp: float | None = None,
        broken: ArrayLike = (0.0, 0.0),
        doubted: bool = False,
        heading_var: float | None = None,
        weak_var: float = 0.0,
    ) -> None:
        """Accumulate the motion ``dp`` (robot frame) since the current experience.

        ``broken`` (m, rad): how far a break of the odometry's chain within ``dp`` may have
        put it off (:func:`bioslam.closure.break_extent`), beyond its model's drift. The
        link that carries the step is weighted by that much less (:func:`link_terms`),
        so that a loop closure bends the map at the break rather than spreading its
        correction along a loop whose odometry is good but for one jump. ``doubted``: the
        odometry doubted a step within ``dp`` (:func:`bioslam.closure.odometry_doubted`); the
        link that carries it, like one that carries a break, is left out of the chains
        :meth:`link_distance` finds with ``undoubted``. ``heading_var`` (rad²): the heading
        variance the odometry's matches measured over ``dp`` (each scan's
        :attr:`MatchReport.covariance`, summed); None (or NaN) takes the model's
        (:func:`modelled_heading_var`). A scan-to-map odometry's heading is as good as its
        scans' fit: on the simulated worlds the summed per-scan variances came within a
        factor of two of the steps' true heading errors, 4e-6 to 3e-4 rad² per metre from
        one world and scanner to another, where the model assumes 1e-5 everywhere.
        ``weak_var`` (m²): the position variance of the steps within ``dp`` whose scans left
        a direction unconstrained, as their matches measured it
        (:attr:`CognitiveMapConfig.weak_step_variance`); the link that carries them is
        weighted by that much less, beside the noise model's drift, and is not doubted for
        it."""
        d = np.asarray(dp, dtype=np.float64).reshape(3)
        if not np.all(np.isfinite(d)):
            raise ValueError(f"odometry step must be finite, got {dp}")
        self._offset = compose(self._offset, d)
        self._travel += (math.hypot(d[0], d[1]), abs(d[2]))
        if heading_var is None or not math.isfinite(heading_var):
            heading_var = modelled_heading_var(math.hypot(d[0], d[1]), abs(d[2]), self.config)
        self._heading_var += max(float(heading_var), 0.0)
        broken_var = np.square(np.asarray(broken, dtype=np.float64).reshape(2))
        self._broken_var += broken_var
        self._doubted = self._doubted or doubted or bool(broken_var.any())
        if math.isfinite(weak_var):
            self._broken_var[0] += max(float(weak_var), 0.0)  # a possible slide, no doubt
        if stamp is not None:
            self._last_stamp = float(stamp)

    @property
    def doubted_since_entry(self) -> bool:
        """Whether the odometry doubted or broke a step since the robot's pose last hung off
        an experience of its own (:meth:`integrate_odometry`)."""
        return self._doubted

    def anchor(self) -> tuple[int, FloatArray]:
        """(experience id, robot pose in its frame): the experience the robot's pose hangs off
        (the current one, or the last of its own chain after a measured loop closure); id -1
        before the first experience, when the offset is in the map frame."""
        return self._base, self._offset.copy()

    def poses_of(
        self, experience_ids: ArrayLike, offsets: ArrayLike,
        experience_poses: ArrayLike | None = None,
    ) -> FloatArray:
        """Map poses ``p_e ⊕ offset`` for arrays of anchors (vectorised; id -1 = map origin),
        ``p_e`` the map's experience poses or ``experience_poses`` ((N, 3), :meth:`solved`)."""
        ids = np.asarray(experience_ids, dtype=np.int64).reshape(-1)
        off = np.asarray(offsets, dtype=np.float64).reshape(-1, 3)
        nodes = self._poses.view() if experience_poses is None else np.asarray(experience_poses)
        base = np.zeros((ids.shape[0], 3))
        known = ids >= 0
        base[known] = nodes[ids[known]]
        return compose(base, off)

    def pose(self) -> FloatArray:
        """The robot's current map pose."""
        if self._base < 0:
            return self._offset.copy()
        return compose(self._poses.view()[self._base], self._offset)

    # --- topology (Eq. 12-13) --------------------------------------------------------------

    def update(
        self,
        view_id: int,
        is_new: bool,
        pc_centre: ArrayLike,
        stamp: float,
        payload: Any = None,
        refine: Callable[[Experience], Measurement | ArrayLike | None] | None = None,
        nearby: int | None = None,
    ) -> MapEvent:
        """One topological action for the active view (see the module docstring).

        ``nearby``: an experience the path-integration cue puts the robot near
        (:mod:`bioslam.closure`); when the view proposes no move, the robot moves there if
        ``refine`` accepts it, instead of making a new experience.
        """
        vid = int(view_id)
        centre = np.asarray(pc_centre, dtype=np.float64).reshape(3)
        stamp = float(stamp)
        if self._current < 0:
            return self._new_experience(vid, centre, stamp, payload)
        candidates = self.experiences_of_view(vid)
        refused: MapEvent | None = None
        if not is_new and candidates:
            dist = wrapped_cell_distance(self._centres.view()[candidates], centre, self.dims)
            best = int(np.argmin(dist))
            if dist[best] <= self.config.match_threshold:
                event = self._move_to(candidates[best], stamp, refine, (vid, centre, payload))
                if event.kind != "none":
                    return event
                # The view proposed no move (its place is where the robot already is, or a
                # look-alike the verification refused): that does not deny the
                # path-integration cue's old place, tried below.
                if nearby in (None, self._current, candidates[best]):
                    nearby = None
                if not event.rejected:
                    if nearby is None:
                        return event  # still at the current experience
                    other = self._move_to(int(nearby), stamp, refine, (vid, centre, payload))
                    return event if other.rejected else other
                refused = event
        if nearby is not None and nearby != self._current:
            event = self._move_to(int(nearby), stamp, refine, (vid, centre, payload))
            if not event.rejected:
                return event
            refused = refused or event
        # No place verified here: a new one. (After a refused look-alike, staying on the
        # current experience would stretch it over the metres the look-alike's view keeps
        # matching, and a later return there would find no experience near: 2-3 m gaps in
        # the rooms world's first pass.)
        new = self._new_experience(vid, centre, stamp, payload)
        if refused is None:
            return new
        return MapEvent("new", new.experience, rejected=True, matched=refused.matched)

    def _add_experience(
        self, pose: FloatArray, vid: int, centre: FloatArray, stamp: float, payload: Any
    ) -> int:
        """Eq. 12: e_j = <PC^j, V^j, p^j>."""
        eid = len(self._poses)
        self._poses.append(pose)
        self._centres.append(centre)
        self._stamps.append(stamp)
        self._view_ids.append(vid)
        self._payloads.append(payload)
        self._scanned.append(_has_points(payload))
        self._next_of_view.append(-1)
        if vid in self._view_last:
            self._next_of_view.view()[self._view_last[vid]] = eid
        else:
            self._view_first[vid] = eid
        self._view_last[vid] = eid
        return eid

    def _add_link(
        self, source: int, target: int, dp: FloatArray, stamp: float, kind: LinkKind,
        shape: FloatArray = ISOTROPIC,
    ) -> None:
        """Eq. 13: l_ij = <Δp^ij, Δt^ij>, weighted by the odometry and registrations it
        composes (:func:`information_of`)."""
        terms = self._terms(registrations=int(kind == "loop"))
        self._append_link(
            NewLink(source, target, np.asarray(dp, dtype=np.float64), stamp,
                     stamp - self._entered, terms, np.asarray(shape, dtype=np.float64),
                     self._doubted),
            kind,
        )  # fmt: skip

    def _terms(self, registrations: int) -> FloatArray:
        """The uncertainty terms of a link from the current experience to the robot's pose
        now: the odometry and breaks since it was entered, ``registrations`` at the robot's
        end and one more if the experience was entered by one (:func:`link_terms`)."""
        registrations += int(self._entered_measured)
        return link_terms(
            *self._travel, registrations, self.config, self._broken_var, self._heading_var
        )

    def _weigh(self, terms: FloatArray) -> FloatArray:
        """:func:`information_of` ``terms`` under the map's noise model."""
        return information_of(terms, self.noise, self.config.link_var_floor)

    def _modelled_weights(self, noise: LinkNoise) -> tuple[NDArray[np.bool_], FloatArray]:
        """Which links the noise model weighs (not those given their information as
        measured) and their weights under ``noise``."""
        terms = self._link_terms.view()
        modelled = np.isfinite(terms[:, 0])
        weights = information_of(terms[modelled], noise, self.config.link_var_floor)
        if self.closures_dropped:  # under any model (:meth:`drop_closures_if_sharper`)
            weights[self._link_loop.view()[modelled]] = WEIGHTLESS
        return modelled, weights

    def set_noise(self, noise: LinkNoise) -> None:
        """Weigh every link by the noise model ``noise`` from now on (:mod:`bioslam.link_noise`);
        the next :meth:`relax` solves when the weights changed."""
        if noise == self.noise:
            return
        self.noise = noise
        if self.num_links == 0:
            return
        modelled, new = self._modelled_weights(noise)
        info = self._link_info.view()
        if np.allclose(new, info[modelled], rtol=1e-3, atol=0.0):
            return
        info[modelled] = new
        self._dirty = self._needs_solve = True

    def _append_link(self, link: NewLink, kind: LinkKind) -> None:
        self._link_ends.append((link.source, link.target))
        self._link_dp.append(link.dp)
        self._link_dt.append(link.dt)
        self._link_stamp.append(link.stamp)
        self._link_loop.append(kind == "loop")
        if link.info is None:
            self._link_terms.append(link.terms)
            self._link_info.append(self._weigh(link.terms))
        else:
            self._link_terms.append(np.full(5, np.nan))
            self._link_info.append(link.info)
        self._link_scale.append(1.0)
        self._link_shape.append(link.shape)
        self._link_partial.append(link.partial)
        # (intel with 0.0005 rad/s of heading drift injected: partial closures the odometry
        # did not vouch for, 1.3-1.6 m off along their corridors, taken as links a few
        # centimetres long; the checks after them trusted a map 1.6 m off, 2.6 m ATE against
        # 0.24 with no chain through them)
        length = math.hypot(float(link.dp[0]), float(link.dp[1])) if link.vouched else math.inf
        self._neighbours.add(int(link.source), int(link.target), length, link.doubted)
        self._csr = None

    def _enter(self, eid: int, offset: FloatArray, stamp: float, measured: bool = False) -> None:
        self._travel = np.zeros(2)
        self._heading_var = 0.0
        self._broken_var = np.zeros(2)
        self._doubted = False
        self._entered_measured = measured
        self._current = self._base = eid
        self._offset = np.asarray(offset, dtype=np.float64).copy()
        self._entered = stamp

    def _new_experience(self, vid: int, centre: FloatArray, stamp: float, payload: Any) -> MapEvent:
        """Eq. 13: e_j at p^i ⊕ Δp^ij, linked from the current experience by the odometry."""
        pose = self.pose()
        eid = self._add_experience(pose, vid, centre, stamp, payload)
        if self._base >= 0:
            self._add_link(self._base, eid, self._offset.copy(), stamp, "odometry")
        self._enter(eid, np.zeros(3), stamp)
        return MapEvent("new", eid)

    def _move_to(
        self,
        target: int,
        stamp: float,
        refine: Callable[[Experience], Measurement | ArrayLike | None] | None,
        here: tuple[int, FloatArray, Any],
    ) -> MapEvent:
        """Move the robot to experience ``target``.

        Without ``refine`` (the paper) the robot is placed on it, and a loop link records the
        odometry since the current experience. With ``refine``, its registration measures
        the robot's pose in ``target``'s frame. The robot's pose becomes an experience of
        its own chain (``here``: its view id, packet centre and payload), linked by the
        odometry, and the measurement a new loop link from it to ``target`` (also along an
        existing link: a new measurement of it), weighted as one registration
        (:func:`information_of`); the robot's pose hangs off that experience, so that the
        relaxation corrects it. (Entering ``target`` at the measured pose instead would put
        the measurement into every link made afterwards too, where the robust kernel could
        not demote it.)"""
        current = self._current
        if target == current:
            return MapEvent("none", current, matched=target)
        if refine is None:
            kind: EventKind = "link"
            if not self._neighbours.has_link(current, target):
                self._close(target, Measurement(np.zeros(3)), stamp)
                kind = "loop"
            self._enter(target, np.zeros(3), stamp, measured=True)
            return MapEvent(kind, target, matched=target)
        refined = refine(self.experience(target))
        if refined is None:
            self.rejected_closures += 1
            return MapEvent("none", current, rejected=True, matched=target)
        if not isinstance(refined, Measurement):
            refined = Measurement(np.asarray(refined, dtype=np.float64).reshape(3))
        if self._offset.any():
            self._new_experience(*here[:2], stamp, here[2])
        self._close(target, refined, stamp)
        self._current = target
        return MapEvent("loop", target, matched=target)

    def _close(self, target: int, arrival: Measurement, stamp: float) -> None:
        """A loop link to ``target``, the robot being at ``arrival`` in its frame."""
        self.add_loop_link(self.loop_link(target, arrival, stamp))

    def loop_link(self, target: int, measurement: Measurement, stamp: float) -> NewLink:
        """The loop link that ``measurement`` (the robot's pose in ``target``'s frame, now)
        makes, from the experience the robot's pose hangs off, to enter the map now or
        later (:meth:`add_loop_link`): a closure held until another confirms it
        (:class:`bioslam.closure.ClosureConsensus`) keeps the odometry and the pose it was
        measured at."""
        # p_base ⊕ offset = p_target ⊕ arrival, so Δp = offset ⊕ arrival⁻¹; a registration's
        # error moves the robot's end of the link, in the robot's frame (offset from the base)
        arrival = np.asarray(measurement.pose, dtype=np.float64).reshape(3)
        dp = compose(self._offset, inverse(arrival))
        terms = self._terms(registrations=1)
        info = None
        if (
            self.config.registration_covariance
            and measurement.covariance is not None
            and np.all(np.isfinite(measurement.covariance))
        ):
            modelled = self._weigh(terms)
            info, shape = measured_information(
                (float(modelled[0]), float(modelled[1])), measurement.covariance,
                float(self._offset[2]),
            )  # fmt: skip
        else:
            shape = measurement.link_shape(self.config.partial_across_share)
            shape = rotate_shape(shape, float(self._offset[2]))
        doubted = self._doubted or measurement.doubted
        return NewLink(
            self._base, int(target), dp, stamp, stamp - self._entered, terms, shape, doubted,
            info, measurement.partial, measurement.vouched,
        )  # fmt: skip

    def add_odometry_link(
        self, source: int, target: int, dp: ArrayLike, stamp: float, terms: ArrayLike
    ) -> bool:
        """An odometry measurement ``dp`` (``target``'s pose in ``source``'s frame) between
        two experiences of the robot's chain that are not neighbours, with its uncertainty
        ``terms`` (:func:`link_terms`): the motion across a slide the odometry undid,
        whose own links are weak (:meth:`integrate_odometry`'s ``broken``). Returns whether
        the map must be relaxed (it disagrees with the link)."""
        dp = np.asarray(dp, dtype=np.float64).reshape(3)
        stamps = self._stamps.view()
        link = NewLink(
            int(source), int(target), dp, float(stamp), float(stamp - stamps[source]),
            np.asarray(terms, dtype=np.float64).reshape(5), ISOTROPIC.copy(), doubted=True,
        )  # fmt: skip
        self._append_link(link, "odometry")
        if self._agrees(link.source, link.target, dp):
            return False
        self._dirty = self._needs_solve = True
        return True

    def add_loop_link(self, link: NewLink) -> None:
        """Enter a loop link made by :meth:`loop_link`; the next :meth:`relax` solves."""
        self._append_link(link, "loop")
        self.loop_closures += 1
        if not self._agrees(link.source, link.target, link.dp):
            self._dirty = True
            self._needs_solve = True

    def _agrees(self, source: int, target: int, dp: FloatArray) -> bool:
        """Whether the map already satisfies a new link exactly (a closure that confirms the
        map's own prediction): relaxing would then move nothing."""
        poses = self._poses.view()
        residual = compose(inverse(poses[target]), compose(poses[source], dp))
        return bool(np.hypot(residual[0], residual[1]) < 1e-9 and abs(residual[2]) < 1e-9)

    # --- relaxation (Eq. 14) ---------------------------------------------------------------

    @property
    def converged(self) -> bool:
        """True when the last relaxation reached the tolerance (or nothing needed it)."""
        return not self._dirty

    def mark_dirty(self) -> None:
        """Force the next ``relax`` to sweep (e.g. after editing poses by hand)."""
        self._dirty = True

    def _adjacency(self) -> tuple[NDArray[np.int64], ...]:
        if self._csr is None:
            n = len(self)
            ends = self._link_ends.view().astype(np.int64)
            src, dst = np.ascontiguousarray(ends[:, 0]), np.ascontiguousarray(ends[:, 1])
            out_e = np.argsort(src, kind="stable")
            in_e = np.argsort(dst, kind="stable")
            out_ptr = np.concatenate([[0], np.cumsum(np.bincount(src, minlength=n))])
            in_ptr = np.concatenate([[0], np.cumsum(np.bincount(dst, minlength=n))])
            self._csr = (src, dst, out_ptr, out_e, in_ptr, in_e)
        return self._csr

    def link_weights(self) -> FloatArray:
        """(E, 2) Eq. 14's weight of every link, position and heading: its information
        (:func:`information_of`) times the robust kernel's factor (:func:`robust_scale`)."""
        return self._link_info.view() * self._link_scale.view()[:, None]

    def relax(self, iterations: int | None = None) -> int:
        """Relax the map per the weighted Eq. 14; returns the number of sweeps run.

        Nothing runs while the map is consistent. After a loop closure the fixed point is
        solved directly (``solve_on_loop``, no sweeps needed); otherwise at most ``iterations``
        (default ``sweeps_per_update``) in-place sweeps run, stopping once converged.
        """
        if not self._dirty or len(self) < 2:
            self._dirty = False
            return 0
        if self._needs_solve and self.config.solve_on_loop:
            # The solve lands on the fixed point (within its window): nothing left to sweep.
            self.solve()
            self._needs_solve = False
            self._dirty = False
            return 0
        self._needs_solve = False
        n_sweeps = self.config.sweeps_per_update if iterations is None else int(iterations)
        src, dst, out_ptr, out_e, in_ptr, in_e = self._adjacency()
        poses = self._poses.view()
        dps = self._link_dp.view()
        weights = self.link_weights()
        done = n_sweeps
        for k in range(n_sweeps):
            move, turn = _relax_sweep(
                poses, src, dst, dps, weights, out_ptr, out_e, in_ptr, in_e,
                self.config.correction,
            )  # fmt: skip
            if move < self.config.tolerance_m and turn < self.config.tolerance_rad:
                self._dirty = False
                done = k + 1
                break
        return done

    def solve(self, window: int | None = -1) -> None:
        """Jump to the fixed point of the weighted Eq. 14 (every Δp^i zero) by a sparse
        linear solve, with the robust kernel re-weighting loop links that the solution
        contradicts (:func:`robust_scale`, at most ``robust_iterations`` solves).

        Headings first (the linearised weighted Laplacian system of the heading residuals),
        then positions with the headings fixed: ``min Σ w_ij |p_j - p_i - R(θ_i) Δp_ij|²``,
        whose normal equations are exactly "the weighted sum of each node's residuals is
        zero". Only the ``window`` most recent experiences move (default
        ``config.solve_window``; ``None`` = all but experience 0); older ones act as fixed
        boundary conditions.
        """
        n, m = len(self), self.num_links
        if n < 2 or m == 0:
            return
        window = self.config.solve_window if window == -1 else window
        lo = 1 if window is None else max(1, n - int(window))
        src, dst, *_ = self._adjacency()
        keep = np.flatnonzero((src >= lo) | (dst >= lo))
        start = self._poses.view()[lo:].copy()
        loops = self._link_loop.view()[keep]
        info = self._link_info.view()[keep]
        scale = self._link_scale.view()
        shapes: FloatArray | None = self._link_shape.view()[keep]
        if np.array_equal(shapes, np.broadcast_to(ISOTROPIC, shapes.shape)):
            shapes = None  # the scalar solve: two small Laplacians instead of one twice as big
        for _ in range(self.config.robust_iterations):
            self._poses.view()[lo:] = start
            _solve_fixed_point(
                self._poses.view(), src[keep], dst[keep], self._link_dp.view()[keep],
                info * scale[keep][:, None], lo, shapes,
            )  # fmt: skip
            if not loops.any() or self.config.robust_sigmas <= 0.0:
                break
            # judged against the registration's best-direction accuracy, not its shape: a
            # false closure slides along a corridor, exactly where the shape excuses it
            chi2 = _link_chi2(
                self._poses.view(), src[keep], dst[keep], self._link_dp.view()[keep], info,
                self._link_shape.view()[keep], self._link_partial.view()[keep],
            )  # fmt: skip
            wanted = robust_scale(chi2[loops], self.config.robust_sigmas)
            changed = np.abs(wanted - scale[keep[loops]]) > 0.05 * np.maximum(wanted, 1e-3)
            scale[keep[loops]] = wanted
            if not changed.any():
                break

    def solved(
        self,
        dps: ArrayLike | None = None,
        loops: bool = True,
        noise: LinkNoise | None = None,
    ) -> FloatArray:
        """(N, 3) the experience poses the whole map solves to (:meth:`solve`, every
        experience free, the robust kernel started afresh) with every link's Δp replaced by
        ``dps`` ((E, 3), e.g. the true relative poses), with ``loops`` False without its
        loop links, and with ``noise`` its links weighed by that model
        instead of the map's (:func:`information_of`); the map itself is left as it was.
        Measures how much of the trajectory's error the closures' own errors cause (the
        closures given the truth), how much they correct (none at all) and what the learned
        link noise does (the configured model instead)."""
        view = self._poses.view()
        saved = (view.copy(), self._link_dp.view().copy(), self._link_scale.view().copy(),
                 self._link_info.view().copy())  # fmt: skip
        try:
            if dps is not None:
                self._link_dp.view()[:] = np.asarray(dps, dtype=np.float64).reshape(-1, 3)
            if noise is not None:
                modelled, weights = self._modelled_weights(noise)
                self._link_info.view()[modelled] = weights
            self._link_scale.view()[:] = 1.0
            if not loops:
                loop = self._link_loop.view()
                self._link_info.view()[loop] = WEIGHTLESS  # as if absent
            self.solve(window=None)
            return view.copy()
        finally:
            view[:] = saved[0]
            self._link_dp.view()[:] = saved[1]
            self._link_scale.view()[:] = saved[2]
            self._link_info.view()[:] = saved[3]

    def jump_links(self) -> NDArray[np.bool_]:
        """Which links carry the variance of the odometry's jumps and breaks (and, with
        ``weak_step_variance``, its degenerate steps'): those ``LinkNoise.jump_scale``
        weighs."""
        terms = self._link_terms.view()
        extra = (terms[:, TERM_EXTRA_XY] > 0.0) | (terms[:, TERM_EXTRA_TH] > 0.0)
        return np.isfinite(terms[:, TERM_DISTANCE]) & extra

    def adopt_if_sharper(self, noise: LinkNoise, significance: float) -> SharpnessComparison | None:
        """Solve the map with its links weighed by ``noise`` instead, and keep that solution
        where the map's own scans agree better with it: the experiences' payloads, placed by
        each solution, at the revisits either finds, at ``significance`` (a one-sided
        Wilcoxon test, :func:`bioslam.consistency.compare_sharpness`). Returns the
        comparison, or None where there was none to make (no loop closure, or the two
        solutions within :data:`SAME_MAP_M` of each other everywhere). The links' own
        residuals cannot judge between two weighings of themselves; where the robot came
        back, the walls of the two passes fall on one another only where the map is right
        between them."""
        if significance <= 0.0 or noise == self.noise or self.loop_closures == 0:
            return None
        comparison = self._compare_scans(self.solved(noise=noise))
        if comparison is not None and comparison.p_second_sharper < significance:
            self.set_noise(noise)
            self.solve(window=None)
        return comparison

    def drop_closures_if_sharper(self, significance: float) -> SharpnessComparison | None:
        """Let the loop links weigh nothing, the map then the odometry's own chain, where the
        map's scans agree better with it at ``significance`` (:meth:`adopt_if_sharper`'s
        test); the closures stay in the map as links. Returns the comparison, or None where
        there was none to make.

        The last word on whether the closures earned their keep: each was verified alone,
        and the noise model weighs them by how they agree with each other and the odometry,
        but a map they bend where the odometry was right (a model that trusts them more than
        their errors deserve, an odometry link that takes a correction its step did not
        need, a look-alike accepted) puts the walls of the passes beside each other where
        the odometry had them on one another. Measured (``benchmarks/README.md``, "The
        closures' last test"): a thinned warehouse URG-04LX run 1.41 -> 1.26 cm, its
        odometry's (p 4e-8), while every map the closures pulled toward the truth kept them
        (freiburg-079 p 0.9999)."""
        if significance <= 0.0 or self.loop_closures == 0:
            return None
        comparison = self._compare_scans(self.solved(loops=False))
        if comparison is not None and comparison.p_second_sharper < significance:
            self._link_info.view()[self._link_loop.view()] = WEIGHTLESS
            self._dirty = self._needs_solve = self.closures_dropped = True
            self.solve(window=None)
        return comparison

    def _compare_scans(self, other: FloatArray) -> SharpnessComparison | None:
        """The experiences' scans placed by the map's poses and by ``other`` at the revisits
        either finds (:func:`bioslam.consistency.compare_sharpness`); None where the two lie
        within :data:`SAME_MAP_M` of each other everywhere."""
        poses = self._poses.view()
        if np.max(np.hypot(*(other[:, :2] - poses[:, :2]).T)) < SAME_MAP_M:
            return None
        scanned = np.flatnonzero(self._scanned.view())
        return compare_sharpness(
            _Picked(self._payloads, scanned), self._stamps.view()[scanned], poses[scanned],
            other[scanned],
        )  # fmt: skip

    def hold_jumps_if_sharper(self, significance: float) -> SharpnessComparison | None:
        """Hold the odometry's jumps as any other step (``jump_scale`` 0) where the map's own
        scans agree better so (:meth:`adopt_if_sharper`); None where no jump is free to
        bend.

        A jump's link is free to bend because a jump may be the odometry's error (a step to
        a look-alike, which the closures across it take back); it may as well be its
        routine (a reversing robot's steps), and then the closures' own centimetres, or a
        slide elsewhere that the odometry did not notice and the closures cannot place
        (every closure that spans it spans the jumps beside it), are put into the jumps
        instead. The link model cannot tell the two apart; the scans can. Measured on the
        runs where the two differ (``benchmarks/README.md``, "Holding the jumps where the
        scans say so"): the maze's SICK reversing route with two people 62.44 -> 47.29 cm
        (p 5e-9), intel 8.35 -> 8.24 cm, while a warehouse route whose odometry jumped to a
        look-alike aisle keeps its jumps free (34.14 cm; held, 135.58; the scans sharper as
        it is)."""
        if self.noise.jump_scale == 0.0 or not self.jump_links().any():
            return None
        return self.adopt_if_sharper(replace(self.noise, jump_scale=0.0), significance)

    def hold_unbent_jumps(self, share: float, significance: float) -> SharpnessComparison | None:
        """Hold as any other step each jump's link (:meth:`jump_links`) that the solved map
        bends by at most ``share`` of what the jumps add to it, position and heading each as
        a standard deviation under the map's model, solving again after each round (holding
        one may leave another less bent); keep them held unless the map's scans agree better
        with the map as it was, at ``significance`` (:meth:`adopt_if_sharper`'s test, the
        other way round). Returns the comparison, or None where no link was held.

        The jumps the finished map keeps free (:meth:`hold_jumps_if_sharper` kept them so)
        are free because some may be the odometry's errors, which the closures across them
        take back; a wrong jump is taken back about whole, as far as it went wrong. One the
        closures bend by a small share of its allowance was no error: the bend is their own
        centimetres, which a free hinge gathers and turns by the length of the map beyond.
        Partial closures need no rule of their own here: weighed across their slides at
        ``partial_across_share`` (:meth:`Measurement.link_shape`), many of them
        along aisles no longer add up to a pull along one that a free hinge gives way to
        (the built-in warehouse, SICK, reversing route kept every third scan, seed 633:
        109 partial closures weighed whole bent the reversal's jump 46.8 cm, 1.6 times its
        allowance, 19.64 cm against the odometry's 1.05 until a rule held such jumps; at a
        hundredth, 1.05 without that rule, whose removal left 87 runs as they were;
        ``benchmarks/README.md``, "Jumps only partial closures bend: the rule removed")."""
        jumps = np.flatnonzero(self.jump_links())
        if share <= 0.0 or self.noise.jump_scale == 0.0 or jumps.size == 0:
            return None
        terms = self._link_terms.view()
        saved = (
            self._poses.view().copy(), self._link_scale.view().copy(), terms[jumps].copy(),
            self._link_info.view()[jumps].copy(),
        )  # fmt: skip
        allowed = np.sqrt(self.noise.jump_scale * terms[jumps][:, [TERM_EXTRA_XY, TERM_EXTRA_TH]])
        bends = self._bends(jumps)
        held = np.zeros(jumps.size, dtype=bool)
        while True:
            unbent = ~held & np.all(bends <= share * allowed, axis=1)
            if not unbent.any():
                break
            held |= unbent
            chosen = jumps[unbent]
            terms[chosen, TERM_EXTRA_XY] = terms[chosen, TERM_EXTRA_TH] = 0.0
            self._link_info.view()[chosen] = self._weigh(terms[chosen])
            self.solve(window=None)
            bends = self._bends(jumps)
        if not held.any():
            return None
        comparison = self._compare_scans(saved[0])
        if comparison is not None and comparison.p_second_sharper < significance:
            self._poses.view()[:], self._link_scale.view()[:] = saved[0], saved[1]
            terms[jumps], self._link_info.view()[jumps] = saved[2], saved[3]
        return comparison

    def _bends(self, links: NDArray[np.int64], poses: FloatArray | None = None) -> FloatArray:
        """(len(links), 2) how far (m, rad) the map's poses (or ``poses``) depart from each
        link's Δp."""
        ends = self._link_ends.view()[links].astype(np.int64)
        poses = self._poses.view() if poses is None else poses
        r = link_residuals(poses, ends[:, 0], ends[:, 1], self._link_dp.view()[links])
        return np.column_stack([np.hypot(r[:, 0], r[:, 1]), np.abs(wrap_angle(r[:, 2]))])

    # --- output ----------------------------------------------------------------------------

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready map: nodes (id, creation time, relaxed pose, view id) and links (from,
        to, Δp, Δt, creation time, kind)."""
        return {k: list(v) if k != "loop_closures" else v for k, v in self.json_fields().items()}

    def json_fields(self) -> dict[str, Any]:
        """:meth:`to_dict`'s fields with the nodes and the links as generators of their
        entries, for a writer that encodes them one at a time
        (:func:`bioslam.io.jsonio.write_json_streamed`): an hour's map is 30,000 of each,
        about 35 MB as Python objects."""
        return {"nodes": self._json_nodes(), "links": self._json_links(),
                "loop_closures": self.loop_closures}  # fmt: skip

    def _json_nodes(self) -> Iterator[dict[str, Any]]:
        poses, stamps, view_ids = self._poses.view(), self._stamps.view(), self._view_ids.view()
        for i in range(len(self)):
            yield {
                "id": i,
                "time": float(stamps[i]),
                "pose": [float(v) for v in poses[i]],
                "view_id": int(view_ids[i]),
            }

    def _json_links(self) -> Iterator[dict[str, Any]]:
        ends = self._link_ends.view()
        dps = self._link_dp.view()
        link_dt, link_stamp = self._link_dt.view(), self._link_stamp.view()
        loops, partial = self._link_loop.view(), self._link_partial.view()
        for k in range(self.num_links):
            yield {
                "from": int(ends[k, 0]),
                "to": int(ends[k, 1]),
                "dp": [float(v) for v in dps[k]],
                "dt": float(link_dt[k]),
                "time": float(link_stamp[k]),
                "kind": _kind(bool(loops[k])),
                "partial": bool(partial[k]),
            }
