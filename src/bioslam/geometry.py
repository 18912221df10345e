"""SE(2) helpers, vectorised over arrays of poses.

A pose is ``(x, y, theta)`` in metres and radians, the map frame; arrays of poses have shape
``(..., 3)``. Angles are wrapped to ``(-pi, pi]``.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]


class Pose2D(NamedTuple):
    """A planar pose: position in metres, heading in radians (counter-clockwise, 0 = +x)."""

    x: float
    y: float
    theta: float

    def as_array(self) -> FloatArray:
        return np.array([self.x, self.y, self.theta], dtype=np.float64)


def wrap_angle(angle: ArrayLike) -> FloatArray | float:
    """Wrap angles to ``(-pi, pi]``."""
    if isinstance(angle, float):  # the per-scan path: no array round trip
        return _wrap_scalar(angle)
    a = np.asarray(angle, dtype=np.float64)
    wrapped = np.pi - np.mod(np.pi - a, 2.0 * np.pi)
    return float(wrapped) if wrapped.ndim == 0 else wrapped


def _as_poses(p: ArrayLike) -> FloatArray:
    arr = np.asarray(p, dtype=np.float64)
    if arr.shape[-1] != 3:
        raise ValueError(f"poses must have a last dimension of 3 (x, y, theta), got {arr.shape}")
    return arr


def _wrap_scalar(angle: float) -> float:
    return math.pi - (math.pi - angle) % (2.0 * math.pi)


def _compose_single(a: FloatArray, b: FloatArray) -> FloatArray:
    # The per-scan path composes single poses thousands of times a second; plain floats
    # avoid the array machinery of the vectorised form.
    return _compose_floats(*a.tolist(), b)


def _compose_floats(ax: float, ay: float, at: float, b: FloatArray) -> FloatArray:
    """``(ax, ay, at) ⊕ b`` for a single pose ``b``."""
    bx, by, bt = b.tolist()
    c, s = math.cos(at), math.sin(at)
    return np.array([ax + c * bx - s * by, ay + s * bx + c * by, _wrap_scalar(at + bt)])


def _is_single(p: object) -> bool:
    return type(p) is np.ndarray and p.shape == (3,)


def compose(a: ArrayLike, b: ArrayLike) -> FloatArray:
    """``a ⊕ b``: apply the relative pose ``b`` in the frame of ``a``."""
    if _is_single(a) and _is_single(b):
        return _compose_single(a, b)  # type: ignore[arg-type]
    a, b = _as_poses(a), _as_poses(b)
    if a.ndim == 1 and b.ndim == 1:
        return _compose_single(a, b)
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    x = a[..., 0] + c * b[..., 0] - s * b[..., 1]
    y = a[..., 1] + s * b[..., 0] + c * b[..., 1]
    return np.stack([x, y, wrap_angle(a[..., 2] + b[..., 2])], axis=-1)


def inverse(p: ArrayLike) -> FloatArray:
    """``⊖p``, so that ``compose(p, inverse(p))`` is the identity."""
    p = p if _is_single(p) else _as_poses(p)  # type: ignore[assignment]
    if p.ndim == 1:
        x, y, t = p.tolist()
        c, s = math.cos(t), math.sin(t)
        return np.array([-c * x - s * y, s * x - c * y, _wrap_scalar(-t)])
    c, s = np.cos(p[..., 2]), np.sin(p[..., 2])
    x = -c * p[..., 0] - s * p[..., 1]
    y = s * p[..., 0] - c * p[..., 1]
    return np.stack([x, y, wrap_angle(-p[..., 2])], axis=-1)


def between(a: ArrayLike, b: ArrayLike) -> FloatArray:
    """The relative pose of ``b`` seen from ``a``: ``⊖a ⊕ b``."""
    if _is_single(a) and _is_single(b):
        # the per-scan path: inverse's arithmetic in plain floats, then compose's
        x, y, t = a.tolist()  # type: ignore[union-attr]
        c, s = math.cos(t), math.sin(t)
        return _compose_floats(-c * x - s * y, s * x - c * y, _wrap_scalar(-t), b)  # type: ignore[arg-type]
    return compose(inverse(a), b)


def separation(a: FloatArray, b: FloatArray) -> tuple[float, float]:
    """How far apart two single poses are: the distance between their positions and the
    absolute turn from ``a``'s heading to ``b``'s (those of ``between(a, b)``, without the
    array: the odometry compares its candidate poses pairwise hundreds of times a scan)."""
    ax, ay, at = a.tolist()
    bx, by, bt = b.tolist()
    return math.hypot(bx - ax, by - ay), abs(_wrap_scalar(bt - at))


def unit(vector: ArrayLike) -> FloatArray:
    """The 2-vector (the first two values of ``vector``) scaled to length 1; (0, 0) stays."""
    v = np.asarray(vector, dtype=np.float64).reshape(-1)[:2]
    length = float(np.hypot(v[0], v[1]))
    return v / length if length > 0.0 else np.zeros(2)


def rotation(theta: float) -> FloatArray:
    """The 2x2 rotation matrix R(theta) of the paper's Eq. 4."""
    c, s = np.cos(theta), np.sin(theta)
    return np.array([[c, -s], [s, c]])


def transform_points(pose: ArrayLike, points: ArrayLike) -> FloatArray:
    """Map points ``(N, 2)`` from the frame of ``pose`` into the parent frame (Eq. 4)."""
    pose = _as_poses(pose)
    pts = np.asarray(points, dtype=np.float64)
    return pts @ rotation(float(pose[2])).T + pose[:2]


def yaw_to_quaternion(theta: ArrayLike) -> FloatArray:
    """Headings to quaternions ``(qx, qy, qz, qw)`` about +z (TUM order)."""
    half = 0.5 * np.asarray(theta, dtype=np.float64)
    zeros = np.zeros_like(half)
    return np.stack([zeros, zeros, np.sin(half), np.cos(half)], axis=-1)


def quaternion_to_yaw(q: ArrayLike) -> FloatArray | float:
    """Quaternions ``(qx, qy, qz, qw)`` to headings about +z (roll and pitch are dropped)."""
    q = np.asarray(q, dtype=np.float64)
    qx, qy, qz, qw = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    yaw = np.arctan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz))
    return wrap_angle(yaw)
