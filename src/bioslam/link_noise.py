"""How uncertain the cognitive map's links are, learned from the loop closures themselves.

Eq. 14 weighs each link by its information (:func:`bioslam.cognitive_map.information_of`):
an odometry link's position variance grows by ``odometry_var_per_m`` per metre, its heading
variance is what its scans' matches measured, and a registration adds its own variance.
Those settings are guesses; the right ones differ by orders of magnitude between a dense
scanner in a simulated world (the odometry's position variance grows by 2-10e-6 m² a metre,
its closures are off by half a centimetre) and a hand-driven robot's log (3-5e-4 m² a metre
on freiburg-079 against its corrected poses, their own error included). A model looser than
the odometry lets every closure's centimetre of error bend a loop the odometry had within
millimetres; one tighter than it makes the robust kernel take true corrections for
outliers.

Each accepted closure measures both at once: the registered pose of the robot in the old
place's frame against what the odometry alone says (no break between), over the distance
travelled in between. Its residual's variance is the odometry's over that distance plus the
registration's, ``rate * distance + floor`` (a random walk plus a constant); the heading's is
``scale * (the matches' summed heading variance) + floor``. :class:`LinkNoiseEstimator` fits
both by maximum likelihood under a Student-t (a false or slid closure among true ones does not
inflate the fit), with a log-normal prior centred on the configured values, so that a few
closures move the model little and many set it. Unless the residuals grow with the distance
significantly (:func:`fit_drift`), the drift is the largest they cannot rule out, small
enough that the map's odometry bends mostly where it broke, and never so small that a slide
the odometry did not notice cannot bend at all; that is the model the map keeps while the run
goes on. The finished map is solved with the drift the closures make likeliest (where they
show none, the median of what they allow: :meth:`LinkNoise.likely`), so that their
registrations' own errors do not bend an odometry better than them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numba
import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]

#: Student-t degrees of freedom of the residuals: heavy enough a tail that a closure several
#: times off its model changes the fit little.
T_DOF = 4.0
#: The Student-t's squared scale that Gaussian residuals of unit variance fit (the root v of
#: E[z / (1 + z)] = 1 / (T_DOF + 1), z = x² / (T_DOF v), x standard normal): the fitted
#: scales are divided by it, so that the model's variances are the residuals' own.
T_SCALE_OF_UNIT_VARIANCE = 0.690
#: log10 step of the grid the fit starts from
COARSE_STEP = 1.0
#: The descent stops once a step moves no parameter by more than this (log10) ...
DESCENT_TOLERANCE = 1e-7
#: ... or after this many steps.
MAX_DESCENT_STEPS = 100


@dataclass(frozen=True)
class LinkNoise:
    """The noise model of the map's links: ``odometry_var_per_m`` (m² per metre travelled),
    ``closure_var`` (m², one registration's position variance), ``heading_scale`` (times the
    odometry's measured heading variance) and ``closure_heading_var`` (rad², one
    registration's heading variance).

    ``jump_scale``: the share of the variance the odometry's jumps put on the links that
    carry them (:func:`bioslam.cognitive_map.link_terms`' ``broken``) that the links keep:
    1 lets a closure bend the odometry at a jump; 0 holds the jump as any other step
    (:func:`bioslam.cognitive_map.untaught_noise`).

    ``likely_var_per_m`` and ``likely_heading_scale``: the drift the closures make likeliest,
    where the two above are the largest they do not rule out (:func:`fit_drift`); None where
    the two are the drift the closures show. The run's map keeps the largest, so that its
    predictions of where the robot is can follow a slide the odometry did not notice; the
    finished map is solved with the likeliest (:meth:`likely`)."""

    odometry_var_per_m: float
    closure_var: float
    heading_scale: float = 1.0
    closure_heading_var: float = 2.5e-5
    likely_var_per_m: float | None = None
    likely_heading_scale: float | None = None
    jump_scale: float = 1.0

    @property
    def likeliest_heading_scale(self) -> float:
        """The heading scale the closures make likeliest (``heading_scale`` where that is
        the one they show)."""
        scale = self.likely_heading_scale
        return self.heading_scale if scale is None else scale

    def likely(self) -> LinkNoise:
        """The model with the drift the closures make likeliest in place of the largest they
        do not rule out."""
        rate = self.likely_var_per_m
        return replace(
            self,
            odometry_var_per_m=self.odometry_var_per_m if rate is None else rate,
            heading_scale=self.likeliest_heading_scale,
            likely_var_per_m=None,
            likely_heading_scale=None,
        )


def random_walk_nll(
    rates: FloatArray, floors: FloatArray, spans: FloatArray, squared: FloatArray
) -> FloatArray:
    """Negative log-likelihood (up to a constant) of one-axis residuals (``squared``: each
    one's square) whose squared scale is ``rate * span + floor``, for every (rate, floor) of
    the broadcast grids; each residual Student-t distributed (:data:`T_DOF` degrees of
    freedom)."""
    var = np.asarray(rates)[..., None] * spans + np.asarray(floors)[..., None]
    return _t_nll(var, squared / (T_DOF * var)).sum(axis=-1)


def _t_nll(var: FloatArray, ratio: FloatArray) -> FloatArray:
    """Each residual's Student-t negative log-likelihood (up to a constant) at squared
    scale ``var``, ``ratio`` being its square over ``T_DOF * var``."""
    return 0.5 * np.log(var) + 0.5 * (T_DOF + 1.0) * np.log1p(ratio)


@numba.njit(cache=True)
def _nll_and_derivatives(a, b, drifting, spans, squared, centre, prior_decades):
    """:func:`random_walk_nll` plus the prior's penalty at log10 rate ``a`` and log10 floor
    ``b`` — the rate 0 and ``a`` ignored when not ``drifting`` — with its gradient (d/da,
    d/db) and Hessian (aa, ab, bb) in them."""
    ln10 = math.log(10.0)
    rate = 10.0**a if drifting else 0.0
    floor = 10.0**b
    cost = 0.0
    # sums over the residuals of l'(var) and l''(var) (var's derivatives), weighed by 1,
    # the span and its square: var = rate * span + floor is linear in rate and floor
    d0 = d1 = h0 = h1 = h2 = 0.0
    for k in range(spans.shape[0]):
        var = rate * spans[k] + floor
        ratio = squared[k] / (T_DOF * var)
        cost += 0.5 * math.log(var) + 0.5 * (T_DOF + 1.0) * math.log1p(ratio)
        # l(var) = -T_DOF/2 ln var + (T_DOF + 1)/2 ln(T_DOF var + x) + const
        shifted = T_DOF * var + squared[k]
        d = -0.5 * T_DOF / var + 0.5 * (T_DOF + 1.0) * T_DOF / shifted
        h = 0.5 * T_DOF / (var * var) - 0.5 * (T_DOF + 1.0) * T_DOF * T_DOF / (shifted * shifted)
        d0 += d
        d1 += d * spans[k]
        h0 += h
        h1 += h * spans[k]
        h2 += h * spans[k] * spans[k]
    # d var / d log10 p = p ln10 times p's term; d2 p / d(log10 p)2 = p ln10²
    gb = floor * ln10 * d0
    hbb = (floor * ln10) ** 2 * h0 + gb * ln10
    ga = rate * ln10 * d1
    haa = (rate * ln10) ** 2 * h2 + ga * ln10
    hab = rate * floor * ln10 * ln10 * h1
    inv = 1.0 / (prior_decades * prior_decades)
    cost += 0.5 * (b - centre[1]) ** 2 * inv
    gb += (b - centre[1]) * inv
    hbb += inv
    if drifting:
        cost += 0.5 * (a - centre[0]) ** 2 * inv
        ga += (a - centre[0]) * inv
        haa += inv
    else:
        ga = haa = hab = 0.0
    return cost, ga, gb, haa, hab, hbb


@numba.njit(cache=True)
def _descend(a, b, drifting, lo, hi, spans, squared, centre, prior_decades):
    """The minimum of :func:`_nll_and_derivatives` from (``a``, ``b``) within the box
    ``lo``-``hi`` (log10): Newton's method with Levenberg-Marquardt damping, a parameter at
    a bound its gradient pushes against held there (``a`` always, when not ``drifting``).
    Refitted at every few closures: a general-purpose minimiser cost 1-2 ms a call in its
    set-up alone, on the scans that accepted a closure (intel: 6-8 ms a scan for the two
    fits of two models)."""
    a = min(max(a, lo[0]), hi[0])
    b = min(max(b, lo[1]), hi[1])
    cost, ga, gb, haa, hab, hbb = _nll_and_derivatives(
        a, b, drifting, spans, squared, centre, prior_decades
    )
    damping = 1e-3
    for _ in range(MAX_DESCENT_STEPS):
        free_a = drifting and not ((a <= lo[0] and ga > 0.0) or (a >= hi[0] and ga < 0.0))
        free_b = not ((b <= lo[1] and gb > 0.0) or (b >= hi[1] and gb < 0.0))
        if not (free_a or free_b):
            break
        # the damped system on the free parameters (Marquardt's scaling of the diagonal)
        maa = haa + damping * (abs(haa) + 1e-12)
        mbb = hbb + damping * (abs(hbb) + 1e-12)
        step_a = step_b = 0.0
        if free_a and free_b:
            det = maa * mbb - hab * hab
            if det > 0.0 and maa > 0.0:
                step_a = -(mbb * ga - hab * gb) / det
                step_b = -(maa * gb - hab * ga) / det
        elif free_a and maa > 0.0:
            step_a = -ga / maa
        elif free_b and mbb > 0.0:
            step_b = -gb / mbb
        if step_a == 0.0 and step_b == 0.0:
            damping *= 10.0  # not a descent direction yet
            if damping > 1e9:
                break
            continue
        ta = min(max(a + step_a, lo[0]), hi[0])
        tb = min(max(b + step_b, lo[1]), hi[1])
        found = _nll_and_derivatives(ta, tb, drifting, spans, squared, centre, prior_decades)
        if found[0] <= cost:
            moved = max(abs(ta - a), abs(tb - b))
            a, b = ta, tb
            cost, ga, gb, haa, hab, hbb = found
            damping = max(damping * 0.1, 1e-9)
            if moved < DESCENT_TOLERANCE:
                break
        else:
            damping *= 10.0
            if damping > 1e9:
                break
    return a, b


def fit_drift(
    spans: FloatArray,
    squared: FloatArray,
    prior: tuple[float, float],
    prior_decades: float,
) -> tuple[float, float, float]:
    """The (rate, floor, likeliest rate) of the variance ``rate * span + floor`` that best
    explains one-axis residuals (``squared``, over ``spans``; :func:`random_walk_nll`, its scales
    taken to variances by :data:`T_SCALE_OF_UNIT_VARIANCE`) with a log-normal prior centred on
    ``prior`` (``prior_decades``: its standard deviation, in decades), from six decades below the
    prior to two above: the best of a coarse grid of log10 values (a flat or two-valleyed likelihood
    does not trap it), refined by a bounded Newton descent (:func:`_descend`).

    The rate is fitted only where the model with it explains the residuals significantly
    better than the one without (the Bayesian information criterion: its gain must exceed
    half the log of the number of residuals): residuals that do not grow are the
    registrations' and the odometry's own local errors, which no correction of the path
    between them removes, and a rate fitted to them would bend every loop by part of them.
    Otherwise it is the largest rate they do not rule out (:func:`_unrefuted_rates`), and the
    third value returned, the likeliest rate, the median of those they allow (as likely above
    it as below: :data:`LIKELY_MARGIN`); else both are the rate fitted. The
    two are compared with their priors' penalties above the settings (:func:`_posterior_cost`):
    where every closure spans the same loop the residuals alone cannot tell a drift from a
    registration floor, and a floor decades above the registrations' prior is the less
    likely of the two (intel with a heading drift injected: its first closures, all 70 m of
    odometry away and 0.2-0.4 m off it, were put down to registrations 24 cm off, and no
    closure could move the map)."""
    centre = np.log10(np.maximum(np.asarray(prior, dtype=np.float64), 1e-300))
    spans = np.asarray(spans, dtype=np.float64)
    squared = np.asarray(squared, dtype=np.float64)
    lo, hi = centre - 6.0, centre + 2.0
    axes = [np.arange(a, b + 0.5 * COARSE_STEP, COARSE_STEP) for a, b in zip(lo, hi, strict=True)]
    grid_rate, grid_floor = np.meshgrid(*axes, indexing="ij")
    prior_cost = ((grid_rate - centre[0]) ** 2 + (grid_floor - centre[1]) ** 2) / (
        2.0 * prior_decades**2
    )

    def refine(rate: float, floor: float, drifting: bool) -> tuple[float, float]:
        return _descend(rate, floor, drifting, lo, hi, spans, squared, centre, prior_decades)

    costs = random_walk_nll(10.0**grid_rate, 10.0**grid_floor, spans, squared) + prior_cost
    k = np.unravel_index(int(np.argmin(costs)), costs.shape)
    drift = refine(float(grid_rate[k]), float(grid_floor[k]), True)
    still_costs = random_walk_nll(np.zeros(1), 10.0 ** axes[1], spans, squared)
    still_costs += (axes[1] - centre[1]) ** 2 / (2.0 * prior_decades**2)
    still = refine(float(centre[0]), float(axes[1][int(np.argmin(still_costs))]), False)[1]
    rate, floor = 10.0 ** drift[0], 10.0 ** drift[1]
    gain = _posterior_cost(None, still, spans, squared, centre, prior_decades) - (
        _posterior_cost(drift[0], drift[1], spans, squared, centre, prior_decades)
    )
    if gain < 0.5 * math.log(max(spans.size, 2)):
        unrefuted, likely = _unrefuted_rates(
            still, lo[0], hi[0], spans, squared, centre, prior_decades,
            (UNREFUTED_MARGIN, LIKELY_MARGIN),
        )  # fmt: skip
        scale = T_SCALE_OF_UNIT_VARIANCE
        return unrefuted / scale, 10.0**still / scale, likely / scale
    rate /= T_SCALE_OF_UNIT_VARIANCE
    return rate, floor / T_SCALE_OF_UNIT_VARIANCE, rate


#: How much worse (in log-likelihood) than none a drift may fit the residuals and still not
#: be ruled out by them (:func:`_unrefuted_rates`): a two-sided 95 % profile bound.
UNREFUTED_MARGIN = 1.92
#: ... and the margin of the median of the drifts they allow: a two-sided 50 % profile bound.
LIKELY_MARGIN = 0.228
#: log10 step of the search for those drifts
UNREFUTED_STEP = 0.125


def _unrefuted_rates(
    log_floor: float, lo: float, hi: float, spans: FloatArray, squared: FloatArray,
    centre: FloatArray, prior_decades: float, margins: tuple[float, ...],
) -> list[float]:
    """For each of ``margins`` (largest first), the largest drift rate (between ``10**lo``
    and ``10**hi``) that fits the residuals within that margin of no drift at all, the floor
    ``10**log_floor`` kept; 0 where none does. One descent from the top serves them all.
    Where the closures show no drift they have not shown that there is none, only that it is
    smaller than they could see, and they never span the slides the odometry did not notice.
    A rate of exactly 0 made every odometry link as stiff as the variance floor: a 1.2 m
    slide in a maze corridor (SICK, reversing, two people) could not bend, the true closures
    beyond it dragged the whole first lap a metre off (61 cm against the odometry's 47), and
    the Laplacian's weights, 1e-1 to 1e10, cost its solve millimetres a link."""
    base = _posterior_cost(None, log_floor, spans, squared, centre, prior_decades)
    found: list[float] = []
    for log_rate in np.arange(hi, lo - 0.5 * UNREFUTED_STEP, -UNREFUTED_STEP):
        cost = _posterior_cost(float(log_rate), log_floor, spans, squared, centre, prior_decades)
        while len(found) < len(margins) and cost - base <= margins[len(found)]:
            found.append(float(10.0**log_rate))
        if len(found) == len(margins):
            break
    return found + [0.0] * (len(margins) - len(found))


def _posterior_cost(
    log_rate: float | None, log_floor: float, spans: FloatArray, squared: FloatArray,
    centre: FloatArray, prior_decades: float,
) -> float:
    """The residuals' negative log-likelihood under the variance ``10**log_rate * span +
    10**log_floor`` (no rate when ``log_rate`` is None) plus the prior's penalty on each
    parameter the model puts above its configured value (``centre``, log10). The settings
    are a cautious guess: a simulated scanner's odometry drifts and its registrations err
    orders of magnitude below them, and a model is not the less likely for finding that;
    registrations decades worse than configured are."""
    rate = 0.0 if log_rate is None else 10.0**log_rate
    cost = float(random_walk_nll(np.array([rate]), np.array([10.0**log_floor]), spans, squared)[0])
    excess = [log_floor - centre[1]] + ([] if log_rate is None else [log_rate - centre[0]])
    return cost + sum(0.5 * (max(e, 0.0) / prior_decades) ** 2 for e in excess)


class LinkNoiseEstimator:
    """The loop closures' residuals against the odometry, and the link noise they imply.

    ``prior``: the configured model; ``min_samples``: closures before the fit replaces it;
    ``max_samples``: the most recent closures the fit reads (its cost is linear in them).
    Past ``refit_every_share`` x ``max_samples`` closures the model is refitted only once
    their number grew by that share since the last fit (a fit of 200 residuals costs a few
    milliseconds, a closure's registration about as much)."""

    def __init__(
        self, prior: LinkNoise, prior_decades: float = 1.0, min_samples: int = 1,
        max_samples: int = 200, refit_every_share: float = 0.1,
    ) -> None:  # fmt: skip
        self.prior = prior
        self.prior_decades = prior_decades
        self.min_samples = min_samples
        self.max_samples = max_samples
        self.refit_every_share = refit_every_share
        self._rows: list[tuple[float, float, float, float]] = []
        self._fitted = prior
        self._added = 0
        self._fitted_at = 0

    def __len__(self) -> int:
        """The closures taken in so far (the fit reads the last ``max_samples``)."""
        return self._added

    @property
    def model(self) -> LinkNoise:
        """The model the closures so far give (the prior until ``min_samples``)."""
        return self._fitted

    def add(
        self, distance: float, position: float, heading: float, heading_var: float
    ) -> LinkNoise:
        """One closure: the odometry travelled ``distance`` metres between the place and now
        with its matches' summed ``heading_var`` (rad²), and the registration put the robot
        ``position`` metres (along one direction) and ``heading`` radians off where the
        odometry alone did. Returns the model refitted (the prior until ``min_samples``
        closures)."""
        row = (distance, position, heading, heading_var)
        if not all(math.isfinite(v) for v in row):
            return self._fitted
        self._rows.append(
            (max(distance, 0.0), position**2, max(heading_var, 0.0), heading**2)
        )  # fmt: skip
        if len(self._rows) > self.max_samples:
            del self._rows[0]
        self._added += 1
        if len(self._rows) >= self.min_samples and self._due():
            self._fitted, self._fitted_at = self._fit(), self._added
        return self._fitted

    def _due(self) -> bool:
        """Whether enough closures came in since the last fit to refit."""
        share = self.refit_every_share
        if self._added <= share * self.max_samples:
            return True
        return self._added - self._fitted_at >= share * self._fitted_at

    def _fit(self) -> LinkNoise:
        rows = np.asarray(self._rows)
        p = self.prior
        rate, floor, likely_rate = fit_drift(
            rows[:, 0], rows[:, 1], (p.odometry_var_per_m, p.closure_var), self.prior_decades
        )
        scale, heading_floor, likely_scale = fit_drift(
            rows[:, 2], rows[:, 3], (p.heading_scale, p.closure_heading_var),
            self.prior_decades,
        )  # fmt: skip
        return LinkNoise(
            rate, floor, scale, heading_floor,
            likely_var_per_m=likely_rate, likely_heading_scale=likely_scale,
        )  # fmt: skip
