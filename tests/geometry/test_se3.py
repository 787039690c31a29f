"""SE(3)/SO(3) round trips and invariants (hypothesis property tests)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from vtrack.errors import InputError
from vtrack.geometry import se3

finite = st.floats(-10.0, 10.0, allow_nan=False, allow_infinity=False)
rotvec = arrays(np.float64, (3,), elements=st.floats(-3.0, 3.0, allow_nan=False))
twist = arrays(np.float64, (6,), elements=st.floats(-3.0, 3.0, allow_nan=False))


def _rand_T(rng: np.random.Generator, n: int) -> np.ndarray:
    phi = rng.normal(size=(n, 3))
    phi *= rng.uniform(0, np.pi, size=(n, 1)) / np.linalg.norm(phi, axis=1, keepdims=True)
    return se3.make_transform(se3.so3_exp(phi), rng.normal(size=(n, 3)))


@settings(max_examples=200, deadline=None)
@given(rotvec)
def test_so3_exp_log_round_trip(phi: np.ndarray) -> None:
    theta = np.linalg.norm(phi)
    R = se3.so3_exp(phi)
    assert np.allclose(R.T @ R, np.eye(3), atol=1e-12)
    assert np.isclose(np.linalg.det(R), 1.0, atol=1e-12)
    back = se3.so3_log(R)
    if theta < np.pi - 1e-6:
        assert np.allclose(back, phi, atol=1e-9)
    else:  # at pi the axis sign is ambiguous; the rotation must still match
        assert np.allclose(se3.so3_exp(back), R, atol=1e-9)


@settings(max_examples=200, deadline=None)
@given(twist)
def test_se3_exp_log_round_trip(xi: np.ndarray) -> None:
    T = se3.se3_exp(xi)
    assert se3.is_rigid(T)
    assert np.allclose(se3.se3_exp(se3.se3_log(T)), T, atol=1e-9)


def test_log_is_stable_near_zero_and_pi() -> None:
    for theta in [0.0, 1e-12, 1e-8, 1e-5, 1e-3, np.pi - 1e-2, np.pi - 1e-5, np.pi - 1e-9, np.pi]:
        axis = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
        R = se3.so3_exp(axis * theta)
        phi = se3.so3_log(R)
        assert np.all(np.isfinite(phi))
        assert np.allclose(se3.so3_exp(phi), R, atol=1e-9), theta
        T = se3.make_transform(R, [1.0, 2.0, 3.0])
        assert np.allclose(se3.se3_exp(se3.se3_log(T)), T, atol=1e-8), theta


@settings(max_examples=100, deadline=None)
@given(arrays(np.float64, (4,), elements=st.floats(-1, 1, allow_nan=False)).filter(lambda q: np.linalg.norm(q) > 1e-3))
def test_quaternion_round_trip(q: np.ndarray) -> None:
    R = se3.quat_to_matrix(q)
    q2 = se3.matrix_to_quat(R)
    qn = q / np.linalg.norm(q)
    assert np.isclose(abs(np.dot(q2, qn)), 1.0, atol=1e-9)
    assert q2[3] >= 0
    assert np.allclose(se3.quat_to_matrix(q2), R, atol=1e-12)


def test_quaternion_matches_scipy() -> None:
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(0)
    q = rng.normal(size=(50, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    assert np.allclose(se3.quat_to_matrix(q), Rotation.from_quat(q).as_matrix(), atol=1e-12)


def test_rpy_matches_urdf_convention() -> None:
    from scipy.spatial.transform import Rotation

    rpy = np.array([0.3, -0.7, 1.9])
    # URDF: fixed-axis X (roll), then Y (pitch), then Z (yaw) == intrinsic ZYX.
    ref = Rotation.from_euler("xyz", rpy).as_matrix()
    assert np.allclose(se3.rpy_to_matrix(rpy), ref, atol=1e-12)
    assert np.allclose(se3.matrix_to_rpy(ref), rpy, atol=1e-12)


def test_batched_compose_invert() -> None:
    rng = np.random.default_rng(1)
    A, B = _rand_T(rng, 64), _rand_T(rng, 64)
    C = se3.compose(A, B)
    assert C.shape == (64, 4, 4)
    assert np.allclose(se3.compose(se3.invert(C), C), np.eye(4), atol=1e-12)
    P = rng.normal(size=(64, 10, 3))
    assert np.allclose(se3.transform_points(C, P), se3.transform_points(A, se3.transform_points(B, P)), atol=1e-12)


def test_interpolate_endpoints_and_midpoint() -> None:
    T0 = se3.xyz_rpy_to_transform([0, 0, 0], [0, 0, 0])
    T1 = se3.xyz_rpy_to_transform([1, 2, 3], [0, 0, 1.2])
    assert np.allclose(se3.interpolate(T0, T1, 0.0), T0)
    assert np.allclose(se3.interpolate(T0, T1, 1.0), T1, atol=1e-12)
    mid = se3.interpolate(T0, T1, 0.5)
    assert np.allclose(mid[:3, 3], [0.5, 1.0, 1.5])
    assert np.isclose(se3.rotation_angle(mid), 0.6)
    batch = se3.interpolate(T0, T1, np.linspace(0, 1, 11))
    assert batch.shape == (11, 4, 4)
    assert np.allclose(se3.rotation_angle(batch), np.linspace(0, 1.2, 11))


def test_far_from_origin_precision() -> None:
    # Objects 10 m from the origin: a 1 mm relative displacement survives composition/inversion.
    T_far = se3.xyz_rpy_to_transform([10.0, -10.0, 10.0], [0.1, 0.2, 0.3])
    d = se3.xyz_rpy_to_transform([0.001, 0, 0], [0, 0, 0])
    rel = se3.compose(se3.invert(T_far), T_far, d)
    assert np.allclose(rel[:3, 3], [0.001, 0, 0], atol=1e-12)


def test_pose_error_and_look_at() -> None:
    T = se3.look_at([1.0, 0, 0], [0, 0, 0])
    assert np.allclose(T[:3, 2], [-1, 0, 0])  # camera z looks at the target
    assert se3.is_rigid(T)
    dt, dr = se3.pose_error(T, se3.compose(T, se3.xyz_rpy_to_transform([0, 0, 0.01], [0, 0, 0.1])))
    assert np.isclose(dt, 0.01) and np.isclose(dr, 0.1)
    with pytest.raises(InputError, match="look_at"):
        se3.look_at([1, 1, 1], [1, 1, 1])


def test_bad_shapes_and_quaternions_raise_clear_errors() -> None:
    with pytest.raises(InputError, match="phi"):
        se3.so3_exp(np.zeros(4))
    with pytest.raises(InputError, match="quaternion"):
        se3.quat_to_matrix(np.zeros(4))
    with pytest.raises(InputError, match="quaternion"):
        se3.quat_to_matrix(np.array([np.nan, 0, 0, 1]))


def test_orthonormalize_repairs_drift() -> None:
    rng = np.random.default_rng(2)
    R = se3.so3_exp(rng.normal(size=3)) + 1e-4 * rng.normal(size=(3, 3))
    Rn = se3.orthonormalize(R)
    assert np.allclose(Rn.T @ Rn, np.eye(3), atol=1e-12) and np.isclose(np.linalg.det(Rn), 1.0)
    assert np.abs(Rn - R).max() < 1e-3


def test_apply_rigid_and_transform_points_are_the_plain_formulas_bit_for_bit():
    """The cheaper one-transform paths give exactly the plain numpy values: ``P @ R.T + t`` for
    :func:`apply_rigid`, the einsum plus a broadcast translation for :func:`transform_points` (camera-scale
    points, 0 to 20 000 of them, and a non-contiguous input), and :func:`add_row_vector` is ``X + v``."""
    from vtrack.geometry.se3 import add_row_vector, apply_rigid, transform_points

    rng = np.random.default_rng(7)
    for n in (0, 1, 5, 300, 1023, 1024, 3001, 20000):
        T = _rand_T(rng, 1)[0]
        P = rng.normal(size=(n, 3)) * 0.2 + [0.0, 0.0, 0.6]
        want = P @ T[:3, :3].T + T[:3, 3]
        got = apply_rigid(T, P)
        assert got.shape == (n, 3) and np.array_equal(got, want)
        ein = np.einsum("...ij,...nj->...ni", T[:3, :3], P)
        assert np.array_equal(transform_points(T, P), ein + T[None, :3, 3])
        Pn = np.asfortranarray(P)[::-1]
        assert np.array_equal(apply_rigid(T, Pn), Pn @ T[:3, :3].T + T[:3, 3])
        X = rng.normal(size=(n, 4))
        v = rng.normal(size=4)
        assert np.array_equal(add_row_vector(X.copy(), v), X + v)
    Ts = _rand_T(rng, 3)  # batched transforms keep their path
    P = rng.normal(size=(3, 10, 3))
    assert np.array_equal(
        transform_points(Ts, P), np.einsum("...ij,...nj->...ni", Ts[..., :3, :3], P) + Ts[:, None, :3, 3]
    )
