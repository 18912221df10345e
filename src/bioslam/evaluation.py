"""Trajectory accuracy: absolute trajectory error (ATE) and relative pose error (RPE).

The definitions follow evo (MichaelGrupp/evo) so that ``bioslam eval`` and ``evo_ape`` /
``evo_rpe`` report the same numbers on the same TUM files:

- association: evo's ``sync.associate_trajectories`` (nearest stamp within ``max_dt``, driven
  by the trajectory with fewer poses, the estimate when both are equally long);
- ATE: position error after a least-squares rigid alignment of the estimate onto the reference
  (Umeyama 1991 without scale, ``evo_ape --align``), statistics over all associated poses;
- RPE over a distance: evo's consecutive pairs of ``filters.filter_pairs_by_path`` (a new pair
  starts each time the *estimate* has travelled at least ``delta`` metres since the last pair
  start, like ``evo_rpe --delta 1 --delta_unit m``), error pose ``E = (Q_i⁻¹ Q_j)⁻¹ (P_i⁻¹ P_j)``,
  translation = ``|t(E)|``, rotation = ``|angle(E)|``; RMSE over pairs.
- RPE over time (evo has no time unit): the same consecutive-pair rule with elapsed time in
  place of travelled distance.
- Not in evo: the three-cornered hat, each of three trajectories' own RPE from their pairwise
  ones, for references that are themselves estimates.

Everything is planar: poses are (x, y, theta), so evo's SE(3) quantities reduce to SE(2) ones.
One known difference: when the best 2-D fit would be a reflection (degenerate, near-collinear
data), evo's 3-D Umeyama may flip the z axis; here the rotation is always a proper 2-D rotation.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from bioslam.geometry import between, wrap_angle
from bioslam.trajectory import Trajectory

IntArray = NDArray[np.intp]
FloatArray = NDArray[np.float64]


@dataclass
class EvalConfig:
    """Evaluation settings.

    max_dt: largest stamp difference (s) for two poses to be associated. 0.02 s is half a
        scan period of a 25 Hz LiDAR; evo's default ``--t_max_diff`` is 0.01 s.
    rpe_delta_m: travelled distance of an RPE pair (m); 1 m as asked by the evaluation issue.
    rpe_delta_s: elapsed time of an RPE pair (s); 1 s as asked by the evaluation issue.
    pairs_from_reference: pick RPE pairs along the reference instead of the estimate
        (evo's ``--pairs_from_reference``; off by default, as in evo).
    min_pairs: fewest associated poses :func:`evaluate` accepts. The SE(2) alignment has
        three degrees of freedom: with one pair the ATE is 0 whatever the estimate, with a
        handful it mostly measures how well the alignment fits noise.
    """

    max_dt: float = 0.02
    rpe_delta_m: float = 1.0
    rpe_delta_s: float = 1.0
    pairs_from_reference: bool = False
    min_pairs: int = 10


def _check_finite(trajectory: Trajectory, what: str) -> None:
    """Refuse NaN/inf stamps or poses: they would turn every statistic into NaN silently."""
    bad = ~(np.isfinite(trajectory.stamps) & np.all(np.isfinite(trajectory.poses), axis=1))
    if np.any(bad):
        k = int(np.argmax(bad))
        raise ValueError(f"{what} pose {k} (stamp {trajectory.stamps[k]}) is not finite: "
                         f"{trajectory.poses[k].tolist()}")


def _check_sorted(stamps: FloatArray, what: str) -> None:
    if stamps.size > 1 and np.any(np.diff(stamps) < 0):
        bad = int(np.argmax(np.diff(stamps) < 0)) + 1
        raise ValueError(f"{what} stamps are not sorted (pose {bad}: {stamps[bad]:.9f} s)")


def _match_nearest(short: FloatArray, long: FloatArray, max_dt: float) -> tuple[IntArray, IntArray]:
    """Indices (into ``short``, into ``long``) of evo's nearest-stamp matches."""
    inside = (short >= long[0] - max_dt) & (short <= long[-1] + max_dt)
    idx_short = np.flatnonzero(inside)
    s = short[idx_short]
    upper = np.minimum(np.searchsorted(long, s, side="right"), long.size - 1)
    diff_ub = long[upper] - s
    diff_lb = np.where(upper > 0, s - long[np.maximum(upper - 1, 0)], np.inf)
    # evo's tie-break: the later stamp only if strictly closer than the earlier one.
    take_upper = (diff_ub <= max_dt) & (diff_ub < diff_lb)
    take_lower = ~take_upper & (diff_lb <= max_dt) & (diff_lb <= diff_ub)
    keep = take_upper | take_lower
    idx_long = np.where(take_upper, upper, upper - 1)
    return idx_short[keep], idx_long[keep].astype(np.intp)


def associate(
    est: Trajectory, gt: Trajectory, max_dt: float = EvalConfig.max_dt
) -> tuple[IntArray, IntArray]:
    """Pair estimate and reference poses by nearest stamp within ``max_dt`` seconds.

    Returns ``(est_idx, gt_idx)``, equally long. Raises ``ValueError`` if either trajectory is
    empty or unsorted, or if no stamps match.
    """
    if len(est) == 0 or len(gt) == 0:
        raise ValueError(f"cannot associate: estimate has {len(est)} poses, reference {len(gt)}")
    _check_finite(est, "estimate")
    _check_finite(gt, "reference")
    _check_sorted(est.stamps, "estimate")
    _check_sorted(gt.stamps, "reference")
    if len(est) > len(gt):
        gt_idx, est_idx = _match_nearest(gt.stamps, est.stamps, max_dt)
    else:
        est_idx, gt_idx = _match_nearest(est.stamps, gt.stamps, max_dt)
    if est_idx.size == 0:
        raise ValueError(
            f"no matching stamps within {max_dt} s: estimate spans "
            f"{est.stamps[0]:.3f}..{est.stamps[-1]:.3f} s, reference "
            f"{gt.stamps[0]:.3f}..{gt.stamps[-1]:.3f} s"
        )
    return est_idx, gt_idx


def _associated(est: Trajectory, gt: Trajectory, max_dt: float) -> tuple[Trajectory, Trajectory]:
    est_idx, gt_idx = associate(est, gt, max_dt)
    return _take(est, est_idx), _take(gt, gt_idx)


def _take(trajectory: Trajectory, idx: IntArray) -> Trajectory:
    return Trajectory(trajectory.stamps[idx], trajectory.poses[idx])


def align_se2(est_xy: ArrayLike, gt_xy: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Least-squares rigid alignment (Umeyama without scale) of ``est_xy`` onto ``gt_xy``.

    Returns ``(R, t)`` (2x2, 2) minimising ``sum |R p_i + t - q_i|²``. In 2-D the optimal
    rotation angle has the closed form ``atan2(Σ p'×q', Σ p'·q')`` over the centred points,
    which is always a proper rotation; with no spread (one point) it is the identity.
    """
    p = np.asarray(est_xy, dtype=np.float64).reshape(-1, 2)
    q = np.asarray(gt_xy, dtype=np.float64).reshape(-1, 2)
    if p.shape != q.shape or p.shape[0] == 0:
        raise ValueError(f"align_se2 needs equal non-empty point sets, got {p.shape}, {q.shape}")
    mp, mq = p.mean(axis=0), q.mean(axis=0)
    pc, qc = p - mp, q - mq
    cross = float(np.sum(pc[:, 0] * qc[:, 1] - pc[:, 1] * qc[:, 0]))
    dot = float(np.sum(pc * qc))
    angle = np.arctan2(cross, dot)
    c, s = np.cos(angle), np.sin(angle)
    R = np.array([[c, -s], [s, c]])
    return R, mq - R @ mp


def apply_se2(R: FloatArray, t: FloatArray, poses: ArrayLike) -> FloatArray:
    """Transform poses (N, 3) by the rigid motion ``(R, t)`` from :func:`align_se2`."""
    poses = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
    xy = poses[:, :2] @ R.T + t
    theta = wrap_angle(poses[:, 2] + np.arctan2(R[1, 0], R[0, 0]))
    return np.column_stack([xy, np.atleast_1d(theta)])


def _stats(errors: FloatArray) -> dict[str, float]:
    return {
        "rmse": float(np.sqrt(np.mean(errors**2))),
        "mean": float(np.mean(errors)),
        "median": float(np.median(errors)),
        "std": float(np.std(errors)),
        "min": float(np.min(errors)),
        "max": float(np.max(errors)),
    }


def _aligned_position_errors(est: Trajectory, gt: Trajectory, align: bool) -> FloatArray:
    est_xy = est.poses[:, :2]
    if align:
        R, t = align_se2(est_xy, gt.poses[:, :2])
        est_xy = est_xy @ R.T + t
    return np.hypot(*(est_xy - gt.poses[:, :2]).T)


def position_errors(
    est: Trajectory, gt: Trajectory, align: bool = True, max_dt: float = EvalConfig.max_dt
) -> tuple[FloatArray, FloatArray]:
    """Per-pose position error (m) at the associated estimate stamps, for error-over-time plots.

    With ``align`` the estimate is first rigidly aligned onto the reference (as for the ATE).
    """
    est_a, gt_a = _associated(est, gt, max_dt)
    return est_a.stamps, _aligned_position_errors(est_a, gt_a, align)


def ate(
    est: Trajectory, gt: Trajectory, align: bool = True, max_dt: float = EvalConfig.max_dt
) -> dict[str, float]:
    """Absolute trajectory error (m): statistics of the position error after alignment.

    Returns ``rmse, mean, median, std, min, max`` and ``pairs`` (associated poses); equal to
    ``evo_ape tum GT EST --align`` (translation part).
    """
    est_a, gt_a = _associated(est, gt, max_dt)
    errors = _aligned_position_errors(est_a, gt_a, align)
    return {**_stats(errors), "pairs": int(errors.size)}


def _consecutive_pairs(progress: FloatArray, delta: float) -> IntArray:
    """evo's consecutive-pair rule: a new pair end each time ``progress`` has grown ``delta``.

    ``progress`` holds the per-step increments (N-1,). Returns pair starts/ends as (M, 2).
    The running sum is reset at each pair end, exactly as evo's ``filter_pairs_by_path``.
    """
    ids = [0]
    running = 0.0
    for i, step in enumerate(progress.tolist(), start=1):
        running += step
        if running >= delta:
            ids.append(i)
            running = 0.0
    ends = np.asarray(ids, dtype=np.intp)
    return np.column_stack([ends[:-1], ends[1:]])


def _pair_errors(est: Trajectory, gt: Trajectory, pairs: IntArray) -> tuple[FloatArray, FloatArray]:
    """Translation (m) and rotation (deg) error of each pair's relative motion."""
    i, j = pairs[:, 0], pairs[:, 1]
    err = between(between(gt.poses[i], gt.poses[j]), between(est.poses[i], est.poses[j]))
    return np.hypot(err[:, 0], err[:, 1]), np.degrees(np.abs(err[:, 2]))


def _rpe_from_pairs(est: Trajectory, gt: Trajectory, pairs: IntArray) -> dict[str, float]:
    return _rpe_summary(*_pair_errors(est, gt, pairs))


def _rpe_summary(trans: FloatArray, rot: FloatArray) -> dict[str, float]:
    if trans.size == 0:
        return {"trans_rmse_m": float("nan"), "rot_rmse_deg": float("nan"), "pairs": 0}
    return {
        "trans_rmse_m": float(np.sqrt(np.mean(trans**2))),
        "rot_rmse_deg": float(np.sqrt(np.mean(rot**2))),
        "trans_mean_m": float(np.mean(trans)),
        "rot_mean_deg": float(np.mean(rot)),
        "pairs": int(trans.size),
    }


def _distance_pairs(trajectory: Trajectory, delta_m: float) -> IntArray:
    """evo's consecutive pairs ``delta_m`` metres apart along ``trajectory``'s path."""
    if delta_m <= 0:
        raise ValueError(f"delta_m must be positive, got {delta_m}")
    d = np.diff(trajectory.poses[:, :2], axis=0)
    return _consecutive_pairs(np.sqrt(d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1]), delta_m)


def rpe_distance(
    est: Trajectory,
    gt: Trajectory,
    delta_m: float = EvalConfig.rpe_delta_m,
    max_dt: float = EvalConfig.max_dt,
    pairs_from_reference: bool = EvalConfig.pairs_from_reference,
) -> dict[str, float]:
    """RPE over ``delta_m`` metres of travel, like ``evo_rpe --delta 1 --delta_unit m``.

    Returns ``trans_rmse_m``, ``rot_rmse_deg`` (RMSE over pairs), their means and ``pairs``;
    NaN errors with ``pairs == 0`` when the path is shorter than ``delta_m``.
    """
    _, _, trans, rot = rpe_distance_pairs(est, gt, delta_m, max_dt, pairs_from_reference)
    return _rpe_summary(trans, rot)


def rpe_distance_pairs(
    est: Trajectory,
    gt: Trajectory,
    delta_m: float = EvalConfig.rpe_delta_m,
    max_dt: float = EvalConfig.max_dt,
    pairs_from_reference: bool = EvalConfig.pairs_from_reference,
) -> tuple[IntArray, IntArray, FloatArray, FloatArray]:
    """The pairs behind :func:`rpe_distance`, with their errors, to find where an RPE comes
    from: the estimate's and the reference's pose indices of each pair's two ends, ``(M, 2)``
    each, and the translation (m) and rotation (deg) errors, ``(M,)`` each."""
    est_idx, gt_idx = associate(est, gt, max_dt)
    est_a, gt_a = _take(est, est_idx), _take(gt, gt_idx)
    pairs = _distance_pairs(gt_a if pairs_from_reference else est_a, delta_m)
    trans, rot = _pair_errors(est_a, gt_a, pairs)
    return est_idx[pairs], gt_idx[pairs], trans, rot


def _common_poses(trajectories: tuple[Trajectory, ...], max_dt: float) -> list[Trajectory]:
    """The poses of each trajectory at the stamps of the first that all the others share."""
    first = trajectories[0]
    matches = [associate(first, other, max_dt) for other in trajectories[1:]]
    shared = np.arange(len(first))
    for first_idx, _ in matches:
        shared = np.intersect1d(shared, first_idx)
    out = [_take(first, shared)]
    for (first_idx, other_idx), other in zip(matches, trajectories[1:], strict=True):
        out.append(_take(other, other_idx[np.searchsorted(first_idx, shared)]))
    return out


def three_cornered_hat(
    reference: Trajectory,
    estimate: Trajectory,
    third: Trajectory,
    delta_m: float = EvalConfig.rpe_delta_m,
    max_dt: float = EvalConfig.max_dt,
) -> dict[str, list[float] | int]:
    """Each trajectory's own RPE over ``delta_m`` metres, without knowing the truth.

    An RPE against a reference measures the estimate's errors and the reference's together;
    when the reference is itself an estimate (a SLAM-corrected log) the two cannot be told
    apart from one comparison. Three estimates of the same motion can: with independent
    errors, the mean square difference of a and b over the same pairs is ``s_a² + s_b²``, and
    the three pairwise differences solve for each ``s`` (the "three-cornered hat" of clock
    metrology). Errors two trajectories share (the same scans, the same wheel odometry) cancel
    in their difference and are blamed on the third one; a negative square means the data
    contradict independence and is reported as NaN.

    Pairs are taken along the reference (evo's consecutive-pair rule) at the stamps all three
    share. Returns ``pairs``; ``pairwise_trans_rmse_m`` and ``pairwise_rot_rmse_deg`` for
    (reference, estimate), (reference, third), (estimate, third); ``trans_rmse_m`` and
    ``rot_rmse_deg`` for (reference, estimate, third).
    """
    traj = _common_poses((reference, estimate, third), max_dt)
    pairs = _distance_pairs(traj[0], delta_m)
    combos = ((0, 1), (0, 2), (1, 2))
    errors = [_pair_errors(traj[b], traj[a], pairs) for a, b in combos]
    out: dict[str, list[float] | int] = {"pairs": int(pairs.shape[0])}
    for key, k in (("trans_rmse_m", 0), ("rot_rmse_deg", 1)):
        mean_sq = np.array([np.mean(e[k] ** 2) if pairs.size else np.nan for e in errors])
        ab, ac, bc = mean_sq
        own = np.array([ab + ac - bc, ab + bc - ac, ac + bc - ab]) / 2
        out["pairwise_" + key] = np.sqrt(mean_sq).tolist()
        out[key] = np.sqrt(np.where(own >= 0, own, np.nan)).tolist()
    return out


def rpe_time(
    est: Trajectory,
    gt: Trajectory,
    delta_s: float = EvalConfig.rpe_delta_s,
    max_dt: float = EvalConfig.max_dt,
) -> dict[str, float]:
    """RPE over ``delta_s`` seconds: consecutive pairs at least ``delta_s`` apart in time.

    Same keys as :func:`rpe_distance`. evo has no time unit; on evenly stamped data this equals
    ``evo_rpe --delta N --delta_unit f`` with ``N = delta_s / period``.
    """
    if delta_s <= 0:
        raise ValueError(f"delta_s must be positive, got {delta_s}")
    est_a, gt_a = _associated(est, gt, max_dt)
    return _rpe_from_pairs(est_a, gt_a, _consecutive_pairs(np.diff(est_a.stamps), delta_s))


def evaluate(est: Trajectory, gt: Trajectory, config: EvalConfig | None = None) -> dict:
    """The ``bioslam eval`` summary: ATE (after alignment) and RPE over 1 m and over 1 s.

    Keys: ``ate_rmse_m, ate_mean_m, ate_max_m, rpe_1m_trans_m, rpe_1m_rot_deg,
    rpe_1s_trans_m, rpe_1s_rot_deg`` and ``pairs`` (associated poses). RPE values are RMSE
    over all pairs, NaN when the trajectory is too short for a single pair. Raises
    ``ValueError`` with fewer than ``config.min_pairs`` associated poses or non-finite poses.
    """
    cfg = config or EvalConfig()
    a = ate(est, gt, align=True, max_dt=cfg.max_dt)
    if a["pairs"] < cfg.min_pairs:
        raise ValueError(
            f"only {a['pairs']} associated poses within {cfg.max_dt} s ({len(est)} estimated, "
            f"{len(gt)} reference); at least {cfg.min_pairs} are needed for a meaningful ATE "
            "(the alignment alone fits a few poses)"
        )
    r_m = rpe_distance(est, gt, cfg.rpe_delta_m, cfg.max_dt, cfg.pairs_from_reference)
    r_s = rpe_time(est, gt, cfg.rpe_delta_s, cfg.max_dt)
    return {
        "ate_rmse_m": a["rmse"],
        "ate_mean_m": a["mean"],
        "ate_max_m": a["max"],
        "rpe_1m_trans_m": r_m["trans_rmse_m"],
        "rpe_1m_rot_deg": r_m["rot_rmse_deg"],
        "rpe_1s_trans_m": r_s["trans_rmse_m"],
        "rpe_1s_rot_deg": r_s["rot_rmse_deg"],
        "pairs": a["pairs"],
    }


#: a loop closure whose measured relative pose is farther than this from the reference's
#: (metres, degrees) is counted false (the loop-closure issue's precision: 0.5 m, 20°)
FALSE_CLOSURE_DISTANCE = 0.5
FALSE_CLOSURE_ANGLE_DEG = 20.0


def off_reference(errors: ArrayLike) -> NDArray[np.bool_]:
    """Which rows of :func:`relative_pose_errors` are beyond :data:`FALSE_CLOSURE_DISTANCE`
    or :data:`FALSE_CLOSURE_ANGLE_DEG` (False where the reference has no pose)."""
    e = np.asarray(errors, dtype=np.float64).reshape(-1, 2)
    with np.errstate(invalid="ignore"):
        return (e[:, 0] > FALSE_CLOSURE_DISTANCE) | (e[:, 1] > FALSE_CLOSURE_ANGLE_DEG)


def relative_pose_errors(
    first_stamps: ArrayLike,
    second_stamps: ArrayLike,
    measured: ArrayLike,
    reference: Trajectory,
    max_dt: float = EvalConfig.max_dt,
    free: ArrayLike | None = None,
) -> FloatArray:
    """(N, 2) position (m) and heading (degrees) errors of ``measured`` relative poses (N, 3:
    the pose at each of ``second_stamps`` in the frame of the pose at ``first_stamps``, as a
    loop closure measures the robot in a place's frame) against ``reference``'s relative pose
    between the same stamps, each taken at the reference's nearest stamp; NaN where the
    reference has no pose within ``max_dt`` seconds of either stamp. ``free`` ((N, 2), unit,
    in the first pose's frame; NaN rows for none): a partial closure's slide, along which it
    measures nothing, so that its position error is the part across it."""
    poses = np.asarray(measured, dtype=np.float64).reshape(-1, 3)
    out = np.full((len(poses), 2), np.nan)
    if len(reference) == 0 or len(poses) == 0:
        return out
    truth = relative_poses(reference, first_stamps, second_stamps, max_dt)
    ok = np.isfinite(truth[:, 0])
    truth = truth[ok]
    err = between(truth, poses[ok]).reshape(-1, 3)
    if free is not None:
        # the slide, given in the place's frame, turned into the robot's (the error's)
        slide = np.nan_to_num(np.asarray(free, dtype=np.float64).reshape(-1, 2)[ok])
        c, s = np.cos(truth[:, 2]), np.sin(truth[:, 2])
        turned = np.stack([c * slide[:, 0] + s * slide[:, 1], c * slide[:, 1] - s * slide[:, 0]], 1)
        err[:, :2] -= turned * np.sum(turned * err[:, :2], axis=1, keepdims=True)
    out[ok, 0] = np.hypot(err[:, 0], err[:, 1])
    out[ok, 1] = np.degrees(np.abs(wrap_angle(err[:, 2])))
    return out


def relative_poses(
    trajectory: Trajectory,
    first_stamps: ArrayLike,
    second_stamps: ArrayLike,
    max_dt: float = EvalConfig.max_dt,
) -> FloatArray:
    """(N, 3) ``trajectory``'s pose nearest each of ``second_stamps`` in the frame of its pose
    nearest the matching one of ``first_stamps`` (the relative pose a loop closure measures
    between the two); NaN rows where it has no pose within ``max_dt`` seconds of either."""
    first = np.asarray(first_stamps, dtype=np.float64).reshape(-1)
    second = np.asarray(second_stamps, dtype=np.float64).reshape(-1)
    out = np.full((len(first), 3), np.nan)
    if len(trajectory) == 0 or len(first) == 0:
        return out
    i = _nearest_reference(trajectory.stamps, first, max_dt)
    j = _nearest_reference(trajectory.stamps, second, max_dt)
    ok = (i >= 0) & (j >= 0)
    out[ok] = between(trajectory.poses[i[ok]], trajectory.poses[j[ok]]).reshape(-1, 3)
    return out


def _nearest_reference(stamps: FloatArray, wanted: FloatArray, max_dt: float) -> IntArray:
    """Index of the nearest of sorted ``stamps`` to each of ``wanted`` (evo's match,
    :func:`_match_nearest`), -1 where none lies within ``max_dt``."""
    idx = np.full(wanted.shape, -1, dtype=np.intp)
    if wanted.size:
        matched, nearest = _match_nearest(wanted, stamps, max_dt)
        idx[matched] = nearest
    return idx
