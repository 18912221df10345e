"""Pose cell network (Sec. III-C, Eq. 10-11)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bioslam.pose_cells import (
    PoseCellConfig,
    PoseCellNetwork,
    consecutive_matches_to_shift,
    gaussian_kernel,
    wrapped_cell_distance,
)

DIMS = (21, 21, 36)


def settled(
    start: tuple[float, float, float], steps: int = 10, min_shift_cells: float = 0.5
) -> PoseCellNetwork:
    net = PoseCellNetwork(PoseCellConfig(dims=DIMS, start=start, min_shift_cells=min_shift_cells))
    for _ in range(steps):
        net.step()
    return net


def signed_cell_delta(a: np.ndarray, b: np.ndarray, dims=DIMS) -> np.ndarray:
    n = np.asarray(dims, dtype=float)
    return np.mod(b - a + n / 2, n) - n / 2


def expected_shift(net: PoseCellNetwork, dp: tuple[float, float, float]) -> np.ndarray:
    """The activity-weighted mean of every θ' layer's own shift (Eq. 10)."""
    cxy, _, cth = net.config.cell_size
    layer_mass = net.activity.sum(axis=(0, 1))
    headings = np.arange(net.dims[2]) * cth
    sx = (np.cos(headings) * dp[0] - np.sin(headings) * dp[1]) / cxy
    sy = (np.sin(headings) * dp[0] + np.cos(headings) * dp[1]) / cxy
    w = layer_mass / layer_mass.sum()
    return np.array([w @ sx, w @ sy, dp[2] / cth])


@pytest.mark.parametrize("heading_cells", [0.0, 4.0, 9.0, 13.5, 18.0, 22.25, 27.0, 31.0])
@pytest.mark.parametrize("forward_m", [0.07, 0.61, 1.37])
@pytest.mark.parametrize("min_shift_cells", [0.0, 0.5])
def test_path_integration_moves_packet_by_expected_cells(heading_cells, forward_m, min_shift_cells):
    # 0.07 m is 0.28 of a 0.25 m cell; 1.37 m is 5.48 cells in a single update. With
    # min_shift_cells = 0 every step goes through Eq. 10's 2x2x2 spread at once.
    net = settled((10.0, 10.0, heading_cells), min_shift_cells=min_shift_cells)
    dp = (forward_m, 0.35 * forward_m, 0.0)
    want = expected_shift(net, dp)
    before = net.centre()
    net.path_integrate(dp)
    got = signed_cell_delta(before, net.centre())
    np.testing.assert_allclose(got, want, atol=0.03)
    # The packet moved along the heading it encodes, so x/y follow that heading.
    heading = heading_cells * net.config.cell_size[2]
    nominal = np.array(
        [
            math.cos(heading) * dp[0] - math.sin(heading) * dp[1],
            math.sin(heading) * dp[0] + math.cos(heading) * dp[1],
        ]
    )
    direction = got[:2] / np.linalg.norm(got[:2])
    assert direction @ (nominal / np.linalg.norm(nominal)) > math.cos(math.radians(3.0))


@pytest.mark.parametrize("turn_rad", [0.05, -0.3, 1.9, -3.0])
def test_path_integration_rotates_packet_any_size(turn_rad):
    net = settled((10.0, 10.0, 5.0), min_shift_cells=0.0)
    before = net.centre()
    net.path_integrate((0.0, 0.0, turn_rad))
    got = signed_cell_delta(before, net.centre())
    np.testing.assert_allclose(got, [0.0, 0.0, turn_rad / net.config.cell_size[2]], atol=0.02)


def test_path_integration_with_dynamics_tracks_odometry_over_many_updates():
    net = settled((10.0, 10.0, 3.0))
    start = net.centre()
    total = np.zeros(3)
    for _ in range(40):
        dp = (0.05, 0.0, 0.01)
        want = expected_shift(net, dp)
        net.path_integrate(dp)
        net.step()
        total += want
    got = signed_cell_delta(start, net.centre())
    # Excitation and inhibition are symmetric, so they neither drag nor push the packet; what
    # remains is the lattice pinning of sub-cell shifts, which the accumulation of small steps
    # (min_shift_cells) keeps to a few percent of the distance instead of ~16%.
    assert np.linalg.norm(got[:2] - total[:2]) < 0.04 * np.linalg.norm(total[:2])
    assert got[2] == pytest.approx(total[2], abs=0.05)


@pytest.mark.parametrize("start", [(7.0, 12.0, 20.0), (7.5, 12.5, 20.5), (0.0, 20.5, 35.0)])
def test_stationary_packet_stays_put_and_sparse(start):
    net = settled(start, steps=0)
    begin = net.centre()
    for _ in range(300):
        net.step()
    np.testing.assert_allclose(signed_cell_delta(begin, net.centre()), 0.0, atol=1e-6)
    assert net.activity.sum() == pytest.approx(1.0)
    assert net.activity.min() >= 0.0
    assert net.active_count < 0.02 * np.prod(DIMS)
    assert net.active_count == np.count_nonzero(net.activity)


def test_packet_between_cells_settles_less_than_half_a_cell_away():
    # The discrete attractor pins a packet to the lattice; the pull is bounded.
    net = settled((7.3, 12.6, 20.4), steps=0)
    begin = net.centre()
    for _ in range(300):
        net.step()
    assert np.all(np.abs(signed_cell_delta(begin, net.centre())) < 0.5)


def test_packet_wraps_across_every_boundary():
    net = settled((20.6, 0.2, 35.7))
    c = net.centre()
    assert wrapped_cell_distance(c, (20.6, 0.2, 35.7), DIMS) < 0.05
    net.path_integrate((0.0, 0.0, 0.2))  # 1.15 cells past the θ' seam
    assert signed_cell_delta(c, net.centre())[2] == pytest.approx(
        0.2 / (2 * math.pi / 36), abs=0.02
    )


def test_single_view_match_does_not_move_packet():
    net = settled((10.0, 10.0, 0.0))
    start = net.centre()
    net.view_links[5] = np.array([16.0, 10.0, 0.0])
    net.inject_view(5, 1.0)
    for _ in range(50):
        net.step()
    assert wrapped_cell_distance(net.centre(), start, DIMS) < 0.05


def test_consecutive_view_matches_move_packet():
    n = consecutive_matches_to_shift(PoseCellConfig(dims=DIMS), offset_cells=(6.0, 0.0, 0.0))
    assert n is not None
    assert 2 <= n <= 10
    # Weaker evidence needs a longer run of matches; none at all never moves it.
    weaker = consecutive_matches_to_shift(
        PoseCellConfig(dims=DIMS, view_energy=0.5 * PoseCellConfig().view_energy)
    )
    assert weaker is not None and weaker > n
    assert consecutive_matches_to_shift(PoseCellConfig(dims=DIMS), activity=0.0) is None


def test_new_view_links_to_current_packet_and_matches_reinforce_it():
    net = settled((4.0, 9.0, 11.0))
    net.inject_view(3, 1.0, is_new=True)
    np.testing.assert_allclose(net.view_links[3], net.centre())
    before = net.centre()
    for _ in range(20):
        net.inject_view(3, 1.0)
        net.step()
    assert wrapped_cell_distance(net.centre(), before, DIMS) < 0.05


def test_kernel_variances_are_real_valued():
    k1 = gaussian_kernel(1.0, 3)
    k15 = gaussian_kernel(1.5, 3)
    assert k1.sum() == pytest.approx(1.0)
    assert k15.sum() == pytest.approx(1.0)
    assert k15[3, 3, 3] < k1[3, 3, 3]  # a wider (non-integer) variance flattens the peak


def test_config_rejects_heading_cells_that_do_not_wrap():
    with pytest.raises(ValueError, match="2π"):
        PoseCellConfig(dims=(21, 21, 36), cell_size_theta=0.1)
    with pytest.raises(ValueError, match="finite"):
        PoseCellNetwork(PoseCellConfig(dims=DIMS)).path_integrate((np.nan, 0.0, 0.0))


def test_one_view_matched_over_and_over_fatigues_and_never_moves_packet():
    # A stationary robot that keeps matching one aliased view: after a few injections the view
    # stops pulling (OpenRatSLAM's template decay), so no sequence of *distinct* matches occurs.
    net = settled((10.0, 10.0, 0.0))
    start = net.centre()
    net.view_links[9] = np.array([16.0, 10.0, 0.0])
    for _ in range(200):
        net.inject_view(9, 1.0)
        net.step()
    assert wrapped_cell_distance(net.centre(), start, DIMS) < 0.05


def test_network_that_loses_all_activity_is_reseeded_not_stopped():
    net = settled((10.0, 10.0, 0.0))
    last = net.centre()
    for _ in range(400):  # path integration without the attractor step smears the packet out
        net.path_integrate((0.2, 0.0, 0.05))
    net.step()
    assert net.collapses == 1
    assert net.activity.sum() == pytest.approx(1.0)
    assert wrapped_cell_distance(net.centre(), last, DIMS) < 0.05


def test_view_links_and_fatigue_cost_few_bytes_a_view_and_keep_their_values():
    """Each learned view keeps its link (Eq. 11) and its fatigue for the whole run (20,000
    views an hour on an unseen warehouse route): as rows by view id, under 80 bytes a view
    (a dict of arrays and of tuples took 500); what is stored is read back exactly."""
    import tracemalloc

    n = 4000  # just below a doubling of the rows: their slack is not counted
    net = settled((4.0, 9.0, 11.0))
    tracemalloc.start()
    try:
        before = tracemalloc.get_traced_memory()[0]
        for v in range(n):
            net.inject_view(v, 1.0, is_new=True)
        for v in range(n):
            net.inject_view(v, 0.5)
        per_view = (tracemalloc.get_traced_memory()[0] - before) / n
    finally:
        tracemalloc.stop()
    assert per_view < 80
    assert len(net.view_links) == n and 5 in net.view_links and n not in net.view_links
    centre = net.centre()
    net.view_links[n + 10] = centre  # any id, in any order
    assert net.view_links[n + 10].tobytes() == centre.tobytes() and n + 9 not in net.view_links
    with pytest.raises(KeyError):
        net.view_links[n + 9]


def _with_activity(activity: np.ndarray) -> PoseCellNetwork:
    net = PoseCellNetwork(PoseCellConfig(dims=DIMS))
    flat = activity.reshape(-1)
    (cells,) = np.nonzero(flat)
    net._pc[:] = flat
    net._active[: cells.size] = cells
    net._n_active = cells.size
    return net


def _dense_step(activity: np.ndarray, cfg: PoseCellConfig) -> np.ndarray:
    """Sec. III-C's step over the whole wrapped network, as OpenRatSLAM computes it."""
    from scipy.ndimage import convolve

    excite = gaussian_kernel(cfg.excite_var, cfg.excite_radius)
    inhibit = gaussian_kernel(cfg.inhibit_var, cfg.inhibit_radius)
    exc = convolve(activity, excite, mode="wrap")
    sources = np.where(exc > cfg.global_inhibition, exc, 0.0)
    new = np.maximum(exc - convolve(sources, inhibit, mode="wrap") - cfg.global_inhibition, 0.0)
    return new / new.sum()


@pytest.mark.parametrize(
    "cells",
    [
        [(20, 0, 35), (0, 20, 0), (19, 1, 34)],  # one packet across all three seams
        [(3, 4, 5), (14, 15, 23)],  # two packets far apart on every axis
        [(10, 10, k) for k in range(0, 36, 3)],  # activity round the whole heading axis
        [(i, (7 * i) % 21, (5 * i) % 36) for i in range(21)],  # spread over the network
    ],
)
def test_the_step_on_the_box_equals_the_step_over_the_whole_wrapped_network(cells):
    rng = np.random.default_rng(len(cells))
    activity = np.zeros(DIMS)
    for cell in cells:
        activity[cell] = rng.uniform(0.2, 1.0)
    activity /= activity.sum()
    net = _with_activity(activity)
    for _ in range(3):
        expected = _dense_step(activity, net.config)
        net.step()
        np.testing.assert_allclose(net.activity, expected, rtol=0, atol=1e-15)
        assert net.active_count == np.count_nonzero(expected)
        activity = expected
