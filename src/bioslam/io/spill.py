"""The experiences' stored scans, and the per-scan columns, kept in a file instead of in memory.

Every experience keeps the scan it was made with (the loop closures fuse them into submaps,
:mod:`bioslam.closure`): about 500 float32 points, 4 kB an experience, 50-100 MB an hour of
40 Hz data, for the whole run. Only the few around a candidate place are read, when its
submap is built, so they need not be resident: :class:`SpilledScans` appends each to an
unlinked temporary file and reads it back when asked. The values come back bit for bit (a
run is the same with or without it); what the process holds is two integers a scan. The
operating system's page cache keeps the recent part of the file in memory while memory is
free and drops it (the data is on disk) when it is not.

A scan that cannot be written (a full disk) is kept in memory instead, and so is every
later one: nothing is lost, only the saving.

The per-scan columns (each scan's stamp, the experience its pose hangs off and the offset from
it, its odometry pose and covariance, its processing time: 97 bytes a scan, 14 MB an hour at
40 Hz) are read only when the outputs are written, after the last scan: :class:`SpilledRows`
appends them to a file in blocks and reads them back whole.
"""

from __future__ import annotations

import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import IO, Any, overload

import numpy as np
from numpy.typing import ArrayLike, DTypeLike, NDArray

from bioslam.growing import GrowingArray

Points = NDArray[np.float32]

_IN_MEMORY = -2  # a scan's count when it is held in memory (the file refused it)
_NONE = -1  # an experience without a stored scan


class SpilledScans(Sequence):  # type: ignore[type-arg]
    """A list of ``(n, 2)`` float32 point arrays (or ``None``) whose contents live in an
    unlinked temporary file in ``directory`` (the system's temporary directory when None):
    ``append`` writes, indexing reads back a fresh array. For the cognitive map's payloads
    (:class:`bioslam.cognitive_map.CognitiveMap`)."""

    def __init__(self, directory: str | Path | None = None) -> None:
        # open for the store's life, closed by close() or when collected
        self._file: IO[bytes] | None = tempfile.TemporaryFile(dir=directory, buffering=0)  # noqa: SIM115
        self._offsets = GrowingArray(np.int64)
        self._counts = GrowingArray(np.int64)
        self._held: dict[int, Points] = {}
        self._end = 0
        self._writing = True

    def append(self, points: ArrayLike | None) -> None:
        index = len(self._counts)
        if points is None:
            self._offsets.append(self._end)
            self._counts.append(_NONE)
            return
        pts = np.ascontiguousarray(points, dtype=np.float32).reshape(-1, 2)
        if self._writing and self._file is not None:
            try:
                self._write(pts.tobytes())
            except OSError:  # a full or failing disk: this scan and the later ones in memory
                self._writing = False
        if not self._writing or self._file is None:
            self._held[index] = pts.copy()
            self._offsets.append(self._end)
            self._counts.append(_IN_MEMORY)
            return
        self._offsets.append(self._end)
        self._counts.append(pts.shape[0])
        self._end += pts.nbytes

    def _write(self, data: bytes) -> None:
        assert self._file is not None
        _write_at(self._file, self._end, data)

    @overload
    def __getitem__(self, index: int) -> Points | None: ...

    @overload
    def __getitem__(self, index: slice) -> list[Points | None]: ...

    def __getitem__(self, index: int | slice) -> Points | list[Points | None] | None:
        if isinstance(index, slice):
            return [self[i] for i in range(*index.indices(len(self)))]
        i = range(len(self))[index]  # negative indices, and IndexError beyond the end
        count = int(self._counts[i])
        if count == _NONE:
            return None
        if count == _IN_MEMORY:
            return self._held[i].copy()
        out = np.empty((count, 2), dtype=np.float32)
        if count:
            self._read_into(out, int(self._offsets[i]))
        return out

    def _read_into(self, out: Points, offset: int) -> None:
        if self._file is None:
            raise ValueError("the scans' file was closed")
        _read_at(self._file, offset, out)

    def __len__(self) -> int:
        return len(self._counts)

    @property
    def file_bytes(self) -> int:
        """Bytes of points in the file (what memory holds instead: 16 bytes a scan)."""
        return self._end

    @property
    def held_bytes(self) -> int:
        """Bytes of points held in memory because the file refused them."""
        return sum(points.nbytes for points in self._held.values())

    def close(self) -> None:
        """Stop using the file (it is deleted); scans already written can no longer be
        read, later ones are held in memory."""
        if self._file is not None:
            self._file.close()
            self._file = None


#: Rows a :class:`SpilledRows` holds in memory before it writes them (a block).
SPILL_BLOCK_ROWS = 4096


class SpilledRows:
    """Rows of ``width`` values of ``dtype`` (``width=0``: scalars) appended one at a time,
    like :class:`bioslam.growing.GrowingArray`, but written to an unlinked temporary file in
    ``directory`` a block of ``block`` rows at a time; :meth:`array` (and :meth:`view`)
    reads them back, bit for bit, into a fresh array. Memory holds one block.

    A block the file refuses (a full disk) is kept in memory, and so is every later one."""

    def __init__(
        self, dtype: DTypeLike = np.float64, width: int = 0, directory: str | Path | None = None,
        block: int = SPILL_BLOCK_ROWS,
    ) -> None:  # fmt: skip
        self._shape: tuple[int, ...] = () if width == 0 else (int(width),)
        self._buffer: NDArray[Any] = np.empty((max(int(block), 1), *self._shape), dtype=dtype)
        self._filled = 0  # rows in the buffer
        self._written = 0  # rows in the file
        self._held: list[NDArray[Any]] = []  # blocks the file refused
        try:
            self._file: IO[bytes] | None = tempfile.TemporaryFile(dir=directory, buffering=0)  # noqa: SIM115
        except OSError:
            self._file = None

    def append(self, row: ArrayLike) -> None:
        self._buffer[self._filled] = row
        self._filled += 1
        if self._filled == self._buffer.shape[0]:
            self._flush()

    def _flush(self) -> None:
        block = self._buffer[: self._filled]
        if self._file is not None and not self._held:
            try:
                _write_at(self._file, self._written * self._row_bytes, block.tobytes())
                self._written += self._filled
                self._filled = 0
                return
            except OSError:  # this block and every later one in memory
                pass
        self._held.append(block.copy())
        self._filled = 0

    @property
    def _row_bytes(self) -> int:
        return int(self._buffer[:1].nbytes)

    def __len__(self) -> int:
        return self._written + sum(len(block) for block in self._held) + self._filled

    def array(self) -> NDArray[Any]:
        """Every row so far, a fresh array."""
        out = np.empty((len(self), *self._shape), dtype=self._buffer.dtype)
        if self._written:
            assert self._file is not None
            _read_at(self._file, 0, out[: self._written])
        at = self._written
        for block in (*self._held, self._buffer[: self._filled]):
            out[at : at + len(block)] = block
            at += len(block)
        return out

    view = array

    def __array__(self, dtype: DTypeLike = None, copy: bool | None = None) -> NDArray[Any]:
        out = self.array()
        return out.astype(dtype) if dtype is not None else out

    @property
    def nbytes(self) -> int:
        """Bytes held in memory (the buffer and the blocks the file refused)."""
        return int(self._buffer.nbytes + sum(block.nbytes for block in self._held))

    @property
    def file_bytes(self) -> int:
        """Bytes of rows in the file."""
        return self._written * self._row_bytes


def _write_at(file: IO[bytes], offset: int, data: bytes) -> None:
    """All of ``data`` into ``file`` at ``offset`` (an unbuffered file may write less)."""
    file.seek(offset)
    view = memoryview(data)
    while view:
        written = file.write(view)
        if not written:
            raise OSError("nothing written")
        view = view[written:]


def _read_at(file: IO[bytes], offset: int, out: NDArray[Any]) -> None:
    """Fill ``out`` (contiguous) from ``file`` at ``offset``."""
    file.seek(offset)
    view = memoryview(out.reshape(-1)).cast("B")
    while view:
        got = file.readinto(view)
        if not got:
            raise OSError(f"the spill file ended {view.nbytes} bytes early")
        view = view[got:]
