"""The learned boundary views, stored compactly and exactly, in fixed-size chunks.

A view's boundary-cell activity ``B`` (:mod:`bioslam.views`) is 1008 cells in the default
layout, float32: 4 kB a view. A run learns thousands of views an hour (22,000 on a 60 min
adversarial warehouse route), keeps them for the whole run and compares them at every look,
so the templates were the largest thing a long run held (93 MB an hour in a doubling array,
which needs twice that for a moment each time it grows).

Most of ``B`` is exactly zero: a boundary cell's field is cut off a few widths from the
walls (:mod:`bioslam.boundary`), and a wall lights only the cells near it; 70 % of the cells
are zero at the median on the warehouse, 83 % on the maze. :class:`ViewStore` keeps per view
one bit per cell (zero or not), the nonzero values themselves (float32, as before) and where
its values begin; a compiled kernel decodes the cells in order, only as far as it reads
(:func:`decode_cells`). Nothing is rounded: every ``S`` (Eq. 8) and every match is that of
the dense store.

Views are held in chunks of ``CHUNK_VIEWS``, each a tuple of arrays, in a Numba typed list
(:attr:`ViewStore.chunks`, what the kernels take): growing adds a chunk and copies nothing.
A chunk's value array is allocated for its views at their densest, but the values are
written from its start and the pages not yet written are not resident (fresh zeroed pages),
so what a chunk holds in memory is its views' nonzero values. The typed list is only made
and extended by compiled functions cached on disk (calling its methods from Python would
compile them at every start: half a second and 60 MB).

Given a directory (``spill_dir``), a chunk's zero bits and values (1.5 kB of a view's 2.1 kB
on the warehouse) live in an unlinked file there, mapped into memory: the kernels read them
as before, but only the views a look compares are read, a few dozen of thousands, and
:meth:`ViewStore.drop_pages` hands the pages read so far back to the system's page cache
(``madvise``): the file's data stays, in the page cache while memory is free and on disk
when it is not, and a view read again comes back at its first read, from memory. What the
process holds for a view is then its value start, block sums, coverage and ring key (the
candidate selection reads those of every view). A chunk the file cannot take (a full disk:
its space is reserved before it is mapped) is held in memory, and so is every later one.
"""

from __future__ import annotations

import mmap
import os
import tempfile
from pathlib import Path
from typing import IO, Any

import numpy as np
from numba import njit
from numba.typed import List
from numpy.typing import NDArray

#: How the views' values are stored: a scan matches its own view exactly (S = 0).
VIEW_DTYPE = np.float32

#: Views per chunk (a power of two: a view's chunk is ``id >> CHUNK_SHIFT``).
CHUNK_SHIFT = 10
CHUNK_VIEWS = 1 << CHUNK_SHIFT
CHUNK_MASK = CHUNK_VIEWS - 1

# A chunk: (zero bits (n, ceil(cells / 8)) uint8, each view's first value in ``values``
# (n,) int32, block sums (n, blocks) float64, coverage (n, cols) bool, ring keys
# (n, rings) float64, values (n * cells,) float32), n = CHUNK_VIEWS.
Chunk = tuple[NDArray[np.uint8], NDArray[np.int32], NDArray[np.float64], NDArray[np.bool_],
              NDArray[np.float64], NDArray[np.float32]]  # fmt: skip


@njit(cache=True)
def decode_cells(
    bits: NDArray[np.uint8], values: NDArray[np.float32], pos: int, first: int, count: int,
    out: NDArray[np.float64],
) -> int:  # fmt: skip
    """Cells ``first .. first + count - 1`` of a view into ``out`` (same indices), from its
    zero bits (``np.packbits`` order) and ``values``, where the value of the first nonzero
    of those cells is at ``pos``; the position after the last one read."""
    for i in range(first, first + count):
        if (bits[i >> 3] >> (7 - (i & 7))) & 1:
            out[i] = values[pos]
            pos += 1
        else:
            out[i] = 0.0
    return pos


@njit(cache=True)
def _encode(
    row: NDArray[np.float32], bits: NDArray[np.uint8], values: NDArray[np.float32], pos: int
) -> int:
    """Write ``row`` as one view: its zero bits, its nonzero values into ``values`` from
    ``pos``; the position after the last."""
    bits[:] = 0
    for i in range(row.size):
        if row[i] != 0.0:
            bits[i >> 3] |= np.uint8(1 << (7 - (i & 7)))
            values[pos] = row[i]
            pos += 1
    return pos


@njit(cache=True)
def _new_chunks(first: Any) -> Any:
    chunks = List()
    chunks.append(first)
    return chunks


@njit(cache=True)
def _add_chunk(chunks: Any, chunk: Any) -> None:
    chunks.append(chunk)


#: A chunk's file region and its values start on a multiple of this (a page).
_PAGE = mmap.ALLOCATIONGRANULARITY
#: Whether the system can reserve a file's space and drop mapped pages (POSIX with
#: ``madvise``: Linux, the BSDs); elsewhere the views stay in memory.
_CAN_MAP = hasattr(os, "posix_fallocate") and hasattr(mmap, "MADV_DONTNEED")


def _pages(nbytes: int) -> int:
    """``nbytes`` rounded up to whole pages."""
    return -(-nbytes // _PAGE) * _PAGE


class ViewStore:
    """Per view: ``B`` (exact, without its zeros), its block sums, coverage and ring key.

    ``cells``: the size of ``B``; ``blocks``, ``cols``, ``rings``: the widths of the sums,
    coverage and key rows. ``spill_dir``: keep the zero bits and values in an unlinked file
    there (module doc); None: in memory.
    """

    def __init__(
        self, cells: int, blocks: int, cols: int, rings: int, spill_dir: str | Path | None = None
    ) -> None:
        if cells < 1:
            raise ValueError(f"a view needs at least one cell, got {cells}")
        self.cells = int(cells)
        self._widths = ((self.cells + 7) // 8, blocks, cols, rings)
        self._chunks: list[Chunk] = []
        self.chunks: Any = None  # the typed list of the same chunks, for the kernels
        self._filled = 0  # values written in the last chunk
        self._size = 0
        self.value_count = 0
        self.file_value_count = 0  # of which in the file
        self._maps: list[mmap.mmap] = []  # the chunks' file regions, mapped
        self._file: IO[bytes] | None = None
        if spill_dir is not None and _CAN_MAP:
            try:
                self._file = tempfile.TemporaryFile(dir=spill_dir, buffering=0)  # noqa: SIM115
            except OSError:
                self._file = None
        self._file_end = 0

    def _decoded_parts(self) -> tuple[NDArray[np.uint8], NDArray[np.float32]]:
        """A new chunk's zero bits and values: in the file while it takes them, else in
        memory (a fresh array is resident only as it is written)."""
        n, packed = CHUNK_VIEWS, self._widths[0]
        if self._file is not None:
            start = _pages(n * packed)
            size = _pages(start + n * self.cells * np.dtype(VIEW_DTYPE).itemsize)
            try:
                # reserved first: writing a mapped page the disk has no room for would kill
                # the process (SIGBUS)
                os.posix_fallocate(self._file.fileno(), self._file_end, size)
                region = mmap.mmap(self._file.fileno(), size, offset=self._file_end)
            except (OSError, ValueError):
                self.close()
            else:
                self._maps.append(region)
                self._file_end += size
                bits = np.frombuffer(region, np.uint8, n * packed).reshape(n, packed)
                return bits, np.frombuffer(region, VIEW_DTYPE, n * self.cells, start)
        return np.zeros((n, packed), dtype=np.uint8), np.zeros(n * self.cells, dtype=VIEW_DTYPE)

    def _new_chunk(self) -> Chunk:
        n = CHUNK_VIEWS
        _, blocks, cols, rings = self._widths
        bits, values = self._decoded_parts()
        chunk = (
            bits,
            np.zeros(n, dtype=np.int32),
            np.zeros((n, blocks)),
            np.zeros((n, cols), dtype=np.bool_),
            np.zeros((n, rings)),
            values,
        )
        if self.chunks is None:
            self.chunks = _new_chunks(chunk)
        else:
            _add_chunk(self.chunks, chunk)
        self._chunks.append(chunk)
        self._filled = 0
        return chunk

    def append(
        self, b: NDArray[np.float32], sums: NDArray[np.float64], cover: NDArray[np.bool_],
        key: NDArray[np.float64],
    ) -> int:  # fmt: skip
        """Store a view; its id."""
        row = np.asarray(b, dtype=VIEW_DTYPE).reshape(-1)
        if row.size != self.cells:
            raise ValueError(f"a view has {self.cells} cells, got {row.size}")
        view_id, at = self._size, self._size & CHUNK_MASK
        bits, starts, block_sums, coverage, keys, values = (
            self._new_chunk() if at == 0 else self._chunks[-1]
        )
        starts[at] = self._filled
        filled = _encode(row, bits[at], values, self._filled)
        self.value_count += filled - self._filled
        if len(self._maps) == len(self._chunks):  # this chunk is in the file
            self.file_value_count += filled - self._filled
        self._filled = filled
        block_sums[at], coverage[at], keys[at] = sums, cover, key
        self._size += 1
        return view_id

    def __len__(self) -> int:
        return self._size

    def _part(self, view_id: int, part: int) -> NDArray:  # type: ignore[type-arg]
        if not 0 <= view_id < self._size:
            raise IndexError(f"view id {view_id} out of range ({self._size} views)")
        return self._chunks[view_id >> CHUNK_SHIFT][part][view_id & CHUNK_MASK]

    def row(self, view_id: int) -> NDArray[np.float32]:
        """View ``view_id``'s ``B``, dense (a copy)."""
        nonzero = np.unpackbits(self._part(view_id, 0), count=self.cells).astype(bool)
        start = int(self._part(view_id, 1))
        out = np.zeros(self.cells, dtype=VIEW_DTYPE)
        out[nonzero] = self._chunks[view_id >> CHUNK_SHIFT][5][start : start + nonzero.sum()]
        return out

    def cover(self, view_id: int) -> NDArray[np.bool_]:
        return self._part(view_id, 3)

    def drop_pages(self) -> None:
        """Hand the file's pages read or written so far back to the page cache (module
        doc): the process holds none of them until a view is read again."""
        for region in self._maps:
            region.madvise(mmap.MADV_DONTNEED)

    def close(self) -> None:
        """Hold the chunks made from now on in memory (those in the file stay readable:
        the file is deleted when the store is)."""
        if self._file is not None:
            self._file.close()
            self._file = None

    @property
    def in_file(self) -> int:
        """Views whose bits and values are in the file."""
        return min(len(self._maps) * CHUNK_VIEWS, self._size)

    @property
    def resident_bytes(self) -> int:
        """Bytes the views take in memory (the file's pages read since the last
        :meth:`drop_pages` aside): every array but the values' unwritten tail and the parts
        in the file."""
        fixed = sum(a.nbytes for chunk in self._chunks for a in chunk[1:5])
        fixed += sum(chunk[0].nbytes for chunk in self._chunks[len(self._maps) :])
        held = self.value_count - self.file_value_count
        return int(fixed + held * np.dtype(VIEW_DTYPE).itemsize)
