"""Pipeline figures: files are written, drawn where the data says, and bad input is refused."""

from __future__ import annotations

import numpy as np
import pytest
from matplotlib.colors import to_rgb
from PIL import Image

from bioslam.io.mapfile import OccupancyImage
from bioslam.plots import figures
from bioslam.plots.figures import (
    plot_active_view,
    plot_cognitive_map,
    plot_error_over_time,
    plot_mapping_progress,
    plot_occupancy,
    plot_revisit_sharpness,
    plot_views_and_errors,
)


@pytest.fixture(autouse=True)
def _small_figures(monkeypatch):
    # Low resolution keeps the module fast; nothing below depends on the pixel count.
    monkeypatch.setattr(figures.CONFIG, "dpi", 50)


def _square_route(n: int = 40) -> np.ndarray:
    s = np.linspace(0.0, 4.0, n, endpoint=False)
    side, f = np.divmod(s, 1.0)
    x = np.choose(side.astype(int), [f, np.ones(n), 1 - f, np.zeros(n)])
    y = np.choose(side.astype(int), [np.zeros(n), f, np.ones(n), 1 - f])
    return 5.0 * np.column_stack([x, y])


def _pixels(path) -> np.ndarray:
    return np.asarray(Image.open(path).convert("RGB"), dtype=np.float64) / 255.0


def _count_colour(rgb: np.ndarray, colour: str) -> int:
    """Pixels that are ``colour`` blended over white (anti-aliased thin lines included)."""
    towards = 1.0 - np.asarray(to_rgb(colour))
    away = 1.0 - rgb
    alpha = away @ towards / (towards @ towards)
    residual = np.linalg.norm(away - alpha[..., None] * towards, axis=-1)
    return int(np.sum((alpha > 0.3) & (residual < 0.08)))


def test_cognitive_map_highlights_loop_links(tmp_path):
    nodes = _square_route()
    chain = [(i, i + 1, "odom") for i in range(len(nodes) - 1)]
    plain = plot_cognitive_map(tmp_path / "plain.png", nodes, chain)
    looped = plot_cognitive_map(
        tmp_path / "sub" / "loop.png", nodes, [*chain, (0, 20, "loop"), (5, 25, "loop")]
    )
    assert looped == tmp_path / "sub" / "loop.png" and looped.is_file()
    red = figures.CONFIG.loop_colour
    assert _count_colour(_pixels(plain), red) < 20  # at most the legend swatch
    assert _count_colour(_pixels(looped), red) > 100


def test_cognitive_map_refuses_a_link_to_a_missing_node(tmp_path):
    with pytest.raises(ValueError, match=r"link 1 \(3, 9\)"):
        plot_cognitive_map(tmp_path / "x.png", np.zeros((4, 2)), [(0, 1, "odom"), (3, 9, "odom")])
    assert not (tmp_path / "x.png").exists()


def test_occupancy_map_is_drawn_with_row_zero_at_the_bottom(tmp_path):
    prob = np.full((60, 80), 0.0)
    prob[45:, :20] = 1.0  # an occupied block at high y, low x: the picture's upper left
    prob[:10, 60:] = np.nan  # unknown at low y, high x: the lower right
    path = plot_occupancy(tmp_path / "occ.png", OccupancyImage(prob, 0.1, (-2.0, 3.0, 0.0)))
    rgb = _pixels(path)
    dark = np.argwhere(rgb.sum(axis=-1) < 0.3)
    unknown = np.argwhere(np.all(np.abs(rgb - to_rgb(figures.CONFIG.unknown_colour)) < 0.05, -1))
    h, w = rgb.shape[:2]
    # Dark pixels include the frame and tick labels, so compare the block's side against the
    # other side rather than expecting an exact position.
    assert np.mean(dark[:, 0] < h / 2) > 0.5 and np.mean(dark[:, 1] < w / 2) > 0.5
    assert unknown.size and np.mean(unknown[:, 0]) > h / 2 and np.mean(unknown[:, 1]) > w / 2


def test_a_large_map_is_reduced_keeping_thin_walls_and_its_place(tmp_path, monkeypatch):
    """A map wider than the figure is drawn block by block: a one-cell wall survives, the
    whole-unknown region stays unknown, and the picture covers the same metres."""
    prob = np.zeros((301, 250), dtype=np.float64)
    prob[:, 123] = 1.0  # a one-cell wall, not on a block boundary
    prob[150:, 200:] = np.nan
    shown, block = figures._display_cells(prob.astype(np.float32), 100)
    assert block == 4 and shown.shape == (76, 63)
    assert np.all(shown[:75, 30] == 1.0) and np.all(shown[:, :30] == 0.0)
    assert np.all(np.isnan(shown[38:75, 50:62])) and not np.isnan(shown[36, 50])
    monkeypatch.setattr(figures.CONFIG, "max_map_pixels", 100)
    reduced = _pixels(plot_occupancy(tmp_path / "reduced.png", (prob, 0.1, (0.0, 0.0))))
    monkeypatch.setattr(figures.CONFIG, "max_map_pixels", 10_000)
    full = _pixels(plot_occupancy(tmp_path / "full.png", (prob, 0.1, (0.0, 0.0))))
    # the same picture but for the wall's width: the wall's columns agree within a block
    dark_reduced = np.argwhere(reduced.sum(axis=-1) < 0.3)[:, 1]
    dark_full = np.argwhere(full.sum(axis=-1) < 0.3)[:, 1]
    assert abs(np.median(dark_reduced) - np.median(dark_full)) <= 4


def test_occupancy_accepts_a_plain_tuple_and_draws_the_trajectory(tmp_path):
    prob = np.zeros((50, 50))
    route = _square_route() * 0.5 + 1.0
    bare = plot_occupancy(tmp_path / "bare.png", (prob, 0.1, (0.0, 0.0)))
    drawn = plot_occupancy(tmp_path / "traj.png", (prob, 0.1, (0.0, 0.0)), trajectory_xy=route)
    assert _count_colour(_pixels(bare), "tab:red") == 0
    assert _count_colour(_pixels(drawn), "tab:red") > 50
    with pytest.raises(ValueError, match="2-D"):
        plot_occupancy(tmp_path / "bad.png", (np.zeros(5), 0.1, (0.0, 0.0)))


def test_time_series_figures_are_written_and_check_lengths(tmp_path):
    t = 1.7e9 + np.arange(100) * 0.5
    ids = np.minimum(np.arange(100), 60)
    new = np.arange(100) < 60
    err = np.abs(np.sin(np.arange(100) / 10.0))
    assert plot_active_view(tmp_path / "views.png", t, ids, new).is_file()
    assert plot_error_over_time(tmp_path / "err.png", t, err, (t, 2 * err)).is_file()
    fig6 = plot_views_and_errors(tmp_path / "fig6.png", t, ids, new, t, err)
    with_odometry = _pixels(plot_error_over_time(tmp_path / "odo.png", t, err, (t, 2 * err)))
    without = _pixels(plot_error_over_time(tmp_path / "no_odo.png", t, err))
    orange = figures.CONFIG.odometry_colour
    assert _count_colour(with_odometry, orange) > 50 and _count_colour(without, orange) == 0
    assert fig6.is_file()
    with pytest.raises(ValueError, match="differ in length"):
        plot_active_view(tmp_path / "v.png", t, ids[:-1], new)
    with pytest.raises(ValueError, match="differ in length"):
        plot_error_over_time(tmp_path / "e.png", t, err[:-1])


def test_mapping_progress_has_one_panel_per_snapshot_plus_ground_truth(tmp_path):
    route = _square_route()
    snaps = [
        (t, route[:n], [(i, i + 1, "odom") for i in range(n - 1)])
        for t, n in ((200.0, 10), (400.0, 25), (600.0, 40))
    ]
    four = Image.open(plot_mapping_progress(tmp_path / "fig5.png", snaps, route)).size
    two = Image.open(plot_mapping_progress(tmp_path / "two.png", snaps[:1], route)).size
    assert four[0] == pytest.approx(2 * two[0], rel=0.05)
    assert four[1] == two[1]
    with pytest.raises(ValueError, match="at least one"):
        plot_mapping_progress(tmp_path / "none.png", [], None)


def test_revisit_sharpness_has_a_panel_per_trajectory_on_one_colour_scale(tmp_path):
    route = _square_route()
    sharp = np.full(len(route), 0.004)
    blurred = sharp.copy()
    blurred[:10] = 0.4  # one side of the square 40 cm off
    blurred[10] = np.nan  # a scan not judged is left out
    two = plot_revisit_sharpness(tmp_path / "two.png", route, [("a", sharp), ("b", blurred)])
    one = plot_revisit_sharpness(tmp_path / "one.png", route, [("a", sharp)])
    assert Image.open(two).size[0] > 1.5 * Image.open(one).size[0] - 60
    # the blurred side is drawn in the scale's top colour (which the colour bar shows in both)
    top = "#fde725"
    assert _count_colour(_pixels(two), top) > _count_colour(_pixels(one), top) + 10
    with pytest.raises(ValueError, match="one residual per judged scan"):
        plot_revisit_sharpness(tmp_path / "bad.png", route, [("a", sharp[:-1])])
