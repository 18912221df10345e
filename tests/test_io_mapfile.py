"""map_server maps: write as map_saver, read as map_server (PGM and PNG, negate, thresholds)."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from bioslam.io.mapfile import OccupancyImage, read_map, write_map


def _grid(rng: np.random.Generator) -> np.ndarray:
    occ = rng.choice([0.0, 1.0, np.nan], size=(7, 11))
    occ[0, 0] = 1.0  # lowest-y, lowest-x corner occupied to pin the orientation
    occ[-1, 0] = 0.0
    return occ


def test_roundtrip_trinary_keeps_cells_and_geometry(tmp_path):
    occ = _grid(np.random.default_rng(1))
    image = OccupancyImage(occ, 0.05, (-1.5, 2.25, 0.0))
    pgm, yaml = write_map(tmp_path / "out", image)
    assert pgm.name == "map.pgm" and yaml.name == "map.yaml"
    back = read_map(yaml)
    assert back.resolution == pytest.approx(0.05)
    assert back.origin == pytest.approx((-1.5, 2.25, 0.0))
    np.testing.assert_array_equal(np.isnan(back.occupancy), np.isnan(occ))
    known = ~np.isnan(occ)
    np.testing.assert_array_equal(back.occupancy[known], occ[known])


def test_pgm_pixels_follow_map_saver(tmp_path):
    occ = np.array([[1.0, 0.0], [np.nan, 0.3]])  # row 0 is the lowest y
    pgm, _ = write_map(tmp_path, OccupancyImage(occ, 0.1), name="floor")
    pixels = np.asarray(Image.open(pgm))
    # Image row 0 is the top of the map (highest y): the grid's last row.
    np.testing.assert_array_equal(pixels, [[205, 205], [0, 254]])
    text = (tmp_path / "floor.yaml").read_text()
    for line in ("image: floor.pgm", "negate: 0", "occupied_thresh: 0.65",
                 "free_thresh: 0.196", "mode: trinary"):
        assert line in text


def test_stem_with_suffix_names_the_files(tmp_path):
    pgm, yaml = write_map(tmp_path / "sub" / "office.yaml", OccupancyImage(np.zeros((2, 3)), 1.0))
    assert pgm == tmp_path / "sub" / "office.pgm" and yaml.exists()


def test_reads_png_with_negate_and_custom_thresholds(tmp_path):
    # negate: 1 makes white occupied; a 50 % grey is occupied with occupied_thresh 0.4.
    pixels = np.array([[255, 0], [128, 60]], dtype=np.uint8)
    Image.fromarray(pixels).convert("RGB").save(tmp_path / "plan.png")
    (tmp_path / "plan.yaml").write_text(
        "image: plan.png  # a comment\nresolution: 0.5\norigin: [1.0, -2.0, 0.0]\n"
        "negate: 1\noccupied_thresh: 0.4\nfree_thresh: 0.3\n"
    )
    back = read_map(tmp_path / "plan.yaml")
    # p = v / 255: 255 -> 1 (occ), 0 -> 0 (free), 128 -> 0.50 (occ), 60 -> 0.235 (free)
    np.testing.assert_array_equal(back.occupancy, [[1.0, 0.0], [1.0, 0.0]])
    x, y = back.cell_centres()
    np.testing.assert_allclose(x, [1.25, 1.75])
    np.testing.assert_allclose(y, [-1.75, -1.25])


def test_scale_mode_and_transparent_pixels(tmp_path):
    rgba = np.zeros((1, 3, 4), dtype=np.uint8)
    rgba[0, :, :3] = [[0, 0, 0], [140, 140, 140], [0, 0, 0]]
    rgba[0, :, 3] = [255, 255, 0]
    Image.fromarray(rgba, mode="RGBA").save(tmp_path / "m.png")
    (tmp_path / "m.yaml").write_text(
        "image: m.png\nresolution: 1\norigin: [0, 0, 0]\nmode: scale\nnegate: 0\n"
    )
    occ = read_map(tmp_path / "m.yaml").occupancy[0]
    p = (255 - 140) / 255
    assert occ[0] == 1.0
    assert occ[1] == pytest.approx((p - 0.196) / (0.65 - 0.196))
    assert np.isnan(occ[2])


@pytest.mark.parametrize(
    ("yaml_text", "message"),
    [
        ("resolution: 0.1\norigin: [0, 0, 0]\n", "missing 'image'"),
        ("image: x.pgm\nresolution: fine\norigin: [0, 0, 0]\n", "'resolution' must be a number"),
        ("image: x.pgm\nresolution: 0.1\norigin: [0, a]\n", "'origin'"),
        ("image: x.pgm\nresolution: 0.1\norigin: [0, 0, 0]\nmode: fancy\n", "unknown mode"),
        ("image: x.pgm\nresolution: -1\norigin: [0, 0, 0]\n", "resolution must be a positive"),
        ("image x.pgm\n", "expected 'key: value'"),
    ],
)
def test_bad_yaml_is_a_clear_error(tmp_path, yaml_text, message):
    Image.fromarray(np.zeros((2, 2), dtype=np.uint8)).save(tmp_path / "x.pgm")
    (tmp_path / "bad.yaml").write_text(yaml_text)
    with pytest.raises(ValueError, match=message) as info:
        read_map(tmp_path / "bad.yaml")
    assert "bad.yaml" in str(info.value)


def test_missing_image_and_garbage_image(tmp_path):
    (tmp_path / "a.yaml").write_text("image: nope.pgm\nresolution: 0.1\norigin: [0, 0, 0]\n")
    with pytest.raises(FileNotFoundError, match=r"nope\.pgm"):
        read_map(tmp_path / "a.yaml")
    (tmp_path / "junk.pgm").write_bytes(b"P5\n3 3\n255\n\x00")
    (tmp_path / "b.yaml").write_text("image: junk.pgm\nresolution: 0.1\norigin: [0, 0, 0]\n")
    with pytest.raises(ValueError, match=r"junk\.pgm"):
        read_map(tmp_path / "b.yaml")
