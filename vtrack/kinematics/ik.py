"""Batched damped-least-squares inverse kinematics placing tactile sensors on target contacts.

Each sensor has a target for its frame origin (gel centre, world, m) and for its outward gel
normal (world unit vector). A finger has fewer DoF than 6, so the normal is a soft target weighted
by ``normal_weight`` (metres of position error per radian of normal error). All frames and all
fingers are solved at once: one (N, J, J) linear solve per iteration, joint limits enforced by
clipping after every step (projected Levenberg-Marquardt).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vtrack.errors import InputError


@dataclass
class IKResult:
    q: np.ndarray  # (N, J) rad, within the joint limits
    position_error: dict[str, np.ndarray]  # per sensor (N,) m
    normal_error: dict[str, np.ndarray]  # per sensor (N,) rad


def solve_sensor_ik(
    hk,
    q0: np.ndarray,
    target_pos: dict[str, np.ndarray],
    target_normal: dict[str, np.ndarray] | None = None,
    *,
    normal_weight: float = 0.05,
    tangent_weight: float = 1.0,
    iterations: int = 40,
    damping: float = 1e-4,
    active: dict[str, np.ndarray] | None = None,
    rest_weight: float = 1e-3,
    q_init: np.ndarray | None = None,
) -> IKResult:
    """Solve joint vectors placing sensors at targets, batched over N frames.

    Args:
        hk: :class:`~vtrack.kinematics.hand.HandKinematics`.
        q0: (J,) or (N, J) initial joint vectors (also the rest posture weakly pulled towards).
        target_pos: sensor -> (N, 3) world targets of the sensor origin, m.
        target_normal: sensor -> (N, 3) world targets of the sensor z axis (unit; normalised here).
        normal_weight: m per rad; 0 ignores normals.
        tangent_weight: weight of the position error *across* the target normal relative to the
            error along it (< 1 lets a contact slide on the surface so the gel can stay flush with
            it: depth and orientation matter more than where exactly the contact lies).
        iterations, damping: LM iterations and damping (m^2).
        active: sensor -> (N,) bool; inactive rows are not pulled to their target (rest only).
        rest_weight: regulariser towards ``q0`` (m per rad), keeps redundant joints near the rest posture.
        q_init: optional (N, J) start (warm start); default ``q0``.
    """
    sensors = list(target_pos)
    for s in sensors:
        if s not in hk.sensor_names:
            raise InputError("unknown sensor", field="target_pos", expected=hk.sensor_names, got=s)
    n = next(iter(target_pos.values())).shape[0] if sensors else 1
    q_rest = np.broadcast_to(np.asarray(q0, dtype=np.float64), (n, hk.n_joints)).copy()
    q = hk.clip_to_limits(
        q_rest.copy() if q_init is None else np.broadcast_to(np.asarray(q_init, np.float64), (n, hk.n_joints)).copy()
    )
    tp = {s: np.asarray(target_pos[s], dtype=np.float64) for s in sensors}
    tn = {}
    if target_normal is not None:
        for s in sensors:
            v = np.asarray(target_normal[s], dtype=np.float64)
            tn[s] = v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-12)
    for s in sensors:
        if not (np.all(np.isfinite(tp[s])) and (s not in tn or np.all(np.isfinite(tn[s])))):
            raise InputError("IK targets must be finite", field=f"target_pos/{s}")
    act = {s: np.ones(n, bool) if active is None or s not in active else np.asarray(active[s], bool) for s in sensors}
    eye = np.eye(hk.n_joints)[None]
    for _ in range(iterations):
        poses = hk.link_poses(q)
        JtJ = np.broadcast_to(eye * rest_weight**2, (n, hk.n_joints, hk.n_joints)).copy()
        Jtr = (q_rest - q) * rest_weight**2
        for s in sensors:
            Tp, J = hk.jacobian(q, hk.sensor_links[s], hk.T_link_sensor[s], poses=poses)
            w = act[s][:, None].astype(np.float64)
            rp = (tp[s] - Tp[:, :3, 3]) * w
            Jp = J[:, :3] * w[:, :, None]
            if s in tn and tangent_weight != 1.0:
                nn = tn[s][:, :, None] * tn[s][:, None, :]
                W = nn + tangent_weight**2 * (np.eye(3)[None] - nn)
            else:
                W = np.broadcast_to(np.eye(3), (n, 3, 3))
            JtJ += np.einsum("nki,nkl,nlj->nij", Jp, W, Jp)
            Jtr += np.einsum("nki,nkl,nl->ni", Jp, W, rp)
            if s in tn and normal_weight > 0:
                z = Tp[:, :3, 2]
                rn = np.cross(z, tn[s]) * normal_weight * w
                # Only rotations that move z count: project out the spin about z.
                P = np.eye(3)[None] - z[:, :, None] * z[:, None, :]
                Jn = (P @ J[:, 3:]) * normal_weight * w[:, :, None]
                JtJ += np.einsum("nki,nkj->nij", Jn, Jn)
                Jtr += np.einsum("nki,nk->ni", Jn, rn)
        dq = np.linalg.solve(JtJ + damping * eye, Jtr[..., None])[..., 0]
        q = hk.clip_to_limits(q + dq)
    sp = hk.sensor_poses(q)
    pos_err = {s: np.linalg.norm(sp[s][:, :3, 3] - tp[s], axis=-1) for s in sensors}
    nrm_err = {
        s: (np.arccos(np.clip(np.einsum("ni,ni->n", sp[s][:, :3, 2], tn[s]), -1, 1)) if s in tn else np.zeros(n))
        for s in sensors
    }
    return IKResult(q, pos_err, nrm_err)
