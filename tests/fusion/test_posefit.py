"""Offline per-frame pose refinement against an SDF (vtrack.fusion.posefit): drifted frames of a box come back
onto its surface, the first frame stays the object frame, degenerate input is harmless."""

from __future__ import annotations

import numpy as np

from vtrack.fusion.cloud import TOUCH, VISION
from vtrack.fusion.observations import Observation
from vtrack.fusion.posefit import PoseFitConfig, align_frames, apply_corrections, corrected_poses
from vtrack.fusion.reconstruct import reconstruct_observations
from vtrack.geometry import se3

HALF = np.array([0.03, 0.02, 0.045])  # box half-sizes, m (no symmetry an SDF could slide along)


def box_sdf(P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Exact SDF of the box at the origin and its gradient (finite differences), m."""

    def f(X):
        q = np.abs(X) - HALF
        return np.linalg.norm(np.maximum(q, 0), axis=1) + np.minimum(q.max(1), 0)

    e = 1e-5
    g = np.stack([(f(P + e * d) - f(P - e * d)) / (2 * e) for d in np.eye(3)], axis=1)
    return f(P), g


def box_points(n: int, rng) -> np.ndarray:
    """n points on the box surface (random faces, area-weighted enough for a test)."""
    P = rng.uniform(-1, 1, (n, 3)) * HALF
    ax = rng.integers(0, 3, n)
    P[np.arange(n), ax] = np.sign(rng.uniform(-1, 1, n)) * HALF[ax]
    return P


def drift(k: int, K: int) -> np.ndarray:
    """A smooth tracking drift: up to 3 mm and 3 deg at the last frame, none at the first."""
    a = k / (K - 1)
    return se3.make_transform(
        se3.so3_exp(np.radians(3.0) * a * np.array([0.3, 0.8, 0.5])), a * np.array([3e-3, -2e-3, 1e-3])
    )


def make_frames(K: int = 20, seed: int = 0):
    """K frames (vision + one touch patch each) of the box, frame k placed with drift(k)."""
    rng = np.random.default_rng(seed)
    obs, truth = [], []
    for k in range(K):
        D = drift(k, K)
        for mod, n in ((VISION, 600), (TOUCH, 40)):
            P = box_points(n, rng)
            Q = se3.transform_points(D, P)
            z = np.zeros(n, np.float32)
            obs.append(Observation(0.1 * k, mod, mod, "s", Q, np.zeros_like(Q), np.ones(n, np.float32), z, np.eye(4)))
            truth.append(P)
    return obs, truth


def mean_err(obs, truth) -> float:
    return float(np.mean([np.linalg.norm(o.points - p, axis=1).mean() for o, p in zip(obs, truth, strict=True)]))


def test_drifted_frames_return_to_the_surface():
    obs, truth = make_frames()
    before = mean_err(obs, truth)
    times, C, info = align_frames(box_sdf, obs, PoseFitConfig(smooth=1))
    fixed = apply_corrections(obs, times, C)
    after = mean_err(fixed, truth)
    assert before > 1.5e-3  # the drift is real
    assert after < 0.35 * before, (before, after)
    assert np.allclose(C[0], np.eye(4))  # the first frame defines the object frame
    assert info["frames_aligned"] == 20
    # the corrected points lie on the box
    r = np.abs(box_sdf(np.concatenate([o.points for o in fixed]))[0])
    assert np.median(r) < 0.3e-3


def test_corrected_poses_move_the_world_points_consistently():
    """A frame's object-frame points under the corrected pose give the same world points as before."""
    obs, _ = make_frames(K=6)
    times, C, _ = align_frames(box_sdf, obs)
    T_wo = np.stack([se3.make_transform(t=np.array([0.1 * k, 0, 0.5])) for k in range(len(times))])
    T_new = corrected_poses(times, T_wo, times, C)
    fixed = apply_corrections(obs, times, C)
    k = 3
    o, f = obs[2 * k], fixed[2 * k]
    w_old = se3.transform_points(T_wo[k], o.points)
    w_new = se3.transform_points(T_new[k], f.points)
    assert np.allclose(w_old, w_new, atol=1e-9)
    assert np.allclose(f.T_view_object @ np.append(f.points[0], 1), o.T_view_object @ np.append(o.points[0], 1))


def test_degenerate_inputs():
    times, C, info = align_frames(box_sdf, [])
    assert len(times) == 0 and C.shape == (0, 4, 4) and info["frames"] == 0
    # frames without points / with too few points stay where they are (no NaN)
    e = np.zeros((0, 3))
    o = [
        Observation(0.0, VISION, 0, "c", e, e, np.zeros(0), np.zeros(0), np.eye(4)),
        Observation(0.1, VISION, 0, "c", np.full((3, 3), 0.03), np.zeros((3, 3)), np.ones(3), np.zeros(3), np.eye(4)),
    ]
    times, C, info = align_frames(box_sdf, o)
    assert np.all(np.isfinite(C)) and np.allclose(C, np.eye(4)) and info["frames_aligned"] == 0
    # an SDF returning NaN does not poison the corrections
    times, C, _ = align_frames(lambda P: (np.full(len(P), np.nan), np.zeros((len(P), 3))), make_frames(K=3)[0])
    assert np.all(np.isfinite(C)) and np.allclose(C, np.eye(4))


def test_reconstruct_observations_refines_and_reports_poses():
    """The offline option: a drifted copy of the box frames is refitted; corrections come back, first = identity."""
    obs, _ = make_frames(K=8)
    res = reconstruct_observations(obs, "neural_sdf", n_iters=15, pose_rounds=1, pose_iters=15, mesh_cell_mm=4.0)
    times, C = res["pose_corrections"]
    assert len(times) == 8 and C.shape == (8, 4, 4) and np.all(np.isfinite(C))
    assert np.allclose(C[0], np.eye(4))
    assert len(res["observations"]) == len(obs) and len(res["pose_refine"]) == 1
    assert len(res["vertices"]) > 0
