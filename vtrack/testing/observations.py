"""Small synthetic observation sets (object frame) for tests and benchmarks without a simulator.

Depth is ray-cast from a mesh with Open3D's ``RaycastingScene`` from cameras on a ring around the
object; "touch" observations are surface patches (disc of ``patch_radius`` around random surface
points, seen from a virtual sensor 1 cm outside along the normal). Only tests/benchmarks import this.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from vtrack.fusion.cloud import TOUCH, VISION, from_rgbd
from vtrack.fusion.observations import Observation
from vtrack.geometry import se3
from vtrack.geometry.camera import PinholeCamera


def raycast_depth(
    vertices: np.ndarray,
    faces: np.ndarray,
    cam: PinholeCamera,
    T_object_camera: np.ndarray,
) -> np.ndarray:
    """(H, W) float32 depth (m, 0 = miss) of a mesh given in the object frame."""
    import open3d as o3d

    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(
        o3d.core.Tensor(np.asarray(vertices, np.float32)), o3d.core.Tensor(np.asarray(faces, np.uint32))
    )
    rays_c = cam.pixel_rays().reshape(-1, 3)
    d = rays_c / np.linalg.norm(rays_c, axis=1, keepdims=True)
    R, t = T_object_camera[:3, :3], T_object_camera[:3, 3]
    rays = np.concatenate([np.broadcast_to(t, d.shape), d @ R.T], axis=1).astype(np.float32)
    ans = scene.cast_rays(o3d.core.Tensor(rays))
    th = ans["t_hit"].numpy()
    z = np.where(np.isfinite(th), th * (rays_c[:, 2] / np.linalg.norm(rays_c, axis=1)), 0.0)
    return z.reshape(cam.height, cam.width).astype(np.float32)


def ring_cameras(
    center: np.ndarray, radius: float, n: int, height: float = 0.1, arc_deg: float = 360.0
) -> list[np.ndarray]:
    """``T_object_camera`` for ``n`` cameras on a horizontal arc around ``center`` looking at it."""
    out = []
    for k in range(n):
        a = np.deg2rad(arc_deg) * k / max(n, 1)
        eye = center + np.array([radius * np.cos(a), radius * np.sin(a), height])
        out.append(se3.look_at(eye, center, (0.0, 0.0, 1.0)))
    return out


def make_observations(
    mesh_path: str | Path,
    *,
    n_views: int = 6,
    arc_deg: float = 360.0,
    n_touch: int = 20,
    patch_radius: float = 0.006,
    cam: PinholeCamera | None = None,
    stride: int = 4,
    touch_region: str = "all",
    seed: int = 0,
    depth_noise_m: float = 0.0,
) -> tuple[list[Observation], np.ndarray, np.ndarray]:
    """Vision + touch observations of a mesh, all in the object (= mesh) frame.

    ``touch_region``: ``"all"`` samples contact centres anywhere, ``"unseen"`` prefers points not
    visible from the cameras (what touch is for under occlusion). Returns (observations, V, F).
    """
    from vtrack.eval.reconstruction import sample_surface
    from vtrack.io.mesh import load_mesh

    V, F = load_mesh(mesh_path)
    center = 0.5 * (V.min(0) + V.max(0))
    cam = cam or PinholeCamera.from_fov(160, 120, np.deg2rad(45))
    rng = np.random.default_rng(seed)
    obs: list[Observation] = []
    seen = np.zeros(0, bool)
    S, Sn = sample_surface(V, F, 20_000, seed)
    vis_count = np.zeros(len(S), int)
    for k, T_oc in enumerate(ring_cameras(center, 0.35, n_views, 0.12, arc_deg)):
        depth = raycast_depth(V, F, cam, T_oc)
        if depth_noise_m > 0:
            depth = np.where(depth > 0, depth + rng.normal(0, depth_noise_m, depth.shape), 0).astype(np.float32)
        c = from_rgbd(depth, cam, T_oc, t=0.1 * k, sensor_id=0, stride=stride, min_depth=0.01)
        T_co = se3.invert(T_oc)
        obs.append(
            Observation(0.1 * k, VISION, 0, "cam", c.xyz, c.normal, c.confidence, c.tactile_value, T_co, depth, cam.K)
        )
        # visibility of surface samples: depth test
        pc = S @ T_co[:3, :3].T + T_co[:3, 3]
        uv, front = cam.project(pc)
        inside = cam.in_image(uv) & front
        r = np.clip(np.round(uv[:, 1]).astype(int), 0, cam.height - 1)
        cc = np.clip(np.round(uv[:, 0]).astype(int), 0, cam.width - 1)
        zz = depth[r, cc]
        vis_count += inside & (zz > 0) & (np.abs(zz - pc[:, 2]) < 0.004)
    seen = vis_count > 0
    pool = np.nonzero(~seen)[0] if touch_region == "unseen" and (~seen).sum() > n_touch else np.arange(len(S))
    for j in range(n_touch):
        i = rng.choice(pool)
        d = np.linalg.norm(S - S[i], axis=1)
        sel = (d < patch_radius) & (np.einsum("ij,j->i", Sn, Sn[i]) > 0.5)
        pts, nrm = S[sel], Sn[sel]
        z = Sn[i]
        x = np.cross(z, [0.0, 0.0, 1.0] if abs(z[2]) < 0.9 else [1.0, 0.0, 0.0])
        x /= np.linalg.norm(x)
        T_os = se3.make_transform(np.stack([x, np.cross(-z, x), -z], axis=1), S[i] + 0.0 * z)
        obs.append(
            Observation(
                1.0 + 0.05 * j, TOUCH, 1, "touch", pts, nrm, np.ones(len(pts)), np.ones(len(pts)), se3.invert(T_os)
            )
        )
    return obs, V, F
