"""Tiny deterministic vtrack sessions written with the session API (no simulator).

- :func:`write_synthetic_session` (batch engine tests and timing): a static RGB-D camera looks at a table
  plane (0.6 m away) with a sphere (radius 5 cm) moving along a circle; ``gt/object_pose`` holds the sphere
  pose, ``mask`` its pixels, ``assets/object.ply`` its mesh (object frame, so reconstructions can be
  scored), ``tactile/pad`` a synthetic tactile image whose blob grows and shrinks. Depth is uint16 in mm
  with seeded noise: sessions are reproducible.
- :func:`write_live_session` (live / streaming tests): one RGB-D camera, DIGIT streams and joints with
  cheap, slowly varying content at real image sizes.
- :func:`write_sphere_session` (live tracking tests): a sphere moving along x, depth rendered exactly.

Use :func:`vtrack.sim.generate.generate_session` (cached: :mod:`vtrack.testing.sim`) for realistic data.
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


def sphere_depth(rays: np.ndarray, center: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """Ray-sphere intersection from a camera at the origin: (hit (H, W) bool, distance along each unit ray
    (H, W) m, 0 where it misses) for ``rays`` (H, W, 3) unit directions and a sphere at ``center`` (m)."""
    b = rays @ center
    disc = b**2 - (center @ center - radius**2)
    hit = disc > 0
    return hit, np.where(hit, b - np.sqrt(np.where(hit, disc, 0.0)), 0.0)


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
        path, None, overwrite=overwrite, flush_every=64, info={"generator": "vtrack.testing.sessions", "seed": seed}
    ) as w:
        w.add_stream("camera/cam0", cam)
        w.add_stream("tactile/pad", tac)
        w.add_stream("gt/object_pose", pose)
        mesh_path = Path(path) / "assets" / "object.ply"
        export_mesh(mesh_path, *_sphere_mesh(radius))
        w.manifest["assets"]["object.ply"] = {"role": "object_mesh", "source": "vtrack.testing.sessions"}
        for i in range(frames):
            t = i / rate_hz
            a = phase + 0.8 * t
            c = np.array([0.06 * np.cos(a), 0.04 * np.sin(a), 0.45])
            # Ray-sphere intersection (camera at the origin), else the plane z = 0.6 m.
            hit, along = sphere_depth(ray, c, radius)
            depth_along = np.where(hit, along, 0.6 / ray[..., 2])
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


def write_live_session(
    path: Path,
    seconds: float = 1.0,
    cam_hw=(480, 640),
    tac_hw=(320, 240),
    n_tactile: int = 4,
    cam_hz: float = 30.0,
    tac_hz: float = 60.0,
) -> Path:
    """A session with one RGB-D camera (cam_hz), ``n_tactile`` DIGIT streams and joints (tac_hz);
    frame content is cheap, slowly varying synthetic data (so compression behaves like real data)."""
    from vtrack.io.importers.scene_build import camera_entry, finalize_scene, tactile_entry
    from vtrack.io.session import SessionWriter
    from vtrack.io.streams import camera_stream, joints_stream, tactile_stream
    from vtrack.scene.load import scene_from_dict
    from vtrack.testing.recordings import tactile_image

    H, W = cam_hw
    th, tw = tac_hw
    names = ["digit_index", "digit_middle", "digit_ring", "digit_thumb"][:n_tactile]
    K = np.array([[500.0, 0, W / 2], [0, 500.0, H / 2], [0, 0, 1]])
    scene = {
        "name": "live_test",
        "object": {"name": "object"},
        "cameras": [camera_entry("cam0", K, W, H, np.eye(4), 0.001, cam_hz)],
        "tactile": [tactile_entry(n, "digit", tw, th, tac_hz) for n in names],
    }
    sd = finalize_scene(scene)
    sc = scene_from_dict(sd, check_files=False)
    yy, xx = np.mgrid[0:H, 0:W]
    base_rgb = np.stack([xx % 256, yy % 256, (xx + yy) % 256], -1).astype(np.uint8)
    with SessionWriter(path, sd, overwrite=True, flush_every=32) as w:
        w.add_stream("camera/cam0", camera_stream(sc.camera_by_name("cam0"), with_mask=False))
        for n in names:
            w.add_stream(f"tactile/{n}", tactile_stream(sc.tactile_by_name(n)))
        w.add_stream("joints", joints_stream([f"joint_{j}.0" for j in range(16)], tac_hz))
        n_cam = int(round(seconds * cam_hz))
        n_tac = int(round(seconds * tac_hz))
        for i in range(n_cam):
            depth = (400 + (xx // 8 + i) % 200).astype(np.uint16)
            w.append("camera/cam0", i / cam_hz, rgb=np.roll(base_rgb, i, axis=1), depth=depth)
        for i in range(n_tac):
            for n in names:
                w.append(f"tactile/{n}", i / tac_hz, image=tactile_image(i, th, tw))
            w.append("joints", i / tac_hz, q=np.full(16, 0.01 * i))
    return path


def write_sphere_session(
    path: Path, seconds: float = 1.0, hw=(60, 80), radius: float = 0.03, speed: float = 0.01, hz: float = 30.0
) -> Path:
    """A session of a sphere (``assets/object.ply``) moving along world x at ``speed`` m/s, seen by
    one camera at the world origin looking along +z (depth rendered exactly, with mask), plus the
    ground-truth ``gt/object_pose``."""
    import trimesh

    from vtrack.io.importers.scene_build import camera_entry, finalize_scene
    from vtrack.io.session import SessionWriter
    from vtrack.io.streams import camera_stream, pose_stream
    from vtrack.scene.load import scene_from_dict

    H, W = hw
    K = np.array([[60.0, 0, (W - 1) / 2], [0, 60.0, (H - 1) / 2], [0, 0, 1]])
    sd = finalize_scene(
        {
            "name": "sphere",
            "object": {"name": "sphere"},
            "cameras": [camera_entry("cam0", K, W, H, np.eye(4), 0.001, hz)],
        }
    )
    sc = scene_from_dict(sd, check_files=False)
    v, u = np.mgrid[0:H, 0:W]
    rays = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u, dtype=float)], -1)
    rays /= np.linalg.norm(rays, axis=-1, keepdims=True)
    mesh_file = path.parent / f"{path.name}_sphere.ply"
    trimesh.creation.icosphere(subdivisions=3, radius=radius).export(mesh_file)
    with SessionWriter(path, sd, overwrite=True, flush_every=16) as w:
        w.add_asset(mesh_file, "object.ply", role="object_mesh")
        w.add_stream("camera/cam0", camera_stream(sc.camera_by_name("cam0"), with_mask=True))
        w.add_stream("gt/object_pose", pose_stream(rate_hz=hz))
        for i in range(int(round(seconds * hz))):
            t = i / hz
            c = np.array([-0.01 + speed * t, 0.0, 0.3])
            hit, along = sphere_depth(rays, c, radius)
            z = along * rays[..., 2]
            depth = np.rint(z * 1000).astype(np.uint16)
            T = np.eye(4)
            T[:3, 3] = c
            w.append("camera/cam0", t, rgb=np.zeros((H, W, 3), np.uint8), depth=depth, mask=hit.astype(np.uint8))
            w.append("gt/object_pose", t, T_world_object=T)
    return path
