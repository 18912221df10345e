"""The learned boundary views, stored compactly and exactly, in fixed-size chunks.

A view's boundary-cell activity ``B`` (:mod:`bioslam.views`) is 1008 cells in the default
layout, float32: 4 kB a view. A run learns thousands of views an hour (23,000 on a 60 min
adversarial warehouse route), keeps them for the whole run and compares them at every look,
so the templates were the largest thing a long run held (93 MB an hour in a doubling array,
which needs twice that for a moment each time it grows).

Most of ``B`` is exactly zero: a boundary cell's field is cut off a few widths from the
walls (:mod:`bioslam.boundary`), and a wall lights only the cells near it; 70 % of the cells
are zero at the median on the warehouse, 83 % on the maze. :class:`ViewStore` keeps per view
one bit per cell (zero or not), the nonzero values themselves (float32, as before) and where
each segment's (ring's) values begin, so that a compiled kernel decodes one ring at a time,
only the rings it reads (:func:`decode_cells`). Nothing is rounded: every ``S`` (Eq. 8) and
every match is that of the dense store.

Views are held in chunks of ``CHUNK_VIEWS``, each a tuple of arrays, in a Numba typed list
(:attr:`ViewStore.chunks`, what the kernels take): growing adds a chunk and copies nothing.
A chunk's value array is allocated for its views at their densest, but the values are
written from its start and the pages not yet written are not resident (fresh zeroed pages),
so what a chunk holds in memory is its views' nonzero values. The typed list is only made
and extended by compiled functions cached on disk (calling its methods from Python would
compile them at every start: half a second and 60 MB).
"""

from __future__ import annotations

from typing import Any

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

# A chunk: (zero bits (n, ceil(cells / 8)) uint8, each segment's first value in ``values``
# (n, segments) int32, block sums (n, blocks) float64, coverage (n, cols) bool, ring keys
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
    row: NDArray[np.float32], segment: int, bits: NDArray[np.uint8], segments: NDArray[np.int32],
    values: NDArray[np.float32], pos: int,
) -> int:  # fmt: skip
    """Write ``row`` as one view: its zero bits, its nonzero values into ``values`` from
    ``pos`` and where each segment's begin; the position after the last."""
    bits[:] = 0
    for i in range(row.size):
        if i % segment == 0:
            segments[i // segment] = pos
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


class ViewStore:
    """Per view: ``B`` (exact, without its zeros), its block sums, coverage and ring key.

    ``cells``: the size of ``B``; ``segment``: cells per segment (a ring), each of which a
    kernel can decode on its own; ``blocks``, ``cols``, ``rings``: the widths of the sums,
    coverage and key rows.
    """

    def __init__(self, cells: int, segment: int, blocks: int, cols: int, rings: int) -> None:
        if cells < 1 or segment < 1 or cells % segment:
            raise ValueError(f"{cells} cells do not split into segments of {segment}")
        self.cells, self.segment = int(cells), int(segment)
        self._widths = ((self.cells + 7) // 8, self.cells // self.segment, blocks, cols, rings)
        self._chunks: list[Chunk] = []
        self.chunks: Any = None  # the typed list of the same chunks, for the kernels
        self._filled = 0  # values written in the last chunk
        self._size = 0
        self.value_count = 0

    def _new_chunk(self) -> Chunk:
        n = CHUNK_VIEWS
        packed, segments, blocks, cols, rings = self._widths
        chunk = (
            np.zeros((n, packed), dtype=np.uint8),
            np.zeros((n, segments), dtype=np.int32),
            np.zeros((n, blocks)),
            np.zeros((n, cols), dtype=np.bool_),
            np.zeros((n, rings)),
            np.zeros(n * self.cells, dtype=VIEW_DTYPE),  # resident only as it is written
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
        bits, segments, block_sums, coverage, keys, values = (
            self._new_chunk() if at == 0 else self._chunks[-1]
        )
        filled = _encode(row, self.segment, bits[at], segments[at], values, self._filled)
        self.value_count += filled - self._filled
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
        start = int(self._part(view_id, 1)[0])
        out = np.zeros(self.cells, dtype=VIEW_DTYPE)
        out[nonzero] = self._chunks[view_id >> CHUNK_SHIFT][5][start : start + nonzero.sum()]
        return out

    def cover(self, view_id: int) -> NDArray[np.bool_]:
        return self._part(view_id, 3)

    @property
    def resident_bytes(self) -> int:
        """Bytes a run holds for the views: every array but the values' unwritten tail."""
        fixed = sum(a.nbytes for chunk in self._chunks for a in chunk[:5])
        return int(fixed + self.value_count * np.dtype(VIEW_DTYPE).itemsize)
