"""SE(3) / SO(3) utilities, batched over leading dimensions, in float64 numpy.

Conventions:
- A transform ``T_a_b`` is a (..., 4, 4) homogeneous matrix mapping points in frame ``b`` to
  frame ``a``: ``p_a = T_a_b @ p_b``. Translations are metres.
- Tangent vectors ``xi`` are (..., 6) = ``[rho (translation part, m), phi (rotation vector, rad)]``,
  so ``se3_exp(xi)`` is a left-multiplied perturbation when used as ``se3_exp(dxi) @ T``.
- Quaternions are (..., 4) in **scalar-last** order ``[x, y, z, w]`` (as scipy and ROS), unit norm,
  with ``w >= 0`` returned by :func:`matrix_to_quat` (canonical hemisphere).
- Euler ``rpy`` follows URDF: ``R = Rz(yaw) @ Ry(pitch) @ Rx(roll)``.

Small-angle branches use Taylor series so that exp/log are smooth and finite at and near zero.
"""

from __future__ import annotations

import numpy as np

from vtrack.errors import InputError

_EPS = 1e-8


def _as_f64(x, name: str, last_shape: tuple[int, ...]) -> np.ndarray:
    arr = np.asarray(x, dtype=np.float64)
    if arr.shape[arr.ndim - len(last_shape) :] != last_shape:
        raise InputError("wrong shape", field=name, expected=f"(..., {', '.join(map(str, last_shape))})", got=arr.shape)
    return arr


def hat(v: np.ndarray) -> np.ndarray:
    """Skew-symmetric matrix of (..., 3) vectors: ``hat(a) @ b == cross(a, b)``."""
    v = np.asarray(v, dtype=np.float64)
    out = np.zeros(v.shape[:-1] + (3, 3))
    out[..., 0, 1] = -v[..., 2]
    out[..., 0, 2] = v[..., 1]
    out[..., 1, 0] = v[..., 2]
    out[..., 1, 2] = -v[..., 0]
    out[..., 2, 0] = -v[..., 1]
    out[..., 2, 1] = v[..., 0]
    return out


def vee(M: np.ndarray) -> np.ndarray:
    """Inverse of :func:`hat` (uses the antisymmetric part)."""
    M = np.asarray(M, dtype=np.float64)
    return 0.5 * np.stack(
        [M[..., 2, 1] - M[..., 1, 2], M[..., 0, 2] - M[..., 2, 0], M[..., 1, 0] - M[..., 0, 1]], axis=-1
    )


def make_transform(R: np.ndarray | None = None, t: np.ndarray | None = None) -> np.ndarray:
    """Build (..., 4, 4) transforms from rotations (..., 3, 3) and translations (..., 3)."""
    if R is None and t is None:
        return np.eye(4)
    R = np.eye(3) if R is None else np.asarray(R, dtype=np.float64)
    t = np.zeros(3) if t is None else np.asarray(t, dtype=np.float64)
    batch = np.broadcast_shapes(R.shape[:-2], t.shape[:-1])
    T = np.zeros(batch + (4, 4))
    T[..., :3, :3] = R
    T[..., :3, 3] = t
    T[..., 3, 3] = 1.0
    return T


def invert(T: np.ndarray) -> np.ndarray:
    """Inverse of rigid transforms (..., 4, 4), exact (uses R^T, not a general inverse)."""
    T = _as_f64(T, "T", (4, 4))
    R = T[..., :3, :3]
    t = T[..., :3, 3]
    Rt = np.swapaxes(R, -1, -2)
    return make_transform(Rt, -np.einsum("...ij,...j->...i", Rt, t))


def compose(*Ts: np.ndarray) -> np.ndarray:
    """``compose(A, B, C) == A @ B @ C`` with broadcasting over batch dimensions."""
    if not Ts:
        return np.eye(4)
    out = np.asarray(Ts[0], dtype=np.float64)
    for T in Ts[1:]:
        out = out @ np.asarray(T, dtype=np.float64)
    return out


def add_row_vector(X: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``X += v`` in place for an (N, D) float array and a (D,) vector (e.g. a translation), column by column:
    the same sums, ~4x cheaper for N in the thousands (numpy broadcasts ``v`` as N inner loops of D elements).
    Returns ``X``."""
    if len(X) < 1024:  # below ~1000 rows the broadcast is as cheap (the column loop costs ~10 us fixed)
        X += v
        return X
    for k, x in enumerate(np.asarray(v, np.float64).tolist()):
        X[:, k] += x
    return X


def apply_rigid(T: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(N, 3) ``points`` moved by one (4, 4) transform ``T``: the same values as
    ``points @ T[:3, :3].T + T[:3, 3]`` (checked bit for bit), ~5x cheaper for thousands of points (the rotation
    transposed into a contiguous block: the transposed BLAS operand costs ~4x; the translation added by
    :func:`add_row_vector`)."""
    T = np.asarray(T, dtype=np.float64)
    out = np.asarray(points, dtype=np.float64) @ np.ascontiguousarray(T[:3, :3].T)
    return add_row_vector(out, T[:3, 3])


def transform_points(T: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply (..., 4, 4) transforms to (..., N, 3) points."""
    T = np.asarray(T, dtype=np.float64)
    P = np.asarray(points, dtype=np.float64)
    X = np.einsum("...ij,...nj->...ni", T[..., :3, :3], P)
    if T.ndim == 2 and X.ndim == 2 and len(X) >= 1024:  # one transform, many points: the translation column by
        return add_row_vector(X, T[:3, 3])  # column (same sums, cheaper; a small broadcast is cheaper as it is)
    return X + T[..., None, :3, 3]


def rotate_vectors(T_or_R: np.ndarray, vectors: np.ndarray) -> np.ndarray:
    """Rotate (..., N, 3) direction vectors (normals) by a transform or rotation matrix."""
    M = np.asarray(T_or_R, dtype=np.float64)[..., :3, :3]
    return np.einsum("...ij,...nj->...ni", M, np.asarray(vectors, dtype=np.float64))


def _rotation_angle_terms(phi: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Shared start of the SO(3) series: (phi as float64 (..., 3), theta^2 (..., 1, 1), small = theta^2 below
    the series threshold, safe = theta with 1 where small (no division by zero in the closed forms))."""
    phi = _as_f64(phi, "phi", (3,))
    theta2 = np.sum(phi * phi, axis=-1)[..., None, None]
    small = theta2 < _EPS
    return phi, theta2, small, np.where(small, 1.0, np.sqrt(theta2))


def so3_exp(phi: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) from rotation vectors (..., 3) (Rodrigues)."""
    phi, theta2, small, safe = _rotation_angle_terms(phi)
    A = np.where(small, 1.0 - theta2 / 6.0 + theta2**2 / 120.0, np.sin(safe) / safe)
    B = np.where(small, 0.5 - theta2 / 24.0 + theta2**2 / 720.0, (1.0 - np.cos(safe)) / (safe * safe))
    K = hat(phi)
    return np.eye(3) + A * K + B * (K @ K)


def so3_log(R: np.ndarray) -> np.ndarray:
    """Rotation vectors (..., 3) from rotation matrices; stable near 0 and near pi."""
    R = _as_f64(R, "R", (3, 3))
    cos = np.clip((np.trace(R, axis1=-2, axis2=-1) - 1.0) / 2.0, -1.0, 1.0)
    theta = np.arccos(cos)
    w = vee(R)  # = sin(theta) * axis
    sin = np.sin(theta)
    small = theta < 1e-4
    near_pi = np.pi - theta < 1e-3
    regular = ~(small | near_pi)
    out = np.zeros(R.shape[:-2] + (3,))
    # Regular: theta / (2 sin) * (R - R^T)^vee; vee already halves.
    scale = np.where(regular, theta / np.where(regular, sin, 1.0), 1.0)
    out = np.where(regular[..., None], w * scale[..., None], out)
    # Small angle: theta/sin ~ 1 + theta^2/6.
    out = np.where(small[..., None], w * (1.0 + theta**2 / 6.0)[..., None], out)
    if np.any(near_pi):
        # Near pi the antisymmetric part vanishes; take the axis from the symmetric part:
        # (R + R^T)/2 = cos(theta) I + (1 - cos(theta)) a a^T, choosing its best-conditioned column.
        Rp = R[near_pi]
        th = theta[near_pi]
        c = cos[near_pi][..., None, None]
        S = (0.5 * (Rp + np.swapaxes(Rp, -1, -2)) - c * np.eye(3)) / (1.0 - c)
        diag = np.diagonal(S, axis1=-2, axis2=-1)
        k = np.argmax(diag, axis=-1)
        col = np.take_along_axis(S, k[:, None, None].repeat(3, axis=1), axis=2)[..., 0]
        axis = col / np.linalg.norm(col, axis=-1, keepdims=True)
        # Fix the sign with the (small) antisymmetric part when available.
        sgn = np.sign(np.sum(axis * w[near_pi], axis=-1))
        sgn = np.where(sgn == 0, 1.0, sgn)
        out[near_pi] = axis * (sgn * th)[..., None]
    return out


def so3_left_jacobian(phi: np.ndarray) -> np.ndarray:
    """Left Jacobian J(phi) of SO(3), (..., 3, 3)."""
    phi, theta2, small, safe = _rotation_angle_terms(phi)
    B = np.where(small, 0.5 - theta2 / 24.0, (1.0 - np.cos(safe)) / (safe * safe))
    C = np.where(small, 1.0 / 6.0 - theta2 / 120.0, (safe - np.sin(safe)) / (safe**3))
    K = hat(phi)
    return np.eye(3) + B * K + C * (K @ K)


def so3_left_jacobian_inv(phi: np.ndarray) -> np.ndarray:
    """Inverse of the SO(3) left Jacobian, (..., 3, 3); valid for |phi| < 2 pi."""
    phi, theta2, small, safe = _rotation_angle_terms(phi)
    D = np.where(
        small,
        1.0 / 12.0 + theta2 / 720.0,
        # (1 + cos)/sin == cot(theta/2): written this way it stays finite at theta = pi.
        (1.0 / (safe * safe)) - np.cos(safe / 2.0) / (2.0 * safe * np.sin(safe / 2.0)),
    )
    K = hat(phi)
    return np.eye(3) - 0.5 * K + D * (K @ K)


def se3_exp(xi: np.ndarray) -> np.ndarray:
    """Transforms (..., 4, 4) from twists (..., 6) = [rho, phi]."""
    xi = _as_f64(xi, "xi", (6,))
    rho, phi = xi[..., :3], xi[..., 3:]
    R = so3_exp(phi)
    t = np.einsum("...ij,...j->...i", so3_left_jacobian(phi), rho)
    return make_transform(R, t)


def se3_log(T: np.ndarray) -> np.ndarray:
    """Twists (..., 6) = [rho, phi] from transforms (..., 4, 4)."""
    T = _as_f64(T, "T", (4, 4))
    phi = so3_log(T[..., :3, :3])
    rho = np.einsum("...ij,...j->...i", so3_left_jacobian_inv(phi), T[..., :3, 3])
    return np.concatenate([rho, phi], axis=-1)


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices from quaternions [x, y, z, w] (normalised here; zero quaternion rejected)."""
    q = _as_f64(q, "quaternion", (4,))
    n = np.linalg.norm(q, axis=-1, keepdims=True)
    if np.any(n < 1e-12) or not np.all(np.isfinite(q)):
        raise InputError("quaternion must be finite and non-zero", field="quaternion", expected="[x, y, z, w]")
    x, y, z, w = np.moveaxis(q / n, -1, 0)
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
            np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
            np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def matrix_to_quat(R: np.ndarray) -> np.ndarray:
    """Quaternions [x, y, z, w] with w >= 0 from rotation matrices (Shepperd's method, stable)."""
    R = _as_f64(R, "R", (3, 3))[..., :3, :3]
    m = R
    tr = m[..., 0, 0] + m[..., 1, 1] + m[..., 2, 2]
    cands = np.stack(
        [
            np.stack(
                [m[..., 2, 1] - m[..., 1, 2], m[..., 0, 2] - m[..., 2, 0], m[..., 1, 0] - m[..., 0, 1], 1 + tr], -1
            ),
            np.stack(
                [
                    1 + m[..., 0, 0] - m[..., 1, 1] - m[..., 2, 2],
                    m[..., 0, 1] + m[..., 1, 0],
                    m[..., 0, 2] + m[..., 2, 0],
                    m[..., 2, 1] - m[..., 1, 2],
                ],
                -1,
            ),
            np.stack(
                [
                    m[..., 0, 1] + m[..., 1, 0],
                    1 + m[..., 1, 1] - m[..., 0, 0] - m[..., 2, 2],
                    m[..., 1, 2] + m[..., 2, 1],
                    m[..., 0, 2] - m[..., 2, 0],
                ],
                -1,
            ),
            np.stack(
                [
                    m[..., 0, 2] + m[..., 2, 0],
                    m[..., 1, 2] + m[..., 2, 1],
                    1 + m[..., 2, 2] - m[..., 0, 0] - m[..., 1, 1],
                    m[..., 1, 0] - m[..., 0, 1],
                ],
                -1,
            ),
        ],
        -2,
    )  # (..., 4 candidates, 4)
    keys = np.stack([tr, m[..., 0, 0], m[..., 1, 1], m[..., 2, 2]], -1)
    best = np.argmax(keys, axis=-1)
    q = np.take_along_axis(cands, best[..., None, None].repeat(4, axis=-1), axis=-2)[..., 0, :]
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(q[..., 3:4] < 0, -q, q)


def rpy_to_matrix(rpy: np.ndarray) -> np.ndarray:
    """URDF roll-pitch-yaw (rad) to rotation: ``Rz(yaw) @ Ry(pitch) @ Rx(roll)``."""
    rpy = _as_f64(rpy, "rpy", (3,))
    r, p, y = np.moveaxis(rpy, -1, 0)
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    return np.stack(
        [
            np.stack([cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr], -1),
            np.stack([sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr], -1),
            np.stack([-sp, cp * sr, cp * cr], -1),
        ],
        -2,
    )


def matrix_to_rpy(R: np.ndarray) -> np.ndarray:
    """Inverse of :func:`rpy_to_matrix` (pitch in [-pi/2, pi/2]; gimbal lock sets roll = 0)."""
    R = _as_f64(R, "R", (3, 3))
    pitch = np.arcsin(np.clip(-R[..., 2, 0], -1.0, 1.0))
    lock = np.abs(np.cos(pitch)) < 1e-9
    roll = np.where(lock, 0.0, np.arctan2(R[..., 2, 1], R[..., 2, 2]))
    yaw = np.where(lock, np.arctan2(-R[..., 0, 1], R[..., 1, 1]), np.arctan2(R[..., 1, 0], R[..., 0, 0]))
    return np.stack([roll, pitch, yaw], -1)


def xyz_rpy_to_transform(xyz, rpy) -> np.ndarray:
    """Transform from URDF-style ``xyz`` (m) and ``rpy`` (rad)."""
    return make_transform(rpy_to_matrix(rpy), np.asarray(xyz, dtype=np.float64))


def look_at(eye, target, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """``T_world_camera`` for an OpenCV camera (x right, y down, z forward) at ``eye`` looking at ``target``."""
    eye = np.asarray(eye, dtype=np.float64)
    target = np.asarray(target, dtype=np.float64)
    z = target - eye
    nz = np.linalg.norm(z)
    if nz < 1e-12:
        raise InputError("eye and target coincide", field="look_at", expected="distinct points")
    z /= nz
    up = np.asarray(up, dtype=np.float64)
    x = np.cross(z, up)
    if np.linalg.norm(x) < 1e-9:  # looking along up: pick any perpendicular
        x = np.cross(z, [1.0, 0.0, 0.0] if abs(z[0]) < 0.9 else [0.0, 1.0, 0.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return make_transform(np.stack([x, y, z], axis=1), eye)


def interpolate(T0: np.ndarray, T1: np.ndarray, alpha) -> np.ndarray:
    """Interpolate rigid transforms: slerp on rotation, linear on translation.

    ``alpha`` may be a scalar or an array broadcasting against the batch dims; 0 gives T0, 1 gives T1.
    """
    T0 = _as_f64(T0, "T0", (4, 4))
    T1 = _as_f64(T1, "T1", (4, 4))
    a = np.asarray(alpha, dtype=np.float64)
    R0, R1 = T0[..., :3, :3], T1[..., :3, :3]
    dphi = so3_log(np.swapaxes(R0, -1, -2) @ R1)
    R = R0 @ so3_exp(dphi * a[..., None])
    t = (1.0 - a)[..., None] * T0[..., :3, 3] + a[..., None] * T1[..., :3, 3]
    return make_transform(R, t)


def rotation_angle(R: np.ndarray) -> np.ndarray:
    """Rotation angle (rad, in [0, pi]) of rotation matrices (..., 3, 3) or transforms."""
    R = np.asarray(R, dtype=np.float64)[..., :3, :3]
    return np.arccos(np.clip((np.trace(R, axis1=-2, axis2=-1) - 1.0) / 2.0, -1.0, 1.0))


def pose_error(T_est: np.ndarray, T_gt: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Translation error (m) and rotation error (rad) between pose estimates and ground truth."""
    T_est = _as_f64(T_est, "T_est", (4, 4))
    T_gt = _as_f64(T_gt, "T_gt", (4, 4))
    dt = np.linalg.norm(T_est[..., :3, 3] - T_gt[..., :3, 3], axis=-1)
    dR = np.swapaxes(T_gt[..., :3, :3], -1, -2) @ T_est[..., :3, :3]
    return dt, rotation_angle(dR)


def is_rigid(T: np.ndarray, tol: float = 1e-6) -> bool:
    """True if every transform has an orthonormal, right-handed rotation and a [0 0 0 1] last row."""
    T = np.asarray(T, dtype=np.float64)
    if T.shape[-2:] != (4, 4) or not np.all(np.isfinite(T)):
        return False
    R = T[..., :3, :3]
    ortho = np.abs(np.swapaxes(R, -1, -2) @ R - np.eye(3)).max() < tol
    det = np.abs(np.linalg.det(R) - 1.0).max() < tol
    last = np.abs(T[..., 3, :] - np.array([0, 0, 0, 1.0])).max() < tol
    return bool(ortho and det and last)


def orthonormalize(R: np.ndarray) -> np.ndarray:
    """Nearest rotation (SVD projection) to (..., 3, 3) matrices; fixes drift after many compositions."""
    U, _, Vt = np.linalg.svd(np.asarray(R, dtype=np.float64))
    d = np.sign(np.linalg.det(U @ Vt))
    U[..., :, 2] *= d[..., None]
    return U @ Vt
