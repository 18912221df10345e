"""Gauss-Newton scan-to-map matching (paper Sec. III-A, Eq. 1-4), after Hector SLAM.

The pose maximising the summed map function M* at the scan endpoints (Eq. 3), with the
endpoints placed by the pose (Eq. 4), found by Gauss-Newton on Σ (1 - M*)² coarse to fine
over a :class:`bioslam.occupancy_grid.MapPyramid`, with Levenberg-Marquardt damping and a
guard against directions the scan does not constrain. The Numba kernels take a map as the
tuple of :func:`grid_args`. No file or terminal I/O here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray

from bioslam.geometry import separation, wrap_angle
from bioslam.occupancy_grid import (
    NORMAL_MAX_GAP,
    NORMAL_RADIUS,
    MapPyramid,
    OccupancyGrid,
    above_near_point,
    interpolate_point,
    scan_normals,
    subcell_point,
    subsample_by_spacing,
)

FloatArray = NDArray[np.float64]


@dataclass
class MatchReport:
    """What the last :meth:`LidarOdometry.update` did.

    Attributes:
        iterations: Gauss-Newton iterations summed over the levels.
        degenerate: some direction was unconstrained by the scan (e.g. a long corridor).
        degenerate_direction: unit vector (x, y, theta * length_scale) in the map frame of the
            least constrained direction (zeros when not degenerate).
        condition: smallest / largest curvature (scaled Hessian eigenvalues), 1 = isotropic.
        weakest_direction: unit vector (x, y, theta * length_scale) in the sensor frame of the
            least constrained direction of the scan's geometry, degenerate or not (zeros when
            the match was given no normals): the motion model keeps its velocity along it.
        score: mean M* over the matched endpoints at the finest level (1 = all on walls).
        information: largest eigenvalue of the scan's point-to-line information (with
            normals; :func:`geometric_information`): times ``condition``, the endpoints'
            worth of information along the weakest direction.
        prior_share: along a degenerate direction, the motion prior's share of the
            curvature at the match (:func:`prior_share`): the match moved from the prior by
            ``1 - prior_share`` of where the scan alone put it.
        num_points: endpoints used for matching (after subsampling).
        inserted: the scan was fused into the map.
        predicted_only: no usable scan; the pose is the constant-velocity prediction.
        converged: the finest level stopped on a small step within its iteration budget.
        free_fraction: matched endpoints that fell in cells the map knows to be free.
        through_fraction: beams that pass through a cell the map knows to be occupied on
            their way to their endpoint (computed only where matches are compared: when the
            odometry weighs a search's matches against the prediction's).
        recovered: the match comes from the wide-basin search, run because the prediction
            could not be trusted (``OdometryConfig.search_*``, ``gap_time``), which found a
            better one.
        ambiguous: the search found a distinct pose that fits about as well as the match
            kept (a look-alike); the match nearest the prediction was kept.
        restarted: the pyramid's descent ended worse on the finest level than its start,
            and the finest level was matched again from the start (:func:`match_scan_to_map`).
        broken: on sparse scans (a thinned log), the match kept fits far worse than recent
            ones, or a match turned the other way fits about as well
            (``OdometryConfig.break_score_ratio``): the odometry cannot vouch for the step,
            a break of its chain (:func:`bioslam.closure.odometry_broke`).
        vetoed: on sparse scans, a match turned the other way (``break_turn``) fits better,
            step cost included, but the map's free space rejected it: the step kept rests
            on that veto alone, which a map fused from a few sparse scans, some misplaced,
            does not make sure. The odometry keeps its choice; where the step turns away
            from the motion, its chain is broken there for the closures
            (:func:`bioslam.closure.odometry_broke`).
        rebuilt: the local map was rebuilt from the recent scans after this match, its
            earlier passes in conflict with them (``OdometryConfig.rebuild_scans``): the
            steps that led here were matched against a map found wrong, a break for the
            closures (:func:`bioslam.closure.odometry_broke`).
        bend: how far the scan's sweep is bent (rad): the turn its de-skewing put through the
            sweep less the turn at the rate of the step matched (set by
            :class:`bioslam.odometry.LidarOdometry`; 0 for a scan taken at one instant).
        covariance: 3x3 covariance of (x, y, theta) in the map frame from the scan alone
            (:func:`match_covariance`); NaN where no match was made. Along a direction the
            scan does not constrain it is large: there the pose kept the motion prior.
    """

    iterations: int = 0
    degenerate: bool = False
    degenerate_direction: FloatArray = field(default_factory=lambda: np.zeros(3))
    condition: float = 1.0
    weakest_direction: FloatArray = field(default_factory=lambda: np.zeros(3))
    score: float = 0.0
    information: float = 0.0
    num_points: int = 0
    inserted: bool = False
    predicted_only: bool = False
    converged: bool = False
    free_fraction: float = 0.0
    through_fraction: float = 0.0
    recovered: bool = False
    ambiguous: bool = False
    restarted: bool = False
    rebuilt: bool = False
    broken: bool = False
    vetoed: bool = False
    overruled: bool = False
    bend: float = 0.0
    #: :func:`match_covariance`'s arguments, kept so that the covariance is computed only for
    #: the report someone reads (the searches' and closures' candidates are never read)
    covariance_terms: tuple | None = field(default=None, repr=False)
    _covariance: FloatArray | None = field(default=None, init=False, repr=False)
    #: :func:`prior_share`'s arguments (None where no prior acted), computed on first use
    prior_terms: tuple | None = field(default=None, repr=False)

    @property
    def prior_share(self) -> float:
        """See the class's attributes (0 where no prior acted)."""
        return 0.0 if self.prior_terms is None else prior_share(*self.prior_terms)

    @property
    def covariance(self) -> FloatArray:
        """See the class's attributes (computed on first use)."""
        if self._covariance is None:
            terms = self.covariance_terms
            self._covariance = (
                np.full((3, 3), np.nan) if terms is None else match_covariance(*terms)
            )
        return self._covariance


# --------------------------------------------------------------------------------------------
# Numba kernels


@numba.njit(cache=True)
def _add_outer(M, a, b, c):
    """Add the upper triangle of the outer product of (a, b, c) to the 3x3 ``M``."""
    M[0, 0] += a * a
    M[0, 1] += a * b
    M[0, 2] += a * c
    M[1, 1] += b * b
    M[1, 2] += b * c
    M[2, 2] += c * c


@numba.njit(cache=True)
def _mirror_upper(M):
    M[1, 0] = M[0, 1]
    M[2, 0] = M[0, 2]
    M[2, 1] = M[1, 2]


@numba.njit(cache=True)
def _normal_equations(g, pts, facing, pose, H, b):
    """Gauss-Newton normal equations of Eq. 3 linearised at ``pose``, into ``H`` (3x3) and
    ``b`` (3,).

    Residual ``1 - M*(S_i(p))`` with ``S_i(p) = R_p e_i + T_p`` (Eq. 4); its Jacobian is
    ``∇M* · ∂S_i/∂p``. Returns ``(mean M* inside, cost, points inside the map)``; the
    cost Σ (1 - M*)² counts points outside the map as unknown (M* = 0.5), so that pushing
    points out of the map never looks like an improvement.
    """
    kind, logodds, means, weights, ox, oy, res, sigma = g
    H[:] = 0.0
    b[:] = 0.0
    c = math.cos(pose[2])
    s = math.sin(pose[2])
    total = 0.0
    cost = 0.0
    inside = 0
    for k in range(pts.shape[0]):
        px = pts[k, 0]
        py = pts[k, 1]
        wx = c * px - s * py + pose[0]
        wy = s * px + c * py + pose[1]
        # (the arrays go to the map function directly: a helper taking the tuple ``g``
        # costs a third of the loop in reference counting, and even occupancy_grid.map_point,
        # which takes the arrays, measured 42 against 28 µs per call on 211 points)
        if kind == 0:
            m, gx, gy, ok = interpolate_point(logodds, ox, oy, res, wx, wy)
        else:
            fx, fy = _facing(facing, k, c, s)
            m, gx, gy, ok = subcell_point(means, weights, ox, oy, res, sigma, wx, wy, fx, fy)
        cost += (1.0 - m) * (1.0 - m)
        if ok:
            inside += 1
            total += m
            _add_point(H, b, px, py, c, s, m, gx, gy)
    _mirror_upper(H)
    mean = total / inside if inside > 0 else 0.0
    return mean, cost, inside


@numba.njit(cache=True)
def _facing(facing, k, c, s):
    """Point ``k``'s surface normal (sensor frame, towards the sensor) turned by the pose's
    rotation (cos ``c``, sin ``s``); none (zeros) where ``facing`` holds no normal per point."""
    if facing.shape[0] == 0:
        return 0.0, 0.0
    nx = facing[k, 0]
    ny = facing[k, 1]
    return c * nx - s * ny, s * nx + c * ny


@numba.njit(cache=True)
def _add_point(H, b, px, py, c, s, m, gx, gy):
    """Add the terms of one point (sensor frame ``px, py``; map value ``m`` and gradient
    ``gx, gy`` where the pose (cos ``c``, sin ``s``) puts it) to the upper triangle of ``H``
    and to ``b``."""
    j2 = gx * (-s * px - c * py) + gy * (c * px - s * py)
    r = 1.0 - m
    b[0] += gx * r
    b[1] += gy * r
    b[2] += j2 * r
    _add_outer(H, gx, gy, j2)


@numba.njit(cache=True)
def _guarded_step(H, b, length, ratio, damping, hold):
    """Solve ``H dp = b`` in the eigenbasis of the scaled Hessian, leaving out the direction
    ``hold`` (unit, scaled; zeros for none) that the scan's geometry does not constrain,
    and any direction with curvature below ``ratio`` of the largest: along them the pose
    keeps the prediction.

    ``damping`` is Marquardt's scaled form: every eigen-curvature grows by that fraction
    of itself, so the step shortens by ``1 + damping`` without turning away from weakly
    constrained directions (an additive term would freeze those, and a robot in a
    corridor would fall behind its true motion). Returns ``(dp, condition, weakest unit
    direction, degenerate)``.
    """
    scale = np.array([1.0, 1.0, 1.0 / length])
    Hs = H * np.outer(scale, scale)
    bs = b * scale
    if hold @ hold > 0.5:
        proj = np.eye(3) - np.outer(hold, hold)
        Hs = proj @ Hs @ proj + np.trace(Hs) * np.outer(hold, hold)
        bs = proj @ bs
    w, v = np.linalg.eigh(Hs)
    step = np.zeros(3)
    top = w[2]
    if top <= 1e-12:
        return step, 0.0, v[:, 0].copy(), True
    degenerate = False
    for k in range(3):
        if w[k] < ratio * top:
            degenerate = True
            continue
        step += v[:, k] * (v[:, k] @ bs) / (w[k] * (1.0 + damping))
    return step * scale, max(w[0], 0.0) / top, v[:, 0].copy(), degenerate


@numba.njit(cache=True)
def _newton_step(H, b, length, ratio, damping, hold):
    """The step of :func:`_guarded_step` without its eigen-decomposition where none is
    needed: with no held direction and every curvature above ``ratio`` of the largest, the
    guarded step is the damped Newton step ``H⁻¹ b / (1 + damping)``, solved in closed form.
    (A 3x3 LAPACK ``eigh`` and its temporaries cost 4.6 µs per iteration, a fifth of a
    Gauss-Newton iteration on 200 points.) Only the eigenvalues, by the trigonometric
    formula, are needed to tell."""
    if hold @ hold > 0.5:
        return _guarded_step(H, b, length, ratio, damping, hold)[0]
    k = 1.0 / length
    a00 = H[0, 0]
    a01 = H[0, 1]
    a02 = H[0, 2] * k
    a11 = H[1, 1]
    a12 = H[1, 2] * k
    a22 = H[2, 2] * k * k
    lowest, highest = _symmetric_eigen_range(a00, a01, a02, a11, a12, a22)
    if highest <= 1e-12 or lowest < ratio * highest:
        return _guarded_step(H, b, length, ratio, damping, hold)[0]
    b0 = b[0]
    b1 = b[1]
    b2 = b[2] * k
    # adjugate of the symmetric matrix
    c00 = a11 * a22 - a12 * a12
    c01 = a02 * a12 - a01 * a22
    c02 = a01 * a12 - a02 * a11
    c11 = a00 * a22 - a02 * a02
    c12 = a01 * a02 - a00 * a12
    c22 = a00 * a11 - a01 * a01
    scale = 1.0 / ((a00 * c00 + a01 * c01 + a02 * c02) * (1.0 + damping))
    step = np.empty(3)
    step[0] = (c00 * b0 + c01 * b1 + c02 * b2) * scale
    step[1] = (c01 * b0 + c11 * b1 + c12 * b2) * scale
    step[2] = (c02 * b0 + c12 * b1 + c22 * b2) * scale * k
    return step


@numba.njit(cache=True)
def _symmetric_eigen_range(a00, a01, a02, a11, a12, a22):
    """Smallest and largest eigenvalue of a symmetric 3x3 matrix (trigonometric method)."""
    off = a01 * a01 + a02 * a02 + a12 * a12
    q = (a00 + a11 + a22) / 3.0
    d0 = a00 - q
    d1 = a11 - q
    d2 = a22 - q
    p2 = d0 * d0 + d1 * d1 + d2 * d2 + 2.0 * off
    if p2 <= 1e-300:
        return q, q
    p = math.sqrt(p2 / 6.0)
    det = d0 * (d1 * d2 - a12 * a12) - a01 * (a01 * d2 - a12 * a02) + a02 * (a01 * a12 - d1 * a02)
    r = min(max(det / (2.0 * p * p * p), -1.0), 1.0)
    phi = math.acos(r) / 3.0
    highest = q + 2.0 * p * math.cos(phi)
    lowest = q + 2.0 * p * math.cos(phi + 2.0 * math.pi / 3.0)
    return lowest, highest


@numba.njit(cache=True)
def _add_prior(H, b, pose, prior, length):
    """Add a motion prior along one direction to the normal equations at ``pose``: the cost
    ``k (d . D (pose - p0))²`` with ``d`` the unit direction in scaled coordinates
    (x, y, theta * ``length``), ``D = diag(1, 1, length)``, ``p0`` the prior pose and
    ``k`` the weight times the trace of the scaled ``H``: along a direction the scan
    constrains, the scan's own curvature outweighs it; along one it hardly constrains (a
    corridor's axis) the pose follows the prior, smoothly. ``prior`` is (d, p0, weight).
    Returns the prior's cost."""
    d, p0, weight = prior
    if weight <= 0.0:
        return 0.0
    k = weight * (H[0, 0] + H[1, 1] + H[2, 2] / (length * length))
    u0 = d[0]
    u1 = d[1]
    u2 = d[2] * length  # d . D (pose) = u . pose
    turn = p0[2] - pose[2]  # wrapped: a prior at -179° is 2° from a pose at 179°
    turn = math.atan2(math.sin(turn), math.cos(turn))
    offset = u0 * (p0[0] - pose[0]) + u1 * (p0[1] - pose[1]) + u2 * turn
    H[0, 0] += k * u0 * u0
    H[0, 1] += k * u0 * u1
    H[0, 2] += k * u0 * u2
    H[1, 1] += k * u1 * u1
    H[1, 2] += k * u1 * u2
    H[2, 2] += k * u2 * u2
    _mirror_upper(H)
    b[0] += k * u0 * offset
    b[1] += k * u1 * offset
    b[2] += k * u2 * offset
    return k * offset * offset


@numba.njit(cache=True)
def _gauss_newton_level(g, pts, facing, pose, max_iter, tol, length, ratio, hold, prior):
    """Gauss-Newton on one level with Levenberg-Marquardt damping (Nielsen's schedule): a
    step that raises the cost is refused and retried shorter, and the damping of an
    accepted step shrinks by how well the quadratic model predicted the gain, so that the
    map function's kinks at cell boundaries cannot make the pose oscillate. A first refusal
    halves the step at once: near the optimum Gauss-Newton underestimates the curvature of
    a peaked M* (its Hessian drops the (1 - M*) M*'' term) and overshoots, mostly in
    heading, and a token damping of 0.001 only wasted iterations (maze: 1.0 vs 1.3 ms per
    scan, RPE 0.38 cm / 0.085° vs 0.40 cm / 0.106°). ``hold`` is a direction kept fixed
    (:func:`_guarded_step`), ``prior`` :func:`_add_prior`'s (direction, pose, weight). Returns
    ``(pose, H, mean M*, iterations, converged, cost, scan)``, the cost with the prior's,
    ``scan`` the normal matrix, cost and points inside the map of the scan alone at ``pose``
    (for :func:`match_covariance`)."""
    pose = pose.copy()
    trial = np.empty(3)
    H = np.zeros((3, 3))
    b = np.zeros(3)
    H2 = np.zeros((3, 3))
    b2 = np.zeros(3)
    mean, cost, inside = _normal_equations(g, pts, facing, pose, H, b)
    # the scan's own terms at ``pose`` (before the prior's are added), for its covariance
    scan_H, trial_H = H.copy(), np.empty((3, 3))
    scan_cost, scan_inside = cost, inside
    cost += _add_prior(H, b, pose, prior, length)
    damping = 0.0
    growth = 2.0
    iterations = 0
    converged = False
    if inside < 3:
        return pose, H, mean, iterations, converged, cost, (scan_H, scan_cost, scan_inside)
    for _ in range(max_iter):
        iterations += 1
        step = _newton_step(H, b, length, ratio, damping, hold)
        # judged on the undamped step: a damped one is short without being converged
        undamped = 1.0 + damping
        small = (
            math.hypot(step[0], step[1]) * undamped < tol and abs(step[2]) * undamped * length < tol
        )
        for i in range(3):
            trial[i] = pose[i] + step[i]
        mean2, cost2, inside2 = _normal_equations(g, pts, facing, trial, H2, b2)
        trial_H[:, :] = H2
        trial_cost = cost2
        cost2 += _add_prior(H2, b2, trial, prior, length)
        # the gain Gauss-Newton's quadratic model predicts for residuals r = 1 - M*
        predicted = 0.0
        for i in range(3):
            predicted += 2.0 * step[i] * b[i]
            for j in range(3):
                predicted -= step[i] * H[i, j] * step[j]
        if cost2 <= cost and inside2 >= 3:
            rho = (cost - cost2) / predicted if predicted > 0.0 else 1.0
            pose, trial = trial, pose
            H, H2 = H2, H
            b, b2 = b2, b
            mean, cost = mean2, cost2
            scan_H, trial_H = trial_H, scan_H
            scan_cost, scan_inside = trial_cost, inside2
            damping *= max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3)
            if damping < 1e-6:
                damping = 0.0
            growth = 2.0
        else:
            damping = max(growth * damping, 1.0)
            growth *= 2.0
        if small:
            converged = True
            break
    return pose, H, mean, iterations, converged, cost, (scan_H, scan_cost, scan_inside)


@numba.njit(cache=True)
def summed_map(g, pts, facing, c, s, tx, ty, residual):
    """Σ M* over the points placed by rotation (c, s) and translation (tx, ty), or with
    ``residual`` the Gauss-Newton cost Σ (1 - M*)²."""
    kind, logodds, means, weights, ox, oy, res, sigma = g
    score = 0.0
    for k in range(pts.shape[0]):
        wx = c * pts[k, 0] - s * pts[k, 1] + tx
        wy = s * pts[k, 0] + c * pts[k, 1] + ty
        if kind == 0:
            m = interpolate_point(logodds, ox, oy, res, wx, wy)[0]
        else:
            fx, fy = _facing(facing, k, c, s)
            m = subcell_point(means, weights, ox, oy, res, sigma, wx, wy, fx, fy)[0]
        score += (1.0 - m) * (1.0 - m) if residual else m
    return score


@numba.njit(cache=True)
def pose_costs(g, pts, facing, poses):
    """The Gauss-Newton cost Σ (1 - M*)² of the points at each of ``poses`` (K, 3)."""
    out = np.empty(poses.shape[0])
    for j in range(poses.shape[0]):
        c = math.cos(poses[j, 2])
        s = math.sin(poses[j, 2])
        out[j] = summed_map(g, pts, facing, c, s, poses[j, 0], poses[j, 1], np.bool_(True))
    return out


# no surface normals: every endpoint draws on every cell (see :func:`_facing`)
NO_FACING = np.zeros((0, 2))


def grid_args(grid: OccupancyGrid, subcell_sigma: float | None) -> tuple:
    kind = 0 if subcell_sigma is None else 1
    sigma = grid.resolution * (subcell_sigma or 1.0)
    ox, oy = grid.origin.tolist()
    return (kind, grid.logodds, grid.means, grid.weights, ox, oy, grid.resolution, sigma)


def points_per_level(
    points: FloatArray, spacing: float, levels: int, finest: NDArray[np.bool_]
) -> list[FloatArray]:
    """The endpoints matched on each level, finest first: ``finest`` (the endpoints kept at
    ``spacing``) and, per coarser level, ``spacing`` doubled."""
    keeps = [finest] + [subsample_by_spacing(points, spacing * 2**k) for k in range(1, levels)]
    return [kept_rows(points, keep) for keep in keeps]


def matched_normals(level_points: list[FloatArray]) -> FloatArray:
    """Surface normals of the finest level's endpoints (the kept ones of
    :func:`bioslam.occupancy_grid.thinned_normals`)."""
    return scan_normals(level_points[0], NORMAL_RADIUS, NORMAL_MAX_GAP)


# The pyramid levels (finest first) whose endpoints draw only on surfaces facing their way
FACING_LEVELS = 2


def facing_normals(level_points: list[FloatArray], finest: FloatArray) -> list[FloatArray]:
    """Each level's surface normals, pointing towards the sensor: ``finest`` (those of
    :func:`matched_normals`) and, on the next ``FACING_LEVELS - 1`` levels, taken over a
    radius and gap as much larger as its endpoints lie farther apart; none above. The
    finer levels tell a thin wall's two faces apart (the rooms' 0.2 m walls, a 240°
    scanner thinned to a scan per metre: every fifth step 0.2 m short with none, 26 cm ATE
    with the finest level's alone, 3.6 cm with two); the coarsest level's cells hold both
    faces of such walls and of pillars, and its pull from afar is what brings a distant
    start into the right basin (with faces there too, a thinned maze route backing up took
    a look-alike 0.4 m on that a motion hypothesis turned 16° had led into)."""
    coarser = [
        scan_normals(points, NORMAL_RADIUS * 2**k, NORMAL_MAX_GAP * 2**k)
        for k, points in enumerate(level_points[1:FACING_LEVELS], start=1)
    ]
    return [finest, *coarser] + [NO_FACING] * (len(level_points) - 1 - len(coarser))


@numba.njit(cache=True)
def kept_rows(points, keep):
    """``points[keep]``, contiguous (NumPy's boolean indexing of rows is ten times slower)."""
    out = np.empty((np.count_nonzero(keep), 2))
    n = 0
    for k in range(points.shape[0]):
        if keep[k]:
            out[n, 0] = points[k, 0]
            out[n, 1] = points[k, 1]
            n += 1
    return out


def levels_up_to(iterations: tuple[int, ...], level: int) -> tuple[int, ...]:
    """Gauss-Newton iterations per level (finest first) with the levels above ``level`` off:
    a descent that starts on ``level``, from a pose a search located on that level's lattice,
    which a coarser level's blur would only pull away."""
    return tuple(n if k <= level else 0 for k, n in enumerate(iterations))


def in_map_frame(direction: ArrayLike, heading: float) -> FloatArray:
    """A direction (x, y, theta * length_scale) of the sensor frame, e.g. a scan's weakest
    (:func:`geometric_information`), in the map frame of a pose of ``heading``."""
    x, y, t = (float(v) for v in np.asarray(direction, dtype=np.float64).reshape(3))
    c, s = math.cos(heading), math.sin(heading)
    return np.array([c * x - s * y, s * x + c * y, t])


def match_scan_to_map(
    pyramid: MapPyramid,
    level_points: list[FloatArray],
    initial_pose: ArrayLike,
    max_iterations: tuple[int, ...],
    step_tolerance: float = 0.05,
    length_scale: float = 3.0,
    degeneracy_ratio: float = 0.01,
    subcell_sigma: float | None = 1.0,
    normals: FloatArray | None = None,
    prior_weight: float | None = None,
    prior_pose: ArrayLike | None = None,
    restart: bool = False,
    prior_information: float | None = None,
    geometry: tuple[float, FloatArray, float] | None = None,
    facing: list[FloatArray] | None = None,
) -> tuple[FloatArray, MatchReport]:
    """Eq. 3: the pose maximising Σ M*(R_p e_i + T_p) (Eq. 4 transform), by Gauss-Newton.

    As in Hector SLAM, maximising Σ M* is done by minimising Σ (1 - M*)², linearised at the
    current estimate; the pose goes through the pyramid coarsest level first, each level
    starting where the previous stopped. ``level_points[k]`` are the sensor-frame endpoints
    used at level ``k`` (finest first). The report's conditioning refers to the finest level.
    ``subcell_sigma`` (in cells) selects the sub-cell map function
    (:func:`bioslam.occupancy_grid.subcell_point`); ``None`` is Hector's bilinear M*.

    Degeneracy guard: with ``normals`` (sensor-frame surface normals of ``level_points[0]``)
    the scan's geometry is checked first (:func:`geometric_conditioning`); along a direction
    it hardly constrains (conditioning below ``degeneracy_ratio``: a corridor's axis) the
    pose is pulled towards the initial pose (the motion prior) by a term weighted by
    ``prior_weight`` and by how little the scan constrains it (:func:`_add_prior`); with
    ``prior_weight`` None it is held there. The odometry uses the prior: a hard hold threw
    away what little the scan has (a warehouse aisle's uprights), and the estimate drifted
    with the prediction (simulated warehouse, SICK: ATE 5.9 m). Pairwise registration,
    whose start is a search's guess and not a motion prior, holds. ``prior_pose`` (default:
    the initial pose) is where the prior pulls: the odometry may start Gauss-Newton from the
    last pose (a better start on the coarse level) while the prior stays the motion model's
    prediction; pulled towards a standstill start, the pose stalled in a corridor longer
    than the range. With ``restart``, a descent that ended worse on the finest level than its
    start or the prior's pose is redone there from the cheaper (:func:`_cheaper_start`): for
    a start that is a trusted prediction; from a search's seed or after a gap the coarse
    levels' move may be the escape from a wrong start (intel: RPE 13.5 cm with restarts
    there, 10.5 without).
    With ``prior_information`` (the prior's information along the weak direction in
    endpoints' worth: an endpoint's variance over the prediction's,
    :meth:`bioslam.motion_model.ConstantVelocityModel.prior_information`) the prior is
    weighed against the scan's own information along that direction instead of its whole
    curvature: the weight is ``prior_information`` over the largest eigenvalue of the
    point-to-line information, so that the prior and the scan's curvature along the weak
    direction (its conditioning times the largest) stand as the endpoints' information
    there and the prediction's. ``geometry``: :func:`geometric_information` of
    ``level_points[0]`` and ``normals``, for a caller that matches one scan from many
    starts (it depends on the scan alone). ``facing``: :func:`facing_normals` of
    ``level_points``; an endpoint then draws only on the map's cells whose surface faces
    the way its own does (:func:`bioslam.occupancy_grid.subcell_point`).

    """
    pose = np.asarray(initial_pose, dtype=np.float64).copy()
    report = MatchReport(num_points=int(level_points[0].shape[0]))
    hold = np.zeros(3)
    weight = 0.0
    if normals is not None:
        cond, weakest, top = geometry or geometric_information(
            level_points[0], normals, length_scale
        )
        report.condition = cond
        report.information = float(top)
        report.weakest_direction = np.asarray(weakest, dtype=np.float64)
        if cond < degeneracy_ratio:
            hold = in_map_frame(weakest, pose[2])
            report.degenerate = True
            report.degenerate_direction = hold
            if prior_information is not None and top > 0.0:
                weight = prior_information / top
            elif prior_weight is not None:
                weight = prior_weight * (1.0 - cond / degeneracy_ratio)
    target = pose.copy() if prior_pose is None else np.asarray(prior_pose, dtype=np.float64)
    prior = (hold, target.reshape(3).copy(), weight)
    if prior_weight is not None:
        hold = np.zeros(3)
    iters = max_iterations[::-1]
    start = pose.copy()
    faces = facing or [NO_FACING] * len(level_points)
    for k in range(len(pyramid.grids) - 1, -1, -1):
        level_iterations = iters[len(pyramid.grids) - 1 - k]
        if k > 0 and level_iterations == 0:
            continue  # a level turned off (:func:`levels_up_to`) would only score the start
        pose, H, mean, n, converged, cost, scan = _gauss_newton_level(
            grid_args(pyramid.grids[k], subcell_sigma), level_points[k], faces[k], pose,
            level_iterations, step_tolerance * pyramid.grids[k].resolution,
            length_scale, degeneracy_ratio, hold, prior,
        )  # fmt: skip
        report.iterations += int(n)
    finest = grid_args(pyramid.finest, subcell_sigma)
    restart_from = None
    if (
        restart
        and len(pyramid.grids) > 1
        and _may_have_left_basin(
            report.condition, degeneracy_ratio, start, pose, pyramid.finest.resolution, length_scale
        )
    ):
        starts = (start,) if prior_pose is None else (start, target)
        restart_from = _cheaper_start(finest, level_points[0], faces[0], starts, cost)
    if restart_from is not None:
        # the coarse levels led the finest one out of the basin it started in
        pose, H, mean, n, converged, cost, scan = _gauss_newton_level(
            finest, level_points[0], faces[0], restart_from, iters[-1],
            step_tolerance * pyramid.finest.resolution, length_scale, degeneracy_ratio, hold, prior,
        )  # fmt: skip
        report.iterations += int(n)
        report.restarted = True
    pose[2] = wrap_angle(pose[2])
    if normals is None:
        _, cond, weakest, degenerate = _guarded_step(
            H, np.zeros(3), length_scale, degeneracy_ratio, 0.0, hold
        )
        report.condition = float(cond)
        report.degenerate = bool(degenerate)
        if degenerate:
            report.degenerate_direction = np.asarray(weakest, dtype=np.float64)
    if weight > 0.0:
        report.prior_terms = (scan[0], prior[0], weight, length_scale)
    report.converged = bool(converged)
    report.score = float(mean)
    report.covariance_terms = (
        *scan, level_points[0].shape[0], 0.25 if subcell_sigma is None else 1.0, length_scale,
        report.degenerate_direction.copy(), report.condition,
    )  # fmt: skip
    return pose, report


def prior_share(H: FloatArray, direction: FloatArray, weight: float, length_scale: float) -> float:
    """The motion prior's share of the curvature along ``direction`` (unit, scaled) at the
    match: :func:`_add_prior`'s weight against the scan's own normal matrix ``H`` there. The
    match moved from the prior by ``1 - share`` of where the scan alone put it: along a
    featureless corridor the map's texture and edges give ``H`` a curvature far above what
    the scan's few surfaces across the axis do, and taken as the geometry's (its
    conditioning), a pull of a millimetre by them read as a metre of evidence."""
    scale = np.array([1.0, 1.0, 1.0 / length_scale])
    hs = np.asarray(H, dtype=np.float64) * np.outer(scale, scale)
    k = weight * float(np.trace(hs))
    along = float(direction @ hs @ direction)
    return k / (k + along) if k + along > 0.0 else 0.0


def match_covariance(
    H: FloatArray, cost: float, inside: int, points: int, outside: float, length_scale: float,
    degenerate: FloatArray | None = None, condition: float = 1.0,
) -> FloatArray:
    """Covariance of a match's pose (x, y, theta; map frame): ``σ² H⁻¹`` with ``H`` the
    Gauss-Newton normal matrix of Eq. 3 at the final pose from the scan alone (without the
    motion prior, whose weight is relative to the scan's and no measured variance) and
    ``σ²`` the residual variance Σ (1 - M*)² / (n - 3) over the ``inside`` endpoints in the
    map (``cost`` sums all ``points``, each outside adding ``outside``: the map function's
    residual there). The usual least-squares estimate: it assumes independent residuals, so
    it is optimistic where neighbouring endpoints share cells.

    Along a ``degenerate`` direction (unit, (x, y, theta * ``length_scale``), map frame:
    :attr:`MatchReport.degenerate_direction`) ``H`` is not trusted: a featureless
    corridor's walls, mapped from noisy ranges, have a texture along the axis that gives
    ``H`` a curvature there as large as across it (simulated corridor: 6 mm along, 4 mm
    across). There the curvature is replaced by ``condition`` (the scan's geometric
    conditioning, :func:`geometric_conditioning`) times the largest, the share the scan's
    surfaces give it. Curvatures below 1e-9 of the largest are raised to that. NaN with
    fewer than 4 points inside the map."""
    if inside < 4:
        return np.full((3, 3), np.nan)
    variance = max(cost - outside * (points - inside), 0.0) / (inside - 3)
    d = np.zeros(3) if degenerate is None else np.asarray(degenerate, dtype=np.float64)
    return _scaled_inverse(np.ascontiguousarray(H), variance, float(length_scale), d,
                           float(condition))  # fmt: skip


@numba.njit(cache=True)
def _scaled_inverse(H, variance, length, degenerate, condition):
    """``variance * H⁻¹`` with the curvature along ``degenerate`` (scaled) set to
    ``condition`` times the largest and the eigenvalues of the scaled ``H`` floored (see
    :func:`match_covariance`)."""
    scale = np.array([1.0, 1.0, 1.0 / length])
    Hs = H * np.outer(scale, scale)
    if degenerate @ degenerate > 0.5:
        top = np.linalg.eigvalsh(Hs)[2]
        proj = np.eye(3) - np.outer(degenerate, degenerate)
        Hs = proj @ Hs @ proj + condition * top * np.outer(degenerate, degenerate)
    w, v = np.linalg.eigh(Hs)
    if w[2] <= 0.0:
        return np.full((3, 3), np.nan)
    w = np.maximum(w, 1e-9 * w[2])
    return variance * np.outer(scale, scale) * ((v / w) @ v.T)


def _may_have_left_basin(
    condition: float, degeneracy_ratio: float, start: FloatArray, pose: FloatArray,
    resolution: float, length_scale: float,
) -> bool:
    """Whether the pyramid's descent may have led the finest level out of the basin its
    start lay in, so that :func:`_worse_than_start` is worth its pass over the endpoints: the
    scan constrains some direction weakly (conditioning below ten times
    ``degeneracy_ratio``), or the descent ended farther than a finest cell (or that at
    ``length_scale`` in heading) from a start that was a trusted prediction. A
    well-conditioned scan does not pin the coarse levels' optimum: their cells' sub-cell
    means sit up to half a cell off a wall that straddles two (the map's alignment decides
    how far), and on the simulated rooms, UTM-30LX at 40 Hz, the coarsest level moved
    every pose 10 cm aside and the middle one sometimes carried it on into the next basin
    (a 19 cm jump back on a well-conditioned scan, 18 cm off at worst where started on the
    world's frame the run stayed within 4.3 cm)."""
    if condition < 10.0 * degeneracy_ratio:
        return True
    moved, turn = separation(start, pose)
    return moved > resolution or turn * length_scale > resolution


def _cheaper_start(
    finest: tuple, points: FloatArray, facing: FloatArray, starts: tuple[FloatArray, ...],
    cost: float,
) -> FloatArray | None:
    """Of ``starts`` (the descent's start and the motion prior's pose), the one whose finest
    level cost Σ (1 - M*)² is lowest, if below ``cost``, where the pyramid's descent ended
    (the motion prior's included); else None. A coarse level's optimum can lie a cell off
    the true one (in a corridor longer than the range, the coarse map's edge ahead pulls the
    pose back: simulated URG-04LX, a 19 cm slip backwards from a start 1 cm off), and the
    finer levels then converge in a neighbouring basin; matched again on the finest level
    from the cheaper start, the pose can only end better than both (Gauss-Newton with
    damping never raises the cost). The prior's pose counts where
    the descent started elsewhere (:meth:`bioslam.odometry.LidarOdometry._best_start` chose
    the last pose, standing still, on the coarsest level's cost): along a corridor whose
    walls the scan sees up to 25 m ahead, the coarsest level's pull of a lone far endpoint
    chose the standstill, the finest level settled 12 cm behind the prediction, which it
    scored better, and the speed carried fell from 0.5 m/s to nothing in a second (a ring
    of 100 m corridors, SICK, seed 3). Checked only where :func:`_may_have_left_basin`: on
    every scan it would cost a dense scan a tenth of its match."""
    best, lowest = None, cost
    for pose in starts:
        c, s = math.cos(pose[2]), math.sin(pose[2])
        value = summed_map(finest, points, facing, c, s, pose[0], pose[1], True)
        if value < lowest:
            best, lowest = pose, value
    return best


def geometric_conditioning(
    points: FloatArray, normals: FloatArray, length_scale: float
) -> tuple[float, FloatArray]:
    """How well a scan's surfaces pin down (x, y, theta): each endpoint with a normal n
    constrains the motion along n and the rotation by ``p x n`` (point-to-line
    information). Returns the smallest / largest eigenvalue of that information, with theta
    scaled by ``length_scale``, and its weakest unit direction (x, y, theta * length_scale)
    in the sensor frame. A featureless corridor gives ~0 along its axis."""
    return geometric_information(points, normals, length_scale)[:2]


def geometric_information(
    points: FloatArray, normals: FloatArray, length_scale: float
) -> tuple[float, FloatArray, float]:
    """:func:`geometric_conditioning` and the largest eigenvalue of the point-to-line
    information (about the number of endpoints whose normals pin its strongest direction):
    the conditioning times it is the information along the weakest direction, in endpoints
    (a far end wall's few beams)."""
    return _conditioning_kernel(
        np.ascontiguousarray(points, dtype=np.float64),
        np.ascontiguousarray(normals, dtype=np.float64),
        float(length_scale),
    )


def mapped_conditioning(
    grid: OccupancyGrid, points: FloatArray, normals: FloatArray, pose: ArrayLike,
    level: float, length_scale: float,
) -> tuple[float, FloatArray]:
    """:func:`geometric_conditioning` of the endpoints that ``pose`` puts on a wall the map
    already holds (a cell of ``grid``, or one of its 8 neighbours, with a log-odds above
    ``level``): a surface seen for the first time (a corridor's end coming into range) does
    not fix the pose against the map."""
    p = np.asarray(pose, dtype=np.float64).reshape(3)
    ox, oy = grid.origin.tolist()
    pts = np.ascontiguousarray(points, dtype=np.float64)
    used = _mapped_normals(grid.logodds, ox, oy, grid.resolution, pts, normals, p, level)
    return _conditioning_kernel(pts, used, float(length_scale))[:2]


@numba.njit(cache=True)
def _mapped_normals(logodds, ox, oy, res, pts, normals, pose, level):
    """``normals`` with those of the points ``pose`` does not place next to a cell above
    ``level`` zeroed (no normal: no constraint)."""
    out = np.zeros_like(normals)
    c = math.cos(pose[2])
    s = math.sin(pose[2])
    for k in range(pts.shape[0]):
        wx = c * pts[k, 0] - s * pts[k, 1] + pose[0]
        wy = s * pts[k, 0] + c * pts[k, 1] + pose[1]
        if above_near_point(logodds, wx, wy, ox, oy, res, level):
            out[k, 0] = normals[k, 0]
            out[k, 1] = normals[k, 1]
    return out


@numba.njit(cache=True)
def _conditioning_kernel(points, normals, length_scale):
    info = np.zeros((3, 3))
    used = 0
    for k in range(points.shape[0]):
        nx = normals[k, 0]
        ny = normals[k, 1]
        if nx == 0.0 and ny == 0.0:
            continue
        used += 1
        _add_outer(info, nx, ny, (points[k, 0] * ny - points[k, 1] * nx) / length_scale)
    _mirror_upper(info)
    if used < 3:
        return 0.0, np.array([1.0, 0.0, 0.0]), 0.0
    w, v = np.linalg.eigh(info)
    return max(w[0], 0.0) / w[2], v[:, 0].copy(), w[2]
