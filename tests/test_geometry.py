import numpy as np
import pytest

from bioslam.geometry import (
    between,
    compose,
    inverse,
    quaternion_to_yaw,
    transform_points,
    wrap_angle,
    yaw_to_quaternion,
)

rng = np.random.default_rng(0)


def random_poses(n: int) -> np.ndarray:
    return np.column_stack([rng.uniform(-5, 5, n), rng.uniform(-5, 5, n), rng.uniform(-3, 3, n)])


def test_wrap_angle_range_and_values():
    a = np.linspace(-20, 20, 1001)
    w = wrap_angle(a)
    assert np.all(w > -np.pi) and np.all(w <= np.pi)
    assert np.allclose(np.sin(w), np.sin(a)) and np.allclose(np.cos(w), np.cos(a))
    assert wrap_angle(-np.pi) == pytest.approx(np.pi)


def test_compose_inverse_is_identity_vectorised():
    p = random_poses(50)
    ident = compose(p, inverse(p))
    assert np.allclose(ident, 0.0, atol=1e-12)


def test_between_recovers_relative_pose():
    a, d = random_poses(20), random_poses(20)
    b = compose(a, d)
    assert np.allclose(between(a, b), d)


def test_compose_known_value():
    assert np.allclose(compose([1, 0, np.pi / 2], [1, 0, 0]), [1, 1, np.pi / 2])


def test_transform_points_matches_compose():
    pose = np.array([1.0, -2.0, 0.7])
    pts = rng.normal(size=(10, 2))
    out = transform_points(pose, pts)
    expected = compose(np.broadcast_to(pose, (10, 3)), np.column_stack([pts, np.zeros(10)]))
    assert np.allclose(out, expected[:, :2])


def test_quaternion_round_trip():
    yaw = rng.uniform(-np.pi, np.pi, 100)
    q = yaw_to_quaternion(yaw)
    assert np.allclose(np.linalg.norm(q, axis=1), 1.0)
    assert np.allclose(quaternion_to_yaw(q), yaw)


def test_single_pose_path_matches_vectorised():
    a, b = random_poses(30), random_poses(30)
    batched = compose(a, b)
    single = np.array([compose(a[i], b[i]) for i in range(30)])
    assert np.allclose(single, batched)
    assert np.allclose(np.array([inverse(p) for p in a]), inverse(a))
    assert np.allclose(np.array([between(a[i], b[i]) for i in range(30)]), between(a, b))


def test_unit_scales_a_vector_to_length_one_and_leaves_zero_be():
    from bioslam.geometry import unit

    np.testing.assert_allclose(unit((3.0, -4.0, 7.0)), (0.6, -0.8))
    np.testing.assert_array_equal(unit((0.0, 0.0)), (0.0, 0.0))
