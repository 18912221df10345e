"""Tests of the step prior: a density of the robot's recent steps between scans."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bioslam.matching.deskew import se2_exp
from bioslam.step_prior import (
    StepPrior,
    StepPriorConfig,
    along_axis,
    arc_length,
    driven_backwards,
    heading_cone_offset,
)


def thinned_log_steps(n: int = 100, seed: int = 0) -> np.ndarray:
    """Steps of a log thinned to a scan per metre or per 30° of turn: mostly about a metre
    straight on with a few degrees of turn, sometimes a turn on the spot either way."""
    rng = np.random.default_rng(seed)
    steps = np.zeros((n, 3))
    spin = rng.random(n) < 0.3
    steps[:, 0] = np.where(spin, rng.uniform(0.0, 0.1, n), rng.uniform(0.9, 1.1, n))
    steps[:, 1] = rng.normal(0.0, 0.03, n)
    turn = np.where(rng.random(n) < 0.5, -1.0, 1.0) * math.radians(30.0)
    steps[:, 2] = np.where(spin, turn, rng.normal(0.0, math.radians(5.0), n))
    return steps


def prior_of(steps: np.ndarray, **kwargs: float) -> StepPrior:
    prior = StepPrior(StepPriorConfig(**kwargs))
    for s in steps:
        prior.add(s)
    return prior


def test_a_thinned_logs_own_steps_are_cheap_and_look_alikes_are_not():
    prior = prior_of(thinned_log_steps())
    cap = -math.log(prior.config.floor * prior.config.cone_floor)
    forward = prior.cost((1.0, 0.0, 0.0))
    spin = prior.cost((0.05, 0.0, math.radians(-30.0)))
    assert forward < 1.0 and spin < 2.0
    # The poses a corridor or a scan's own beam pattern cannot tell from the true one: standing
    # still, a metre sideways, a turn of 90 degrees.
    for wrong in ((0.0, 0.0, 0.0), (0.5, -1.0, 0.0), (1.0, 0.0, math.pi / 2)):
        cost = prior.cost(wrong)
        assert cost > forward + 1.5, wrong
        assert cost <= cap + 1e-12
    # a metre back: what the robot does backing up, at ``cone_reverse`` of a metre on
    back = prior.cost((-0.8, 0.0, 0.0))
    assert forward + 1.0 < back < prior.cost((0.5, -1.0, 0.0))


def test_a_dense_scanners_steps_make_any_long_step_cost_the_most():
    rng = np.random.default_rng(1)
    steps = np.column_stack([rng.uniform(0.01, 0.03, 100), rng.normal(0, 0.002, 100),
                             rng.normal(0, 0.01, 100)])  # fmt: skip
    prior = prior_of(steps)
    assert prior.cost((0.02, 0.0, 0.0)) < 0.05
    # a metre is unlike every step and far beyond the longest: the floor's and the cones'
    # least density together
    cap = -math.log(prior.config.floor * prior.config.cone_floor)
    assert prior.cost((1.0, 0.0, 0.0)) == pytest.approx(cap, abs=0.1)


def test_a_step_beyond_the_reach_of_the_recent_ones_costs_as_one_off_the_cones():
    """Once the prior is no longer young, a step longer than the longest recent one (a
    look-alike a rack period down an aisle) costs more the farther it reaches, up to what a
    step off the heading cones costs; young, the longest step known says nothing yet (a log
    that starts with turns on the spot)."""
    steps = thinned_log_steps()
    prior = prior_of(steps)
    longest = float(np.max(np.hypot(steps[:, 0], steps[:, 1])))
    within = prior.cost((longest, 0.0, 0.0))
    assert prior.kinematic((longest, 0.0, 0.0)) == pytest.approx(1.0)
    assert 0.3 < prior.kinematic((longest + 0.25, 0.0, 0.0)) < 0.7
    assert prior.kinematic((longest + 2.0, 0.0, 0.0)) == pytest.approx(prior.config.cone_floor)
    sideways = prior.cost((0.0, 2.0, 0.0))
    assert prior.cost((longest + 2.0, 0.0, 0.0)) == pytest.approx(sideways, abs=0.01)
    assert prior.cost((longest + 2.0, 0.0, 0.0)) > within + 2.0
    young = prior_of(steps[:40])
    assert young.kinematic((longest + 2.0, 0.0, 0.0)) == 1.0


def test_a_step_turning_beyond_the_recent_ones_costs_as_one_off_the_cones():
    """Once the prior is no longer young, a step that turns farther than the widest recent
    turn (a room seen turned round, in a log thinned to a scan per 30° of turn) costs more
    the farther it turns, up to what a step off the heading cones costs; young, the widest
    turn known says nothing yet."""
    steps = thinned_log_steps()
    prior = prior_of(steps)
    c = prior.config
    widest = float(np.max(np.abs(steps[:, 2])))
    assert prior.kinematic((0.0, 0.0, widest)) == pytest.approx(1.0)
    assert prior.kinematic((0.0, 0.0, -widest)) == pytest.approx(1.0)
    assert 0.3 < prior.kinematic((0.0, 0.0, widest + c.sigma_angle)) < 0.7
    assert prior.kinematic((0.0, 0.0, math.pi)) == pytest.approx(c.cone_floor)
    assert prior.cost((0.0, 0.0, math.pi)) == pytest.approx(prior.cost((0.0, 2.0, 0.0)), abs=0.01)
    assert prior.cost((0.0, 0.0, math.pi)) > prior.cost((0.0, 0.0, widest)) + 2.0
    young = prior_of(steps[:40])
    assert young.kinematic((0.0, 0.0, math.pi)) == 1.0


def test_a_few_wrong_steps_among_many_do_not_make_their_kind_typical():
    steps = thinned_log_steps()
    steps[[10, 40, 70]] = 0.0  # three standstills accepted by mistake
    prior = prior_of(steps)
    assert prior.cost((0.0, 0.0, 0.0)) > -math.log(0.1)  # still implausible
    assert prior.cost((1.0, 0.0, 0.0)) < 1.0


def test_few_steps_give_a_weak_prior_and_none_a_flat_one():
    """Without the kinematic density (``cone_sigma`` None) the young prior is flat; the
    floor raised to ``floor_steps / n`` (uncapped here)."""
    prior = StepPrior(StepPriorConfig(cone_sigma=None, max_young_floor=1.0))
    assert prior.cost((5.0, 5.0, 3.0)) == 0.0 and prior.density((5.0, 5.0, 3.0)) == 1.0
    for _ in range(3):
        prior.add((1.0, 0.0, 0.0))
    assert prior.cost((-1.0, 0.0, 0.0)) == 0.0  # floor_steps / 3 > 1: still flat
    assert prior.flat
    prior.add((1.0, 0.0, 0.0))
    assert prior.flat and prior.cost((-1.0, 0.0, 0.0)) == 0.0  # 4 / 4: flat still
    prior.add((1.0, 0.0, 0.0))
    assert not prior.flat
    # five steps alike: the floor is 4/5, so even the most unlike step costs little
    assert 0.0 < prior.cost((-1.0, 0.0, 0.0)) <= -math.log(4.0 / 5.0) + 1e-12
    assert len(prior) == 5


def test_a_robot_that_drove_on_may_back_up_the_same_steps():
    """Steps of a metre on along an arc: the same steps driven backwards (speed and turn rate
    negated) have ``cone_reverse`` of their density, a step sideways or a step back turning
    the other way none."""
    config = StepPriorConfig()
    prior = StepPrior(config)
    arc = (0.95, 0.15, 0.3)
    for _ in range(20):
        prior.add(arc)
    on = prior.density(arc)
    assert on == pytest.approx(1.0)
    assert prior.density(driven_backwards(np.array(arc))) == pytest.approx(config.cone_reverse)
    assert prior.density((-0.95, -0.15, 0.3)) < 0.01  # backing up, turning the other way
    assert prior.density((0.0, 1.0, 0.0)) < 1e-3
    assert prior.cost(driven_backwards(np.array(arc))) < prior.cost((0.0, 1.0, 0.0)) - 1.0


@pytest.mark.parametrize("mount", [math.pi, math.pi / 2, -math.pi / 2, math.radians(50.0)])
def test_the_cones_turn_with_the_axis_the_robot_drives_along_in_the_scans_frame(mount):
    """A scanner mounted turned by ``-mount`` on the robot: the thinned log's steps, seen in
    its frame, drive along ``mount``. The prior learns that axis, and prices the steps as a
    forward-facing scanner's prior prices them in its own frame: a metre on along the axis
    is free, the same step the other way (backing up) pays the reverse cone, sideways the
    most."""
    steps = thinned_log_steps(100, seed=3)
    ahead = prior_of(steps)
    turned = prior_of(np.array([along_axis(s, mount) for s in steps]))
    assert ahead.axis == 0.0
    assert abs(math.remainder(turned.axis - mount, 2.0 * math.pi)) < math.radians(5.0)
    for step in ((1.0, 0.02, 0.05), (-1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.05, 0.0, 0.5)):
        assert turned.cost(along_axis(step, mount)) == pytest.approx(ahead.cost(step), abs=0.05)
    assert turned.cost(along_axis((-1.0, 0.0, 0.0), mount)) > turned.cost(
        along_axis((1.0, 0.0, 0.0), mount)
    ) + 0.5


def test_turns_on_the_spot_with_the_scanner_off_the_axle_leave_the_axis_forward():
    """A scanner ahead of the axle moves sideways as the robot turns on the spot (intel's
    first ten scans: 0.25 m at -110° summed): those steps say nothing of the driving axis,
    nor do steps that go every way, nor a robot that backs up now and then."""
    spins = [(0.02, -0.06, math.radians(30.0))] * 20
    assert prior_of(np.array(spins)).axis == 0.0
    rng = np.random.default_rng(1)
    angles = rng.uniform(-math.pi, math.pi, 60)
    wander = np.stack([np.cos(angles), np.sin(angles), np.zeros(60)], axis=1)
    assert prior_of(wander).axis == 0.0
    reversing = np.array([(1.0, 0.0, 0.0)] * 60 + [(-1.0, 0.0, 0.0)] * 15)
    assert prior_of(reversing).axis == 0.0
    assert prior_of(-reversing).axis == pytest.approx(math.pi)


def test_a_step_driven_backwards_mirrors_across_the_axis():
    """Backing up negates the speed and the turn rate: across a forward (or backward) axis
    the displacement along it flips, across a sideways one the sideways part does."""
    step = np.array([0.9, 0.2, 0.3])
    np.testing.assert_allclose(driven_backwards(step), [-0.9, 0.2, -0.3])
    np.testing.assert_allclose(driven_backwards(step, math.pi), [-0.9, 0.2, -0.3], atol=1e-12)
    np.testing.assert_allclose(driven_backwards(step, math.pi / 2), [0.9, -0.2, -0.3], atol=1e-12)


def test_from_min_steps_on_the_learned_density_weighs_at_least_half():
    """The raised floor is capped (``max_young_floor``): three steps of a metre on known, a
    standstill costs what a step unlike all known does under a floor of one half, and more
    steps lower the floor as ``floor_steps / n`` once that is below the cap."""
    config = StepPriorConfig(cone_sigma=None)
    prior = StepPrior(config)
    for _ in range(config.min_steps - 1):
        prior.add((1.0, 0.0, 0.0))
    assert prior.flat and prior.cost((0.0, 0.0, 0.0)) == 0.0
    prior.add((1.0, 0.0, 0.0))
    assert not prior.flat
    assert prior.cost((1.0, 0.0, 0.0)) < 0.01
    still = prior.cost((0.0, 0.0, 0.0))
    assert still == pytest.approx(-math.log(config.max_young_floor), abs=1e-3)
    for _ in range(7):
        prior.add((1.0, 0.0, 0.0))
    still = prior.cost((0.0, 0.0, 0.0))
    assert still == pytest.approx(-math.log(config.floor_steps / 10), abs=1e-3)


@pytest.mark.parametrize(
    ("step", "forward", "reverse"),
    [
        ((1.0, 0.0, 0.6), 0.0, 1.0),  # a metre on, then a turn
        ((math.cos(0.6), math.sin(0.6), 0.6), 0.0, 1.0),  # a turn, then a metre on
        ((math.cos(0.3), math.sin(0.3), 0.6), 0.0, 1.0),  # an arc
        ((0.0, 0.0, -1.2), 0.0, 0.0),  # a turn on the spot
        ((-1.0, 0.0, 0.0), 1.0, 0.0),  # backing up straight
        ((-math.cos(0.3), -math.sin(0.3), 0.6), 1.0, 0.0),  # backing up on an arc
        ((1.0, -0.3, 0.6), 0.3, math.hypot(1.0, 0.3)),  # beside the start heading's ray
        ((0.0, 1.0, 0.0), 1.0, 1.0),  # a metre sideways, going straight
        ((math.cos(0.5), math.sin(0.5), -0.4), math.sin(0.5), 1.0),  # left of a right turn
    ],
)
def test_the_heading_cones_hold_every_step_of_a_wheeled_robot(step, forward, reverse):
    assert heading_cone_offset(step) == pytest.approx(forward, abs=1e-9)
    assert heading_cone_offset(step, reverse=True) == pytest.approx(reverse, abs=1e-9)


def test_with_no_step_known_only_what_a_wheeled_robot_cannot_do_costs_the_most():
    """The first steps of a log: nothing learned, but two metres sideways after a turn (the
    look-alike that lost a thinned maze route at its first turn) costs the most; backing up a
    metre (where a warehouse aisle's look-alike lies) part of it; a metre on or a turn
    nothing."""
    prior = StepPrior()
    c = prior.config
    worst = -math.log(c.cone_floor)
    for step in ((1.0, 0.0, 0.0), (0.0, 0.0, 0.6), (0.9, 0.1, 0.6), (0.05, 0.0, -0.6)):
        assert prior.cost(step) < 0.05, step
    assert prior.cost((0.87, -1.93, 0.64)) == pytest.approx(worst, abs=0.01)
    backing = -math.log(c.cone_floor + (1.0 - c.cone_floor) * c.cone_reverse)
    assert prior.cost((-1.3, 0.0, 0.0)) == pytest.approx(backing, abs=1e-9)
    assert 0.3 * worst < backing < 0.7 * worst
    for _ in range(5):
        prior.add((1.0, 0.0, 0.0))
    # learned and kinematic: unlike every step known, sideways costs more than back
    assert prior.cost((0.0, 1.0, 0.0)) > prior.cost((-1.0, 0.0, 0.0)) + 0.2


def test_the_window_forgets_old_steps():
    prior = prior_of(np.tile([1.0, 0.0, 0.0], (100, 1)), window=40)
    for _ in range(40):
        prior.add((0.0, 0.0, 0.5))
    assert len(prior) == 40
    assert prior.cost((1.0, 0.0, 0.0)) > prior.cost((0.0, 0.0, 0.5)) + 2.0


def test_angles_wrap():
    prior = prior_of(np.tile([0.0, 0.0, math.pi - 0.01], (10, 1)))
    assert prior.cost((0.0, 0.0, -math.pi + 0.01)) < 0.01


BAD_CONFIGS = [
    {"window": 0}, {"min_steps": 0}, {"sigma_distance": 0.0}, {"sigma_angle": -1.0},
    {"floor": 0.0}, {"floor": 1.5}, {"floor_steps": -1.0}, {"cone_sigma": 0.0},
    {"max_young_floor": 0.0}, {"max_young_floor": 1.5},
    {"cone_floor": 0.0}, {"cone_floor": 1.5}, {"cone_reverse": -0.1}, {"cone_reverse": 1.5},
]  # fmt: skip


@pytest.mark.parametrize("kwargs", BAD_CONFIGS)
def test_bad_configs_are_refused(kwargs):
    with pytest.raises(ValueError):
        StepPriorConfig(**kwargs)


def test_modes_are_the_typical_steps_each_distinct():
    """A thinned log's typical steps: a metre on (the commonest first), a turn on the spot
    either way; never two of one kind, and nothing before ``min_steps`` steps are known."""
    prior = prior_of(thinned_log_steps())
    modes = prior.modes(3)
    assert len(modes) == 3
    assert 0.9 <= modes[0][0] <= 1.1 and abs(modes[0][2]) < math.radians(10.0)
    turns = sorted(m[2] for m in modes[1:])
    assert turns[0] == pytest.approx(math.radians(-30.0), abs=1e-9)
    assert turns[1] == pytest.approx(math.radians(30.0), abs=1e-9)
    assert all(m[0] < 0.1 for m in modes[1:])
    assert len(prior.modes(10)) < 10  # three kinds of step: few distinct ones
    assert prior_of(thinned_log_steps()[:2]).modes(3) == []


def reference_modes(steps: np.ndarray, count: int, sigma_d: float, sigma_a: float) -> list:
    """The definition of :meth:`StepPrior.modes`, pair by pair: density the sum of the
    Gaussian kernel over every known step; densest first (the older of equals), each
    beyond twice a kernel width of every one chosen before it."""
    def kernel(a: np.ndarray, b: np.ndarray) -> float:
        turn = math.remainder(a[2] - b[2], 2 * math.pi)
        e = ((a[0] - b[0]) ** 2 + (a[1] - b[1]) ** 2) / sigma_d**2 + turn**2 / sigma_a**2
        return math.exp(-0.5 * e)

    density = [sum(kernel(a, b) for b in steps) for a in steps]
    chosen: list = []
    for i in sorted(range(len(steps)), key=lambda k: -density[k]):
        far = all(
            math.hypot(*(steps[i][:2] - c[:2])) > 2 * sigma_d
            or abs(math.remainder(steps[i][2] - c[2], 2 * math.pi)) > 2 * sigma_a
            for c in chosen
        )
        if far and len(chosen) < count:
            chosen.append(steps[i])
    return chosen


@pytest.mark.parametrize("seed", range(6))
def test_modes_follow_their_definition(seed):
    """The modes (computed in a compiled loop) are those of the definition, on steps that
    include exact repeats (ties in density) and turns across ±180°."""
    rng = np.random.default_rng(seed)
    steps = thinned_log_steps(int(rng.integers(5, 100)), seed)
    steps[::7] = steps[0]  # repeats: equal densities, the older first
    steps[1::9, 2] = math.pi - rng.uniform(0.0, 0.05, len(steps[1::9]))
    steps[2::9, 2] = -math.pi + rng.uniform(0.0, 0.05, len(steps[2::9]))
    prior = prior_of(steps)
    c = prior.config
    got = prior.modes(8)
    want = reference_modes(steps, 8, c.sigma_distance, c.sigma_angle)
    assert len(got) == len(want) >= 3
    for g, w in zip(got, want, strict=True):
        np.testing.assert_allclose(g, w, atol=1e-12)


def test_modes_follow_their_definition_once_the_window_is_full():
    """Past ``window`` steps the modes are those of the last ``window`` alone (the pairwise
    kernels the prior keeps drop the oldest step's row and column)."""
    steps = thinned_log_steps(70, seed=3)
    steps[40:, 0] *= 1.6  # the later steps longer: the dropped ones would show
    prior = prior_of(steps, window=30)
    c = prior.config
    got = prior.modes(6)
    want = reference_modes(steps[-30:], 6, c.sigma_distance, c.sigma_angle)
    assert len(got) == len(want) >= 2
    for g, w in zip(got, want, strict=True):
        np.testing.assert_allclose(g, w, atol=1e-12)


def test_a_cost_asked_again_after_a_new_step_is_the_new_priors():
    """Costs are remembered between two steps only: a step asked about before and after
    the prior learns a new kind of step costs what the new prior says."""
    prior = prior_of(np.tile([1.0, 0.0, 0.0], (20, 1)))
    turn = (0.0, 0.0, math.radians(30.0))
    before = prior.cost(turn)
    assert prior.cost(turn) == before
    for _ in range(20):
        prior.add(turn)
    assert prior.cost(turn) < before - 1.0
    fresh = prior_of(np.vstack([np.tile([1.0, 0.0, 0.0], (20, 1)), [turn] * 20]))
    assert prior.cost(turn) == fresh.cost(turn)


def test_a_step_unlike_the_few_known_costs_when_not_young():
    """Below ``min_steps`` the young prior is flat, but the cost an echo pays (not young)
    already counts the steps known: two metres on make standing still cost the most."""
    prior = StepPrior()
    assert prior.cost((0.0, 0.0, 0.0), young=False) == 0.0  # nothing known at all
    prior.add((1.0, 0.0, 0.0))
    prior.add((1.0, 0.0, 0.0))
    assert prior.cost((0.0, 0.0, 0.0)) == 0.0
    worst = -math.log(prior.config.floor)
    assert prior.cost((0.0, 0.0, 0.0), young=False) == pytest.approx(worst, abs=0.01)
    assert prior.cost((1.0, 0.0, 0.0), young=False) < 0.05 * worst


@pytest.mark.parametrize(
    "twist", [(1.0, 0.0, 1.2), (0.7, 0.0, -0.5), (-1.0, 0.0, 0.3), (0.4, 0.0, 0.0)]
)
def test_a_step_driven_along_an_arc_has_that_arc_s_length(twist):
    assert arc_length(se2_exp(twist)) == pytest.approx(abs(twist[0]), abs=1e-12)


def test_a_robot_turning_on_the_spot_goes_nowhere_while_it_turns():
    """Steps of a metre straight on and turns of 0.6 rad on the spot (a log thinned by
    distance or angle): a turn as wide goes no path; one that turns while it drives a metre
    goes a metre; none is known for a turn while only straight steps are."""
    prior = StepPrior()
    for k in range(20):
        prior.add((1.0, 0.01 * (k % 3), 0.01))
    assert prior.turning_length(0.8) is None
    for k in range(10):
        prior.add((0.02, 0.0, 0.6 * (-1) ** k))
    assert prior.turning_length(-0.7) == pytest.approx(0.02, abs=1e-3)
    for _ in range(15):
        prior.add(se2_exp((1.0, 0.0, 0.9)))
    assert prior.turning_length(1.0) == pytest.approx(1.0, abs=1e-9)


def corner_steps() -> np.ndarray:
    """A log thinned to a scan per metre or per 0.6 rad: metres straight on, turns of 0.6
    rad that ended the step within a few decimetres, and one metre on while turning 24°."""
    straight = [se2_exp((1.0, 0.0, 0.0))] * 12
    turns = [se2_exp((0.3, 0.0, math.radians(a))) for a in (36.0, -37.0, 35.0)]
    return np.array([*straight, *turns, se2_exp((1.0, 0.0, math.radians(24.0)))])


def steady_steps() -> np.ndarray:
    """A scanner at its rate: steps of 0.1 m turning 0.02 rad, none ending short."""
    return np.tile([0.1, 0.0, 0.02], (30, 1))


def test_the_thinning_rule_is_read_from_the_steps():
    """A metre on when nearly straight, the least turn of the steps that ended short; none
    from a scanner at its rate (no step ends short) or from turns alone."""
    assert prior_of(corner_steps()).thinning_extent() == pytest.approx((1.0, math.radians(35.0)))
    assert prior_of(steady_steps()).thinning_extent() is None
    assert prior_of(np.tile([0.0, 0.0, 0.6], (30, 1))).thinning_extent() is None


def test_a_step_that_turned_less_than_the_thinning_angle_went_the_thinning_distance():
    """Turning 29°, short of the 35° at which steps ended short, a metre on costs nothing
    and 0.3 m on does, more than the joint density, to which each is unlike every recent
    step, prefers it. Turning 36°, or a metre on, a step reached the rule's end and costs
    nothing."""
    prior = prior_of(corner_steps())
    long_turn = se2_exp((1.0, 0.0, math.radians(29.0)))
    short_turn = se2_exp((0.3, 0.0, math.radians(29.0)))
    assert prior.length_cost(long_turn) == 0.0
    assert prior.length_cost(short_turn) > 0.15
    assert prior.length_cost(se2_exp((0.3, 0.0, math.radians(22.0)))) > prior.length_cost(
        short_turn
    )
    assert prior.cost(long_turn) + prior.length_cost(long_turn) < prior.cost(
        short_turn
    ) + prior.length_cost(short_turn)
    assert prior.length_cost(se2_exp((0.3, 0.0, math.radians(36.0)))) == 0.0


def test_without_a_thinning_rule_no_length_costs_anything():
    """A scanner at its rate (steps of 0.1 m, none ended short), and a prior too young to
    say anything: no length costs."""
    steady = prior_of(steady_steps())
    young = prior_of(corner_steps()[:2])
    assert young.flat
    for prior in (steady, young):
        assert prior.length_cost(se2_exp((0.01, 0.0, 0.05))) == 0.0


@given(
    seed=st.integers(0, 2**16),
    length=st.floats(0.0, 3.0),
    turn=st.floats(-math.pi, math.pi),
    more=st.floats(0.0, 1.0),
)
@settings(max_examples=60, deadline=None)
def test_the_length_cost_is_bounded_and_falls_as_a_step_reaches_further(seed, length, turn, more):
    """On any thinned log's steps: the cost lies in [0, -log(floor)], is 0 for a step that
    reached the rule's distance or angle, and never grows as the same turn goes further or
    the same length turns further."""
    prior = prior_of(thinned_log_steps(60, seed))
    extent = prior.thinning_extent()
    assert extent is not None
    distance, angle = extent
    floor = prior.config.floor

    def cost(arc: float, heading: float) -> float:
        return prior.length_cost(se2_exp((arc, 0.0, heading)))

    here = cost(length, turn)
    assert 0.0 <= here <= -math.log(floor) + 1e-12
    if length >= distance or abs(turn) >= angle:
        assert here == 0.0
    assert cost(length + more, turn) <= here + 1e-12
    wider = math.copysign(min(abs(turn) + more, math.pi), turn)
    assert cost(length, wider) <= here + 1e-12
