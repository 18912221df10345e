"""JSON writer: numpy types, non-finite floats, atomic replacement."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from bioslam.io import jsonio
from bioslam.io.jsonio import read_json, write_json


@dataclass
class _Node:
    id: int
    pose: tuple[float, float, float]


def test_numpy_and_dataclasses_become_plain_json(tmp_path):
    value = {
        "n": np.int64(3), "x": np.float32(0.5), "ok": np.bool_(True),
        "arr": np.arange(3), "nan": float("nan"), "node": _Node(1, (0.0, 1.0, np.pi)),
        "path": Path("a/b"), 7: "int key",
    }
    path = write_json(tmp_path / "s.json", value)
    back = json.loads(path.read_text())
    assert back == {
        "n": 3, "x": 0.5, "ok": True, "arr": [0, 1, 2], "nan": None,
        "node": {"id": 1, "pose": [0.0, 1.0, pytest.approx(np.pi)]}, "path": "a/b",
        "7": "int key",
    }


def test_failed_write_keeps_the_previous_file(tmp_path, monkeypatch):
    path = write_json(tmp_path / "s.json", {"a": 1})
    with pytest.raises(TypeError):
        write_json(path, {"a": object()})
    assert read_json(path) == {"a": 1}

    def boom(*_args):
        raise OSError("disk full")

    monkeypatch.setattr(jsonio.os, "replace", boom)
    with pytest.raises(OSError, match="disk full"):
        write_json(path, {"a": 2})
    assert read_json(path) == {"a": 1}
    assert [p.name for p in tmp_path.iterdir()] == ["s.json"]


def test_read_json_names_file_and_line(tmp_path):
    (tmp_path / "bad.json").write_text('{\n  "a": 1,\n}\n')
    with pytest.raises(ValueError, match=r"bad.json:3:"):
        read_json(tmp_path / "bad.json")


def test_atomic_writes_get_ordinary_permissions(tmp_path):
    import os
    import stat

    from bioslam.io.jsonio import atomic_write_bytes

    mask = os.umask(0o022)
    try:
        path = atomic_write_bytes(tmp_path / "x.bin", b"abc")
    finally:
        os.umask(mask)
    assert stat.S_IMODE(path.stat().st_mode) == 0o644


@pytest.mark.parametrize("indent", [2, 4])
def test_streamed_json_is_write_jsons_bytes_with_arrays_encoded_as_they_come(tmp_path, indent):
    import numpy as np

    from bioslam.io.jsonio import write_json, write_json_streamed

    def items(n):
        for k in range(n):
            yield {"id": k, "pose": np.array([k * 0.1, -k, np.nan]), "nested": {"a": [k, []]},
                   "kind": "loop\n\u00e9"}  # fmt: skip

    cases = [
        {"nodes": items(3), "links": items(0), "count": 7, "meta": {"x": [1, {"y": None}]}},
        {"only": items(1)},
        {"plain": 1.5, "empty": [], "text": "a\"b"},
        {},
    ]
    for n, fields in enumerate(cases):
        plain = {k: list(v) if hasattr(v, "__next__") else v for k, v in fields.items()}
        fields = {k: items(len(v)) if hasattr(v, "__next__") else v for k, v in plain.items()}
        expected = write_json(tmp_path / f"a{n}.json", plain, indent=indent).read_bytes()
        got = write_json_streamed(tmp_path / f"b{n}.json", fields, indent=indent).read_bytes()
        assert got == expected, n


def test_the_cognitive_maps_streamed_json_is_its_dict(tmp_path):
    import json

    from bioslam.cognitive_map import CognitiveMap
    from bioslam.io.jsonio import write_json_streamed

    cmap = CognitiveMap()
    for k in range(6):  # a square driven past its start: links, and a loop
        cmap.integrate_odometry((1.0, 0.0, 1.5707963), stamp=float(k))
        cmap.update(k % 4, k < 4, (1.0, 1.0, 0.0), float(k))
    whole = cmap.to_dict()
    assert len(whole["nodes"]) >= 4 and len(whole["links"]) >= 4
    path = write_json_streamed(tmp_path / "map.json", cmap.json_fields())
    assert json.loads(path.read_text()) == whole
