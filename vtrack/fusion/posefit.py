"""Joint pose and shape, offline: align every fused frame to the fitted neural SDF, then fit again.

The tracker's poses place each frame's observations in the object frame; where they are off (drift, a slipped
spin under occlusion) the fused cloud is smeared and the SDF averages the copies. Like NeuralFeels' pose
graph with SDF factors, but offline and per frame: with the SDF ``f`` fitted on all frames, each frame ``k``
(its vision and touch points together, object frame) gets a rigid correction ``C_k`` minimising the robust
sum of ``f(C_k p)^2`` (Gauss-Newton on the SDF's analytic gradient, Cauchy weights, a damping prior that
keeps ``C_k`` small), the corrections are smoothed over neighbouring frames (the pose error of a tracker is
smooth in time; one frame's few points must not rotate it alone), re-expressed relative to the first frame
(which defines the object frame, as in SLAM), and the SDF is fitted again on the corrected observations.

Corrections are in the object frame: a point ``p`` of frame ``k`` moves to ``C_k p``, so the frame's pose
``T_world_object`` becomes ``T_world_object @ inv(C_k)`` (:func:`corrected_poses`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from vtrack.geometry import se3


@dataclass
class PoseFitConfig:
    """Options of :func:`align_frames` (lengths in m, angles in rad).

    max_points: points per frame used (random, seeded; touch points always kept). touch_weight: weight of a touch
    point relative to a vision point. scale: Cauchy scale of the SDF residual. gate: residuals beyond this are
    ignored (unseen surface, segmentation leaks). iters: Gauss-Newton steps. damping: prior weight on the
    correction (per point, on translation m and rotation rad x ``rot_scale``). smooth: half-width (frames) of
    the triangular window over which the corrections are averaged. max_shift / max_angle: a frame whose
    correction exceeds these is left as it was (a wrong basin). min_points: frames with fewer in-gate points are
    not corrected on their own (they take their neighbours' smoothed correction).
    """

    max_points: int = 400
    touch_weight: float = 3.0
    scale: float = 0.002
    gate: float = 0.008
    iters: int = 6
    damping: float = 0.02
    rot_scale: float = 0.05
    smooth: int = 3
    max_shift: float = 0.015
    max_angle: float = 0.35
    min_points: int = 30


def frame_groups(observations: list) -> tuple[np.ndarray, list[np.ndarray]]:
    """Distinct observation times (s, sorted) and, per time, the indices of its observations."""
    t = np.array([float(o.t) for o in observations])
    if len(t) == 0:
        return np.zeros(0), []
    times, inv = np.unique(t, return_inverse=True)
    return times, [np.nonzero(inv == k)[0] for k in range(len(times))]


def _twist_to_T(xi: np.ndarray) -> np.ndarray:
    """4x4 transform of a twist (3 translation, 3 rotation vector) applied as ``R p + t``."""
    from scipy.spatial.transform import Rotation

    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(xi[3:]).as_matrix()
    T[:3, 3] = xi[:3]
    return T


def _T_to_twist(T: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return np.concatenate([T[:3, 3], Rotation.from_matrix(T[:3, :3]).as_rotvec()])


def align_frames(
    sdf: Any, observations: list, config: PoseFitConfig | None = None, seed: int = 0
) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
    """Per-frame rigid corrections of the observations against an SDF.

    Args:
        sdf: callable ``(N, 3) points -> (sdf (N,), grad (N, 3))`` in the object frame (m), e.g.
            :meth:`~vtrack.fusion.neural_sdf.NeuralSDFReconstructor.query`.
        observations: object-frame :class:`~vtrack.fusion.observations.Observation` list.

    Returns ``(times (K,), corrections (K, 4, 4), info)``: one correction per distinct observation time, the
    first time's being the identity (it defines the object frame); ``info`` has the mean / max shift (mm) and
    angle (deg) of the corrections and the number of frames corrected on their own data.
    """
    cfg = config or PoseFitConfig()
    times, groups = frame_groups(observations)
    K = len(times)
    if K == 0:
        return times, np.zeros((0, 4, 4)), {"frames": 0}
    rng = np.random.default_rng(seed)
    P_list, W_list = [], []
    for g in groups:
        ps, ws = [], []
        for i in g:
            o = observations[i]
            if len(o) == 0:
                continue
            P = np.asarray(o.points, np.float64)
            touch = int(o.modality) == 1
            if not touch and len(P) > cfg.max_points:
                P = P[rng.choice(len(P), cfg.max_points, replace=False)]
            ps.append(P)
            ws.append(np.full(len(P), cfg.touch_weight if touch else 1.0))
        P_list.append(np.concatenate(ps) if ps else np.zeros((0, 3)))
        W_list.append(np.concatenate(ws) if ws else np.zeros(0))
    sizes = np.array([len(p) for p in P_list])
    owner = np.repeat(np.arange(K), sizes)
    P0 = np.concatenate(P_list) if sizes.sum() else np.zeros((0, 3))
    W0 = np.concatenate(W_list) if sizes.sum() else np.zeros(0)
    xi = np.zeros((K, 6))
    ok_frame = np.zeros(K, bool)
    Dg = np.diag([1.0] * 3 + [cfg.rot_scale**2] * 3) * cfg.damping
    for _ in range(max(1, int(cfg.iters))):
        # current transformed points
        Ts = np.stack([_twist_to_T(x) for x in xi])
        Q = np.einsum("nij,nj->ni", Ts[owner, :3, :3], P0) + Ts[owner, :3, 3]
        f, g = sdf(Q)
        f = np.asarray(f, np.float64)
        g = np.asarray(g, np.float64)
        inl = (np.abs(f) < cfg.gate) & np.isfinite(f) & (np.linalg.norm(g, axis=1) > 0.3)
        w = W0 * inl / (1.0 + (f / cfg.scale) ** 2)
        # residual derivative w.r.t. a left increment (v, w) of the point: g, Q x g
        J = np.concatenate([g, np.cross(Q, g)], axis=1)
        Jw = J * w[:, None]
        H = np.zeros((K, 6, 6))
        b = np.zeros((K, 6))
        np.add.at(H, owner, Jw[:, :, None] * J[:, None, :])
        np.add.at(b, owner, Jw * f[:, None])
        n_in = np.bincount(owner[inl], minlength=K)
        ok_frame = n_in >= cfg.min_points
        wsum = np.bincount(owner, weights=w, minlength=K)
        for k in np.nonzero(ok_frame)[0]:
            # damping scaled with the frame's weight: the prior is per point, keeps a few points from swinging
            A = H[k] + Dg * max(wsum[k], 1.0)
            try:
                d = -np.linalg.solve(A, b[k])
            except np.linalg.LinAlgError:
                continue
            xi[k] = _T_to_twist(_twist_to_T(d) @ _twist_to_T(xi[k]))
    # wrong basins: leave those frames alone
    big = (np.linalg.norm(xi[:, :3], axis=1) > cfg.max_shift) | (np.linalg.norm(xi[:, 3:], axis=1) > cfg.max_angle)
    use = ok_frame & ~big
    # smooth over neighbouring frames (triangular window, weight = frame's use), frames without data take it too
    h = max(0, int(cfg.smooth))
    xs = np.zeros_like(xi)
    for k in range(K):
        a, e = max(0, k - h), min(K, k + h + 1)
        wk = (h + 1 - np.abs(np.arange(a, e) - k)) * use[a:e]
        xs[k] = (wk[:, None] * xi[a:e]).sum(0) / wk.sum() if wk.sum() > 0 else 0.0
    C = np.stack([_twist_to_T(x) for x in xs])
    C = np.einsum("ij,njk->nik", se3.invert(C[0]), C)  # the first frame defines the object frame
    shift = np.linalg.norm(C[:, :3, 3], axis=1) * 1e3
    ang = np.degrees(np.arccos(np.clip((np.trace(C[:, :3, :3], axis1=1, axis2=2) - 1) / 2, -1, 1)))
    info = {
        "frames": int(K),
        "frames_aligned": int(use.sum()),
        "shift_mm_mean": float(shift.mean()),
        "shift_mm_max": float(shift.max()),
        "angle_deg_mean": float(ang.mean()),
        "angle_deg_max": float(ang.max()),
    }
    return times, C, info


def apply_corrections(observations: list, times: np.ndarray, corrections: np.ndarray) -> list:
    """The observations with each frame's correction applied (points, normals, viewpoint); new objects."""
    idx = np.searchsorted(times, [float(o.t) for o in observations])
    out = []
    for o, k in zip(observations, idx, strict=True):
        Ck = corrections[min(int(k), len(times) - 1)]
        R, t = Ck[:3, :3], Ck[:3, 3]
        P = np.asarray(o.points, np.float64) @ R.T + t
        N = np.asarray(o.normals, np.float64) @ R.T
        out.append(
            replace(
                o,
                points=P.astype(np.asarray(o.points).dtype),
                normals=N.astype(np.asarray(o.normals).dtype),
                T_view_object=o.T_view_object @ se3.invert(Ck),
            )
        )
    return out


def corrected_poses(
    pose_times: np.ndarray, poses: np.ndarray, times: np.ndarray, corrections: np.ndarray
) -> np.ndarray:
    """``T_world_object`` (N, 4, 4) at ``pose_times`` after the corrections (frames at ``times``; other times
    take the nearest corrected frame's correction)."""
    pose_times = np.asarray(pose_times, np.float64)
    if len(times) == 0:
        return np.asarray(poses).copy()
    j = np.clip(np.searchsorted(times, pose_times), 0, len(times) - 1)
    jm = np.clip(j - 1, 0, len(times) - 1)
    j = np.where(np.abs(times[jm] - pose_times) < np.abs(times[j] - pose_times), jm, j)
    return np.einsum("nij,njk->nik", np.asarray(poses, np.float64), se3.invert(corrections[j]))
