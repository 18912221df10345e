"""The experiences' scans kept in a file: read back bit for bit, and never lost."""

from __future__ import annotations

import numpy as np
import pytest

from bioslam.io.spill import SpilledScans


def scans(seed: int = 0) -> list[np.ndarray | None]:
    rng = np.random.default_rng(seed)
    out: list[np.ndarray | None] = [
        (rng.normal(size=(n, 2)) * 10.0 ** rng.integers(-3, 4)).astype(np.float32)
        for n in (500, 1, 0, 37, 1081)
    ]
    out.insert(2, None)
    weird = np.array([[np.nan, np.inf], [-0.0, np.float32(1e-42)], [3e38, -3e38]], np.float32)
    return [*out, weird]


def test_scans_come_back_bit_for_bit_in_order(tmp_path):
    store = SpilledScans(tmp_path)
    kept = scans()
    for points in kept:
        store.append(points)
    assert len(store) == len(kept)
    assert store.file_bytes == sum(p.nbytes for p in kept if p is not None)
    assert store.held_bytes == 0
    for i, points in enumerate(kept):
        got = store[i]
        if points is None:
            assert got is None
            continue
        assert got.dtype == np.float32 and got.shape == points.reshape(-1, 2).shape
        assert got.tobytes() == points.tobytes()  # NaN, signed zero, subnormals included
    assert store[-1].tobytes() == kept[-1].tobytes()
    assert [p is None for p in store[1:4]] == [False, True, False]
    with pytest.raises(IndexError):
        store[len(kept)]
    # a read is the caller's own copy: changing it changes nothing stored
    got = store[0]
    got[:] = 0.0
    assert store[0].tobytes() == kept[0].tobytes()
    # the file is unlinked: nothing is left in the directory
    assert list(tmp_path.iterdir()) == []


def test_a_scan_the_file_refuses_is_kept_in_memory_and_so_are_later_ones(tmp_path):
    store = SpilledScans(tmp_path)
    kept = scans(1)
    store.append(kept[0])

    def full(_data: bytes) -> None:
        raise OSError(28, "No space left on device")

    store._write = full  # type: ignore[method-assign]
    for points in kept[1:]:
        store.append(points)
    assert store.file_bytes == kept[0].nbytes
    assert store.held_bytes == sum(p.nbytes for p in kept[1:] if p is not None)
    for i, points in enumerate(kept):
        got = store[i]
        assert (got is None) == (points is None)
        if points is not None:
            assert got.tobytes() == points.tobytes()
