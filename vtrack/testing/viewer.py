"""A tiny hand-made session + result folders for the viewer tests (built with the session API).

Layout written by :func:`make_view_fixture` under ``root``::

    root/session/                 vtrack session: cam0 RGB-D, 2 tactile sensors (+ GT height/contact),
                                  joints (Allegro hand when the shared URDF is present), GT object pose
    root/demo/reconstruction/     cloud.ply (vision + touch, per-point t), mesh.ply, result.json
    root/demo/tracking/           poses.csv (estimate + gt_* columns), result.json
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

N_FRAMES = 12
RATE_HZ = 30.0


def _box_mesh(half: float = 0.03):
    import trimesh

    return trimesh.creation.box(extents=(2 * half, 2 * half, 3 * half))


def make_view_fixture(root: Path, with_hand: bool = True, n_cloud: int = 6000) -> dict[str, Path]:
    from vtrack.geometry import se3
    from vtrack.io import streams
    from vtrack.io.export import write_ply_points
    from vtrack.io.session import SessionWriter
    from vtrack.paths import shared_data_dir
    from vtrack.scene.load import scene_from_dict

    root.mkdir(parents=True, exist_ok=True)
    box = _box_mesh()
    obj_path = root / "object.ply"
    box.export(obj_path)
    urdf = shared_data_dir() / "robots" / "allegro_digit" / "allegro_digit_left.urdf"
    scene_d: dict = {
        "name": "viz_tiny",
        "object": {"name": "box", "mesh": str(obj_path)},
        "cameras": [
            {
                "name": "cam0",
                "width": 64,
                "height": 48,
                "fx": 60.0,
                "fy": 60.0,
                "look_at": {"eye": [0.4, 0.0, 0.2], "target": [0.0, 0.0, 0.05]},
            }
        ],
        "tactile": [
            {"name": "digit_index", "type": "digit", "width": 24, "height": 32, "mm_per_px": 0.9},
            {"name": "digit_thumb", "type": "digit", "width": 24, "height": 32, "mm_per_px": 0.9},
        ],
        "sim": {"seconds": N_FRAMES / RATE_HZ, "penetration_mm": [0.5, 1.6]},
    }
    hand = with_hand and urdf.exists()
    if hand:
        scene_d["hand"] = {
            "urdf": str(urdf),
            "sensors": [
                {
                    "sensor": "digit_index",
                    "link": "link_3.0_tip",
                    "T_link_sensor": {"xyz": [0.022, 0.0, 0.015], "rpy": [0.0, 1.5707963, 0.0]},
                },
                {
                    "sensor": "digit_thumb",
                    "link": "link_15.0_tip",
                    "T_link_sensor": {"xyz": [0.022, 0.0, 0.015], "rpy": [0.0, 1.5707963, 0.0]},
                },
            ],
        }
    scene = scene_from_dict(scene_d, check_files=False)
    rng = np.random.default_rng(0)
    t = np.arange(N_FRAMES) / RATE_HZ
    T_gt = np.stack(
        [
            se3.make_transform(
                se3.rpy_to_matrix(np.array([0.0, 0.0, 0.8 * ti])), np.array([0.0, 0.005 * np.sin(3 * ti), 0.08])
            )
            for ti in t
        ]
    )
    sess = root / "session"
    with SessionWriter(sess, scene) as w:
        cam = scene.cameras[0]
        w.add_stream("camera/cam0", streams.camera_stream(cam))
        for ts in scene.tactile:
            w.add_stream(f"tactile/{ts.name}", streams.tactile_stream(ts))
            w.add_stream(f"gt/tactile/{ts.name}", streams.tactile_gt_stream(ts))
        w.add_stream("gt/object_pose", streams.pose_stream(rate_hz=RATE_HZ))
        if hand:
            from vtrack.kinematics.hand import HandKinematics

            names = HandKinematics.from_scene(scene).joint_names
            w.add_stream("joints", streams.joints_stream(names, RATE_HZ))
        w.add_asset(obj_path, "object.ply", role="object mesh")
        yy, xx = np.mgrid[0:32, 0:24]
        for k, ti in enumerate(t):
            rgb = np.zeros((48, 64, 3), np.uint8)
            rgb[..., 0] = 40 + 15 * k
            rgb[10:30, 20:40] = (200, 60, 60)
            depth = np.full((48, 64), 400, np.uint16)
            mask = np.zeros((48, 64), np.uint8)
            mask[10:30, 20:40] = 1
            w.append("camera/cam0", ti, rgb=rgb, depth=depth, mask=mask)
            for j, ts in enumerate(scene.tactile):
                r2 = (yy - 16 - 4 * np.sin(ti * 5 + j)) ** 2 + (xx - 12) ** 2
                h = np.clip(1.5 - r2 / 40.0, 0, None).astype(np.float32)
                img = np.clip(120 + 60 * h[..., None] + rng.normal(0, 3, (32, 24, 3)), 0, 255).astype(np.uint8)
                w.append(f"tactile/{ts.name}", ti, image=img)
                w.append(f"gt/tactile/{ts.name}", ti, height_mm=h, contact=(h > 0.05).astype(np.uint8))
            w.append("gt/object_pose", ti, T_world_object=T_gt[k])
            if hand:
                q = np.full(len(names), 0.3 + 0.3 * np.sin(ti * 4))
                w.append("joints", ti, q=q)

    # Reconstruction: object-frame cloud sampled on the box, first vision then touch points.
    demo = root / "demo"
    rec = demo / "reconstruction"
    rec.mkdir(parents=True)
    pts, _ = box.sample(n_cloud, return_index=True) if hasattr(box, "sample") else (None, None)
    pts = np.asarray(pts, np.float64)
    n_touch = n_cloud // 6
    modality = np.zeros(n_cloud, np.int32)
    modality[-n_touch:] = 1
    pt_t = np.sort(rng.uniform(0, t[-1], n_cloud))
    write_ply_points(
        rec / "cloud.ply",
        pts,
        scalars={
            "modality": modality,
            "sensor_id": np.where(modality == 1, rng.integers(0, 2, n_cloud), 0).astype(np.int32),
            "t": pt_t,
            "confidence": rng.uniform(0.2, 1.0, n_cloud).astype(np.float32),
            "tactile_value": np.where(modality == 1, rng.uniform(0.1, 1.5, n_cloud), 0.0).astype(np.float32),
        },
    )
    box.export(rec / "mesh.ply")
    (rec / "result.json").write_text(json.dumps({"kind": "reconstruction", "session": str(sess), "frame": "object"}))
    trk = demo / "tracking"
    trk.mkdir(parents=True)
    lines = ["t,x,y,z,qx,qy,qz,qw,gt_x,gt_y,gt_z,gt_qx,gt_qy,gt_qz,gt_qw"]
    for k, ti in enumerate(t):
        Te = T_gt[k].copy()
        Te[:3, 3] += [0.002 * k / N_FRAMES, 0.0, 0.0]
        qe, qg = se3.matrix_to_quat(Te[:3, :3]), se3.matrix_to_quat(T_gt[k][:3, :3])
        vals = [ti, *Te[:3, 3], *qe, *T_gt[k][:3, 3], *qg]
        lines.append(",".join(f"{v:.9g}" for v in vals))
    (trk / "poses.csv").write_text("\n".join(lines) + "\n")
    (trk / "result.json").write_text(json.dumps({"kind": "tracking", "session": str(sess)}))
    return {"session": sess, "demo": demo, "reconstruction": rec, "tracking": trk, "hand": hand}
