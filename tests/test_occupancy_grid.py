import math

import numpy as np
import pytest

from bioslam.occupancy_grid import MapPyramid, OccupancyGrid, edge_twins


def _wall_scan(x_wall: float, n: int = 181, half_width: float = 1.5) -> np.ndarray:
    """Endpoints of a scan from the origin of a straight wall at x = x_wall."""
    y = np.linspace(-half_width, half_width, n)
    return np.column_stack([np.full(n, x_wall), y])


def test_hits_are_occupied_rays_are_free_rest_unknown():
    grid = OccupancyGrid(0.05, 6.0)
    grid.insert_scan([0.0, 0.0, 0.0], _wall_scan(2.0))
    p = grid.probability(unknown=np.nan)
    (r, c), = grid.world_to_cell([[2.01, 0.0]])
    assert p[r, c] > 0.5
    (r, c), = grid.world_to_cell([[1.0, 0.0]])
    assert p[r, c] < 0.5
    (r, c), = grid.world_to_cell([[-1.0, 0.0]])
    assert np.isnan(p[r, c])
    assert np.all((np.nan_to_num(p, nan=0.5) >= 0.0) & (np.nan_to_num(p, nan=0.5) <= 1.0))


def test_row_zero_is_lowest_y_and_pose_is_applied():
    grid = OccupancyGrid(0.1, 4.0)
    # sensor at (0, 1) facing +y (theta = pi/2): a point 0.5 m ahead lands at (0, 1.5)
    grid.insert_scan([0.0, 1.0, np.pi / 2], np.array([[0.5, 0.0]]))
    r, c = np.unravel_index(np.argmax(grid.logodds), grid.shape)
    x0, y0 = grid.origin
    assert x0 + c * 0.1 <= 0.0 < x0 + (c + 1) * 0.1
    assert y0 + r * 0.1 <= 1.5 < y0 + (r + 1) * 0.1


@pytest.mark.parametrize("sigma", [None, 1.0])
def test_gradient_matches_finite_differences(sigma):
    grid = OccupancyGrid(0.05, 6.0)
    rng = np.random.default_rng(1)
    for k in range(5):
        angle = rng.uniform(-np.pi, np.pi)
        grid.insert_scan([0.1 * k, 0.0, angle], _wall_scan(1.3 + 0.07 * k))
    pts = rng.uniform(-1.8, 1.8, size=(400, 2))
    val, grad = grid.value_and_gradient(pts, subcell_sigma=sigma)
    h = 1e-6
    vx, _ = grid.value_and_gradient(pts + np.array([h, 0.0]), subcell_sigma=sigma)
    vy, _ = grid.value_and_gradient(pts + np.array([0.0, h]), subcell_sigma=sigma)
    fd = np.column_stack([(vx - val) / h, (vy - val) / h])
    # away from the kinks at cell-centre lines the analytic gradient is exact
    smooth = np.all(np.abs(fd - grad) < 1e-3, axis=1)
    assert smooth.mean() > 0.97
    assert np.any(np.abs(grad) > 0.1)


@pytest.mark.parametrize("x_wall", [1.003, 1.042, 1.047])
def test_subcell_map_peaks_at_the_measured_wall_bilinear_at_the_cell_centre(x_wall):
    # a wall near a boundary of the cell [1.00, 1.05) (centre 1.025), hits with 1 cm range
    # noise straddling two cells (deep inside a cell the sub-cell map also peaks at the centre)
    grid = OccupancyGrid(0.05, 6.0, origin=(-3.0, -3.0))
    rng = np.random.default_rng(2)
    for _ in range(20):
        wall = _wall_scan(x_wall)
        wall[:, 0] += rng.normal(0.0, 0.01, len(wall))
        grid.insert_scan([0.0, 0.0, 0.0], wall)
    xs = np.linspace(0.95, 1.10, 1501)
    along = np.linspace(-0.5, 0.5, 41)  # average along the wall, as a scan does

    def profile(sigma):
        return np.mean(
            [grid.value_and_gradient(np.column_stack([xs, np.full_like(xs, y)]), sigma)[0]
             for y in along], axis=0,
        )  # fmt: skip

    assert abs(xs[np.argmax(profile(1.0))] - x_wall) < 0.003
    bilinear_peak = xs[np.argmax(profile(None))]
    assert abs(bilinear_peak - 1.025) < 0.003 or abs(bilinear_peak - 1.075) < 0.003
    assert abs(bilinear_peak - x_wall) > 0.015


def test_scrolling_keeps_content_in_place_and_memory_constant():
    grid = OccupancyGrid(0.05, 4.0)
    grid.insert_scan([0.0, 0.0, 0.0], _wall_scan(1.2))
    before = grid.nbytes
    probe = np.array([[1.2, 0.3], [0.6, -0.2]])
    v0, _ = grid.value_and_gradient(probe)
    s0, _ = grid.value_and_gradient(probe, subcell_sigma=1.0)
    grid.recenter(0.8, 0.4)
    assert grid.nbytes == before
    assert grid.origin[0] > -2.0  # it moved
    v1, _ = grid.value_and_gradient(probe)
    s1, _ = grid.value_and_gradient(probe, subcell_sigma=1.0)
    assert np.allclose(v0, v1) and np.allclose(s0, s1)
    grid.recenter(100.0, 100.0)  # far away: everything is forgotten
    assert not grid.known_mask().any() and grid.nbytes == before


def _scrolled(layer: np.ndarray, drow: int, dcol: int) -> np.ndarray:
    """``layer`` with cell (r, c) taken from (r + drow, c + dcol), 0 where that is outside."""
    out = np.zeros_like(layer)
    rows, cols = layer.shape[:2]
    for r in range(rows):
        for c in range(cols):
            if 0 <= r + drow < rows and 0 <= c + dcol < cols:
                out[r, c] = layer[r + drow, c + dcol]
    return out


@pytest.mark.parametrize(
    "drow, dcol", [(3, -2), (-3, 2), (0, 5), (0, -5), (4, 0), (-4, 0), (-1, -1), (17, 3), (0, -40)]
)
def test_every_layer_scrolls_cell_for_cell_in_place(drow, dcol):
    """Each layer (log-odds, stamps, the four sub-cell moments, hits, weights) scrolled by
    whole cells either way, or past its edge, moves every value to its new cell and zeroes
    the cells that came in; the arrays themselves are kept (no copy of the map a scroll)."""
    rng = np.random.default_rng(abs(drow) * 100 + abs(dcol))
    grid = OccupancyGrid(0.1, (1.7, 1.2))  # 12 rows x 17 columns
    for name in grid._layers:
        layer = getattr(grid, name)
        layer[...] = rng.integers(1, 1000, size=layer.shape).astype(layer.dtype)
    before = {name: getattr(grid, name).copy() for name in grid._layers}
    arrays = {name: getattr(grid, name) for name in grid._layers}
    origin = grid.origin.copy()
    grid.shift_cells(drow, dcol)
    for name in grid._layers:
        assert getattr(grid, name) is arrays[name]
        np.testing.assert_array_equal(getattr(grid, name), _scrolled(before[name], drow, dcol))
    np.testing.assert_allclose(grid.origin, origin + 0.1 * np.array([dcol, drow]))


def test_grow_to_include_keeps_alignment_and_content():
    grid = OccupancyGrid(0.05, 2.0, auto_grow=True)
    grid.insert_scan([0.0, 0.0, 0.0], _wall_scan(0.6, half_width=0.5))
    v0, _ = grid.value_and_gradient([[0.6, 0.1]])
    grid.insert_scan([0.0, 0.0, 0.0], np.array([[7.3, -4.1]]))
    _, ymin, xmax, _ = grid.extent
    assert xmax > 7.3 and ymin < -4.1
    v1, _ = grid.value_and_gradient([[0.6, 0.1]])
    assert np.allclose(v0, v1)
    assert grid.probability()[tuple(grid.world_to_cell([[7.3, -4.1]])[0])] > 0.5


def test_pyramid_levels_stay_aligned_when_scrolling():
    pyr = MapPyramid(0.05, 8.0, 3)
    assert [g.resolution for g in pyr.grids] == [0.05, 0.1, 0.2]
    pyr.insert_scan([0.0, 0.0, 0.0], _wall_scan(1.0))
    pyr.recenter(1.37, -2.11)
    extents = np.array([g.extent for g in pyr.grids])
    assert np.allclose(extents, extents[0])
    for g in pyr.grids:
        (r, c), = g.world_to_cell([[1.01, 0.0]])
        assert g.logodds[r, c] > 0


def test_bad_input_is_rejected():
    with pytest.raises(ValueError, match="resolution"):
        OccupancyGrid(0.0, 1.0)
    grid = OccupancyGrid(0.1, 1.0)
    with pytest.raises(ValueError, match=r"\(N, 2\)"):
        grid.insert_scan([0, 0, 0], np.zeros((3, 3)))


def test_cached_weights_follow_the_log_odds_of_hit_cells():
    grid = OccupancyGrid(0.05, 6.0)
    grid.insert_scan([0.0, 0.0, 0.0], _wall_scan(2.0))
    # the wall moves: rays now cross (and lower) the cells hit before; one hit (+2.2) takes
    # six misses (-0.41 each) to undo
    for _ in range(8):
        grid.insert_scan([0.0, 0.0, 0.0], _wall_scan(2.6))
    grid.shift_cells(3, -2)
    hit = grid.hits > 0
    assert np.count_nonzero(hit) > 100
    np.testing.assert_allclose(grid.weights[hit], grid.probability()[hit], rtol=1e-6)
    assert np.all(grid.weights[~hit] == 0.0)
    old_wall = grid.world_to_cell([[2.01, 0.0]])[0]
    assert grid.weights[tuple(old_wall)] < 0.5  # erased by the later rays


def test_above_near_looks_at_the_cell_and_its_eight_neighbours():
    grid = OccupancyGrid(0.1, 2.0)
    grid.logodds[10, 10] = 2.0  # the cell around (0.05, 0.05)
    pts = np.array([[0.05, 0.05], [0.15, -0.05], [0.25, 0.05], [-5.0, -5.0]])
    # the cell itself, a diagonal neighbour, two cells away, far outside (unknown there)
    assert grid.above_near(pts, 1.0).tolist() == [True, True, False, False]
    assert not grid.above_near(pts, 2.0).any()


def test_beyond_the_grid_is_unknown_not_its_border():
    """A long-range scanner's far endpoints fall past a local map's edge; the map saw free
    space up to there, but not beyond: they are no evidence of a wall seen through."""
    grid = OccupancyGrid(0.1, 2.0)
    grid.logodds[:] = -3.0  # all seen free
    pts = np.array([[0.5, 0.5], [0.95, 0.0], [1.5, 0.0], [-8.0, 3.0]])
    # inside, beside the edge (its outer neighbours unknown), beyond, far beyond
    assert grid.above_near(pts, -1.5).tolist() == [False, True, True, True]
    assert not grid.above_near(pts, 0.0).any()  # unknown is not above an occupied level
    assert grid.fraction_not_above_near((0.0, 0.0, 0.0), pts, -1.5) == 0.25


def test_fraction_not_above_near_places_sensor_points_by_the_pose():
    grid = OccupancyGrid(0.1, 2.0)
    grid.logodds[10, 10] = 2.0  # the cell around world (0.05, 0.05)
    sensor = np.array([[0.05, -0.05], [0.15, 0.05], [0.35, -0.05], [0.5, 0.5]])
    pose = (0.0, 0.0, np.pi / 2)  # sensor (a, b) -> world (-b, a)
    world = np.column_stack([-sensor[:, 1], sensor[:, 0]])
    expected = 1.0 - grid.above_near(world, 1.0).mean()
    assert expected == 0.5
    assert grid.fraction_not_above_near(pose, sensor, 1.0) == pytest.approx(expected)
    assert grid.fraction_not_above_near(pose, np.zeros((0, 2)), 1.0) == 0.0


def test_display_grid_has_the_same_logodds_in_less_memory() -> None:
    """A grid kept only for drawing (subcell=False) fuses scans to the very same log-odds."""
    rng = np.random.default_rng(3)
    full = OccupancyGrid.from_extent(0.05, (-12.0, -9.0, 14.0, 11.0))
    light = OccupancyGrid.from_extent(0.05, (-12.0, -9.0, 14.0, 11.0), subcell=False)
    for _ in range(25):
        pose = np.array([rng.uniform(-3, 3), rng.uniform(-3, 3), rng.uniform(-np.pi, np.pi)])
        angles = np.linspace(-2.3, 2.3, 400)
        ranges = rng.uniform(0.5, 20.0, size=angles.size)  # some beyond the grid
        pts = np.column_stack([ranges * np.cos(angles), ranges * np.sin(angles)])
        full.insert_scan(pose, pts, max_range=15.0)
        light.insert_scan(pose, pts, max_range=15.0)
    np.testing.assert_array_equal(light.logodds, full.logodds)
    np.testing.assert_array_equal(light.known_mask(), full.known_mask())
    assert light.nbytes * 3 < full.nbytes
    with pytest.raises(ValueError, match="subcell"):
        light.value_and_gradient(np.zeros((1, 2)))


def test_fraction_through_walls_counts_beams_that_cross_a_known_wall():
    """A wall at x = 2 seen from the origin: beams from a pose behind it that end beyond the
    wall cross it; beams ending in front of it, or within the margin of it, do not; nor do
    beams whose path only crosses unknown or free cells."""
    grid = OccupancyGrid(0.05, 8.0)
    grid.insert_scan([0.0, 0.0, 0.0], _wall_scan(2.0))
    level, margin = 1.5, 0.3
    # from the origin, facing +x: ends at 3 m (beyond the wall), 1.5 m (in front), 2.2 m
    # (just beyond, within the margin), and at -2 m (behind the sensor, unknown space)
    pts = np.array([[3.0, 0.0], [1.5, 0.0], [2.2, 0.1], [-2.0, 0.0]])
    assert grid.fraction_through_walls((0.0, 0.0, 0.0), pts, level, margin) == 0.25
    # turned by 180 degrees: three beams go into unknown space, the fourth ends on the wall
    assert grid.fraction_through_walls((0.0, 0.0, np.pi), pts, level, margin) == 0.0
    # moved 1.5 m back: the 3 m and 2.2 m beams end at 1.5 / 0.7 m, in front of the wall
    assert grid.fraction_through_walls((-1.5, 0.0, 0.0), pts, level, margin) == 0.0
    # moved 0.5 m forward: the 1.5 m beam now ends on the wall, the 3 m and 2.2 m beams
    # (at x = 3.5 and 2.7) beyond it
    assert grid.fraction_through_walls((0.5, 0.0, 0.0), pts, level, margin) == 0.5
    assert grid.fraction_through_walls((0.0, 0.0, 0.0), np.zeros((0, 2)), level, margin) == 0.0


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_scan_fused_without_rays_has_the_same_map_function_and_no_free_cell(seed):
    # a submap for registration reads its hit cells only: its rays may be skipped
    rng = np.random.default_rng(seed)
    angles = np.sort(rng.uniform(-np.pi, np.pi, 400))
    ranges = rng.uniform(0.5, 4.0, 400)
    scan = np.column_stack([ranges * np.cos(angles), ranges * np.sin(angles)])
    pose = np.array([rng.uniform(-1, 1), rng.uniform(-1, 1), rng.uniform(-np.pi, np.pi)])
    with_rays, hits_only = (MapPyramid(0.05, 12.0, 3) for _ in range(2))
    with_rays.insert_scan(pose, scan)
    hits_only.insert_scan(pose, scan, rays=False)
    queries = rng.uniform(-5.0, 5.0, (2000, 2))
    for full, bare in zip(with_rays.grids, hits_only.grids, strict=True):
        np.testing.assert_array_equal(bare.weights, full.weights)
        np.testing.assert_array_equal(bare.means, full.means)
        for a, b in zip(
            full.value_and_gradient(queries, 1.0), bare.value_and_gradient(queries, 1.0),
            strict=True,
        ):
            np.testing.assert_array_equal(a, b)
        assert (full.logodds < 0).any() and not (bare.logodds < 0).any()
        np.testing.assert_array_equal(bare.logodds > 0, full.logodds > 0)


def test_edge_twins_hold_a_wall_along_a_cell_edge_in_the_cells_on_both_sides():
    """A wall along a cell edge (y = 1.0 on a 5 cm grid), its endpoints 4 mm either side of
    it: each is copied just across the edge, so every cell along the wall on both sides is
    hit; a point 1 cm from an edge gets a twin across it, one 2 cm from the nearer edge (in
    the middle half of its cell) none, nor one on a surface facing 45° off both axes."""
    xs = np.arange(0.0, 1.0, 0.05) + 0.025
    ys = 1.0 + np.where(np.arange(xs.size) % 2 == 0, 0.004, -0.004)
    world = np.column_stack([xs, ys])
    normals = np.tile([0.0, -1.0], (xs.size, 1))
    twins, twin_normals = edge_twins(world, normals, np.zeros(2), 0.05)
    assert twins.shape == world.shape
    np.testing.assert_allclose(twins[:, 0], xs)
    assert np.all(np.sign(twins[:, 1] - 1.0) == -np.sign(ys - 1.0))  # across the edge
    assert np.all(np.abs(twins[:, 1] - 1.0) <= 0.0011)
    np.testing.assert_array_equal(twin_normals, normals)
    rows = {int(np.floor(y / 0.05)) for y in np.concatenate([ys, twins[:, 1]])}
    assert rows == {19, 20}
    up = np.array([[0.0, 1.0]])
    near, _ = edge_twins(np.array([[0.3, 0.51]]), up, np.zeros(2), 0.05)
    assert near.shape == (1, 2) and np.floor(near[0, 1] / 0.05) == 9  # 0.51: row 10
    mid, _ = edge_twins(np.array([[0.3, 0.52]]), up, np.zeros(2), 0.05)
    assert mid.shape == (0, 2)
    diagonal = np.array([[math.sqrt(0.5), math.sqrt(0.5)]])
    none, _ = edge_twins(np.array([[0.3, 0.5]]), diagonal, np.zeros(2), 0.05)
    assert none.shape == (0, 2)


def test_edge_twins_are_fused_as_hits_without_rays():
    """A grid's twins of a wall seen from 2 m: the wall's cells on the far side of its edge
    become occupied too; no cell the first scan left unknown is marked free by them."""
    grid = OccupancyGrid(0.05, (4.0, 4.0), origin=(-2.0, -2.0))
    ys = np.linspace(-0.5, 0.5, 41)
    wall = np.column_stack([np.full(ys.size, 1.004), ys])  # 4 mm past the edge at x = 1.0
    normals = np.tile([-1.0, 0.0], (ys.size, 1))
    grid.insert_scan((0.0, 0.0, 0.0), wall, normals=normals)
    before = grid.logodds.copy()
    grid.insert_edge_twins((0.0, 0.0, 0.0), wall, normals)
    col = int(np.floor((1.0 - 0.01 + 2.0) / 0.05))  # the column just short of the edge
    rows = np.floor((ys + 2.0) / 0.05).astype(int)
    assert np.all(before[rows, col] <= 0.0) and np.all(grid.logodds[rows, col] > 0.0)
    assert np.all(grid.logodds[before == 0.0] >= 0.0)
