"""A parameter grid: a TOML file of setting lists expanded into every combination.

A grid file names settings with dotted keys, as the tables of a ``--config`` file would nest
them, and gives each a list of values to try; a plain value is a setting fixed for every run::

    mode = ["full", "odometry-only"]
    "odometry.resolution" = [0.03, 0.05]
    [loop_closure]
    min_score = [0.8, 0.9]
    max_scans = 2000            # a single value: every run reads the first 2000 scans

Two keys are not SLAM settings but say how a run is made: ``mode`` (``full`` or
``odometry-only``) and ``max_scans`` (read only the first N scans of each log). Every
combination is checked against the configuration's own fields before any run starts, so a
misspelt key fails the batch at once instead of failing every run.
"""

from __future__ import annotations

import dataclasses
import hashlib
import itertools
import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from bioslam.config import SLAMConfig, config_from_dict

MODES = ("full", "odometry-only")
RUN_KEYS = ("mode", "max_scans")
_ID_LIMIT = 80


@dataclass(frozen=True)
class GridPoint:
    """One configuration of a grid.

    Attributes:
        config_id: a file-name-safe name made of the settings that vary (stable across grids,
            so that a re-run finds the runs it already has).
        settings: every setting of this point, dotted keys, run keys included.
        varying: the keys the grid varies (for the results table's columns).
    """

    config_id: str
    settings: dict[str, Any]
    varying: tuple[str, ...] = field(default=())

    @property
    def mode(self) -> str:
        return str(self.settings.get("mode", "full"))

    @property
    def max_scans(self) -> int | None:
        value = self.settings.get("max_scans")
        return None if value is None else int(value)

    def overrides(self) -> dict[str, Any]:
        """The SLAM settings as the nested dict :func:`bioslam.config.config_from_dict` takes."""
        return nest({k: v for k, v in self.settings.items() if k not in RUN_KEYS})

    def config(self) -> SLAMConfig:
        return config_from_dict(self.overrides(), f"grid point {self.config_id}")


def flatten(table: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    """Nested tables to dotted keys: ``{"a": {"b": 1}}`` and ``{"a.b": 1}`` both give ``a.b``."""
    flat: dict[str, Any] = {}
    for key, value in table.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            flat.update(flatten(value, f"{name}."))
        else:
            flat[name] = value
    return flat


def nest(flat: dict[str, Any]) -> dict[str, Any]:
    """Dotted keys back to nested dicts; ``a.b`` and a plain ``a`` cannot both be given."""
    nested: dict[str, Any] = {}
    for key, value in flat.items():
        *parents, leaf = key.split(".")
        node = nested
        for part in parents:
            node = node.setdefault(part, {})
            if not isinstance(node, dict):
                raise ValueError(f"setting {key!r} lies inside {part!r}, which has a value")
        if isinstance(node.get(leaf), dict):
            raise ValueError(f"setting {key!r} is a table of settings, not a value")
        node[leaf] = value
    return nested


def _default_value(key: str) -> Any:
    """The default of a dotted setting (``None`` for a run key or an unknown name)."""
    obj: Any = SLAMConfig()
    for part in key.split("."):
        if not dataclasses.is_dataclass(obj) or not hasattr(obj, part):
            return None
        obj = getattr(obj, part)
    return obj


def _axis(key: str, value: Any) -> list[Any]:
    """The values a grid key takes. A list is a list of alternatives, except for a setting whose
    value is itself a sequence (a tuple in the configuration): there only a list of lists is."""
    sequence_setting = isinstance(_default_value(key), tuple)
    if not isinstance(value, list) or (sequence_setting and not all(
        isinstance(v, list) for v in value
    )):
        return [value]
    if not value:
        raise ValueError(f"grid key {key!r} has an empty list of values")
    return value


def _format_value(value: Any) -> str:
    if isinstance(value, float):
        return repr(value)
    if isinstance(value, list):
        return "-".join(_format_value(v) for v in value)
    return str(value).lower() if isinstance(value, bool) else str(value)


def config_id(settings: dict[str, Any], varying: tuple[str, ...]) -> str:
    """``key=value`` pairs of the varying settings joined by ``,``; characters a file name
    cannot hold become ``_``, and an overlong name is cut and given a hash of the full one."""
    if not varying:
        return "default"
    text = ",".join(f"{key}={_format_value(settings[key])}" for key in varying)
    safe = re.sub(r"[^A-Za-z0-9._=,+-]", "_", text)
    if len(safe) <= _ID_LIMIT:
        return safe
    digest = hashlib.sha1(text.encode()).hexdigest()[:10]
    return f"{safe[: _ID_LIMIT - 11]}~{digest}"


def _check_run_keys(settings: dict[str, Any], where: str) -> None:
    mode = settings.get("mode", "full")
    if mode not in MODES:
        raise ValueError(f"{where}: mode must be one of {', '.join(MODES)}, got {mode!r}")
    max_scans = settings.get("max_scans")
    if max_scans is not None and (not isinstance(max_scans, int) or max_scans < 2):
        raise ValueError(f"{where}: max_scans must be an integer >= 2, got {max_scans!r}")


def expand_grid(table: dict[str, Any], where: str = "grid") -> list[GridPoint]:
    """Every combination of the grid's lists, in the file's key order (the last key varies
    fastest); each is validated against the configuration."""
    flat = flatten(table)
    axes = {key: _axis(key, value) for key, value in flat.items()}
    varying = tuple(key for key, values in axes.items() if len(values) > 1)
    points: list[GridPoint] = []
    seen: dict[str, dict[str, Any]] = {}
    for combination in itertools.product(*axes.values()):
        settings = dict(zip(axes, combination, strict=True))
        point = GridPoint(config_id(settings, varying), settings, varying)
        _check_run_keys(settings, f"{where} ({point.config_id})")
        point.config()  # raises ValueError naming an unknown setting
        if point.config_id in seen:
            raise ValueError(f"{where}: two grid points are both named {point.config_id!r}")
        seen[point.config_id] = settings
        points.append(point)
    return points


def load_grid(path: str | Path | None) -> list[GridPoint]:
    """Read and expand a grid file; no file is the one default configuration."""
    if path is None:
        return expand_grid({})
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"grid file {path} does not exist")
    try:
        table = tomllib.loads(path.read_text(encoding="utf-8"))
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"{path}: cannot parse the grid: {exc}") from None
    return expand_grid(table, str(path))
