"""Small self-contained synthetic tracking sequences (for tests and the quick benchmark).

Renders depth of a mesh with Open3D ray casting under a known smooth pose trajectory and samples
tactile contact patches where fixed "fingertips" (world points around the object) touch the
surface. It produces :class:`~vtrack.tracking.frame.TrackingFrame` objects directly (no session
IO), so the tracker can be exercised in milliseconds; full sessions come from ``vtrack.sim``.

Frames: world; the object starts at ``T0`` and rotates about ``axis`` (world) through its
centre while translating sinusoidally. Units: m, rad, s.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from vtrack.geometry import se3
from vtrack.geometry.camera import PinholeCamera
from vtrack.io.mesh import load_mesh
from vtrack.tracking.frame import TrackingFrame


@dataclass
class SynthSequence:
    """Frames plus ground truth ``T_world_object`` (N, 4, 4) and the object-frame model."""

    frames: list[TrackingFrame]
    gt: np.ndarray
    vertices: np.ndarray
    faces: np.ndarray
    centre: np.ndarray
    info: dict = field(default_factory=dict)


_OCCLUSION_KEEP = {"none": 1.0, "medium": 0.5, "heavy": 0.15}


def make_sequence(
    mesh_path,
    n_frames: int = 60,
    fps: float = 30.0,
    rot_speed: float = 0.6,
    axis=(0.3, 0.2, 1.0),
    trans_amp: float = 0.006,
    occlusion: str = "none",
    depth_noise: float = 0.001,
    touch_noise: float = 0.0002,
    n_fingers: int = 3,
    contact_radius: float = 0.005,
    width: int = 160,
    height: int = 120,
    seed: int = 0,
    contact_schedule=None,
) -> SynthSequence:
    """Render a synthetic sequence.

    Args:
        occlusion: none | medium | heavy: fraction of the object's image kept (a sliding band is
            blanked, as a hand in front of the object would).
        depth_noise: std of depth noise, m (plus quantisation to 1 mm like uint16 sensors).
        contact_schedule: optional callable ``(frame_index, finger) -> bool`` (default: always).
    """
    import open3d as o3d

    rng = np.random.default_rng(seed)
    V, F = load_mesh(mesh_path)
    centre = 0.5 * (V.min(0) + V.max(0))
    radius = float(np.linalg.norm(V - centre, axis=1).max())
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(V.astype(np.float32)), o3d.core.Tensor(F.astype(np.uint32)))
    # Dense surface samples with normals for contact patches, drawn from the sequence's own seeded
    # generator (Open3D's sampler uses an unseeded global RNG: sequences differed between processes).
    from vtrack.eval.reconstruction import sample_surface

    S, SN = sample_surface(V, F, 20000, seed=seed + 1)

    ax = np.asarray(axis, float)
    ax /= np.linalg.norm(ax)
    cam = PinholeCamera.from_fov(width, height, np.deg2rad(45.0))
    T_wc = se3.look_at([0.0, -0.35, 0.22], [0.0, 0.0, 0.1])
    rays_c = cam.pixel_rays().reshape(-1, 3)
    rays_c_n = rays_c / np.linalg.norm(rays_c, axis=1, keepdims=True)
    # fingertips: fixed world points on a circle around the object centre
    fingers = [
        np.array([0.0, 0.0, 0.1]) + (radius * 0.9) * np.array([np.cos(a), np.sin(a), 0.15 * np.sin(3 * a)])
        for a in np.linspace(0, 2 * np.pi, n_fingers, endpoint=False) + 0.4
    ]
    keep_frac = _OCCLUSION_KEEP[occlusion]
    frames, gts = [], []
    for i in range(n_frames):
        t = i / fps
        R = se3.so3_exp(ax * rot_speed * t)
        c_w = np.array([0.0, 0.0, 0.1]) + trans_amp * np.array([np.sin(2.1 * t), np.sin(1.3 * t), 0.5 * np.sin(t)])
        # rotate about the object centre: T = [R, c_w - R c] in object coordinates
        Tw = se3.make_transform(R, c_w - R @ centre)
        gts.append(Tw)
        T_ow = se3.invert(Tw)
        T_oc = T_ow @ T_wc
        o = np.broadcast_to(T_oc[:3, 3], rays_c_n.shape)
        d = rays_c_n @ T_oc[:3, :3].T
        ans = scene.cast_rays(o3d.core.Tensor(np.concatenate([o, d], 1).astype(np.float32)))
        th = ans["t_hit"].numpy().astype(np.float64)
        hit = np.isfinite(th)
        z = np.where(hit, th, 0.0) * rays_c_n[:, 2]
        z = z + rng.normal(0, depth_noise, z.shape) * z / 0.3
        z = np.round(z * 1000.0) / 1000.0
        img_hit = hit.reshape(height, width)
        if keep_frac < 1.0:
            cols = np.nonzero(img_hit.any(0))[0]
            if len(cols):
                lo, hi = cols.min(), cols.max() + 1
                span = hi - lo
                keep_w = max(1, int(round(span * keep_frac)))
                start = lo + int((span - keep_w) * (0.5 + 0.5 * np.sin(0.7 * t)))
                band = np.zeros(width, bool)
                band[start : start + keep_w] = True
                img_hit &= band[None, :]
        sel = img_hit.ravel()
        pts_c = rays_c[sel] * z[sel, None]
        Vw = se3.transform_points(T_wc, pts_c)
        # contacts
        tp, tn, free = [], [], []
        S_w = se3.transform_points(Tw, S)
        N_w = se3.rotate_vectors(Tw, SN)
        for k, fpos in enumerate(fingers):
            on = contact_schedule(i, k) if contact_schedule is not None else True
            j = int(np.argmin(np.linalg.norm(S_w - fpos, axis=1)))
            if on:
                near = np.linalg.norm(S_w - S_w[j], axis=1) < contact_radius
                P = S_w[near] + rng.normal(0, touch_noise, (int(near.sum()), 3))
                tp.append(P)
                tn.append(N_w[near])
            else:
                # a retracted fingertip 4 mm off the surface: gel points for non-penetration
                c = S_w[j] + 0.004 * N_w[j]
                u = np.cross(N_w[j], [0.0, 0.0, 1.0])
                u = u / max(np.linalg.norm(u), 1e-9)
                v = np.cross(N_w[j], u)
                g = np.linspace(-0.006, 0.006, 4)
                free.append(np.array([c + a * u + b * v for a in g for b in g]))
        frames.append(
            TrackingFrame(
                t=t,
                vision_points=Vw,
                touch_points=np.concatenate(tp) if tp else None,
                touch_normals=np.concatenate(tn) if tn else None,
                free_points=np.concatenate(free) if free else None,
            )
        )
    return SynthSequence(
        frames=frames,
        gt=np.stack(gts),
        vertices=V,
        faces=F,
        centre=centre,
        info={"occlusion": occlusion, "depth_noise": depth_noise, "fps": fps},
    )


def run_sequence(tracker, seq: SynthSequence, drop: tuple[str, ...] = (), frames=None) -> tuple[np.ndarray, np.ndarray]:
    """Step ``tracker`` over ``seq`` (optionally dropping "vision"/"touch").

    Returns the estimates (N, 4, 4) and the per-frame error of the object centre (N,), m.
    """
    import copy

    est = []
    for f in frames if frames is not None else seq.frames:
        f = copy.copy(f)
        if "touch" in drop:
            f.touch_points = f.touch_normals = f.free_points = None
        if "vision" in drop:
            f.vision_points = None
        est.append(tracker.step(f))
    E = np.stack(est)
    c = seq.centre[None]
    err = np.linalg.norm(se3.transform_points(E, c)[:, 0] - se3.transform_points(seq.gt[: len(E)], c)[:, 0], axis=1)
    return E, err


def drifting_keyframes(
    seq: SynthSequence,
    axis,
    lag_per_frame: float = 0.05,
    lag_frames: int = 20,
    trans_noise: float = 3e-4,
    n_points: int = 400,
    camera_origin=(0.0, -0.35, 0.22),
    seed: int = 0,
    centre=None,
) -> list:
    """Back-end keyframes (:class:`~vtrack.tracking.posegraph.Keyframe`) of every frame of ``seq`` with the
    drift a SLAM front end shows: the spin about the world ``axis`` (through the object centre) lags by
    ``lag_per_frame`` rad per frame over the first ``lag_frames`` frames and then stays behind, plus
    ``trans_noise`` m of position noise. Normals: Open3D PCA facing the camera of :func:`make_sequence`.
    ``centre``: the object-frame point (m) the lag turns about (default the object centre); a front end that
    loses a mug's spin keeps its body on the data, so its error turns about the body's axis."""
    from vtrack.tracking.posegraph import Keyframe
    from vtrack.tracking.slam import estimate_normals

    rng = np.random.default_rng(seed)
    ax = np.asarray(axis, np.float64)
    ax = ax / np.linalg.norm(ax)
    cam = np.asarray(camera_origin, np.float64)
    kfs = []
    for i, f in enumerate(seq.frames):
        R = se3.so3_exp(ax * (-lag_per_frame * min(i, lag_frames)))
        c = se3.transform_points(seq.gt[i], np.asarray(seq.centre if centre is None else centre, float)[None])[0]
        T = se3.make_transform(R, c - R @ c) @ seq.gt[i]
        T[:3, 3] += rng.normal(0.0, trans_noise, 3)
        V = f.vision_points
        N = estimate_normals(V, cam, None)
        sel = rng.choice(len(V), min(n_points, len(V)), replace=False)
        kfs.append(Keyframe(t=float(f.t), T=T, points=V[sel], normals=N[sel]))
    return kfs
