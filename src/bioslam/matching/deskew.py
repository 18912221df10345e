"""SE(2) motion at a constant body twist and the de-skewing of scans taken while moving.

A rotating-mirror scanner measures its beams one after another; with per-beam timing each
endpoint is moved into the sensor frame at the scan's stamp (the first beam, as in ROS)
with the current constant-velocity estimate.
"""

from __future__ import annotations

import math

import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]


@numba.njit(cache=True)
def _se2_exp_scalar(vx: float, vy: float, w: float, t: float) -> tuple[float, float, float]:
    th = w * t
    mx, my = _twist_translation(vx, vy, w, t, math.cos(th), math.sin(th))
    return mx, my, th


@numba.njit(cache=True)
def _twist_translation(vx, vy, w, t, c, s):
    """The translation of :func:`se2_exp` after ``t``, given ``c, s = cos, sin(w t)``."""
    if abs(w) < 1e-9:
        a = t
        bb = 0.5 * w * t * t
    else:
        a = s / w
        bb = (1.0 - c) / w
    return vx * a - vy * bb, vx * bb + vy * a


def se2_exp(twist: ArrayLike, t: ArrayLike = 1.0) -> FloatArray:
    """The relative pose reached after time ``t`` (array) moving with body twist (vx, vy, w)."""
    vx, vy, w = np.asarray(twist, dtype=np.float64)
    if np.isscalar(t):
        return np.array(_se2_exp_scalar(vx, vy, w, float(t)))
    t = np.asarray(t, dtype=np.float64)
    th = w * t
    small = abs(w) < 1e-9
    a = t if small else np.sin(th) / w
    bb = 0.5 * w * t * t if small else (1.0 - np.cos(th)) / w
    return np.stack([vx * a - vy * bb, vx * bb + vy * a, th], axis=-1)


def se2_log(delta: ArrayLike) -> FloatArray:
    """The constant body twist that reaches relative pose ``delta`` in unit time."""
    x, y, th = np.asarray(delta, dtype=np.float64)
    if abs(th) < 1e-9:
        return np.array([x, y, th])
    a = math.sin(th) / th
    bb = (1.0 - math.cos(th)) / th
    det = a * a + bb * bb
    return np.array([(a * x + bb * y) / det, (-bb * x + a * y) / det, th])


@numba.njit(cache=True)
def _deskewed(px, py, vx, vy, w, t):
    """Point ``(px, py)`` measured ``t`` after the stamp, in the sensor frame at the stamp."""
    return _moved(px, py, vx, vy, w, t, math.cos(w * t), math.sin(w * t))


@numba.njit(cache=True)
def _moved(px, py, vx, vy, w, t, c, s):
    """:func:`_deskewed` given ``c, s = cos, sin(w t)``."""
    mx, my = _twist_translation(vx, vy, w, t, c, s)
    return c * px - s * py + mx, s * px + c * py + my


@numba.njit(cache=True)
def _deskew_kernel(pts, times, vx, vy, w):
    out = np.empty((pts.shape[0], 2))
    for k in range(pts.shape[0]):
        out[k, 0], out[k, 1] = _deskewed(pts[k, 0], pts[k, 1], vx, vy, w, times[k])
    return out


def deskew_points(points: ArrayLike, beam_times: ArrayLike, twist: ArrayLike) -> FloatArray:
    """Move each endpoint ``(N, 2)``, measured ``beam_times`` after the scan stamp, into the
    sensor frame at the stamp, assuming a constant body twist (vx, vy, w)."""
    pts = np.ascontiguousarray(np.asarray(points, dtype=np.float64).reshape(-1, 2))
    times = np.ascontiguousarray(np.asarray(beam_times, dtype=np.float64).reshape(-1))
    vx, vy, w = (float(v) for v in np.asarray(twist, dtype=np.float64).reshape(3))
    return _deskew_kernel(pts, times, vx, vy, w)


@numba.njit(cache=True)
def usable_endpoints(ranges, cos_a, sin_a, lo, hi, time_increment, vx, vy, w):
    """Sensor-frame endpoints of the finite returns within ``[lo, hi]`` metres (beam
    directions ``cos_a, sin_a``), each beam ``k`` de-skewed from ``k * time_increment`` back
    to the scan stamp with the body twist (vx, vy, w) when ``time_increment > 0``."""
    out = np.empty((ranges.shape[0], 2))
    n = 0
    # the sweep's rotation advances by a fixed angle per beam: rotate (c, s) by it instead of
    # two trigonometric calls per beam
    step_c = math.cos(w * time_increment)
    step_s = math.sin(w * time_increment)
    c = 1.0
    s = 0.0
    for k in range(ranges.shape[0]):
        if k > 0:
            c, s = c * step_c - s * step_s, s * step_c + c * step_s
        r = float(ranges[k])
        if not (r >= lo and r <= hi and math.isfinite(r)):  # NaN fails every comparison
            continue
        px = r * cos_a[k]
        py = r * sin_a[k]
        if time_increment > 0.0:
            px, py = _moved(px, py, vx, vy, w, k * time_increment, c, s)
        out[n, 0] = px
        out[n, 1] = py
        n += 1
    return out[:n].copy()

