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


def _rows(n: int, width: int, dtype: type = np.float64, seed: int = 2) -> np.ndarray:
    rng = np.random.default_rng(seed)
    shape = (n, max(width, 1))
    if np.issubdtype(dtype, np.integer):
        rows = rng.integers(-128, 128, size=shape).astype(dtype)
    else:
        reach = np.finfo(dtype).maxexp * 0.3
        scale = 2.0 ** rng.uniform(-reach, reach, size=shape)
        rows = (rng.normal(size=shape) * scale).astype(dtype)
        rows[0, 0], rows[1, 0], rows[2, 0] = np.nan, -0.0, np.inf
    return rows if width else rows[:, 0]


@pytest.mark.parametrize(("dtype", "width"), [(np.float64, 3), (np.float64, 0), (np.int8, 0),
                                              (np.float32, 6)])  # fmt: skip
def test_rows_come_back_bit_for_bit_across_blocks_in_a_block_of_memory(tmp_path, dtype, width):
    """Per-scan columns in a file: every row back as appended, whatever the block edges,
    while memory holds one block however many rows were appended."""
    from bioslam.growing import GrowingArray
    from bioslam.io.spill import SpilledRows

    kept = _rows(1003, width, dtype)
    store = SpilledRows(dtype, width, tmp_path, block=16)
    reference = GrowingArray(dtype, width)
    held = store.nbytes
    for k, row in enumerate(kept):
        store.append(row)
        reference.append(row)
        if k in (0, 15, 16, 500):
            assert store.array().tobytes() == reference.view().tobytes()
    assert len(store) == len(kept)
    assert store.array().tobytes() == kept.tobytes() == np.asarray(store).tobytes()
    assert store.array().shape == kept.shape and store.array().dtype == kept.dtype
    assert store.nbytes == held == 16 * kept[:1].nbytes  # one block, not the 1003 rows
    assert store.file_bytes == 992 * kept[:1].nbytes
    assert list(tmp_path.iterdir()) == []  # unlinked


def test_a_block_of_rows_the_file_refuses_is_kept_in_memory_and_so_are_later_ones(
    tmp_path, monkeypatch
):
    import bioslam.io.spill as spill

    kept = _rows(50, 3)
    store = spill.SpilledRows(np.float64, 3, tmp_path, block=8)
    for row in kept[:20]:
        store.append(row)
    written = store.file_bytes
    refusals = []

    def full(file, offset, data):
        refusals.append(offset)
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(spill, "_write_at", full)
    for row in kept[20:]:
        store.append(row)
    assert store.file_bytes == written == 16 * 24
    assert len(refusals) == 1  # once refused, later blocks are not tried
    assert store.array().tobytes() == kept.tobytes()
    assert store.nbytes == (8 + 32) * 24  # the buffer and the four blocks held
