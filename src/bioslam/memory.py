"""Handing freed memory back to the system between the stages of a command.

glibc's allocator returns a freed block to the system only when it lies at the top of its
heap or was mapped on its own; the pages of other freed blocks stay resident. Drawing the
figures leaves tens of megabytes so (matplotlib's working copies of a map image: 50 MB after a
1000 x 900-cell map), on top of which the next figure is drawn. ``malloc_trim(0)`` returns
them (about a millisecond on such a heap). Elsewhere than glibc (macOS, musl, Windows) there
is no ``malloc_trim`` and this does nothing.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
from collections.abc import Callable


@functools.cache
def _malloc_trim() -> Callable[[int], int] | None:
    """glibc's ``malloc_trim``, or None where the C library has none."""
    try:
        trim = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6").malloc_trim
    except (OSError, AttributeError):
        return None
    trim.argtypes = [ctypes.c_size_t]
    trim.restype = ctypes.c_int
    return trim


def release_free_memory() -> bool:
    """Return the allocator's free pages to the system; False where that is not possible."""
    trim = _malloc_trim()
    if trim is None:
        return False
    trim(0)
    return True
