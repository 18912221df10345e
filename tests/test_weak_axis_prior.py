"""The motion prior along a direction the scan hardly constrains, weighed against the scan's
own information there (``prior_information``) instead of its whole curvature."""

import math

import numpy as np
import pytest
from _scan_world import box, make_scan

from bioslam.matching.gauss_newton import (
    geometric_information,
    match_scan_to_map,
    matched_normals,
    points_per_level,
    prior_share,
)
from bioslam.occupancy_grid import LogOddsConfig, MapPyramid, subsample_by_spacing

# a 2 m corridor whose only feature along its axis is a 0.24 m post 14 m ahead
SEGS = np.array(
    [((-30, -1), (30, -1)), ((-30, 1), (30, 1)), *box(14.0, -0.12, 14.2, 0.12)], dtype=float
)


def _corridor_match(start, **prior):
    rng = np.random.default_rng(0)
    pyramid = MapPyramid(0.05, 48.0, 3, LogOddsConfig(), origin=None)
    pyramid.recenter(0.0, 0.0)
    for x in np.arange(-1.0, 0.01, 0.2):
        scan = make_scan(SEGS, (x, 0.0, 0.0), beams=361, fov=math.pi, sigma=0.01, rng=rng)
        pyramid.insert_scan(np.array([x, 0.0, 0.0]), scan.endpoints(), 30.0)
    scan = make_scan(SEGS, (0.0, 0.0, 0.0), beams=361, fov=math.pi, sigma=0.01, rng=rng)
    points = np.ascontiguousarray(scan.endpoints())
    levels = points_per_level(points, 0.05, 3, subsample_by_spacing(points, 0.05))
    normals = matched_normals(levels)
    return match_scan_to_map(
        pyramid, levels, start, (10, 10, 15), 0.05, 3.0, 0.01, 1.0, normals, 0.05, **prior
    ), geometric_information(levels[0], normals, 3.0)


def test_the_scans_information_along_a_corridor_is_the_posts_few_endpoints():
    (_, report), (condition, weakest, top) = _corridor_match(np.zeros(3))
    assert report.degenerate
    assert abs(weakest[0]) > 0.99  # along the corridor
    assert report.information == pytest.approx(top)
    assert condition * top < 3.0  # a few endpoints' worth, against ~150 across


def test_a_prior_of_more_information_holds_the_match_nearer_to_it():
    """Weighed by information the prior's share of the curvature along the axis grows with
    it, and the match stays nearer the prior (the start, 15 cm off)."""
    start = np.array([-0.15, 0.0, 0.0])
    shares, offsets = [], []
    for information in (0.1, 10.0, 1000.0):
        (pose, report), _ = _corridor_match(start, prior_information=information)
        shares.append(report.prior_share)
        offsets.append(abs(pose[0] - start[0]))
    assert 0.0 < shares[0] < shares[1] < shares[2] < 1.0
    assert offsets[2] < offsets[0]


def test_the_prior_share_is_the_priors_weight_against_the_scans_curvature_along_the_axis():
    H = np.diag([4.0, 100.0, 9.0 * 50.0])  # scaled: 4, 100, 50
    along = np.array([1.0, 0.0, 0.0])
    k = 0.05 * (4.0 + 100.0 + 50.0)
    assert prior_share(H, along, 0.05, 3.0) == pytest.approx(k / (k + 4.0))
