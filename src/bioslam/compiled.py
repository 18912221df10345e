"""Small helpers for the Numba kernels of several modules, compiled once (ours).

Kept apart from :mod:`bioslam.geometry`, which the commands that never run a kernel (``bioslam
eval``, ``info``) import without loading Numba.

No file or terminal I/O here.
"""

from __future__ import annotations

from numba import njit

from bioslam.geometry import _wrap_scalar

#: :func:`bioslam.geometry.wrap_angle` of one angle inside a kernel: the very function of the
#: per-scan path, compiled, so that both wrap alike to the bit.
wrap_scalar = njit(cache=True)(_wrap_scalar)
