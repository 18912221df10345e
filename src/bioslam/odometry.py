"""LiDAR odometry (paper Sec. III-A, Eq. 1-4): scan-to-local-map Gauss-Newton matching.

Follows Hector SLAM (Kohlbrecher et al. 2011), the method the paper cites: every scan is
matched against a local log-odds occupancy grid by maximising the summed map function M* at the
scan endpoints (Eq. 3), coarse to fine over a map pyramid, starting from a constant-velocity
prediction. The map is a window that scrolls with the robot, so memory is constant however long
the run.

Frames: the sensor frame is taken as the robot frame (no extrinsic offset). The pose of a scan
is the pose at ``scan.stamp`` (the first beam, as in ROS); with per-beam timing the endpoints
are de-skewed to that instant with the current constant-velocity estimate.

No file or terminal I/O here.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import ndimage

from bioslam.geometry import between, compose, transform_points, wrap_angle
from bioslam.occupancy_grid import (
    NORMAL_MAX_GAP,
    NORMAL_RADIUS,
    LogOddsConfig,
    MapPyramid,
    OccupancyGrid,
    interpolate_point,
    scan_normals,
    subcell_point,
    subsample_by_spacing,
    thinned_normals,
)
from bioslam.scan import LaserScan

FloatArray = NDArray[np.float64]


@dataclass
class OdometryConfig:
    """Parameters of :class:`LidarOdometry` (defaults and where they come from).

    Attributes:
        resolution: finest map cell, metres. Hector SLAM's default ``map_resolution`` (0.05 m).
        levels: map pyramid levels, each twice as coarse. Hector's ``map_multi_res_levels``
            (3); the coarsest cell (0.2 m) sets the capture range of the matcher.
        map_size: side of the square local window, metres. Larger than the usable range of
            most indoor 2D LiDARs (Hector's 1024 cells x 0.05 m = 51 m is of the same order).
        recenter_distance: the window scrolls when the robot is this far from its centre,
            metres; a quarter of the window keeps at least ``map_size / 4`` of map around it.
        max_range: endpoints farther than this are not used, metres (beyond it a 0.25° beam
            spacing leaves gaps of more than a finest cell; also bounded by the window).
        min_range: endpoints closer than this are dropped (the robot's own body), metres.
        insert_distance, insert_angle: a scan is fused into the map when the pose has moved
            this far (metres, radians) from the last fused pose. Hector fuses at 0.4 m / 0.9
            rad; we fuse more often because a small field of view needs the map refreshed
            when turning (measured in ``benchmarks/bench_odometry.py``).
        point_spacing: matching uses endpoints at least this far apart along the scan, per
            level multiplied by the level's coarseness (2^k); keeps the cost bounded for dense
            scans at no measurable accuracy cost (benchmark). Metres.
        max_iterations: Gauss-Newton iterations per level, finest first (Hector runs a few
            per level; more are cheap because a converged level stops early).
        step_tolerance: stop a level when the step is below this fraction of the level's
            cell (and that divided by ``length_scale``, radians): a coarse level only has to
            bring the pose into the next level's basin. At 0.05 (2.5 mm at the finest level)
            the maze's RPE is that of 0.002 with a third fewer iterations (benchmark).
        length_scale: metres that make a radian commensurate with a metre when judging how
            well-conditioned the problem is (a typical indoor endpoint distance).
        degeneracy_ratio: a direction whose curvature is below this fraction of the strongest
            is unconstrained (a featureless corridor): the step keeps the prediction along it
            instead of letting noise move the pose, and the report flags it.
        subcell_sigma: width of the sub-cell map function's kernels in cells of each level
            (:func:`bioslam.occupancy_grid.subcell_point`); ``None`` uses Hector's bilinear
            M*, which biases the match towards cell centres (benchmark: more drift).
        start_margin: the repeated-motion or standstill start replaces the prediction only if
            its coarse-level cost is lower by this fraction (ours; see ``_best_start``).
        velocity_window: seconds of past poses the constant-velocity estimate (prediction and
            de-skew) is taken over; ours, about the time constant of a robot's acceleration,
            and several scans of a 40 Hz scanner.
        velocity_scans: ... and over at least this many scan intervals: a 360° scanner
            sweeps during the whole scan period, so a velocity error de-skews the next scan
            wrongly by up to a period's worth of motion; averaging 3 intervals keeps that
            loop stable (measured: the 7 Hz low-cost preset diverges with 1, drifts 0.5 %
            with 3).
        free_logodds: endpoints falling where the cell and its neighbours are all at or below
            this log-odds (free, seen so by about four scans with the default miss update) are
            not fused into the map (moving objects; ours).
        deskew: correct per-beam motion when ``scan.time_increment > 0``.
        min_points: fewer valid endpoints than this give a prediction-only update.
        recovery_free_fraction: a match that leaves more than this fraction of the matched
            endpoints in cells the map knows to be free has probably failed (a good match
            leaves almost none there: 1 % median, 4 % at the 90th percentile on freiburg-079,
            0 on the maze). The scan is then searched for exhaustively around its start
            (``recovery_distance`` metres, ``recovery_angle`` radians, a half-cell lattice
            of the coarsest level) and matched again from the best lattice poses; a match
            is kept if its score less its fraction in free space is higher. (A person close
            to the sensor also puts endpoints in free space; the retry then costs time but
            finds nothing better.)
        recovery_score_ratio, score_window: a match has also failed if its score (mean
            M*) is below this fraction of the median score of the last ``score_window``
            matches (of the first scan on its own map before that): early in a run, or in a
            log whose scans are far apart, few cells are yet known free, and a failed match
            is told by its points landing on nothing (intel: 0.02 for a failed match of the
            second scan, against 0.6 for the first scan on its own map; the lowest accepted
            scores on our logs and simulations are 0.24-0.5 of the median).
        wide_recovery_distance, wide_recovery_angle: when the close search fails too, a
            one-cell lattice this far around the previous pose (metres, radians) is
            searched; its match must pass both tests above to be kept (a scan that matches
            nowhere well, the view blocked, stays near the prediction). 0 disables it.
        recovery_seeds: Gauss-Newton runs from this many of a search's best local maxima:
            in a cluttered or narrow view the lattice's best peak is often a neighbour's
            (freiburg thinned to a scan per 0.5 m: RPE 6.0 cm with 1, 4.2 cm with 3).
        gap_time: after this many seconds without a scan both searches run even if the
            first match looks fine: the constant-velocity prediction is then no better
            than the previous pose (freiburg-079 drops a scan in a turn; thinned logs
            such as intel have scans 0.5-1 m and up to 35 degrees apart), and a match in
            the wrong basin of a corridor can look fine. A match found this way replaces
            one that did not fail only if it is clearly better (``start_margin``).
        log_odds: hit/miss increments of the map cells.
    """

    resolution: float = 0.05
    levels: int = 3
    map_size: float = 48.0
    recenter_distance: float = 10.0
    max_range: float = 30.0
    min_range: float = 0.05
    insert_distance: float = 0.2
    insert_angle: float = 0.15
    point_spacing: float = 0.05
    max_iterations: tuple[int, ...] = (10, 10, 15)
    step_tolerance: float = 0.05
    length_scale: float = 3.0
    degeneracy_ratio: float = 0.01
    velocity_window: float = 0.1
    velocity_scans: int = 3
    start_margin: float = 0.1
    subcell_sigma: float | None = 1.0
    free_logodds: float = -1.5
    deskew: bool = True
    min_points: int = 20
    recovery_free_fraction: float = 0.2
    recovery_distance: float = 0.3
    recovery_angle: float = 0.35
    wide_recovery_distance: float = 1.5
    wide_recovery_angle: float = math.pi / 4
    recovery_score_ratio: float = 0.5
    recovery_seeds: int = 3
    gap_time: float = 0.5
    score_window: int = 100
    log_odds: LogOddsConfig = field(default_factory=LogOddsConfig)

    def __post_init__(self) -> None:
        if self.levels < 1 or len(self.max_iterations) != self.levels:
            raise ValueError(
                f"max_iterations needs one entry per level ({self.levels}), "
                f"got {self.max_iterations}"
            )
        if not (self.resolution > 0 and self.map_size > 4 * self.recenter_distance > 0):
            raise ValueError("need resolution > 0 and map_size > 4 * recenter_distance > 0")
        if self.score_window < 1 or self.recovery_seeds < 1:
            raise ValueError(
                f"score_window and recovery_seeds must be at least 1, got "
                f"{self.score_window} and {self.recovery_seeds}"
            )


@dataclass
class MatchReport:
    """What the last :meth:`LidarOdometry.update` did.

    Attributes:
        iterations: Gauss-Newton iterations summed over the levels.
        degenerate: some direction was unconstrained by the scan (e.g. a long corridor).
        degenerate_direction: unit vector (x, y, theta * length_scale) in the map frame of the
            least constrained direction (zeros when not degenerate).
        condition: smallest / largest curvature (scaled Hessian eigenvalues), 1 = isotropic.
        score: mean M* over the matched endpoints at the finest level (1 = all on walls).
        num_points: endpoints used for matching (after subsampling).
        inserted: the scan was fused into the map.
        predicted_only: no usable scan; the pose is the constant-velocity prediction.
        converged: the finest level stopped on a small step within its iteration budget.
        free_fraction: matched endpoints that fell in cells the map knows to be free.
        recovered: the match comes from an exhaustive search, run because the first match
            failed or after a gap between scans (``OdometryConfig.recovery_*``,
            ``gap_time``), which found a better one.
    """

    iterations: int = 0
    degenerate: bool = False
    degenerate_direction: FloatArray = field(default_factory=lambda: np.zeros(3))
    condition: float = 1.0
    score: float = 0.0
    num_points: int = 0
    inserted: bool = False
    predicted_only: bool = False
    converged: bool = False
    free_fraction: float = 0.0
    recovered: bool = False


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
def _normal_equations(g, pts, pose, H, b):
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
            m, gx, gy, ok = subcell_point(means, weights, ox, oy, res, sigma, wx, wy)
        cost += (1.0 - m) * (1.0 - m)
        if ok:
            inside += 1
            total += m
            _add_point(H, b, px, py, c, s, m, gx, gy)
    _mirror_upper(H)
    mean = total / inside if inside > 0 else 0.0
    return mean, cost, inside


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
def _gauss_newton_level(g, pts, pose, max_iter, tol, length, ratio, hold):
    """Gauss-Newton on one level with Levenberg-Marquardt damping (Nielsen's schedule): a
    step that raises the cost is refused and retried shorter, and the damping of an
    accepted step shrinks by how well the quadratic model predicted the gain, so that the
    map function's kinks at cell boundaries cannot make the pose oscillate. A first refusal
    halves the step at once: near the optimum Gauss-Newton underestimates the curvature of
    a peaked M* (its Hessian drops the (1 - M*) M*'' term) and overshoots, mostly in
    heading, and a token damping of 0.001 only wasted iterations (maze: 1.0 vs 1.3 ms per
    scan, RPE 0.38 cm / 0.085° vs 0.40 cm / 0.106°). Returns
    ``(pose, H, mean M*, iterations, converged)``."""
    pose = pose.copy()
    trial = np.empty(3)
    H = np.zeros((3, 3))
    b = np.zeros(3)
    H2 = np.zeros((3, 3))
    b2 = np.zeros(3)
    mean, cost, inside = _normal_equations(g, pts, pose, H, b)
    damping = 0.0
    growth = 2.0
    iterations = 0
    converged = False
    if inside < 3:
        return pose, H, mean, iterations, converged
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
        mean2, cost2, inside2 = _normal_equations(g, pts, trial, H2, b2)
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
    return pose, H, mean, iterations, converged


@numba.njit(cache=True)
def _correlative_scores(g, pts, pose, nt, nx, step_xy, step_th):
    """The Eq. 3 objective (summed M*) on the (theta, x, y) lattice of ``2 nt + 1`` headings
    and ``(2 nx + 1)^2`` positions around ``pose``."""
    out = np.empty((2 * nt + 1, 2 * nx + 1, 2 * nx + 1))
    for it in range(-nt, nt + 1):
        th = pose[2] + it * step_th
        c = math.cos(th)
        s = math.sin(th)
        for ix in range(-nx, nx + 1):
            for iy in range(-nx, nx + 1):
                tx = pose[0] + ix * step_xy
                ty = pose[1] + iy * step_xy
                out[it + nt, ix + nx, iy + nx] = _summed_map(g, pts, c, s, tx, ty, False)
    return out


@numba.njit(cache=True)
def _summed_map(g, pts, c, s, tx, ty, residual):
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
            m = subcell_point(means, weights, ox, oy, res, sigma, wx, wy)[0]
        score += (1.0 - m) * (1.0 - m) if residual else m
    return score


@numba.njit(cache=True)
def _costs(g, pts, poses):
    """The Gauss-Newton cost Σ (1 - M*)² of the points at each of ``poses`` (K, 3)."""
    out = np.empty(poses.shape[0])
    for j in range(poses.shape[0]):
        c = math.cos(poses[j, 2])
        s = math.sin(poses[j, 2])
        out[j] = _summed_map(g, pts, c, s, poses[j, 0], poses[j, 1], True)
    return out


# --------------------------------------------------------------------------------------------
# SE(2) with a constant twist


@numba.njit(cache=True)
def _se2_exp_scalar(vx: float, vy: float, w: float, t: float) -> tuple[float, float, float]:
    th = w * t
    mx, my = _twist_translation(vx, vy, w, t, math.cos(th), math.sin(th))
    return mx, my, th


@numba.njit(cache=True)
def _twist_translation(vx, vy, w, t, c, s):
    """The translation of :func:`se2_exp` after ``t``, given ``c, s = cos, sin(w t)``."""
    if abs(w) < 1e-9:
        a = t
        bb = 0.5 * w * t * t
    else:
        a = s / w
        bb = (1.0 - c) / w
    return vx * a - vy * bb, vx * bb + vy * a


def se2_exp(twist: ArrayLike, t: ArrayLike = 1.0) -> FloatArray:
    """The relative pose reached after time ``t`` (array) moving with body twist (vx, vy, w)."""
    vx, vy, w = np.asarray(twist, dtype=np.float64)
    if np.isscalar(t):
        return np.array(_se2_exp_scalar(vx, vy, w, float(t)))
    t = np.asarray(t, dtype=np.float64)
    th = w * t
    small = abs(w) < 1e-9
    a = t if small else np.sin(th) / w
    bb = 0.5 * w * t * t if small else (1.0 - np.cos(th)) / w
    return np.stack([vx * a - vy * bb, vx * bb + vy * a, th], axis=-1)


def se2_log(delta: ArrayLike) -> FloatArray:
    """The constant body twist that reaches relative pose ``delta`` in unit time."""
    x, y, th = np.asarray(delta, dtype=np.float64)
    if abs(th) < 1e-9:
        return np.array([x, y, th])
    a = math.sin(th) / th
    bb = (1.0 - math.cos(th)) / th
    det = a * a + bb * bb
    return np.array([(a * x + bb * y) / det, (-bb * x + a * y) / det, th])


@numba.njit(cache=True)
def _deskewed(px, py, vx, vy, w, t):
    """Point ``(px, py)`` measured ``t`` after the stamp, in the sensor frame at the stamp."""
    return _moved(px, py, vx, vy, w, t, math.cos(w * t), math.sin(w * t))


@numba.njit(cache=True)
def _moved(px, py, vx, vy, w, t, c, s):
    """:func:`_deskewed` given ``c, s = cos, sin(w t)``."""
    mx, my = _twist_translation(vx, vy, w, t, c, s)
    return c * px - s * py + mx, s * px + c * py + my


@numba.njit(cache=True)
def _deskew_kernel(pts, times, vx, vy, w):
    out = np.empty((pts.shape[0], 2))
    for k in range(pts.shape[0]):
        out[k, 0], out[k, 1] = _deskewed(pts[k, 0], pts[k, 1], vx, vy, w, times[k])
    return out


def deskew_points(points: ArrayLike, beam_times: ArrayLike, twist: ArrayLike) -> FloatArray:
    """Move each endpoint ``(N, 2)``, measured ``beam_times`` after the scan stamp, into the
    sensor frame at the stamp, assuming a constant body twist (vx, vy, w)."""
    pts = np.ascontiguousarray(np.asarray(points, dtype=np.float64).reshape(-1, 2))
    times = np.ascontiguousarray(np.asarray(beam_times, dtype=np.float64).reshape(-1))
    vx, vy, w = (float(v) for v in np.asarray(twist, dtype=np.float64).reshape(3))
    return _deskew_kernel(pts, times, vx, vy, w)


@numba.njit(cache=True)
def _usable_endpoints(ranges, cos_a, sin_a, lo, hi, time_increment, vx, vy, w):
    """Sensor-frame endpoints of the finite returns within ``[lo, hi]`` metres (beam
    directions ``cos_a, sin_a``), each beam ``k`` de-skewed from ``k * time_increment`` back
    to the scan stamp with the body twist (vx, vy, w) when ``time_increment > 0``."""
    out = np.empty((ranges.shape[0], 2))
    n = 0
    # the sweep's rotation advances by a fixed angle per beam: rotate (c, s) by it instead of
    # two trigonometric calls per beam
    step_c = math.cos(w * time_increment)
    step_s = math.sin(w * time_increment)
    c = 1.0
    s = 0.0
    for k in range(ranges.shape[0]):
        if k > 0:
            c, s = c * step_c - s * step_s, s * step_c + c * step_s
        r = float(ranges[k])
        if not (r >= lo and r <= hi and math.isfinite(r)):  # NaN fails every comparison
            continue
        px = r * cos_a[k]
        py = r * sin_a[k]
        if time_increment > 0.0:
            px, py = _moved(px, py, vx, vy, w, k * time_increment, c, s)
        out[n, 0] = px
        out[n, 1] = py
        n += 1
    return out[:n].copy()


# --------------------------------------------------------------------------------------------
# Matching


def _lattice_search(
    grid: OccupancyGrid,
    subcell_sigma: float | None,
    points: FloatArray,
    guess: FloatArray,
    distance: float,
    angle: float,
    step: float,
    radius: float,
    peaks: int = 1,
) -> FloatArray:
    """Exhaustive search of the Eq. 3 objective on ``grid`` within ``distance`` m and
    ``angle`` rad of ``guess``, ``step`` m apart in position and, in heading, by the angle
    that moves a point at ``radius`` m (at least one cell) by ``step``. Returns the poses
    ``(K, 3)`` of the ``peaks`` best local maxima of the lattice, best first."""
    step_th = step / max(radius, grid.resolution)
    nt, nx = int(angle / step_th), int(distance / step)
    scores = _correlative_scores(
        _grid_args(grid, subcell_sigma), points, guess, nt, nx, step, step_th
    )
    if peaks == 1:
        best = np.array([np.argmax(scores)])
    else:
        local = scores == ndimage.maximum_filter(scores, size=3, mode="nearest")
        flat = np.flatnonzero(local)
        best = flat[np.argsort(-scores.ravel()[flat], kind="stable")[:peaks]]
    it, ix, iy = np.unravel_index(best, scores.shape)
    offsets = np.column_stack([(ix - nx) * step, (iy - nx) * step, (it - nt) * step_th])
    return guess + offsets


def _grid_args(grid: OccupancyGrid, subcell_sigma: float | None) -> tuple:
    kind = 0 if subcell_sigma is None else 1
    sigma = grid.resolution * (subcell_sigma or 1.0)
    ox, oy = grid.origin.tolist()
    return (kind, grid.logodds, grid.means, grid.weights, ox, oy, grid.resolution, sigma)


def _level_points(
    points: FloatArray, spacing: float, levels: int, finest: NDArray[np.bool_]
) -> list[FloatArray]:
    """The endpoints matched on each level, finest first: ``finest`` (the endpoints kept at
    ``spacing``) and, per coarser level, ``spacing`` doubled."""
    keeps = [finest] + [subsample_by_spacing(points, spacing * 2**k) for k in range(1, levels)]
    return [_kept_rows(points, keep) for keep in keeps]


def _matched_normals(level_points: list[FloatArray]) -> FloatArray:
    """Surface normals of the finest level's endpoints (the kept ones of
    :func:`bioslam.occupancy_grid.thinned_normals`)."""
    return scan_normals(level_points[0], NORMAL_RADIUS, NORMAL_MAX_GAP)


@numba.njit(cache=True)
def _kept_rows(points, keep):
    """``points[keep]``, contiguous (NumPy's boolean indexing of rows is ten times slower)."""
    out = np.empty((np.count_nonzero(keep), 2))
    n = 0
    for k in range(points.shape[0]):
        if keep[k]:
            out[n, 0] = points[k, 0]
            out[n, 1] = points[k, 1]
            n += 1
    return out


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
) -> tuple[FloatArray, MatchReport]:
    """Eq. 3: the pose maximising Σ M*(R_p e_i + T_p) (Eq. 4 transform), by Gauss-Newton.

    As in Hector SLAM, maximising Σ M* is done by minimising Σ (1 - M*)², linearised at the
    current estimate; the pose goes through the pyramid coarsest level first, each level
    starting where the previous stopped. ``level_points[k]`` are the sensor-frame endpoints
    used at level ``k`` (finest first). The report's conditioning refers to the finest level.
    ``subcell_sigma`` (in cells) selects the sub-cell map function
    (:func:`bioslam.occupancy_grid.subcell_point`); ``None`` is Hector's bilinear M*.

    Degeneracy guard: with ``normals`` (sensor-frame surface normals of ``level_points[0]``)
    the scan's geometry is checked first (:func:`geometric_conditioning`); a direction it
    does not constrain (a featureless corridor's axis) is held at the initial pose, because
    the map's texture along a wall would otherwise pull the pose along it.
    """
    pose = np.asarray(initial_pose, dtype=np.float64).copy()
    report = MatchReport(num_points=int(level_points[0].shape[0]))
    hold = np.zeros(3)
    if normals is not None:
        cond, weakest = geometric_conditioning(level_points[0], normals, length_scale)
        report.condition = cond
        if cond < degeneracy_ratio:
            c, s = math.cos(pose[2]), math.sin(pose[2])
            hold = np.array([c * weakest[0] - s * weakest[1], s * weakest[0] + c * weakest[1],
                             weakest[2]])  # fmt: skip
            report.degenerate = True
            report.degenerate_direction = hold
    iters = max_iterations[::-1]
    for k in range(len(pyramid.grids) - 1, -1, -1):
        pose, H, mean, n, converged = _gauss_newton_level(
            _grid_args(pyramid.grids[k], subcell_sigma), level_points[k], pose,
            iters[len(pyramid.grids) - 1 - k], step_tolerance * pyramid.grids[k].resolution,
            length_scale, degeneracy_ratio, hold,
        )  # fmt: skip
        report.iterations += int(n)
    pose[2] = wrap_angle(pose[2])
    if normals is None:
        _, cond, weakest, degenerate = _guarded_step(
            H, np.zeros(3), length_scale, degeneracy_ratio, 0.0, hold
        )
        report.condition = float(cond)
        report.degenerate = bool(degenerate)
        if degenerate:
            report.degenerate_direction = np.asarray(weakest, dtype=np.float64)
    report.converged = bool(converged)
    report.score = float(mean)
    return pose, report


def geometric_conditioning(
    points: FloatArray, normals: FloatArray, length_scale: float
) -> tuple[float, FloatArray]:
    """How well a scan's surfaces pin down (x, y, theta): each endpoint with a normal n
    constrains the motion along n and the rotation by ``p x n`` (point-to-line
    information). Returns the smallest / largest eigenvalue of that information, with theta
    scaled by ``length_scale``, and its weakest unit direction (x, y, theta * length_scale)
    in the sensor frame. A featureless corridor gives ~0 along its axis."""
    return _conditioning_kernel(
        np.ascontiguousarray(points, dtype=np.float64),
        np.ascontiguousarray(normals, dtype=np.float64),
        float(length_scale),
    )


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
        return 0.0, np.array([1.0, 0.0, 0.0])
    w, v = np.linalg.eigh(info)
    return max(w[0], 0.0) / w[2], v[:, 0].copy()


def _match_quality(report: MatchReport) -> float:
    """Mean M* over the matched endpoints, less the fraction of them in known free space
    (negative evidence: the map saw through where the match puts a wall)."""
    return report.score - report.free_fraction


class LidarOdometry:
    """Pose change from consecutive LiDAR scans alone (paper Sec. III-A).

    ``update(scan)`` returns Δp, the motion since the previous scan in the previous robot
    frame (``geometry.between(prev_pose, pose)``); ``pose`` is the pose in the odometry frame
    (the first scan's pose is ``initial_pose``); ``last_report`` says how the match went and
    ``last_points`` holds the scan's usable endpoints (sensor frame, de-skewed to its stamp).
    """

    def __init__(self, config: OdometryConfig | None = None, initial_pose: ArrayLike = (0, 0, 0)):
        self.config = config or OdometryConfig()
        c = self.config
        self.pose = np.asarray(initial_pose, dtype=np.float64).reshape(3).copy()
        self.pyramid = MapPyramid(
            c.resolution, c.map_size, c.levels, c.log_odds, origin=None
        )
        self.pyramid.recenter(self.pose[0], self.pose[1])
        self.last_report = MatchReport()
        self.last_points: FloatArray = np.zeros((0, 2))
        self.num_scans = 0
        self.num_predicted_only = 0
        self.num_recovered = 0
        self.num_degenerate = 0
        self._twist = np.zeros(3)
        self._last_delta = np.zeros(3)
        self._last_stamp: float | None = None
        self._history: deque[tuple[float, FloatArray]] = deque()
        self._scores: deque[float] = deque(maxlen=self.config.score_window)
        self._typical_score = 0.0
        self._num_scores = 0
        self._last_inserted: FloatArray | None = None
        self._directions: tuple[FloatArray, FloatArray, FloatArray] | None = None

    # -- steps of one update ------------------------------------------------------------------

    def _time_step(self, stamp: float) -> float:
        if self._last_stamp is None:
            return 0.0
        dt = stamp - self._last_stamp
        return dt if dt > 0 else 0.0

    def _sensor_points(self, scan: LaserScan) -> FloatArray:
        c = self.config
        lo = max(c.min_range, scan.range_min, np.nextafter(0.0, 1.0))
        hi = min(c.max_range, scan.range_max)
        increment = scan.time_increment if c.deskew else 0.0
        vx, vy, w = self._twist
        cos_a, sin_a = self._beam_directions(scan.angles)
        return _usable_endpoints(scan.ranges, cos_a, sin_a, lo, hi, increment, vx, vy, w)

    def _beam_directions(self, angles: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Cosines and sines of the beam angles, kept while the scans' angles stay the same."""
        known = self._directions
        same = known is not None and (
            known[0] is angles
            or (known[0].shape == angles.shape and np.array_equal(known[0], angles))
        )
        if not same:
            self._directions = known = (angles, np.cos(angles), np.sin(angles))
        return known[1], known[2]

    def _should_insert(self) -> bool:
        if self._last_inserted is None:
            return True
        d = between(self._last_inserted, self.pose)
        c = self.config
        return bool(math.hypot(d[0], d[1]) >= c.insert_distance or abs(d[2]) >= c.insert_angle)

    def _insert(self, pts: FloatArray, normals: FloatArray) -> None:
        c = self.config
        centre = self.pyramid.finest.origin + 0.5 * c.map_size
        if np.max(np.abs(self.pose[:2] - centre)) > c.recenter_distance:
            self.pyramid.recenter(self.pose[0], self.pose[1])
        static = self._not_in_known_free_space(pts)
        self.pyramid.insert_scan(self.pose, pts[static], c.max_range, normals[static])
        self._last_inserted = self.pose.copy()

    def _not_in_known_free_space(self, pts: FloatArray) -> NDArray[np.bool_]:
        """Endpoints whose cell and its 8 neighbours several earlier scans saw free are taken
        for moving objects (a person) and not fused: fused, they leave a trail in the map
        that the next scans' points on the same person are pulled towards. (The neighbours
        keep the noisy endpoints in front of a wall, whose own cell the rays have freed.)"""
        world = transform_points(self.pose, pts)
        return self.pyramid.finest.above_near(world, self.config.free_logodds)

    # -- public -------------------------------------------------------------------------------

    def update(self, scan: LaserScan) -> FloatArray:
        """Match one scan and return Δp (3,) since the previous scan (zeros on the first)."""
        c = self.config
        dt = self._time_step(scan.stamp)
        previous = self.pose.copy()
        predicted = compose(previous, se2_exp(self._twist, dt)) if self.num_scans else previous
        pts = self.last_points = self._sensor_points(scan)
        keep = subsample_by_spacing(pts, c.point_spacing)
        first = self._last_inserted is None  # nothing to match against yet
        self.num_scans += 1
        if pts.shape[0] < c.min_points:
            self.pose = predicted
            self.num_predicted_only += 1
            self.last_report = MatchReport(predicted_only=True, num_points=int(pts.shape[0]))
        elif first:
            self.last_report = MatchReport(num_points=int(pts.shape[0]))
        else:
            level_pts = _level_points(pts, c.point_spacing, c.levels, keep)
            start = self._best_start(level_pts[-1], previous, predicted)
            self.pose, self.last_report = self._match(
                level_pts, start, previous, _matched_normals(level_pts), dt
            )
            self.num_recovered += self.last_report.recovered
            self.num_degenerate += self.last_report.degenerate
        if not self.last_report.predicted_only and self._should_insert():
            # every endpoint is fused, each with the normal of the kept one before it
            self._insert(pts, thinned_normals(pts, keep))
            self.last_report.inserted = True
        if self.last_report.inserted and not self._scores:
            self._remember_score(self._score_at(self.pose, _kept_rows(pts, keep)))
        self._update_twist(scan.stamp)
        self._last_stamp = scan.stamp
        self._last_delta = between(previous, self.pose)
        return self._last_delta.copy()

    def summary(self) -> dict[str, int]:
        """Counts over the run: scans, matches recovered by a search, scans with an
        unconstrained direction, scans with too few points (prediction only)."""
        return {
            "odometry_scans": self.num_scans,
            "odometry_recovered": self.num_recovered,
            "odometry_degenerate": self.num_degenerate,
            "odometry_predicted_only": self.num_predicted_only,
        }

    def _match(
        self, level_pts: list[FloatArray], start: FloatArray, previous: FloatArray,
        normals: FloatArray, dt: float,
    ) -> tuple[FloatArray, MatchReport]:
        """Eq. 3 from ``start``; if that match failed (:meth:`_failed`), again from
        exhaustive searches: first close around ``start`` (half-cell lattice), then, if the
        best match still failed, widely around the previous pose (one-cell lattice: scans
        far apart in a thinned or gappy log). Gauss-Newton runs from each search's
        ``recovery_seeds`` best lattice peaks; the match with the most endpoints on walls and
        the fewest in known free space (:func:`_match_quality`) is kept."""
        c = self.config
        pose, report = self._match_from(level_pts, start, normals)
        failed = self._failed(report)
        after_gap = dt > c.gap_time
        if not (failed or after_gap):
            self._remember_score(report.score)
            return pose, report
        searches = (
            (start, c.recovery_distance, c.recovery_angle, 0.5, False),
            (previous, c.wide_recovery_distance, c.wide_recovery_angle, 1.0, True),
        )
        iterations = report.iterations
        # the coarsest level's endpoints (0.2 m apart) are too few in a narrow space (30 in a
        # freiburg office) for the lattice to tell poses apart; the next level's are twice
        # as many (on freiburg thinned to a scan per metre: RPE 59 -> 4.5 cm)
        search_pts = level_pts[-2] if len(level_pts) > 1 else level_pts[-1]
        for centre, distance, angle, cells, wide in searches:
            if distance <= 0 or not (failed or after_gap):
                continue
            for seed in self._lattice_seeds(search_pts, centre, distance, angle, cells):
                second, second_report = self._match_from(level_pts, seed, normals)
                iterations += second_report.iterations
                second_failed = self._failed(second_report)
                if self._better(second_report, second_failed, report, failed, wide):
                    second_report.recovered = True
                    pose, report, failed = second, second_report, second_failed
        report.iterations = iterations
        self._remember_score(report.score)
        return pose, report

    def _better(
        self, second: MatchReport, second_failed: bool, first: MatchReport, first_failed: bool,
        must_succeed: bool,
    ) -> bool:
        """Whether a retry's match replaces the first. A match that did not fail is only
        replaced by a clearly better one (``start_margin``): where the map cannot tell
        places apart (a corridor) the prediction's match is kept. A jump found by the wide
        search must itself pass :meth:`_failed`: a scan that matches nowhere well (the view
        blocked) is better left near the prediction."""
        if must_succeed and second_failed:
            return False
        margin = 0.0 if first_failed else self.config.start_margin * first.score
        return _match_quality(second) > _match_quality(first) + margin

    def _failed(self, report: MatchReport) -> bool:
        """Endpoints in known free space, or a score far below that of recent matches."""
        c = self.config
        if report.free_fraction > c.recovery_free_fraction:
            return True
        return report.score < c.recovery_score_ratio * self._typical_score

    def _remember_score(self, score: float) -> None:
        """Keep the last ``score_window`` scores. Their median is refreshed on each of the
        first tenth of a window, then every tenth (per scan it cost more than the rest of
        the failure test)."""
        self._scores.append(score)
        self._num_scores += 1
        step = max(self.config.score_window // 10, 1)
        if self._num_scores <= step or self._num_scores % step == 0:
            self._typical_score = float(np.median(self._scores))

    def _score_at(self, pose: FloatArray, points: FloatArray) -> float:
        """Mean M* of ``points`` at ``pose`` on the finest level (the first scan's score on
        the map made from it is the reference until matches have been made)."""
        grid = _grid_args(self.pyramid.finest, self.config.subcell_sigma)
        c, s = math.cos(pose[2]), math.sin(pose[2])
        return _summed_map(grid, points, c, s, pose[0], pose[1], False) / max(len(points), 1)

    def _lattice_seeds(
        self, points: FloatArray, centre: FloatArray, distance: float, angle: float, cells: float
    ) -> FloatArray:
        """:func:`_lattice_search` on the coarsest level, ``cells`` of it apart in position
        and so in heading that the farthest tenth of the points move by as much (the
        median moved far points by several cells between lattice headings in a narrow
        space, and the search missed the pose)."""
        top = self.pyramid.grids[-1]
        return _lattice_search(
            top, self.config.subcell_sigma, points, centre, distance, angle,
            cells * top.resolution, float(np.percentile(np.hypot(points[:, 0], points[:, 1]), 90)),
            self.config.recovery_seeds,
        )  # fmt: skip

    def _match_from(
        self, level_pts: list[FloatArray], start: FloatArray, normals: FloatArray
    ) -> tuple[FloatArray, MatchReport]:
        c = self.config
        pose, report = match_scan_to_map(
            self.pyramid, level_pts, start, c.max_iterations, c.step_tolerance,
            c.length_scale, c.degeneracy_ratio, c.subcell_sigma, normals,
        )  # fmt: skip
        report.free_fraction = self.pyramid.finest.fraction_not_above_near(
            pose, level_pts[0], c.free_logodds
        )
        return pose, report

    def _best_start(self, coarse_pts: FloatArray, previous: FloatArray, predicted: FloatArray):
        """The initial pose with the lowest cost on the coarsest level among: the
        constant-velocity prediction, the previous scan's motion repeated, and no motion.
        Logged timestamps often jitter (CARMEN logs stamp scans when written, not when
        measured): a robot turning at a steady rate per scan then gets a prediction off by
        tens of degrees from the time-based model alone. An alternative must beat the
        prediction clearly (``start_margin``), so that where the scan cannot tell the
        candidates apart (a featureless corridor) the prediction is kept."""
        candidates = np.array([predicted, compose(previous, self._last_delta), previous])
        grid = _grid_args(self.pyramid.grids[-1], self.config.subcell_sigma)
        costs = _costs(grid, coarse_pts, candidates)
        best = int(np.argmin(costs))
        if costs[best] < (1.0 - self.config.start_margin) * costs[0]:
            return candidates[best]
        return predicted

    def _update_twist(self, stamp: float) -> None:
        """Constant-velocity estimate over the last ``velocity_window`` seconds: differencing
        only two consecutive fast scans turns millimetre match noise into a velocity noise
        that, fed back through the prediction and the de-skew, makes the estimate oscillate."""
        history = self._history
        history.append((stamp, self.pose.copy()))
        c = self.config
        while len(history) > c.velocity_scans + 1 and stamp - history[1][0] >= c.velocity_window:
            history.popleft()
        t0, p0 = history[0]
        if stamp > t0:
            self._twist = se2_log(between(p0, self.pose)) / (stamp - t0)


# --------------------------------------------------------------------------------------------
# Pairwise registration (for loop-closure refinement)


@dataclass
class RegistrationQuality:
    """How trustworthy a :func:`register_scans` result is; ``float(q)`` is ``q.score``.

    Attributes:
        score: fraction of query points (inside the reference map) that land within about a
            cell of ``RegistrationConfig.score_level`` of the reference scan after
            convergence: the sub-cell map function (kernel one cell wide) is at least
            ``hit_level`` there. The reference is densified along its surfaces first
            (:func:`densify_scan`). Points in space the reference never saw count as
            misses. In the tests a correct registration scores above 0.9 and a
            registration of two different places below 0.6.
        mean_value: mean of that map function over those points.
        overlap: fraction of query points that fall inside the reference map at all.
        converged: the finest level stopped on a small step before its iteration limit.
        degenerate: some direction was unconstrained (corridor): ``rel`` is then only
            reliable across that direction.
        condition: smallest / largest scaled curvature.
        iterations: Gauss-Newton iterations summed over the levels.
    """

    score: float
    mean_value: float
    overlap: float
    converged: bool
    degenerate: bool
    condition: float
    iterations: int

    def __float__(self) -> float:
        return float(self.score)


@dataclass(frozen=True)
class RegistrationConfig:
    """Parameters of :func:`register_scans`.

    Attributes:
        resolution, levels: the reference map pyramid (as :class:`OdometryConfig`).
        search_distance, search_angle: half-widths of the exhaustive search on the coarsest
            level around the initial guess (metres, radians); they set the convergence basin
            (a view cell's place match can be half a metre and tens of degrees off).
        max_range: reference/query endpoints beyond this are ignored, metres.
        max_iterations, step_tolerance, length_scale, degeneracy_ratio, subcell_sigma: as in
            OdometryConfig.
        hit_level: map function value at or above which a query point counts as landing on
            the reference scan (0.5: about one cell from a reference endpoint).
        score_level: the pyramid level whose cells that is judged on. Default 1 (10 cm):
            a point lands within about 10 cm of the reference scan. On the finest level
            (5 cm) range noise alone fails a correct registration: two scans with 3 cm noise
            (a low-cost 360° LiDAR) differ by more than 5 cm for a fifth of their points,
            and correct registrations scored 0.66-0.76, so the noisy sensor never closed a
            loop (0 of 336 registrations on a 600 s maze route; 73 on level 1).
    """

    resolution: float = 0.05
    levels: int = 3
    search_distance: float = 0.6
    search_angle: float = math.radians(25.0)
    max_range: float = 30.0
    max_iterations: tuple[int, ...] = (10, 10, 20)
    step_tolerance: float = 0.01
    length_scale: float = 3.0
    degeneracy_ratio: float = 0.01
    subcell_sigma: float | None = 1.0
    hit_level: float = 0.5
    score_level: int = 1


def densify_scan(points: FloatArray, spacing: float, max_gap: float) -> FloatArray:
    """Endpoints in scan order with points added every ``spacing`` metres between neighbours
    closer than ``max_gap`` (the same surface): a sparse scan (1 deg beams reach 10 cm
    apart at 6 m) would otherwise leave empty cells between its points on a wall, where
    the other scan's points of that wall find nothing to land on."""
    if points.shape[0] < 2:
        return points
    step = np.diff(points, axis=0)
    gap = np.hypot(step[:, 0], step[:, 1])
    extra = np.where(gap <= max_gap, np.floor(gap / spacing).astype(np.int64), 0)
    counts = np.append(extra + 1, 1)
    start = np.repeat(np.arange(points.shape[0]), counts)
    offset = np.arange(start.size) - np.repeat(np.cumsum(counts) - counts, counts)
    frac = offset / np.repeat(counts, counts)
    ahead = np.minimum(start + 1, points.shape[0] - 1)
    return points[start] + frac[:, None] * (points[ahead] - points[start])


def _check_points(points: ArrayLike, name: str) -> FloatArray:
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 2:
        raise ValueError(f"{name} must have shape (N, 2), got {pts.shape}")
    return pts[np.all(np.isfinite(pts), axis=1)]


def register_scans(
    reference_points: ArrayLike,
    query_points: ArrayLike,
    initial_guess: ArrayLike = (0.0, 0.0, 0.0),
    config: RegistrationConfig | None = None,
) -> tuple[FloatArray, RegistrationQuality]:
    """The pose of the query scan's frame in the reference scan's frame.

    Both point sets are ``(N, 2)`` endpoints in their own sensor frames. The reference scan is
    fused into a small map pyramid; the query is placed by an exhaustive search of the Eq. 3
    objective on the coarsest level around ``initial_guess`` followed by Gauss-Newton (Eq. 3-4)
    down the pyramid. See :class:`RegistrationQuality` for how to reject a bad result.
    """
    c = config or RegistrationConfig()
    ref = _check_points(reference_points, "reference_points")
    qry = _check_points(query_points, "query_points")
    ref = ref[np.hypot(ref[:, 0], ref[:, 1]) <= c.max_range]
    qry = np.ascontiguousarray(qry[np.hypot(qry[:, 0], qry[:, 1]) <= c.max_range])
    guess = np.asarray(initial_guess, dtype=np.float64).reshape(3)
    if ref.shape[0] < 3 or qry.shape[0] < 3:
        raise ValueError(
            f"register_scans needs at least 3 finite points in each scan, got "
            f"{ref.shape[0]} reference and {qry.shape[0]} query points"
        )
    # The map covers the reference's bounding box (a square around the sensor would be
    # mostly empty, and zeroing it cost a fifth of a registration on a 30 m scanner); query
    # points beyond it still count as misses in the score: they fall where the reference
    # saw nothing, and the map function is 0 outside the map.
    lo = ref.min(axis=0) - 1.0
    hi = ref.max(axis=0) + 1.0
    pyramid = MapPyramid(c.resolution, tuple(hi - lo), c.levels, LogOddsConfig(), origin=lo)
    pyramid.insert_scan(np.zeros(3), densify_scan(ref, 0.5 * c.resolution, NORMAL_MAX_GAP))
    keep = subsample_by_spacing(qry, c.resolution)
    level_pts = _level_points(qry, c.resolution, c.levels, keep)
    top = pyramid.grids[-1]
    # Lattice steps of one coarse cell, in angle at the range of most points: Gauss-Newton
    # on the coarse level converges from anywhere within a cell, so a finer lattice (half a
    # cell at the farthest point) only multiplied the cost, by 20 on a 30 m scanner.
    radius = float(np.percentile(np.hypot(qry[:, 0], qry[:, 1]), 90))
    seed = _lattice_search(
        top, None, level_pts[-1], guess, c.search_distance, c.search_angle, top.resolution, radius
    )[0]
    rel, report = match_scan_to_map(
        pyramid, level_pts, seed, c.max_iterations, c.step_tolerance, c.length_scale,
        c.degeneracy_ratio, c.subcell_sigma, _matched_normals(level_pts),
    )  # fmt: skip
    judge = pyramid.grids[c.score_level]
    world = transform_points(rel, qry)
    values, _ = judge.value_and_gradient(world, subcell_sigma=1.0)
    reach = float(np.max(np.abs(ref))) + 1.0
    inside = _inside((-reach, -reach, reach, reach), judge.resolution, world)
    n_in = int(inside.sum())
    quality = RegistrationQuality(
        score=float(np.mean(values[inside] >= c.hit_level)) if n_in else 0.0,
        mean_value=float(np.mean(values[inside])) if n_in else 0.0,
        overlap=n_in / qry.shape[0],
        converged=report.converged,
        degenerate=report.degenerate,
        condition=report.condition,
        iterations=report.iterations,
    )
    return rel, quality


def _inside(
    extent: tuple[float, float, float, float], margin: float, world: FloatArray
) -> NDArray[np.bool_]:
    """Points at least ``margin`` inside ``extent`` (xmin, ymin, xmax, ymax)."""
    xmin, ymin, xmax, ymax = extent
    half = margin
    return (
        (world[:, 0] >= xmin + half)
        & (world[:, 0] < xmax - half)
        & (world[:, 1] >= ymin + half)
        & (world[:, 1] < ymax - half)
    )
