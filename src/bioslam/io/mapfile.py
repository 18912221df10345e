"""ROS map_server maps: ``map.pgm`` + ``map.yaml``, written and read as map_server does.

Writing follows ``map_saver`` (trinary: 254 free, 0 occupied, 205 unknown; image row 0 is the
top of the map, i.e. the highest y). Reading follows ``map_server``'s image loader: the pixel
colour (mean of the colour channels) gives ``p = (255 - v) / 255`` (or ``v / 255`` when
``negate: 1``); in ``trinary`` mode ``p > occupied_thresh`` is occupied, ``p < free_thresh``
free, the rest unknown; ``scale`` keeps the value in between; ``raw`` takes the pixel as a
percentage (> 100 = unknown). A fully transparent pixel is unknown.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from bioslam.io.jsonio import atomic_write_bytes, atomic_write_text

FREE_PIXEL = 254
OCCUPIED_PIXEL = 0
UNKNOWN_PIXEL = 205
# map_server's documented defaults (wiki.ros.org/map_server, "YAML format").
DEFAULT_OCCUPIED_THRESH = 0.65
DEFAULT_FREE_THRESH = 0.196
MAP_MODES = ("trinary", "scale", "raw")


@dataclass
class OccupancyImage:
    """A 2-D occupancy grid in the map frame.

    ``occupancy[i, j]`` is the cell centred at ``x = origin[0] + (j + 0.5) * resolution``,
    ``y = origin[1] + (i + 0.5) * resolution`` (row 0 = lowest y); values in ``[0, 1]`` are the
    probability of being occupied, NaN = unknown. ``origin`` is ``(x, y, yaw)`` of the lower-left
    corner of cell ``[0, 0]`` (map_server's convention; yaw is carried but rarely non-zero).
    """

    occupancy: NDArray[np.float64]
    resolution: float
    origin: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        self.occupancy = np.asarray(self.occupancy, dtype=np.float64)
        if self.occupancy.ndim != 2 or 0 in self.occupancy.shape:
            raise ValueError(f"occupancy must be a non-empty 2-D array, got {self.occupancy.shape}")
        if not (np.isfinite(self.resolution) and self.resolution > 0):
            raise ValueError(f"resolution must be a positive number, got {self.resolution}")
        self.resolution = float(self.resolution)
        origin = tuple(float(v) for v in self.origin)
        if len(origin) == 2:
            origin = (*origin, 0.0)
        if len(origin) != 3:
            raise ValueError(f"origin must be (x, y, yaw), got {self.origin}")
        self.origin = origin  # type: ignore[assignment]

    @property
    def shape(self) -> tuple[int, int]:
        return self.occupancy.shape  # type: ignore[return-value]

    def cell_centres(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """``(x, y)`` of the column and row centres (1-D each), metres."""
        rows, cols = self.shape
        x = self.origin[0] + (np.arange(cols) + 0.5) * self.resolution
        y = self.origin[1] + (np.arange(rows) + 0.5) * self.resolution
        return x, y


def occupancy_to_pixels(
    occupancy: NDArray[np.float64],
    occupied_thresh: float = DEFAULT_OCCUPIED_THRESH,
    free_thresh: float = DEFAULT_FREE_THRESH,
) -> NDArray[np.uint8]:
    """Trinary map_saver pixels (row 0 = top) from a grid whose row 0 is the lowest y."""
    occ = np.asarray(occupancy, dtype=np.float64)
    pixels = np.full(occ.shape, UNKNOWN_PIXEL, dtype=np.uint8)
    with np.errstate(invalid="ignore"):
        pixels[occ > occupied_thresh] = OCCUPIED_PIXEL
        pixels[occ < free_thresh] = FREE_PIXEL
    return np.ascontiguousarray(pixels[::-1])


def _pgm_bytes(pixels: NDArray[np.uint8]) -> bytes:
    rows, cols = pixels.shape
    header = f"P5\n# CREATOR: bioslam map writer\n{cols} {rows}\n255\n".encode("ascii")
    return header + pixels.tobytes()


def _output_paths(directory_or_stem: str | Path, name: str) -> tuple[Path, Path]:
    """An existing directory or a path without a map suffix is a directory (created); a path
    ending in ``.pgm``/``.yaml``/``.yml`` names the map itself."""
    target = Path(directory_or_stem)
    if not target.is_dir() and target.suffix.lower() in (".pgm", ".yaml", ".yml"):
        stem = target.with_suffix("")
    else:
        stem = target / name
    return stem.with_suffix(".pgm"), stem.with_suffix(".yaml")


def write_map(
    directory_or_stem: str | Path,
    image: OccupancyImage,
    name: str = "map",
    occupied_thresh: float = DEFAULT_OCCUPIED_THRESH,
    free_thresh: float = DEFAULT_FREE_THRESH,
) -> tuple[Path, Path]:
    """Write ``<name>.pgm`` + ``<name>.yaml`` as map_saver does; returns ``(pgm, yaml)``.

    Cells with probability above ``occupied_thresh`` are written occupied, below ``free_thresh``
    free, others and NaN unknown, so that map_server reading the files with the same thresholds
    gets the same trinary map back.
    """
    if not 0.0 <= free_thresh < occupied_thresh <= 1.0:
        raise ValueError(
            f"need 0 <= free_thresh < occupied_thresh <= 1, got {free_thresh}, {occupied_thresh}"
        )
    pgm_path, yaml_path = _output_paths(directory_or_stem, name)
    pixels = occupancy_to_pixels(image.occupancy, occupied_thresh, free_thresh)
    atomic_write_bytes(pgm_path, _pgm_bytes(pixels))
    x, y, yaw = image.origin
    yaml_text = (
        f"image: {pgm_path.name}\n"
        f"resolution: {image.resolution!r}\n"
        f"origin: [{x!r}, {y!r}, {yaw!r}]\n"
        "negate: 0\n"
        f"occupied_thresh: {occupied_thresh!r}\n"
        f"free_thresh: {free_thresh!r}\n"
        "mode: trinary\n"
    )
    atomic_write_text(yaml_path, yaml_text)
    return pgm_path, yaml_path


_NUMBER = re.compile(r"^[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$")


def _parse_scalar(text: str) -> str | float | bool:
    text = text.strip()
    if len(text) >= 2 and text[0] == text[-1] and text[0] in "'\"":
        return text[1:-1]
    if _NUMBER.match(text):
        return float(text)
    if text.lower() in ("true", "false"):
        return text.lower() == "true"
    return text


def _strip_comment(line: str) -> str:
    quote = ""
    for k, ch in enumerate(line):
        if quote:
            quote = "" if ch == quote else quote
        elif ch in "'\"":
            quote = ch
        elif ch == "#" and (k == 0 or line[k - 1].isspace()):
            return line[:k]
    return line


def parse_map_yaml(path: Path) -> dict[str, object]:
    """The flat ``key: value`` YAML map_server uses (scalars and ``[a, b, c]`` lists)."""
    values: dict[str, object] = {}
    for lineno, raw in enumerate(path.read_text(encoding="utf-8").splitlines(), start=1):
        line = _strip_comment(raw).strip()
        if not line or line == "---":
            continue
        key, sep, value = line.partition(":")
        if not sep or not key.strip():
            raise ValueError(f"{path}:{lineno}: expected 'key: value', got {raw.strip()!r}")
        value = value.strip()
        if value.startswith("["):
            if not value.endswith("]"):
                raise ValueError(f"{path}:{lineno}: unterminated list {value!r}")
            values[key.strip()] = [_parse_scalar(v) for v in value[1:-1].split(",") if v.strip()]
        else:
            values[key.strip()] = _parse_scalar(value)
    return values


def _number(meta: dict[str, object], key: str, path: Path, default: float | None = None) -> float:
    value = meta.get(key, default)
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError(f"{path}: '{key}' must be a number, got {value!r}")
    return float(value)


def _load_pixels(image_path: Path) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Mean colour (0-255) of each pixel and a mask of fully transparent pixels."""
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(image_path) as img:
            img.load()
            has_alpha = img.mode in ("RGBA", "LA", "PA") or "transparency" in img.info
            if img.mode in ("I", "I;16", "I;16B", "F"):
                # 16-bit/float images: rescale to 0-255 so thresholds mean the same thing.
                arr = np.asarray(img, dtype=np.float64)
                top = 65535.0 if img.mode.startswith("I") else max(float(arr.max()), 1.0)
                return arr * (255.0 / top), np.zeros(arr.shape, dtype=bool)
            arr = np.asarray(img.convert("RGBA" if has_alpha else "RGB"), dtype=np.float64)
    except (UnidentifiedImageError, OSError) as exc:
        raise ValueError(f"{image_path}: cannot read the map image: {exc}") from None
    colour = arr[..., :3].mean(axis=-1)
    transparent = arr[..., 3] == 0 if has_alpha else np.zeros(colour.shape, dtype=bool)
    return colour, transparent


def pixels_to_occupancy(
    colour: NDArray[np.float64],
    transparent: NDArray[np.bool_],
    mode: str,
    negate: bool,
    occupied_thresh: float,
    free_thresh: float,
) -> NDArray[np.float64]:
    """map_server's interpretation of pixels (row 0 = top) as a grid with row 0 = lowest y."""
    if mode == "raw":
        occ = np.where(colour <= 100.0, colour / 100.0, np.nan)
    else:
        p = colour / 255.0 if negate else (255.0 - colour) / 255.0
        occ = np.full(p.shape, np.nan)
        occ[p > occupied_thresh] = 1.0
        occ[p < free_thresh] = 0.0
        if mode == "scale":
            between = (p >= free_thresh) & (p <= occupied_thresh)
            occ[between] = (p[between] - free_thresh) / (occupied_thresh - free_thresh)
    occ[transparent] = np.nan
    return np.ascontiguousarray(occ[::-1])


def read_map(yaml_path: str | Path) -> OccupancyImage:
    """Read a map_server map (YAML + PGM/PNG/any image Pillow reads).

    Raises ``ValueError`` naming the file for a missing key, a bad value or an unreadable image;
    ``FileNotFoundError`` when the YAML or its image does not exist.
    """
    yaml_path = Path(yaml_path)
    if not yaml_path.is_file():
        raise FileNotFoundError(f"{yaml_path}: map YAML not found")
    meta = parse_map_yaml(yaml_path)
    for key in ("image", "resolution", "origin"):
        if key not in meta:
            raise ValueError(f"{yaml_path}: missing '{key}' in the map YAML")
    image_path = Path(str(meta["image"]))
    if not image_path.is_absolute():
        image_path = yaml_path.parent / image_path
    if not image_path.is_file():
        raise FileNotFoundError(f"{yaml_path}: map image {image_path} not found")
    origin = meta["origin"]
    if not isinstance(origin, list) or len(origin) not in (2, 3) or not all(
        isinstance(v, float) for v in origin
    ):
        raise ValueError(f"{yaml_path}: 'origin' must be [x, y, yaw], got {origin!r}")
    mode = str(meta.get("mode", "trinary")).lower()
    if mode not in MAP_MODES:
        raise ValueError(f"{yaml_path}: unknown mode {mode!r} (expected one of {MAP_MODES})")
    occupied = _number(meta, "occupied_thresh", yaml_path, DEFAULT_OCCUPIED_THRESH)
    free = _number(meta, "free_thresh", yaml_path, DEFAULT_FREE_THRESH)
    negate_value = meta.get("negate", 0.0)
    if not isinstance(negate_value, (bool, float)):
        raise ValueError(f"{yaml_path}: 'negate' must be 0 or 1, got {negate_value!r}")
    negate = bool(negate_value)
    colour, transparent = _load_pixels(image_path)
    occ = pixels_to_occupancy(colour, transparent, mode, negate, occupied, free)
    try:
        return OccupancyImage(occ, _number(meta, "resolution", yaml_path), tuple(origin))
    except ValueError as exc:
        raise ValueError(f"{yaml_path}: {exc}") from None
