"""An append-only array of fixed-width rows that grows by doubling.

Per-scan bookkeeping (stamps, poses, anchors, timings) lives for the whole run: as Python lists
of floats and small NumPy arrays it costs 100-350 bytes a scan, about 50 MB an hour at 40 Hz;
as rows of one array it costs the raw 8 bytes a value (plus the doubling's slack).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Protocol

import numpy as np
from numpy.typing import ArrayLike, DTypeLike, NDArray


class Rows(Protocol):
    """What the per-scan columns need of a store of rows: a :class:`GrowingArray`, or
    :class:`bioslam.io.spill.SpilledRows` that keeps them in a file."""

    def append(self, row: ArrayLike) -> None: ...

    def __len__(self) -> int: ...

    def view(self) -> NDArray[Any]: ...

    def array(self) -> NDArray[Any]: ...


#: Makes an empty store of rows of ``(dtype, width)`` (``width=0``: scalars).
RowsFactory = Callable[[DTypeLike, int], Rows]


class GrowingArray:
    """Rows of ``width`` values of ``dtype`` (``width=0``: scalars), appended one at a time.

    :meth:`view` is the filled part without a copy (valid until the next append);
    :meth:`array` a copy that stays valid.
    """

    def __init__(self, dtype: DTypeLike = np.float64, width: int = 0, capacity: int = 1024):
        self._shape = () if width == 0 else (int(width),)
        self._data = np.empty((max(int(capacity), 1), *self._shape), dtype=dtype)
        self._size = 0

    def append(self, row: ArrayLike) -> None:
        self._reserve(self._size + 1)
        self._data[self._size] = row
        self._size += 1

    def extend(self, rows: ArrayLike) -> None:
        """Append every row of ``rows`` (shape ``(n, width)``, or ``(n,)`` for scalars)."""
        rows = np.asarray(rows).reshape(-1, *self._shape)
        self._reserve(self._size + rows.shape[0])
        self._data[self._size : self._size + rows.shape[0]] = rows
        self._size += rows.shape[0]

    def _reserve(self, size: int) -> None:
        capacity = self._data.shape[0]
        if size <= capacity:
            return
        while capacity < size:
            capacity *= 2
        grown = np.empty((capacity, *self._shape), dtype=self._data.dtype)
        grown[: self._size] = self._data[: self._size]
        self._data = grown

    def truncate(self, size: int) -> None:
        """Keep the first ``size`` rows (rewritten in place through :meth:`view`)."""
        self._size = min(max(int(size), 0), self._size)

    def __len__(self) -> int:
        return self._size

    def __getitem__(self, index: int) -> NDArray:  # type: ignore[type-arg]
        return self.view()[index]

    def __array__(self, dtype: DTypeLike = None, copy: bool | None = None) -> NDArray:  # type: ignore[type-arg]
        view = self.view()
        return view.astype(dtype) if dtype is not None else (view.copy() if copy else view)

    def view(self) -> NDArray:  # type: ignore[type-arg]
        return self._data[: self._size]

    def array(self) -> NDArray:  # type: ignore[type-arg]
        return self.view().copy()

    @property
    def nbytes(self) -> int:
        """Bytes reserved (the filled rows and the slack)."""
        return int(self._data.nbytes)


class IdRows:
    """Rows of ``width`` values of ``dtype`` (``width=0``: scalars) by dense id (0, 1, 2, ...:
    view or experience ids), set in any order, for the run-long tables a dict of small arrays
    or tuples would hold at 200-300 bytes an entry (8 bytes a value here, plus one a row).

    Dict-like where the tables need it: ``i in rows``, ``rows[i]`` (the stored row itself, as
    the dict gave the stored array; KeyError for an id never set), ``rows[i] = row``. The
    table grows by doubling; the rows not yet set are never written, so they are not
    resident."""

    def __init__(self, dtype: DTypeLike = np.float64, width: int = 0, capacity: int = 64):
        self._shape = () if width == 0 else (int(width),)
        self._data = np.empty((max(int(capacity), 1), *self._shape), dtype=dtype)
        self._present = np.zeros(self._data.shape[0], dtype=np.bool_)

    def __contains__(self, i: object) -> bool:
        return isinstance(i, (int, np.integer)) and 0 <= i < self._present.size and bool(
            self._present[i]
        )

    def __getitem__(self, i: int) -> Any:
        if i not in self:
            raise KeyError(i)
        return self._data[i]

    def __setitem__(self, i: int, row: ArrayLike) -> None:
        if i < 0:
            raise KeyError(i)
        if i >= self._present.size:
            capacity = self._present.size
            while capacity <= i:
                capacity *= 2
            data = np.empty((capacity, *self._shape), dtype=self._data.dtype)
            present = np.zeros(capacity, dtype=np.bool_)
            data[: self._present.size] = self._data
            present[: self._present.size] = self._present
            self._data, self._present = data, present
        self._data[i] = row
        self._present[i] = True

    def __len__(self) -> int:
        """Ids set (counted: for tests and read-outs, not the per-scan work)."""
        return int(np.count_nonzero(self._present))

    @property
    def nbytes(self) -> int:
        """Bytes reserved (the rows set and the slack, whose pages stay unwritten)."""
        return int(self._data.nbytes + self._present.nbytes)
