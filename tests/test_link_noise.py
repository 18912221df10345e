"""The link noise model learned from the loop closures (bioslam.link_noise)."""

from __future__ import annotations

import numpy as np
import pytest

from bioslam.link_noise import (
    LinkNoise,
    LinkNoiseEstimator,
    _descend,
    _nll_and_derivatives,
    fit_drift,
)

PRIOR = LinkNoise(odometry_var_per_m=1e-4, closure_var=4e-4)


def residuals(rate: float, floor: float, n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Spans of 1-100 m and one-axis residuals of variance rate * span + floor."""
    rng = np.random.default_rng(seed)
    spans = rng.uniform(1.0, 100.0, n)
    return spans, rng.normal(0.0, np.sqrt(rate * spans + floor))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_fit_recovers_a_drift_and_a_registration_floor(seed):
    # the drift's share equals the floor's at 25 m: both are measured
    spans, r = residuals(rate=2e-6, floor=5e-5, n=2000, seed=seed)
    rate, floor, _ = fit_drift(spans, r**2, (1e-4, 4e-4), 1.0)
    assert rate == pytest.approx(2e-6, rel=0.2)
    assert floor == pytest.approx(5e-5, rel=0.3)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_residuals_that_do_not_grow_with_the_span_give_only_the_drift_they_cannot_rule_out(
    seed,
):
    # the registrations' and the odometry's own local errors: no correction of the path
    # between two places removes them. The drift is what they could not have seen: below
    # one that would double their variance at the longest span, and not none (no
    # odometry link is ever exact), far below the configured 1e-4 m² a metre
    spans, r = residuals(rate=0.0, floor=2e-5, n=40, seed=seed)
    rate, floor, _ = fit_drift(spans, r**2, (1e-4, 4e-4), 1.0)
    assert floor == pytest.approx(2e-5, rel=0.6)
    assert 0.1 * floor < rate * spans.max() < 2.0 * floor


@pytest.mark.parametrize("count", [2, 5])
def test_closures_all_a_loop_away_that_disagree_with_the_odometry_measure_its_drift(count):
    # The first closures of a run often come at the end of one long loop: every residual
    # over the same span, so the data alone cannot tell a drift from a registration floor.
    # A quarter of a metre after 70 m is the odometry's drift, not registrations that err by
    # that much where the prior puts them at 2 cm (intel with a heading drift injected:
    # taking it for the registrations' error made every closure too weak to move the map).
    rng = np.random.default_rng(count)
    spans = rng.uniform(69.0, 73.0, count)
    r = rng.choice([-1.0, 1.0], count) * rng.uniform(0.1, 0.4, count)
    rate, floor, _ = fit_drift(spans, r**2, (1e-4, 4e-4), 1.0)
    assert rate * 70.0 > 10.0 * floor  # the residual is the odometry's
    assert rate * 70.0 == pytest.approx(np.mean(r**2), rel=0.5)


def test_a_few_false_closures_do_not_inflate_the_fit():
    spans, r = residuals(rate=2e-6, floor=5e-5, n=300, seed=4)
    r[:6] = 1.0  # six closures a metre off
    rate, floor, _ = fit_drift(spans, r**2, (1e-4, 4e-4), 1.0)
    assert rate == pytest.approx(2e-6, rel=0.35)
    assert floor == pytest.approx(5e-5, rel=0.4)


def test_the_estimator_keeps_the_prior_until_enough_closures_came_in():
    estimator = LinkNoiseEstimator(PRIOR, min_samples=8)
    spans, r = residuals(rate=0.0, floor=1e-6, n=8, seed=5)
    heading = r / 10.0
    for k in range(7):
        assert estimator.add(spans[k], r[k], heading[k], 1e-4 * spans[k]) == PRIOR
    assert estimator.add(float("nan"), 0.0, 0.0, 0.0) == PRIOR  # not counted
    assert len(estimator) == 7
    fitted = estimator.add(spans[7], r[7], heading[7], 1e-4 * spans[7])
    assert fitted != PRIOR and fitted.closure_var < 1e-5
    assert 0.0 < fitted.odometry_var_per_m < 1e-2 * PRIOR.odometry_var_per_m


@pytest.mark.parametrize("seed", range(8))
def test_the_descent_ends_where_a_general_minimiser_does(seed):
    # the fit's own bounded Newton descent against SciPy's L-BFGS-B on the same
    # likelihood and prior, from the same start, for both models
    from scipy.optimize import minimize

    rng = np.random.default_rng(seed)
    n = int(rng.choice([1, 3, 20, 200]))
    spans, r = residuals(rate=float(rng.choice([0.0, 1e-5])), floor=1e-4, n=n, seed=seed)
    if seed % 2:
        r[: max(1, n // 10)] = 0.5  # closures half a metre off among them
    squared = r**2
    centre = np.log10([1e-4, 4e-4])
    lo, hi = centre - 6.0, centre + 2.0
    start = centre + rng.uniform(-3.0, 1.0, 2)
    for drifting in (True, False):
        keep = slice(None) if drifting else slice(1, None)

        def cost(x, drifting=drifting):
            a, b = (x[0], x[-1]) if drifting else (centre[0], x[0])
            f, ga, gb = _nll_and_derivatives(a, b, drifting, spans, squared, centre, 1.0)[:3]
            return f, (np.array([ga, gb]) if drifting else np.array([gb]))

        general = minimize(
            cost, start[keep], jac=True, method="L-BFGS-B",
            bounds=list(zip(lo[keep], hi[keep], strict=True)), options={"ftol": 1e-14},
        )  # fmt: skip
        a, b = _descend(*start, drifting, lo, hi, spans, squared, centre, 1.0)
        ours = np.array([a, b])[keep]
        assert cost(ours)[0] <= general.fun + 1e-9
        assert ours == pytest.approx(general.x, abs=1e-3)


@pytest.mark.parametrize("seed", [11, 12])
def test_the_likeliest_drift_is_the_median_of_those_allowed_or_the_fit_where_one_shows(seed):
    # The map is finished with the drift the closures make likeliest (LinkNoise.likely):
    # where they show none, far below the largest they cannot rule out (which the run's map
    # keeps, to follow a slide the odometry did not notice), under a third of the
    # registrations' variance over the longest span; where they show one, the fit.
    spans, r = residuals(rate=0.0, floor=2e-5, n=40, seed=seed)
    rate, floor, likely = fit_drift(spans, r**2, (1e-4, 4e-4), 1.0)
    assert 0.0 < likely < rate / 2.5
    assert likely * spans.max() < 0.3 * floor
    spans, r = residuals(rate=3e-5, floor=1e-5, n=200, seed=seed)
    rate, _, likely = fit_drift(spans, r**2, (1e-4, 4e-4), 1.0)
    assert likely == rate == pytest.approx(3e-5, rel=0.4)


def test_the_likeliest_model_keeps_the_closures_own_noise():
    noise = LinkNoise(8e-7, 2e-5, 4e-3, 2e-6, likely_var_per_m=1e-8, likely_heading_scale=1e-3)
    assert noise.likely() == LinkNoise(1e-8, 2e-5, 1e-3, 2e-6)
    assert LinkNoise(8e-7, 2e-5).likely() == LinkNoise(8e-7, 2e-5)
    assert noise.likeliest_heading_scale == 1e-3
    assert LinkNoise(8e-7, 2e-5, 4e-3).likeliest_heading_scale == 4e-3
