import math

import numpy as np
import pytest

from bioslam.motion_model import (
    ConstantVelocityModel,
    kalman_along,
    predict_axis,
    sideways_along,
    translation_part,
    weak_direction_gain,
)

ALONG_X = np.array([1.0, 0.0, 0.0])


def _model(**kw) -> ConstantVelocityModel:
    args = dict(
        window=0.1, scans=3, length_scale=3.0, degeneracy_ratio=0.01, constrained_ratio=0.1,
        accel_noise=0.5, velocity_noise=0.05, max_spread=0.1,
    )
    args.update(kw)
    return ConstantVelocityModel(**args)


def _drive(model, steps, condition, weakest, heading=0.0, start=0.0, t0=0.0, dt=0.1):
    """Feed poses advancing by ``steps`` (metres, along ``heading``) at ``dt`` intervals."""
    x = start
    d = np.array([np.cos(heading), np.sin(heading)])
    for k, step in enumerate(steps):
        x += step
        model.update(t0 + dt * (k + 1), (*(x * d), heading), condition, weakest)
    return x


def test_the_gain_ramps_from_the_degeneracy_ratio_to_the_constrained_ratio():
    assert weak_direction_gain(0.005, 0.01, 0.1) == 0.0
    assert weak_direction_gain(0.055, 0.01, 0.1) == pytest.approx(0.5)
    assert weak_direction_gain(0.3, 0.01, 0.1) == 1.0


@pytest.mark.parametrize("heading", [0.0, 2.0])
def test_a_slip_along_an_unconstrained_direction_keeps_the_speed(heading):
    """A corridor longer than the range: a single 8.7 cm slip backwards, differenced over three
    scan intervals, used to cut the speed to nearly nothing, and the pose stalled. Along the
    scan's unconstrained direction (the robot's x: body frame) the speed must carry on."""
    model = _model()
    x = _drive(model, [0.05] * 20, 1.0, ALONG_X, heading)  # well constrained: 0.5 m/s learned
    assert model.twist[0] == pytest.approx(0.5, abs=1e-6)
    _drive(model, [0.05] * 5 + [-0.087] + [0.0] * 5, 0.0, ALONG_X, heading, x, 2.0)
    assert model.twist[0] == pytest.approx(0.5, abs=1e-6)
    # the plain window difference (no conditioning known) takes the slip whole
    plain = _model()
    x = _drive(plain, [0.05] * 20, 1.0, ALONG_X, heading)
    _drive(plain, [0.05] * 5 + [-0.087], 1.0, None, heading, x, 2.0)
    assert plain.twist[0] < 0.05


def test_across_the_weak_direction_the_measurement_is_taken():
    model = _model()
    _drive(model, [0.05] * 10, 1.0, ALONG_X)
    # sideways drift of 2 cm per scan while x is unconstrained: y speed follows at once
    for k in range(5):
        model.update(1.0 + 0.1 * (k + 1), (0.5 + 0.05 * (k + 1), 0.02 * (k + 1), 0.0), 0.0,
                     ALONG_X)  # fmt: skip
    assert model.twist[1] == pytest.approx(0.2, abs=1e-6)
    assert model.twist[0] == pytest.approx(0.5, abs=1e-6)


def test_a_well_constrained_scan_gives_the_window_measurement_whole():
    """Dense data, where every scan constrains every direction, is unchanged: the twist is
    the plain difference over the window, a change of speed followed at once."""
    model = _model()
    x = _drive(model, [0.05] * 10, 0.5, ALONG_X)
    _drive(model, [0.02] * 3, 0.5, ALONG_X, 0.0, x, 1.0)
    assert model.twist[0] == pytest.approx(0.2, abs=1e-6)


def test_partly_constrained_scans_follow_a_change_of_speed_but_not_a_slip():
    """A door jamb in range gives the speed along a corridor a little information: a robot
    speeding up is followed over a few scans, a 19 cm slip (0.6 m/s in one window) is not."""
    model = _model()
    x = _drive(model, [0.05] * 20, 1.0, ALONG_X)
    weak = 0.03  # gain 0.22
    x = _drive(model, [0.05 + 0.005 * k for k in range(1, 11)], weak, ALONG_X, 0.0, x, 2.0)
    speeding = model.twist[0]
    assert 0.75 < speeding < 1.0  # true 1.0 m/s, followed with a lag
    x = _drive(model, [0.1] * 20, weak, ALONG_X, 0.0, x, 3.0)
    assert model.twist[0] == pytest.approx(1.0, abs=0.02)
    _drive(model, [-0.09], weak, ALONG_X, 0.0, x, 5.0)
    assert model.twist[0] == pytest.approx(1.0, abs=0.02)


def test_a_speed_every_later_scan_contradicts_gives_way_to_theirs():
    """A look-alike's 0.9 m jump, differenced on a well-conditioned scan, set the carried
    speed to 3 m/s; the partly constrained scans after it all measured 0.5 m/s and each was
    rejected against it as a slip, until a degenerate stretch ran on at 3 m/s. A run of
    rejections longer than two slips can cause, all on one side, now resets the speed;
    slips do not."""
    model = _model()
    x = _drive(model, [0.05] * 20, 1.0, ALONG_X)
    x = _drive(model, [0.9], 0.2, ALONG_X, 0.0, x, 2.0)  # the jump, on a scan that pins x
    assert model.twist[0] > 2.0
    weak = 0.07  # gain 0.67: 0.5 m/s is 2.5 m/s off, far beyond the gate
    x = _drive(model, [0.05] * 7, weak, ALONG_X, 0.0, x, 2.1)
    assert model.twist[0] > 2.0  # seven in a row: as many as two slips can explain
    _drive(model, [0.05] * 2, weak, ALONG_X, 0.0, x, 2.8)
    assert model.twist[0] == pytest.approx(0.5, abs=1e-6)
    # two slips two scans apart: five windows in a row span one of them, and the speed holds
    model = _model()
    x = _drive(model, [0.05] * 20, 1.0, ALONG_X)
    x = _drive(model, [0.05] * 10, weak, ALONG_X, 0.0, x, 2.0)
    _drive(model, [-0.25, 0.05, -0.25] + [0.05] * 10, weak, ALONG_X, 0.0, x, 3.0)
    assert model.twist[0] == pytest.approx(0.5, abs=1e-6)


def test_a_weak_direction_that_is_mostly_a_turn_is_not_carried():
    assert translation_part(np.array([0.3, 0.1, 0.95])) is None
    assert translation_part(None) is None
    d = translation_part(np.array([0.9, 0.3, 0.3]))
    assert d is not None and d[2] == 0.0 and np.hypot(d[0], d[1]) == pytest.approx(1.0)


def test_kalman_along_rejects_an_outlier_and_weighs_a_measurement_by_the_gain():
    carried = np.array([0.5, 0.0, 0.0])
    twist, var, rejected = kalman_along(
        np.array([0.1, 0.0, 0.0]), carried, 0.0025, ALONG_X, 1.0, 0.0025, 3.0, 3.0
    )
    assert twist[0] == 0.5 and var == 0.0025  # 0.4 m/s off, 5.7 sigma: a slip
    assert rejected == pytest.approx(-0.4)
    twist, var, rejected = kalman_along(
        np.array([0.55, 0.0, 0.0]), carried, 0.0025, ALONG_X, 0.5, 0.0025, 3.0, 3.0
    )
    assert twist[0] == pytest.approx(0.5 + 0.05 / 3.0)  # variance 0.0025 against 0.005
    assert var == pytest.approx(0.0025 * 2.0 / 3.0)
    assert rejected == 0.0


def test_overlapping_windows_are_not_counted_as_independent_measurements():
    """Partly constrained scans at a corridor's entrance place the pose to within a couple of
    centimetres along it; each velocity measurement differences the poses three scans apart,
    so consecutive ones share the same jitter. Taken as independent, they pulled the carried
    speed 10 % low, and the pose fell 0.3 m behind over the 2 m of corridor that followed
    (simulated URG-04LX, maze, seed 0, 48-53 s), which later passes then snapped to."""
    rng = np.random.default_rng(0)
    errors = []
    for _ in range(200):
        model = _model()
        for k in range(40):
            t, x = 0.1 * k, 0.05 * k
            if k < 10:
                model.update(t, (x, 0.0, 0.0), 1.0, ALONG_X)
            elif k < 20:  # the match jitters by 1.5 cm along the corridor
                model.update(t, (x + rng.normal(0.0, 0.015), 0.0, 0.0), 0.035, ALONG_X)
            else:  # only the motion model carries the pose
                model.update(t, (x, 0.0, 0.0), 0.001, ALONG_X)
        errors.append(model.twist[0] - 0.5)
    # one interval's worth of information per measurement: 2.0 cm/s RMS (3.1 counted whole)
    assert np.sqrt(np.mean(np.square(errors))) < 0.025


def test_the_axis_covariance_grows_as_a_constant_velocity_model_and_its_speed_is_bounded():
    """(position, velocity) along the weak direction: F P F' + Q with a white acceleration,
    the velocity's variance bounded as the carried speed's is."""
    p = np.diag([1e-4, 1e-3])
    out = predict_axis(p, 0.1, 0.5, 1.0)
    assert out[0, 0] == pytest.approx(1e-4 + 0.01 * 1e-3 + 0.25 * 1e-4 / 4)
    assert out[0, 1] == pytest.approx(out[1, 0])
    assert out[0, 1] == pytest.approx(0.1 * 1e-3 + 0.25 * 1e-3 / 2)
    capped = predict_axis(p, 10.0, 0.5, 0.01)
    assert capped[1, 1] == pytest.approx(0.01)
    assert np.all(np.linalg.eigvalsh(capped) >= 0.0)


def _follow(model, speeds, information, dt=0.1):
    """A robot along body x at ``speeds`` (one per scan) in a corridor the scans do not
    constrain along it: each match lands where the scan puts it, weighed by the filter's
    prior against ``information`` endpoints along the axis (Gauss-Newton's blend, as
    :func:`match_scan_to_map` does with ``prior_information``). Returns the position
    errors and the carried speeds."""
    x, true = 0.0, 0.0
    errors, carried = [], []
    for k, speed in enumerate(speeds, start=1):
        true += speed * dt
        prior = model.prior_information(dt)
        predicted = x + model.twist[0] * dt
        share = prior / (prior + information)  # the prior's share along the axis
        x = predicted + (1.0 - share) * (true - predicted)
        model.update(
            k * dt, (x, 0.0, 0.0), 0.001, ALONG_X, (np.array([true - predicted, 0.0]), information)
        )
        errors.append(x - true)
        carried.append(model.twist[0])
    return np.array(errors), np.array(carried)


def test_the_filter_follows_a_speed_change_by_the_scans_own_information_along_the_axis():
    """A robot speeding up from 0.9 to 1.2 m/s once its scans are degenerate (a corridor
    whose end is barely in range): with a few endpoints' worth of information along the axis
    the speed is learnt and the pose follows without falling behind and snapping back; with
    none the speed is carried unchanged (nothing tells it)."""
    speeds = np.r_[np.full(20, 0.9), np.linspace(0.9, 1.2, 4), np.full(76, 1.2)]
    model = _model(point_noise=0.05)
    _follow(model, np.full(20, 0.9), 1.0)  # at 0.9 m/s before
    errors, carried = _follow(model, speeds, 1.0)
    assert carried[-1] == pytest.approx(1.2, abs=0.03)
    assert np.abs(errors).max() < 0.1
    assert np.abs(np.diff(errors)).max() < 0.02  # no snap
    blind = _model(point_noise=0.05)
    _follow(blind, np.full(20, 0.9), 1.0)
    before = blind.twist[0]
    _, carried = _follow(blind, speeds, 0.0)
    assert carried[-1] == pytest.approx(before, abs=1e-6)


def test_a_far_off_offset_is_a_slip_and_leaves_the_speed():
    model = _model(point_noise=0.05)
    _follow(model, np.full(20, 1.0), 1.0)
    before = model.twist[0]
    model.prior_information(0.1)
    x = 2.1 + 0.5  # half a metre ahead of the prediction in one scan
    model.update(2.1, (x, 0.0, 0.0), 0.001, ALONG_X, (np.array([0.5, 0.0]), 1.0))
    assert model.twist[0] == pytest.approx(before, abs=1e-9)


def test_no_sideways_slip_tells_a_stop_from_a_robot_turned_across_the_weak_axis():
    """Carried at 1.2 m/s along a corridor the scans do not constrain, a robot that stopped
    and turns on the spot is 30 degrees off the axis: the scan sees no motion across the
    axis, so a wheeled robot moving on along it would slip sideways at 0.6 m/s. The speed
    along the axis drops towards 0; driving along the axis nothing changes."""
    turned = np.array([math.cos(-math.pi / 6), math.sin(-math.pi / 6), 0.0])  # axis, body
    twist = 1.2 * turned.copy()
    twist[2] = 1.5
    # the scan's velocity across the axis (0) is in the twist already; a second of scans
    # at 10 Hz, the carried speed's variance at its bound (0.1 m/s) before each
    out = twist
    for _ in range(10):
        out, variance = sideways_along(out, 0.01, turned, 0.1)
        assert variance < 0.01
    along = float(out[:2] @ turned[:2])
    assert along < 0.2
    assert float(out[:2] @ np.array([-turned[1], turned[0]])) == pytest.approx(0.0, abs=1e-12)
    assert out[2] == 1.5
    straight, same = sideways_along(np.array([1.2, 0.0, 0.0]), 0.01, ALONG_X, 0.1)
    assert straight[0] == pytest.approx(1.2) and same == 0.01
