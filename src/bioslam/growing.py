"""An append-only array of fixed-width rows that grows by doubling.

Per-scan bookkeeping (stamps, poses, anchors, timings) lives for the whole run: as Python lists
of floats and small NumPy arrays it costs 100-350 bytes a scan, about 50 MB an hour at 40 Hz;
as rows of one array it costs the raw 8 bytes a value (plus the doubling's slack).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, DTypeLike, NDArray


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
