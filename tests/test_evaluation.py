"""ATE / RPE: known answers on synthetic trajectories, and agreement with evo on TUM files."""

from __future__ import annotations

import copy

import numpy as np
import pytest

from bioslam.evaluation import (
    EvalConfig,
    align_se2,
    apply_se2,
    associate,
    ate,
    evaluate,
    off_reference,
    position_errors,
    relative_pose_errors,
    relative_poses,
    rpe_distance,
    rpe_distance_pairs,
    rpe_time,
    three_cornered_hat,
)
from bioslam.geometry import between, compose, wrap_angle
from bioslam.io.tum import read_tum, write_tum
from bioslam.trajectory import Trajectory


def _route(n: int = 400, period: float = 0.1, seed: int = 0) -> Trajectory:
    """A smooth wandering route at ~0.6 m/s with turns, like a robot in a corridor loop."""
    rng = np.random.default_rng(seed)
    v = 0.6 + 0.2 * np.sin(np.arange(n) * 0.05)
    w = 0.4 * np.sin(np.arange(n) * 0.03) + 0.05 * rng.standard_normal(n)
    steps = np.column_stack([v * period, np.zeros(n), w * period])
    poses = np.zeros((n, 3))
    for k in range(1, n):
        poses[k] = compose(poses[k - 1], steps[k - 1])
    return Trajectory(100.0 + period * np.arange(n), poses)


def _drifting_estimate(gt: Trajectory, seed: int = 1, jitter: float = 0.003) -> Trajectory:
    """Odometry-like estimate: noisy, biased increments, then an arbitrary rigid offset."""
    rng = np.random.default_rng(seed)
    est = np.zeros_like(gt.poses)
    for k in range(1, len(gt)):
        rel = between(gt.poses[k - 1], gt.poses[k])
        rel = rel * np.array([1.03, 1.0, 1.0]) + rng.normal(0, [0.01, 0.005, 0.01])
        est[k] = compose(est[k - 1], rel)
    est = np.asarray(compose(np.array([2.0, -1.0, 0.7]), est))
    stamps = gt.stamps + rng.uniform(-jitter, jitter, len(gt))
    return Trajectory(stamps, est)


# --- association ---------------------------------------------------------------------------


def test_associate_picks_nearest_within_max_dt_and_drops_the_rest():
    gt = Trajectory(np.array([0.0, 1.0, 2.0, 3.0]), np.zeros((4, 3)))
    est = Trajectory(np.array([0.005, 0.985, 2.5, 3.01]), np.zeros((4, 3)))
    est_idx, gt_idx = associate(est, gt, max_dt=0.02)
    assert est_idx.tolist() == [0, 1, 3]
    assert gt_idx.tolist() == [0, 1, 3]


def test_associate_breaks_ties_towards_the_earlier_stamp_like_evo():
    gt = Trajectory(np.array([0.0, 1.0, 2.0, 3.0, 4.0]), np.zeros((5, 3)))
    est = Trajectory(np.array([1.5, 2.5]), np.zeros((2, 3)))
    est_idx, gt_idx = associate(est, gt, max_dt=0.5)
    assert gt_idx.tolist() == [1, 2]
    assert est_idx.tolist() == [0, 1]


@pytest.mark.parametrize("n_est, n_gt", [(300, 300), (300, 200), (150, 300)])
def test_associate_matches_evo(n_est, n_gt):
    from evo.core.sync import matching_time_indices

    rng = np.random.default_rng(n_est + n_gt)
    gt_t = np.sort(rng.uniform(0, 30, n_gt))
    est_t = np.sort(rng.uniform(0, 30, n_est))
    est = Trajectory(est_t, np.zeros((n_est, 3)))
    gt = Trajectory(gt_t, np.zeros((n_gt, 3)))
    est_idx, gt_idx = associate(est, gt, max_dt=0.05)
    # evo_ape calls associate_trajectories(ref, est): the shorter one (est on a tie) drives.
    if n_est > n_gt:
        ev_gt, ev_est = matching_time_indices(gt_t, est_t, 0.05)
    else:
        ev_est, ev_gt = matching_time_indices(est_t, gt_t, 0.05)
    assert est_idx.tolist() == list(ev_est)
    assert gt_idx.tolist() == list(ev_gt)
    assert est_idx.size > 0


def test_associate_rejects_disjoint_and_empty_trajectories():
    gt = Trajectory(np.arange(10.0), np.zeros((10, 3)))
    est = Trajectory(np.arange(10.0) + 100.0, np.zeros((10, 3)))
    with pytest.raises(ValueError, match="no matching stamps"):
        associate(est, gt)
    with pytest.raises(ValueError, match="0 poses"):
        associate(Trajectory.empty(), gt)
    unsorted = Trajectory(np.array([0.0, 2.0, 1.0]), np.zeros((3, 3)))
    with pytest.raises(ValueError, match="not sorted"):
        associate(unsorted, gt)


# --- alignment and ATE ---------------------------------------------------------------------


def test_align_se2_recovers_a_known_rigid_motion():
    rng = np.random.default_rng(3)
    p = rng.uniform(-5, 5, (50, 2))
    angle = 2.5
    R_true = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    t_true = np.array([3.0, -7.0])
    R, t = align_se2(p, p @ R_true.T + t_true)
    np.testing.assert_allclose(R, R_true, atol=1e-12)
    np.testing.assert_allclose(t, t_true, atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0)


def test_ate_of_a_rigidly_moved_copy_is_zero_and_of_an_offset_is_the_offset():
    gt = _route()
    quarter_turn = np.array([[0.0, -1.0], [1.0, 0.0]])
    moved = Trajectory(gt.stamps, apply_se2(quarter_turn, np.array([1.0, 2.0]), gt.poses))
    assert ate(moved, gt)["rmse"] < 1e-9
    assert ate(moved, gt, align=False)["rmse"] > 1.0
    shifted = Trajectory(gt.stamps, gt.poses + np.array([0.3, -0.4, 0.0]))
    res = ate(shifted, gt, align=False)
    assert res["rmse"] == pytest.approx(0.5)
    assert res["max"] == pytest.approx(0.5)
    assert res["pairs"] == len(gt)


def test_position_errors_follow_the_associated_estimate_stamps():
    gt = _route(n=50)
    est = Trajectory(gt.stamps + 0.004, gt.poses + np.array([0.0, 0.2, 0.0]))
    stamps, err = position_errors(est, gt, align=False)
    np.testing.assert_allclose(stamps, est.stamps)
    np.testing.assert_allclose(err, 0.2, atol=1e-12)
    _, err_aligned = position_errors(est, gt, align=True)
    assert np.max(err_aligned) < 1e-9


# --- RPE known answers ---------------------------------------------------------------------


def test_rpe_time_of_a_scale_error_is_the_extra_distance_per_interval():
    period = 0.125
    n = 81
    x = 0.5 * period * np.arange(n)  # 0.5 m/s straight line along x
    gt = Trajectory(period * np.arange(n), np.column_stack([x, np.zeros(n), np.zeros(n)]))
    est = Trajectory(gt.stamps, np.column_stack([1.1 * x, np.zeros(n), np.zeros(n)]))
    res = rpe_time(est, gt, delta_s=1.0)
    assert res["pairs"] == 10
    assert res["trans_rmse_m"] == pytest.approx(0.05, rel=1e-9)
    assert res["rot_rmse_deg"] == pytest.approx(0.0, abs=1e-12)


def test_rpe_distance_sees_a_heading_bias_per_metre():
    n = 201
    x = 0.05 * np.arange(n)  # 0.05 m steps, 10 m
    gt = Trajectory(0.1 * np.arange(n), np.column_stack([x, np.zeros(n), np.zeros(n)]))
    est_theta = wrap_angle(np.radians(2.0) * x)  # 2 degrees of heading drift per metre
    est = Trajectory(gt.stamps, np.column_stack([x, np.zeros(n), est_theta]))
    res = rpe_distance(est, gt, delta_m=1.0)
    assert res["pairs"] == 10
    assert res["rot_rmse_deg"] == pytest.approx(2.0, rel=1e-6)


def test_rpe_distance_pairs_locate_a_jump_and_give_the_same_rmse():
    n = 201
    x = 0.05 * np.arange(n)
    gt = Trajectory(0.1 * np.arange(n) + 5.0, np.column_stack([x, np.zeros((n, 2))]))
    poses = gt.poses.copy()
    poses[:, 1] += np.random.default_rng(3).normal(0.0, 0.002, n)
    poses[117:, 1] += 0.1  # a 10 cm sideways jump between poses 116 and 117
    # the estimate has one extra pose first, so its indices differ from the reference's
    est = Trajectory(np.r_[4.9, gt.stamps], np.vstack([poses[:1], poses]))
    est_pairs, gt_pairs, trans, rot = rpe_distance_pairs(est, gt, delta_m=1.0)
    worst = int(np.argmax(trans))
    assert gt_pairs[worst, 0] < 117 <= gt_pairs[worst, 1]
    assert np.array_equal(est_pairs, gt_pairs + 1)
    assert trans[worst] == pytest.approx(0.1, abs=0.01)
    assert np.sqrt(np.mean(trans**2)) == pytest.approx(rpe_distance(est, gt)["trans_rmse_m"])
    assert rot.shape == trans.shape


def _noisy_copy(gt: Trajectory, sigma_xy: float, sigma_theta: float, seed: int) -> Trajectory:
    """gt with independent noise on every step's motion: a random-walk error like odometry's."""
    rng = np.random.default_rng(seed)
    steps = _steps(gt) + rng.normal(0.0, [sigma_xy, sigma_xy, sigma_theta], (len(gt) - 1, 3))
    return _integrate(gt, steps)


def _steps(trajectory: Trajectory) -> np.ndarray:
    return between(trajectory.poses[:-1], trajectory.poses[1:])


def _integrate(like: Trajectory, steps: np.ndarray) -> Trajectory:
    """The trajectory made of ``steps`` from ``like``'s first pose, at ``like``'s stamps."""
    poses = [like.poses[0]]
    for step in steps:
        poses.append(compose(poses[-1], step))
    return Trajectory(like.stamps, np.array(poses))


def test_three_cornered_hat_recovers_each_trajectorys_own_error_without_the_truth():
    truth = _route(n=6000, period=0.1)
    noise = ((0.002, 0.0005), (0.004, 0.001), (0.008, 0.002))  # per 6 cm step: m, rad
    copies = [_noisy_copy(truth, sx, st, seed) for seed, (sx, st) in enumerate(noise)]
    # the third copy's stamps are shifted within max_dt and one pose is missing
    third = Trajectory(np.delete(copies[2].stamps + 0.004, 77), np.delete(copies[2].poses, 77, 0))
    hat = three_cornered_hat(copies[0], copies[1], third, delta_m=1.0)
    assert hat["pairs"] > 300
    for k, copy_k in enumerate((copies[0], copies[1], third)):
        # each copy's error against the truth, which the hat never saw
        truly = rpe_distance(copy_k, truth)["trans_rmse_m"]
        assert hat["trans_rmse_m"][k] == pytest.approx(truly, rel=0.2), k
    ab, ac, bc = hat["pairwise_trans_rmse_m"]
    assert ab == pytest.approx(
        rpe_distance(copies[1], copies[0], pairs_from_reference=True)["trans_rmse_m"], rel=0.05
    )
    assert ab < ac < bc


def test_three_cornered_hat_blames_errors_two_trajectories_share_on_the_third():
    truth = _route(n=3000, period=0.1)
    shared = _noisy_copy(truth, 0.006, 0.0015, seed=5)
    nearly_the_same = _noisy_copy(shared, 0.0005, 0.0001, seed=6)
    hat = three_cornered_hat(truth, shared, nearly_the_same)
    wrong = rpe_distance(shared, truth, pairs_from_reference=True)["trans_rmse_m"]
    assert hat["trans_rmse_m"][0] == pytest.approx(wrong, rel=0.1)
    # the two copies' own errors come out near zero (NaN when sampling makes the square negative)
    assert np.nan_to_num(hat["trans_rmse_m"][1:], nan=0.0).max() < 0.3 * wrong


def test_three_cornered_hat_reports_nan_for_a_negative_square():
    truth = _route(n=3000, period=0.1)
    noisy = _noisy_copy(truth, 0.006, 0.0015, seed=5)
    # errors of opposite sign: the two differ by twice what each differs from the truth
    mirrored = _integrate(truth, 2 * _steps(truth) - _steps(noisy))
    hat = three_cornered_hat(noisy, mirrored, truth)
    assert np.isnan(hat["trans_rmse_m"][2])
    assert hat["trans_rmse_m"][0] > 0.01


def test_rpe_of_a_too_short_path_is_nan_with_no_pairs():
    gt = Trajectory(np.arange(3.0) * 0.1, np.column_stack([np.arange(3) * 0.1, np.zeros((3, 2))]))
    res = rpe_distance(gt, gt, delta_m=1.0)
    assert res["pairs"] == 0
    assert np.isnan(res["trans_rmse_m"])


def test_evaluate_returns_exactly_the_summary_keys():
    gt = _route(n=120)
    summary = evaluate(_drifting_estimate(gt), gt)
    assert list(summary) == [
        "ate_rmse_m",
        "ate_mean_m",
        "ate_max_m",
        "rpe_1m_trans_m",
        "rpe_1m_rot_deg",
        "rpe_1s_trans_m",
        "rpe_1s_rot_deg",
        "pairs",
    ]
    assert summary["pairs"] == 120
    assert 0 < summary["ate_mean_m"] <= summary["ate_rmse_m"] <= summary["ate_max_m"]


# --- cross-check against evo on the same TUM files -----------------------------------------


@pytest.fixture
def tum_pair(tmp_path):
    gt = _route(n=400, period=0.125)
    est = _drifting_estimate(gt)
    # An estimate with a few more poses than the reference exercises the association.
    est = Trajectory(
        np.append(est.stamps, est.stamps[-1] + [0.125, 0.25]),
        np.vstack([est.poses, est.poses[-1], est.poses[-1]]),
    )
    est_path, gt_path = tmp_path / "est.tum", tmp_path / "gt.tum"
    write_tum(est_path, est)
    write_tum(gt_path, gt)
    return est_path, gt_path


def _evo_inputs(est_path, gt_path, max_dt):
    from evo.core import sync
    from evo.tools import file_interface

    ref = file_interface.read_tum_trajectory_file(str(gt_path))
    est = file_interface.read_tum_trajectory_file(str(est_path))
    return sync.associate_trajectories(ref, est, max_diff=max_dt)


def test_ate_matches_evo_ape_with_alignment(tum_pair):
    from evo.core.metrics import PoseRelation
    from evo.main_ape import ape

    est_path, gt_path = tum_pair
    ref, est = _evo_inputs(est_path, gt_path, 0.01)
    stats = ape(ref, est, PoseRelation.translation_part, align=True).stats
    ours = ate(read_tum(est_path), read_tum(gt_path), max_dt=0.01)
    for key in ("rmse", "mean", "median", "std", "min", "max"):
        assert ours[key] == pytest.approx(stats[key], rel=1e-6), key
    assert ours["pairs"] == ref.num_poses


@pytest.mark.parametrize("pairs_from_reference", [False, True])
def test_rpe_per_metre_matches_evo_rpe(tum_pair, pairs_from_reference):
    from evo.core.metrics import PoseRelation, Unit
    from evo.main_rpe import rpe

    est_path, gt_path = tum_pair
    ours = rpe_distance(read_tum(est_path), read_tum(gt_path), 1.0, 0.01, pairs_from_reference)
    for relation, key in [
        (PoseRelation.translation_part, "trans_rmse_m"),
        (PoseRelation.rotation_angle_deg, "rot_rmse_deg"),
    ]:
        ref, est = _evo_inputs(est_path, gt_path, 0.01)
        result = rpe(
            copy.deepcopy(ref),
            copy.deepcopy(est),
            relation,
            delta=1.0,
            delta_unit=Unit.meters,
            align=True,
            pairs_from_reference=pairs_from_reference,
        )
        assert ours[key] == pytest.approx(result.stats["rmse"], rel=1e-6), key
        assert ours["pairs"] == result.np_arrays["error_array"].size


def test_rpe_per_second_matches_evo_rpe_per_frames_on_even_stamps(tum_pair):
    from evo.core.metrics import PoseRelation, Unit
    from evo.main_rpe import rpe

    est_path, gt_path = tum_pair
    gt = read_tum(gt_path)
    # Even stamps (0.125 s, exact in binary): 1 s is exactly 8 frames.
    est = Trajectory(gt.stamps, read_tum(est_path).poses[: len(gt)])
    write_tum(est_path, est)
    ours = rpe_time(est, gt, delta_s=1.0, max_dt=0.01)
    for relation, key in [
        (PoseRelation.translation_part, "trans_rmse_m"),
        (PoseRelation.rotation_angle_deg, "rot_rmse_deg"),
    ]:
        ref, ev_est = _evo_inputs(est_path, gt_path, 0.01)
        result = rpe(ref, ev_est, relation, delta=8, delta_unit=Unit.frames, align=True)
        assert ours[key] == pytest.approx(result.stats["rmse"], rel=1e-6), key
        assert ours["pairs"] == result.np_arrays["error_array"].size


def test_eval_config_defaults_are_the_documented_ones():
    cfg = EvalConfig()
    assert (cfg.rpe_delta_m, cfg.rpe_delta_s, cfg.pairs_from_reference) == (1.0, 1.0, False)


def _straight_reference() -> Trajectory:
    stamps = np.arange(0.0, 10.0, 0.1)
    poses = np.column_stack([0.5 * stamps, np.zeros_like(stamps), np.full_like(stamps, 0.3)])
    return Trajectory(stamps, poses)


def test_relative_pose_errors_measure_a_closure_against_the_reference():
    ref = _straight_reference()
    # the robot at 9 s seen from the place it was at 1 s: 4 m ahead, same heading
    exact = between(ref.poses[10], ref.poses[90])
    off_sideways = compose(exact, [0.0, 0.8, 0.0])
    turned = compose(exact, [0.0, 0.0, np.radians(25.0)])
    errors = relative_pose_errors(
        [1.0, 1.0, 1.0, 1.0], [9.0, 9.0, 9.0, 42.0],
        [exact, off_sideways, turned, exact], ref,
    )  # fmt: skip
    np.testing.assert_allclose(errors[0], [0.0, 0.0], atol=1e-9)
    np.testing.assert_allclose(errors[1], [0.8, 0.0], atol=1e-9)
    np.testing.assert_allclose(errors[2], [0.0, 25.0], atol=1e-9)
    assert np.isnan(errors[3]).all()  # no reference pose near 42 s
    assert off_reference(errors).tolist() == [False, True, True, False]


def test_relative_pose_errors_take_the_nearest_reference_stamp():
    ref = _straight_reference()
    exact = between(ref.poses[10], ref.poses[90])
    # stamps 4 ms off the reference's: still those poses; 60 ms off: none within max_dt
    near = relative_pose_errors([1.004], [8.996], [exact], ref, max_dt=0.02)
    far = relative_pose_errors([1.06], [9.0], [exact], ref, max_dt=0.02)
    np.testing.assert_allclose(near[0], [0.0, 0.0], atol=1e-9)
    assert np.isnan(far).all()


def test_relative_poses_are_a_trajectory_s_own_between_two_stamps():
    # a robot turning as it goes: the pose at 9 s in the frame of the pose at 1 s is 8 m
    # along the first heading rotated into the robot's frame, turned by 0.8 rad
    stamps = np.arange(0.0, 10.0, 0.1)
    trajectory = Trajectory(stamps, np.column_stack([stamps, np.zeros_like(stamps), 0.1 * stamps]))
    rel = relative_poses(trajectory, [1.0, 1.004, 1.0], [9.0, 8.996, 42.0], max_dt=0.02)
    c, s = np.cos(0.1), np.sin(0.1)
    np.testing.assert_allclose(rel[0], [8.0 * c, -8.0 * s, 0.8], atol=1e-9)
    np.testing.assert_allclose(rel[1], rel[0], atol=1e-12)  # the nearest stamps' poses
    assert np.isnan(rel[2]).all()  # none near 42 s
    # judged against the trajectory itself, its own relative poses have no error
    errors = relative_pose_errors([1.0], [9.0], rel[:1], trajectory)
    np.testing.assert_allclose(errors[0], [0.0, 0.0], atol=1e-9)


def test_a_partial_closure_is_judged_across_its_slide_only():
    # The robot turns as it goes (0.1 rad/s), so that the place's frame and the robot's
    # differ by 0.8 rad between 1 s and 9 s. A partial closure measured 2 m off along its
    # slide (given in the place's frame, 30 deg from its x axis) and 3 cm across it: 3 cm;
    # as a whole closure, 2 m.
    stamps = np.arange(0.0, 10.0, 0.1)
    ref = Trajectory(stamps, np.column_stack([stamps, np.zeros_like(stamps), 0.1 * stamps]))
    truth = between(ref.poses[10], ref.poses[90])
    slide = np.array([np.cos(np.radians(30.0)), np.sin(np.radians(30.0))])
    across = np.array([-slide[1], slide[0]])
    measured = truth.copy()
    measured[:2] += 2.0 * slide + 0.03 * across
    errors = relative_pose_errors(
        [1.0, 1.0], [9.0, 9.0], [measured, measured], ref, free=[slide, [np.nan, np.nan]]
    )
    np.testing.assert_allclose(errors[0], [0.03, 0.0], atol=1e-9)
    np.testing.assert_allclose(errors[1, 0], np.hypot(2.0, 0.03), atol=1e-9)
    assert off_reference(errors).tolist() == [False, True]
