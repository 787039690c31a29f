"""Synthetic single views of a mesh for global registration (tests and ``data_tools/globalreg_bench.py``).

Ground truth here only makes the data: the frame carries nothing but what a sensor would see.
"""

from __future__ import annotations

import numpy as np

from vtrack.geometry import se3
from vtrack.tracking.frame import TrackingFrame


def synthetic_frame(
    vertices: np.ndarray,
    faces: np.ndarray,
    T_world_object: np.ndarray,
    *,
    seed: int = 0,
    n_points: int = 3000,
    noise: float = 0.001,
    outlier_frac: float = 0.1,
    n_contacts: int = 4,
    n_free: int = 20,
    camera_position: tuple[float, float, float] = (0.0, -0.4, 0.25),
    t: float = 0.0,
) -> TrackingFrame:
    """One synthetic observation of the mesh at ``T_world_object`` (world frame, metres).

    Vision: surface samples visible from ``camera_position`` (Open3D hidden-point removal), plus
    Gaussian noise ``noise`` (m) and ``outlier_frac`` extra points in a "hand" blob (1.5 cm std)
    sitting 2-4 cm off the object's visible side. Touch: ``n_contacts`` random visible-or-not surface
    points with their outward normals. Free: gel points 3-8 mm outside the surface.
    """
    import open3d as o3d

    from vtrack.eval.reconstruction import sample_surface

    rng = np.random.default_rng(seed)
    P, N = sample_surface(vertices, faces, n_points, seed=seed + 11)
    # face normals are outward only for consistently wound meshes: flip those pointing inside
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(
        o3d.core.Tensor(np.asarray(vertices, np.float32)), o3d.core.Tensor(np.asarray(faces, np.uint32))
    )
    probe = o3d.core.Tensor((P + 5e-4 * N).astype(np.float32))
    N[scene.compute_signed_distance(probe).numpy() < 0] *= -1
    Pw, Nw = se3.transform_points(T_world_object, P), se3.rotate_vectors(T_world_object, N)
    cam = np.asarray(camera_position, dtype=np.float64)
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(Pw))
    diam = float(np.linalg.norm(Pw.max(0) - Pw.min(0)))
    _, idx = pcd.hidden_point_removal(cam, 100.0 * max(np.linalg.norm(cam - Pw.mean(0)), diam))
    vis = Pw[np.asarray(idx, dtype=np.int64)]
    vis = vis + rng.normal(0.0, noise, vis.shape)
    n_out = int(round(outlier_frac * len(vis) / max(1e-9, 1.0 - outlier_frac)))
    if n_out:
        # hand blob: near the object, between it and the camera, off to one side
        to_cam = (cam - Pw.mean(0)) / np.linalg.norm(cam - Pw.mean(0))
        side = np.cross(to_cam, rng.normal(size=3))
        side /= np.linalg.norm(side)
        c = Pw.mean(0) + side * (0.5 * diam + rng.uniform(0.02, 0.04)) + to_cam * 0.02
        vis = np.concatenate([vis, c + rng.normal(0.0, 0.015, (n_out, 3))])
    k = rng.choice(len(P), size=min(n_contacts, len(P)), replace=False)
    free = np.zeros((0, 3))
    if n_free:
        j = rng.choice(len(P), size=n_free, replace=False)
        free = Pw[j] + Nw[j] * rng.uniform(0.003, 0.008, (n_free, 1))
    return TrackingFrame(
        t=t,
        vision_points=vis,
        touch_points=Pw[k] + rng.normal(0, 2e-4, (len(k), 3)),
        touch_normals=Nw[k],
        free_points=free,
        info={"camera_origin": cam.copy()},
    )
