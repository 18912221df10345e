"""JSON output (summaries, the cognitive map) and atomic file replacement.

Files are written to a temporary sibling and renamed into place, so a run interrupted half-way
never leaves a truncated result where a previous good one was.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import tempfile
from collections.abc import Iterator, Mapping
from dataclasses import asdict, is_dataclass
from pathlib import Path
from typing import Any

import numpy as np


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


@contextlib.contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """A temporary path beside ``path`` (same suffix, so that writers choosing a format by
    the name still do) to write to; on leaving the block it is synced and renamed onto
    ``path``. On an exception (a full disk, Ctrl-C) it is removed and ``path`` is untouched:
    no file is ever half-written."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=f".tmp{path.suffix}",
                                dir=path.parent)
    os.close(fd)
    tmp = Path(name)
    try:
        yield tmp
        with tmp.open("rb+") as fh:
            os.fsync(fh.fileno())
        # mkstemp creates the file private (0600); results are meant to be shared like any
        # other file the user writes.
        os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def atomic_write_bytes(path: str | Path, data: bytes) -> Path:
    """Write ``data`` to ``path`` through a temporary file in the same directory + rename."""
    path = Path(path)
    with atomic_path(path) as tmp, tmp.open("wb") as fh:
        fh.write(data)
    return path


def atomic_write_text(path: str | Path, text: str) -> Path:
    """UTF-8 text version of :func:`atomic_write_bytes`."""
    return atomic_write_bytes(path, text.encode("utf-8"))


def to_jsonable(value: Any) -> Any:
    """Convert numpy scalars/arrays, dataclasses, paths, sets and tuples into JSON types.

    Non-finite floats become ``None`` (JSON has no NaN/inf and strict parsers reject them).
    """
    if isinstance(value, Mapping):
        return {str(k): to_jsonable(v) for k, v in value.items()}
    if is_dataclass(value) and not isinstance(value, type):
        return to_jsonable(asdict(value))
    if isinstance(value, np.ndarray):
        return to_jsonable(value.tolist())
    if isinstance(value, (list, tuple, set, frozenset)):
        return [to_jsonable(v) for v in value]
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        f = float(value)
        return f if math.isfinite(f) else None
    if isinstance(value, Path):
        return str(value)
    if value is None or isinstance(value, str):
        return value
    raise TypeError(f"cannot write a {type(value).__name__} as JSON")


def dumps_json(value: Any, indent: int | None = 2) -> str:
    """Serialise ``value`` (see :func:`to_jsonable`) as strict JSON text."""
    return json.dumps(to_jsonable(value), indent=indent, allow_nan=False)


def write_json(path: str | Path, value: Any, indent: int | None = 2) -> Path:
    """Write ``value`` as JSON to ``path`` atomically; returns the path. The text goes to
    the file as it is encoded (the cognitive map of an hour's run is megabytes of it, and
    as one string and its UTF-8 copy it would double the memory its objects take)."""
    path = Path(path)
    jsonable = to_jsonable(value)
    with atomic_path(path) as tmp, tmp.open("w", encoding="utf-8") as fh:
        json.dump(jsonable, fh, indent=indent, allow_nan=False)
        fh.write("\n")
    return path


def write_json_streamed(path: str | Path, fields: Mapping[str, Any], indent: int = 2) -> Path:
    """:func:`write_json` of the object ``fields`` (the same bytes), where a value that is an
    iterator (a generator) is written as an array whose entries are encoded and written one
    at a time as it yields them: a long array of small objects is never held whole, neither
    as objects nor as text."""
    path = Path(path)
    pad = " " * indent

    def encoded(value: Any, depth: int) -> str:
        text = json.dumps(to_jsonable(value), indent=indent, allow_nan=False)
        return text.replace("\n", "\n" + pad * depth)

    with atomic_path(path) as tmp, tmp.open("w", encoding="utf-8") as fh:
        if not fields:
            fh.write("{}\n")
            return path
        fh.write("{")
        for n, (key, value) in enumerate(fields.items()):
            fh.write(("," if n else "") + "\n" + pad + json.dumps(str(key)) + ": ")
            if not isinstance(value, Iterator):
                fh.write(encoded(value, 1))
                continue
            empty = True
            for item in value:
                fh.write(("[" if empty else ",") + "\n" + pad * 2 + encoded(item, 2))
                empty = False
            fh.write("[]" if empty else "\n" + pad + "]")
        fh.write("\n}\n")
    return path


def read_json(path: str | Path) -> Any:
    """Read a JSON file; a parse error names the file, line and column."""
    path = Path(path)
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}:{exc.lineno}:{exc.colno}: invalid JSON: {exc.msg}") from None
