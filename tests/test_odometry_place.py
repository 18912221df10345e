"""On sparse scans the place a match is at is judged by where its scan's walls land, not by
how sure the map is of them (``OdometryConfig.place_logodds``); the mean map value then picks
the match at that place."""

from __future__ import annotations

import math

import numpy as np
import pytest
from _sim_runs import largest_error, odometry_run

from bioslam.matching.gauss_newton import MatchReport
from bioslam.odometry import LidarOdometry, OdometryConfig


def _thinned_sick(route: str, seed: int, **config: float | None) -> float:
    estimate, truth = odometry_run(
        "warehouse", route, "sick", seed, 60.0, config=OdometryConfig(**config), thin=(1.5, 0.6)
    )
    return largest_error(estimate, truth)


@pytest.mark.parametrize(("route", "seed"), [("tour", 4), ("adversarial", 2)])
def test_a_step_down_an_aisle_is_not_taken_short_where_the_map_is_surest(route, seed):
    """The warehouse's aisles with the SICK (181 beams) thinned to a scan per 1.5 m / 0.6 rad:
    each step's scan sees the aisle ahead, held in the map by a few grazing hits, and a match
    a rack back puts it on the part fused from near; by the mean map value the route went
    metres off, by the share of endpoints on walls it stays within centimetres."""
    assert _thinned_sick(route, seed) < 0.2
    assert _thinned_sick(route, seed, place_logodds=None) > 1.0


def _option(x: float, score: float) -> tuple[np.ndarray, MatchReport, bool]:
    return np.array([x, 0.0, 0.0]), MatchReport(score=score), False


def test_the_place_is_chosen_by_its_share_and_the_match_there_by_its_merit():
    """Three matches at one place (x 1.0-1.2) and one a metre back (x 0.0) that the mean map
    value prefers: the place by ``place_quality`` less the cost is the front one, and among
    its matches the one of best merit (mean map value less cost) is kept; without a place
    quality the best merit anywhere is."""
    odo = LidarOdometry()
    pool = [_option(0.0, 0.80), _option(1.0, 0.60), _option(1.1, 0.65), _option(1.2, 0.62)]
    share = {0.0: 0.90, 1.0: 0.95, 1.1: 0.93, 1.2: 0.94}

    def merit(option):
        return option[1].score - 0.01 * option[0][0]

    def place_quality(option):
        return share[float(option[0][0])]

    def cost(option):
        return 0.0

    assert odo._at_place(pool, merit, cost, place_quality)[0][0] == pytest.approx(1.1)
    assert odo._at_place(pool, merit, cost, None)[0][0] == pytest.approx(0.0)


def test_scans_at_the_scanner_rate_run_as_without_it():
    """A SICK at its rate in the maze: every scan is matched from the motion model's
    prediction, and the poses are those of the mean map value alone, to the bit."""
    runs = [
        odometry_run("maze", "adversarial", "sick", 3, 40.0,
                     config=OdometryConfig(place_logodds=level))[0]
        for level in (0.0, None)
    ]  # fmt: skip
    np.testing.assert_array_equal(*runs)


def test_a_place_level_that_is_not_a_number_is_refused():
    with pytest.raises(ValueError, match="place_logodds"):
        OdometryConfig(place_logodds=math.nan)


def _turned(x: float, heading: float, score: float, free: float) -> tuple:
    return np.array([x, 0.0, heading]), MatchReport(score=score, free_fraction=free), False


@pytest.mark.parametrize(("turned_score", "vetoed"), [(1.0, True), (0.7, False)])
def test_a_step_kept_only_by_the_map_s_veto_of_a_better_turned_match_is_flagged(
    turned_score, vetoed
):
    """A thinned scan spinning in a symmetric room: the match 120° round fits better than
    the one kept, its endpoints in free space counted, but too many of them lie where the map
    saw free space (a quarter, above ``recovery_free_fraction``). The odometry
    keeps its step (the veto stands) and flags it ``vetoed``, which breaks its chain for the
    closures where the step turns away from the motion; a turned match that fits worse
    leaves the step unflagged."""
    from bioslam.closure import odometry_broke
    from bioslam.config import LoopClosureConfig

    odo = LidarOdometry()
    kept = _turned(0.5, 0.0, 0.6, 0.0)
    pool = [kept, _turned(0.5, math.radians(120.0), turned_score, 0.25)]
    pose, report = odo._sparse_choice(pool, np.zeros(3), (3.0, math.pi))
    assert pose is kept[0] and not report.broken
    assert report.vetoed is vetoed
    # against a motion turning the other way the kept step is a break where it was vetoed;
    # kept with the motion (a scanner at its rate spinning on the spot), it is none
    step, turning = np.array([0.5, 0.0, 0.0]), np.array([0.5, 0.0, math.radians(-60.0)])
    assert odometry_broke(report, step, turning, 1.0, LoopClosureConfig()) is vetoed
    assert not odometry_broke(report, step, step, 1.0, LoopClosureConfig())
