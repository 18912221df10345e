"""Handing freed memory back to the system.

glibc's allocator returns a freed block to the system only when it lies at the top of its
heap or was mapped on its own; the pages of other freed blocks stay resident. Two cases cost
a run tens of megabytes:

* Large arrays made and freed over and over (the odometry's local map shifted as the robot
  moves, 36 MB of new arrays each time; a loop closure's submap pyramid). glibc maps a block
  of its own only above a threshold that it raises, up to 32 MB, each time such a block is
  freed, so after the first few these arrays come from the heap and leave holes in it.
  :func:`map_large_blocks` fixes the threshold at 256 KiB: on freiburg-079 the peak fell
  from 360 to 310 MB and the growth from 244 to 141 MB an hour (same results, per-scan
  arrays stay far below it).
* Drawing the figures (matplotlib's working copies of a map image: 50 MB after a
  1000 x 900-cell map), on top of which the next figure is drawn. :func:`release_free_memory`
  (``malloc_trim(0)``, about a millisecond on such a heap) returns them.

Elsewhere than glibc (macOS, musl, Windows) both do nothing.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
import re
from collections.abc import Callable


@functools.cache
def _malloc_trim() -> Callable[[int], int] | None:
    """glibc's ``malloc_trim``, or None where the C library has none."""
    trim = getattr(_libc(), "malloc_trim", None)
    if trim is None:
        return None
    trim.argtypes = [ctypes.c_size_t]
    trim.restype = ctypes.c_int
    return trim


#: glibc's ``mallopt`` parameter number of ``M_MMAP_THRESHOLD`` (malloc.h).
_M_MMAP_THRESHOLD = -3


@functools.cache
def _libc() -> ctypes.CDLL | None:
    try:
        return ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
    except OSError:
        return None


def map_large_blocks(threshold: int = 256 * 1024) -> bool:
    """Give every block of at least ``threshold`` bytes a mapping of its own, returned to the
    system when freed (module doc); False where that is not possible. For a program's own
    process: it changes the allocator for everything in it."""
    mallopt = getattr(_libc(), "mallopt", None)
    if mallopt is None:
        return False
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    mallopt.restype = ctypes.c_int
    return bool(mallopt(_M_MMAP_THRESHOLD, int(threshold)))


def release_free_memory() -> bool:
    """Return the allocator's free pages to the system; False where that is not possible."""
    trim = _malloc_trim()
    if trim is None:
        return False
    trim(0)
    return True


#: The libraries only compiling needs: Numba's LLVM (:func:`drop_file_pages`).
COMPILER_LIBRARIES = ("libllvmlite",)
#: Every file a process maps (its libraries, for :func:`drop_file_pages`).
EVERY_FILE = ("/",)
#: ``madvise`` advice that drops a range's pages from the process (``sys/mman.h``, Linux).
_MADV_DONTNEED = 4
_MAPPING = re.compile(r"^([0-9a-f]+)-([0-9a-f]+) \S+ \S+ \S+ \S+\s*(.*)$")


def drop_file_pages(names: tuple[str, ...] = EVERY_FILE) -> int:
    """Drop from this process the resident pages of the files (libraries) whose path contains
    one of ``names``, where they are only the file's own (clean) pages; returns the bytes
    dropped (0 where that is not possible).

    A process keeps every page of its libraries' code it ever ran resident, though most ran
    once: Numba needs LLVM (``libllvmlite.so``, 67 MB of its code resident after the
    warm-up) only to compile or to load its cached kernels; of the other libraries' 37 MB
    (Python, NumPy, SciPy, OpenSSL, ...) about 17 MB ran only while they were imported.
    Dropped, they stay in the system's page cache: what is used again comes back at its
    first use, from memory, not from disk, and the rest stays out of the process, as the
    system would reclaim it under memory pressure. A mapping that holds any page of its own
    (``Anonymous`` in ``/proc/self/smaps``: relocated data) is left alone: dropping it
    would lose what was written there."""
    madvise = getattr(_libc(), "madvise", None)
    if madvise is None:
        return 0
    madvise.argtypes = [ctypes.c_void_p, ctypes.c_size_t, ctypes.c_int]
    madvise.restype = ctypes.c_int
    dropped = 0
    for start, end, rss, anonymous in _file_mappings(names):
        if anonymous == 0 and rss > 0 and madvise(start, end - start, _MADV_DONTNEED) == 0:
            dropped += rss
    return dropped


def _file_mappings(names: tuple[str, ...]) -> list[tuple[int, int, int, int]]:
    """``(start, end, resident bytes, anonymous bytes)`` of this process's mappings of the
    files whose path contains one of ``names`` (none where ``/proc`` is not there)."""
    found: list[tuple[int, int, int, int]] = []
    try:
        with open("/proc/self/smaps") as fh:
            lines = fh.read().splitlines()
    except OSError:
        return found
    current: list[int] | None = None
    for line in lines:
        head = _MAPPING.match(line)
        if head is not None:
            path = head.group(3)
            current = None
            if path.startswith("/") and any(name in path for name in names):
                current = [int(head.group(1), 16), int(head.group(2), 16), 0, 0]
                found.append(current)  # type: ignore[arg-type]
        elif current is not None and line.startswith(("Rss:", "Anonymous:")):
            current[2 if line[0] == "R" else 3] = int(line.split()[1]) * 1024
    return [tuple(entry) for entry in found]  # type: ignore[misc]
