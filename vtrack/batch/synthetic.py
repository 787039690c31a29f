"""Tiny deterministic sessions for testing and timing the batch engine without the simulator.

A static RGB-D camera looks at a table plane (0.6 m away) with a sphere (radius 5 cm) moving along
a circle; ``gt/object_pose`` holds the sphere pose, ``mask`` its pixels, ``assets/object.ply`` its
mesh (object frame, so reconstructions can be scored), ``tactile/pad`` a synthetic tactile image
whose blob grows and shrinks. Depth is uint16 in mm with seeded noise: sessions are reproducible.
Use :func:`vtrack.sim.generate.generate_session` for realistic data.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from vtrack.io.export import export_mesh
from vtrack.io.session import FieldSpec, SessionWriter, StreamSpec


def _sphere_mesh(radius: float, n_lat: int = 16, n_lon: int = 32) -> tuple[np.ndarray, np.ndarray]:
    """UV sphere (vertices m, faces) centred at the object origin."""
    lat = np.linspace(0, np.pi, n_lat + 1)[1:-1]
    lon = np.linspace(0, 2 * np.pi, n_lon, endpoint=False)
    la, lo = np.meshgrid(lat, lon, indexing="ij")
    ring = np.stack([np.sin(la) * np.cos(lo), np.sin(la) * np.sin(lo), np.cos(la)], -1).reshape(-1, 3)
    V = radius * np.vstack([[0, 0, 1], ring, [0, 0, -1]])
    F = []
    idx = lambda i, j: 1 + i * n_lon + (j % n_lon)  # noqa: E731
    for j in range(n_lon):
        F.append([0, idx(0, j), idx(0, j + 1)])
        F.append([len(V) - 1, idx(n_lat - 2, j + 1), idx(n_lat - 2, j)])
        for i in range(n_lat - 2):
            F.append([idx(i, j), idx(i + 1, j), idx(i + 1, j + 1)])
            F.append([idx(i, j), idx(i + 1, j + 1), idx(i, j + 1)])
    return V, np.asarray(F, dtype=np.int64)


def write_synthetic_session(
    path: str | Path,
    *,
    seed: int = 0,
    frames: int = 20,
    width: int = 160,
    height: int = 120,
    rate_hz: float = 30.0,
    overwrite: bool = True,
) -> Path:
    """Write a synthetic session folder and return its path (m, s; depth uint16 mm)."""
    rng = np.random.default_rng(seed)
    fx = fy = 0.9 * width
    cx, cy = (width - 1) / 2.0, (height - 1) / 2.0
    K = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]])
    T_world_camera = np.eye(4)
    cam = StreamSpec(
        kind="rgbd",
        frame="camera/cam0",
        rate_hz=rate_hz,
        fields={
            "rgb": FieldSpec((height, width, 3), "uint8", "sRGB"),
            "depth": FieldSpec((height, width), "uint16", "0.001 m"),
            "mask": FieldSpec((height, width), "uint8", "label"),
        },
        attrs={
            "K": K.tolist(),
            "width": width,
            "height": height,
            "depth_scale": 0.001,
            "T_world_camera": T_world_camera.tolist(),
        },
    )
    tac = StreamSpec(
        kind="tactile", frame="sensor/pad", rate_hz=rate_hz, fields={"image": FieldSpec((24, 32, 3), "uint8", "BGR")}
    )
    pose = StreamSpec(
        kind="pose", frame="object", rate_hz=rate_hz, fields={"T_world_object": FieldSpec((4, 4), "float64", "m")}
    )
    u, v = np.meshgrid(np.arange(width), np.arange(height))
    ray = np.stack([(u - cx) / fx, (v - cy) / fy, np.ones_like(u, dtype=float)], -1)
    ray /= np.linalg.norm(ray, axis=-1, keepdims=True)
    phase = rng.uniform(0, 2 * np.pi)
    radius = 0.05
    with SessionWriter(
        path, None, overwrite=overwrite, flush_every=64, info={"generator": "vtrack.batch.synthetic", "seed": seed}
    ) as w:
        w.add_stream("camera/cam0", cam)
        w.add_stream("tactile/pad", tac)
        w.add_stream("gt/object_pose", pose)
        mesh_path = Path(path) / "assets" / "object.ply"
        export_mesh(mesh_path, *_sphere_mesh(radius))
        w.manifest["assets"]["object.ply"] = {"role": "object_mesh", "source": "vtrack.batch.synthetic"}
        for i in range(frames):
            t = i / rate_hz
            a = phase + 0.8 * t
            c = np.array([0.06 * np.cos(a), 0.04 * np.sin(a), 0.45])
            # Ray-sphere intersection (camera at the origin), else the plane z = 0.6 m.
            b = ray @ c
            disc = b**2 - (c @ c - radius**2)
            hit = disc > 0
            depth_along = np.where(hit, b - np.sqrt(np.where(hit, disc, 0.0)), 0.6 / ray[..., 2])
            z = depth_along * ray[..., 2] + rng.normal(0.0, 0.002, size=depth_along.shape)
            depth = np.clip(np.round(z * 1000.0), 0, 65535).astype(np.uint16)
            depth[rng.random(depth.shape) < 0.02] = 0  # dropouts
            rgb = np.where(hit[..., None], np.array([200, 60, 40]), np.array([90, 90, 90])).astype(np.uint8)
            T = np.eye(4)
            T[:3, :3] = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
            T[:3, 3] = c
            blob = np.exp(
                -(((np.arange(32) - 16) ** 2)[None, :] + ((np.arange(24) - 12) ** 2)[:, None])
                / (2 * (2 + 4 * abs(np.sin(a))) ** 2)
            )
            img = np.clip(100 + 120 * blob[..., None] + rng.normal(0, 2, (24, 32, 3)), 0, 255).astype(np.uint8)
            w.append("camera/cam0", t, rgb=rgb, depth=depth, mask=hit.astype(np.uint8))
            w.append("tactile/pad", t, image=img)
            w.append("gt/object_pose", t, T_world_object=T)
    return Path(path)
