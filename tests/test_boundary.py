import math

import numpy as np
import pytest
from _views_world import box, cast

from bioslam.boundary import (
    BoundaryCellConfig,
    BoundaryCells,
    boundary_cell_update,
    geometric_rings,
    linear_rings,
)
from bioslam.scan import LaserScan

ROOM = [*box(0.0, 0.0, 8.0, 5.0), (3.0, 0.0, 3.0, 3.0)]


def _dense_eq5(cfg: BoundaryCellConfig, scan: LaserScan, weight: float) -> np.ndarray:
    """Eq. 5 summed over every endpoint and every cell, without truncation."""
    d_i, a_i = cfg.cell_centres()
    s_d = np.repeat(cfg.sigma_d(), cfg.cells_per_ring)
    r, a = scan.valid_polar()
    out = np.zeros(cfg.num_cells)
    for c in range(cfg.num_cells):
        out[c] = sum(
            boundary_cell_update(rr, aa, d_i[c], a_i[c], s_d[c], cfg.sigma_alpha)
            for rr, aa in zip(r, a, strict=True)
        )
    return weight * out


def test_eq5_hand_computed():
    # On the ring, 0.1 rad off-centre, sigma_alpha 0.2: 1/2 * exp(-(0.1/0.2)^2).
    assert boundary_cell_update(2.0, 0.1, 2.0, 0.0, 0.4, 0.2) == pytest.approx(
        0.5 * math.exp(-0.25)
    )
    # 0.4 m beyond the ring with sigma_d 0.4, on the centre angle: 1/2.4 * exp(-1).
    assert boundary_cell_update(2.4, 0.0, 2.0, 0.0, 0.4, 0.2) == pytest.approx(
        math.exp(-1.0) / 2.4
    )
    # Angles either side of the rear are 0.1 rad apart, not 2 pi - 0.1.
    assert boundary_cell_update(1.0, math.pi - 0.05, 1.0, -math.pi + 0.05, 0.2, 0.2) == (
        pytest.approx(math.exp(-0.25))
    )


@pytest.mark.parametrize(("cutoff", "tolerance"), [(3.0, math.exp(-9)), (2.0, math.exp(-4))])
def test_activity_equals_untruncated_sum_of_eq5(cutoff, tolerance):
    cfg = BoundaryCellConfig(
        ring_distances=(0.5, 1.0, 2.0, 4.0), cells_per_ring=12, distance_gain=False,
        cutoff_sigmas=cutoff,
    )
    scan = cast(ROOM, (1.5, 2.0, 0.4), fov_deg=270.0, beams=91)
    weight = (math.radians(270.0) / 90) / cfg.reference_beam_spacing
    expected = _dense_eq5(cfg, scan, weight)
    got = BoundaryCells(cfg).activity(scan)
    assert got.shape == (cfg.num_cells,)
    # Truncating at 3 (2) widths drops tails below exp(-9) (exp(-4)) of each peak.
    assert np.allclose(got, expected, rtol=0.0, atol=tolerance * expected.max())
    assert np.all(got <= expected + 1e-12)  # truncation only ever leaves terms out


def test_single_point_peaks_at_its_cell_with_inverse_distance():
    cfg = BoundaryCellConfig(
        ring_distances=(1.0, 2.0, 4.0),
        cells_per_ring=8,
        weight_by_beam_spacing=False,
        distance_gain=False,
    )
    b = BoundaryCells(cfg).activity_polar(np.array([2.0]), np.array([math.pi / 2]))
    ring, cell = divmod(int(np.argmax(b)), cfg.cells_per_ring)
    assert (ring, cell) == (1, 2)
    assert b.max() == pytest.approx(0.5)
    # Cells out of angular reach of the point stay silent.
    assert b.reshape(3, 8)[:, 6].max() == 0.0


def test_distance_gain_scales_each_ring_by_its_distance():
    scan = cast(ROOM, (1.5, 2.0, 0.4))
    plain = BoundaryCells(BoundaryCellConfig(distance_gain=False)).activity(scan)
    gained = BoundaryCells(BoundaryCellConfig()).activity(scan)
    d_i, _ = BoundaryCellConfig().cell_centres()
    assert np.allclose(gained, plain * d_i)


def test_default_rings_overlap_so_no_wall_distance_is_missed():
    cfg = BoundaryCellConfig(weight_by_beam_spacing=False, distance_gain=False)
    bc = BoundaryCells(cfg)
    d = np.linspace(1.5, 15.0, 300)
    peak = np.array([bc.activity_polar(np.array([x]), np.array([0.0])).max() * x for x in d])
    # The widest gap is between the first two rings (0.25 m from each, widths 0.25 and 0.3):
    # a point there still drives a cell at about exp(-(0.25/0.3)^2) = 0.5 of a peak.
    assert 0.4 < peak.min() < 0.6
    assert np.all(peak[d > 6.0] > 0.85)
    # walls right beside the robot are left out on purpose (BoundaryCellConfig)
    assert bc.activity_polar(np.array([0.7]), np.array([0.0])).max() * 0.7 < 0.01


def test_rotation_by_one_cell_shifts_every_ring_by_one_cell():
    cfg = BoundaryCellConfig()
    step = 2.0 * math.pi / cfg.cells_per_ring
    bc = BoundaryCells(cfg)
    b0 = bc.activity(cast(ROOM, (1.5, 2.0, 0.0), fov_deg=360.0, beams=1440))
    b1 = bc.activity(cast(ROOM, (1.5, 2.0, step), fov_deg=360.0, beams=1440))
    rings0 = b0.reshape(-1, cfg.cells_per_ring)
    rings1 = b1.reshape(-1, cfg.cells_per_ring)
    # Turning left moves the scene clockwise in the robot frame: to lower cell indices.
    assert np.allclose(np.roll(rings0, -1, axis=1), rings1, atol=0.02 * b0.max())


@pytest.mark.parametrize("fraction", [0.25, 0.5, 1.0])
def test_a_turned_activity_is_the_activity_of_the_robot_turned_the_other_way(fraction):
    # ``turn`` adds to every bearing: the scene as a robot turned right by that much sees it,
    # a fraction of a bin included (what the view cells compare a view learned at another
    # heading with).
    cfg = BoundaryCellConfig()
    turn = fraction * 2.0 * math.pi / cfg.cells_per_ring
    bc = BoundaryCells(cfg)
    turned = bc.activity(cast(ROOM, (1.5, 2.0, 0.3), fov_deg=360.0, beams=1440), turn)
    right = bc.activity(cast(ROOM, (1.5, 2.0, 0.3 - turn), fov_deg=360.0, beams=1440))
    unturned = bc.activity(cast(ROOM, (1.5, 2.0, 0.3), fov_deg=360.0, beams=1440))
    gap = np.abs(turned - right).max()
    assert gap < 0.02 * right.max()
    assert gap < 0.2 * np.abs(unturned - right).max()


def test_cells_outside_the_field_of_view_stay_silent():
    cfg = BoundaryCellConfig()
    b = BoundaryCells(cfg).activity(cast(ROOM, (1.5, 2.0, 0.0), fov_deg=180.0, beams=181))
    rear = np.abs(cfg.cell_angles()) > math.radians(90.0) + 4.0 * cfg.sigma_alpha
    assert b.reshape(-1, cfg.cells_per_ring)[:, rear].max() == 0.0
    assert b.sum() > 0.0


def test_beam_density_weighting_makes_activity_resolution_independent():
    bc = BoundaryCells()
    pose = (5.0, 2.5, 1.0)
    fine = bc.activity(cast(ROOM, pose, fov_deg=270.0, beams=1081))
    coarse = bc.activity(cast(ROOM, pose, fov_deg=270.0, beams=271))
    assert fine.sum() == pytest.approx(coarse.sum(), rel=0.02)
    raw = BoundaryCells(BoundaryCellConfig(weight_by_beam_spacing=False))
    assert raw.activity(cast(ROOM, pose, beams=1081)).sum() == pytest.approx(
        4.0 * fine.sum(), rel=0.02
    )


def test_points_closer_than_min_distance_are_ignored():
    bc = BoundaryCells(BoundaryCellConfig(min_distance=0.3, weight_by_beam_spacing=False))
    b = bc.activity_polar(np.array([0.2, 1.0]), np.array([0.0, 0.0]))
    b_far = bc.activity_polar(np.array([1.0]), np.array([0.0]))
    assert np.array_equal(b, b_far)


def test_empty_scan_gives_zero_activity():
    scan = LaserScan.from_angle_min(0.0, np.full(50, np.nan), -1.0, 0.04)
    b = BoundaryCells().activity(scan)
    assert b.shape == (BoundaryCellConfig().num_cells,) and not b.any()


def test_bad_config_is_rejected():
    with pytest.raises(ValueError, match="ring_distances"):
        BoundaryCellConfig(ring_distances=(2.0, 1.0))
    with pytest.raises(ValueError, match="sigma_d_ratio"):
        BoundaryCellConfig(sigma_d_ratio=0.0)
    with pytest.raises(ValueError):
        geometric_rings(1.0, 0.5, 4)
    assert linear_rings(0.5, 2.0, 0.5) == (0.5, 1.0, 1.5, 2.0)
    with pytest.raises(ValueError, match="sigma_d_offset"):
        BoundaryCellConfig(sigma_d_offset=-0.1)
    rings = geometric_rings(0.5, 8.0, 5)
    assert rings[0] == pytest.approx(0.5) and rings[-1] == pytest.approx(8.0)
    assert np.allclose(np.diff(np.log(rings)), math.log(2.0))


def test_activity_figure_is_written(tmp_path):
    from bioslam.plots.boundary import plot_boundary_activity

    cfg = BoundaryCellConfig()
    scan = cast(ROOM, (1.5, 2.0, 0.4))
    out = plot_boundary_activity(
        tmp_path / "rings.png", BoundaryCells(cfg).activity(scan), cfg, scan.endpoints()
    )
    assert out.exists() and out.stat().st_size > 10_000
    with pytest.raises(ValueError, match="cells"):
        plot_boundary_activity(tmp_path / "bad.png", np.zeros(3), cfg)
