"""The experiences' stored scans kept in a file instead of in memory.

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
"""

from __future__ import annotations

import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import IO, overload

import numpy as np
from numpy.typing import ArrayLike, NDArray

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
        self._file.seek(self._end)
        view = memoryview(data)
        while view:
            written = self._file.write(view)
            if not written:
                raise OSError("nothing written")
            view = view[written:]

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
        self._file.seek(offset)
        view = memoryview(out.reshape(-1)).cast("B")
        while view:
            got = self._file.readinto(view)
            if not got:
                raise OSError(f"the scans' file ended {view.nbytes} bytes early")
            view = view[got:]

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
