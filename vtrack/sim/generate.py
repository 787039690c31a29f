"""Generate a synthetic in-hand visuo-tactile session with exact ground truth.

``generate_session(scene, out_dir)`` writes a session (see :mod:`vtrack.io.session`) with the
standard streams of :mod:`vtrack.io.streams`:

- ``joints`` (q, rad, ``sim.joint_rate_hz``; column order ``HandKinematics.joint_names``; optional
  encoder noise ``sim.joint_noise``), ``gt/object_pose`` (T_world_object at the joint times);
- ``tactile/<sensor>`` (BGR image) and ``gt/tactile/<sensor>`` (height_mm, contact) at each sensor's
  rate; the image comes from the independent optical model :mod:`vtrack.sim.tactile_optics` (one
  jittered unit per sensor) on the real background; each sensor's calibration, trained on simulated
  ball presses (:func:`vtrack.sim.presses.sensor_calibration`), is in ``assets/calibration/<sensor>.npz``;
- ``camera/<cam>`` (rgb, depth uint16) and ``gt/camera/<cam>`` (the renderer's exact object ``mask``,
  ``visible_fraction``) at each camera's rate (see :mod:`vtrack.sim.rgbd` for the rendering and the
  depth-noise model);
- ``gt/object.ply``: the object mesh in the object frame (bounding-box centre).

Ground truth is for scoring only: everything the simulator knows is under ``gt/`` (streams in
``data.zarr/gt/``, files in ``SESSION/gt/``); the embedded scene gives neither the object's pose nor
its mesh, as a user's recording would not (``vtrack session strip-gt`` removes the rest).

Simplifications (stated): the gel is flat (the real DIGIT gel bulges <= 4-5 mm); contacts are
geometric (no contact forces, no shear); the hand does not collide with the object except at the
gels; the object moves on a prescribed trajectory (not simulated dynamics).

The first camera is placed by the occlusion level (``none`` / ``medium`` / ``heavy``) on a sphere
around the grasp at the distance of its declared placement; other cameras keep theirs. The
session's embedded scene records the effective values (camera extrinsics, duration, seed).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from vtrack.errors import InputError

#: Direction from the object (grasp) centre to the first camera, hand-base frame, per occlusion
#: level. Chosen from a sweep of 72 view directions on the default scene (soup can, 5 poses over
#: 5 s, camera at 0.45 m); mean visible fraction of the object: none 0.78 (front-side, below the
#: fingers: sees the can's side and one end), medium 0.54 (above the curled fingers), heavy 0.19
#: (behind the palm, through the gaps between the fingers).
OCCLUSION_VIEWS: dict[str, tuple[float, float, float]] = {
    "none": (0.75, 0.43, -0.5),
    "medium": (0.5, 0.0, 0.87),
    "heavy": (-1.0, 0.0, 0.0),
}

#: Ground-truth object mesh of a generated session (object frame, m), relative to the session folder.
GT_MESH = "gt/object.ply"


def _log(progress: bool, msg: str) -> None:
    if progress:
        print(f"[generate] {msg}", file=sys.stderr, flush=True)


def _hand_world_meshes(link_meshes, poses: dict[str, np.ndarray], i: int) -> list[tuple[np.ndarray, np.ndarray]]:
    out = []
    for link, meshes in link_meshes.items():
        T = poses[link][i]
        for v, f in meshes:
            out.append((v @ T[:3, :3].T + T[:3, 3], f))
    return out


def _hull_indices(v: np.ndarray) -> np.ndarray:
    """Vertex indices of the convex hull (enough to bound the object's projection)."""
    from scipy.spatial import ConvexHull

    try:
        return np.unique(ConvexHull(v).simplices)
    except Exception:  # degenerate (flat) meshes: use all vertices
        return np.arange(len(v))


def _times(seconds: float, rate_hz: float) -> np.ndarray:
    n = max(1, int(np.floor(seconds * rate_hz + 1e-9)))
    return np.arange(n, dtype=np.float64) / rate_hz


def _load_background(spec) -> np.ndarray:
    """The scene tactile entry's no-contact frame (:func:`vtrack.tactile.sensors.default_background`)."""
    from vtrack.tactile.sensors import default_background

    return default_background(spec.type, spec.width, spec.height, spec.background)


def _render_tactile(height_mm, spec, background, model, rng, noise_scale: float):
    # the independent optical model (vtrack.sim.tactile_optics), not the pipeline's inverse model: no
    # inverse crime; the model's elastomer blur smooths the indenter shape
    return model.render(height_mm, spec.mm_per_px, background, rng=rng if noise_scale > 0 else None, noise=noise_scale)


def place_camera(cam, occlusion: str, centre: np.ndarray) -> np.ndarray:
    """``T_world_camera`` of a camera looking at ``centre`` from the occlusion level's direction."""
    from vtrack.geometry.se3 import look_at

    T_decl = cam.extrinsics()
    dist = float(np.linalg.norm(T_decl[:3, 3] - centre))
    if cam.look_at is not None:
        dist = float(np.linalg.norm(np.asarray(cam.look_at.eye) - np.asarray(cam.look_at.target)))
    dist = min(max(dist, cam.depth_min + 0.1), cam.depth_max - 0.1)
    d = np.asarray(OCCLUSION_VIEWS[occlusion], dtype=np.float64)
    d /= np.linalg.norm(d)
    up = (0.0, 0.0, 1.0) if abs(d[2]) < 0.9 else (1.0, 0.0, 0.0)
    return look_at(centre + dist * d, centre, up)


def generate_session(
    scene: Any,
    out_dir: str | Path,
    *,
    seconds: float | None = None,
    seed: int | None = None,
    occlusion: str | None = None,
    object_mesh: str | Path | None = None,
    overwrite: bool = False,
    progress: bool = False,
) -> Path:
    """Generate a synthetic session from a scene (a :class:`~vtrack.scene.schema.Scene` or a YAML path).

    Args:
        seconds, seed, occlusion: override ``scene.sim`` (``occlusion`` in none|medium|heavy).
        object_mesh: override the object with any watertight mesh in metres.
        overwrite: replace an existing ``out_dir``.
        progress: log stage timings to stderr.

    Returns:
        the session directory.

    Raises:
        InputError: the scene has no hand / tactile sensors, bad overrides, unreadable meshes.
    """
    from vtrack.geometry import se3
    from vtrack.geometry.raycast import Raycaster
    from vtrack.io.session import SessionWriter
    from vtrack.io.streams import (
        camera_gt_stream,
        camera_stream,
        joints_stream,
        pose_stream,
        tactile_gt_stream,
        tactile_stream,
    )
    from vtrack.kinematics.hand import HandKinematics, decimated_link_meshes
    from vtrack.scene import load_scene
    from vtrack.scene.schema import SimSpec
    from vtrack.sim.grasp import plan_grasp
    from vtrack.sim.objects import load_object_mesh
    from vtrack.sim.rgbd import add_depth_noise, object_colour, projected_window, render_geometry, shade_rgb

    t_start = time.perf_counter()
    if isinstance(scene, (str, Path)):
        scene = load_scene(scene)
    out_dir = Path(out_dir)
    if out_dir.exists() and not overwrite:
        raise InputError("output session directory exists (pass overwrite=True / --force)", path=out_dir)
    if scene.hand is None or not scene.hand.sensors:
        raise InputError("a synthetic session needs a hand with tactile sensors", path=scene.source, field="hand")
    sim = (scene.sim or SimSpec()).model_copy()
    if seconds is not None:
        if not (np.isfinite(seconds) and 0 < seconds <= 600):
            raise InputError("duration out of range", field="seconds", expected="0 < s <= 600", got=seconds)
        sim.seconds = float(seconds)
    if seed is not None:
        sim.seed = int(seed)
    if occlusion is not None:
        if occlusion not in OCCLUSION_VIEWS:
            raise InputError("unknown occlusion level", field="occlusion", expected="none|medium|heavy", got=occlusion)
        sim.occlusion = occlusion
    mesh_path = Path(object_mesh) if object_mesh is not None else scene.object.mesh
    if mesh_path is None:
        raise InputError("the simulator needs an object mesh", path=scene.source, field="object.mesh")
    scale = 1.0 if object_mesh is not None else scene.object.scale
    obj_name = Path(mesh_path).stem if object_mesh is not None else scene.object.name

    ss = np.random.SeedSequence(sim.seed)
    rng_plan, rng_joint, rng_tac, rng_cam = (np.random.default_rng(s) for s in ss.spawn(4))

    hk = HandKinematics.from_scene(scene)
    obj = load_object_mesh(mesh_path, scale)
    obj_rc = Raycaster([(obj.vertices, obj.faces)])
    specs = {m.sensor: scene.tactile_by_name(m.sensor) for m in scene.hand.sensors}
    _log(progress, f"setup {time.perf_counter() - t_start:.2f} s")

    # 1. Motion: object trajectory + joint angles (contacts by IK on the closing synergies).
    t0 = time.perf_counter()
    t_joint = _times(sim.seconds, sim.joint_rate_hz)
    plan = plan_grasp(hk, obj, obj_rc, sim, specs, t_joint, rng_plan)
    _log(progress, f"grasp/IK {time.perf_counter() - t0:.2f} s")

    # 2. Effective scene embedded in the manifest.
    centre = plan.T0[:3, 3]
    cams = list(scene.cameras)
    T_cams = {c.name: c.extrinsics() for c in cams}
    if cams:
        T_cams[cams[0].name] = place_camera(cams[0], sim.occlusion, centre)
    sd = scene.to_dict()
    sd["tactile"] = [
        {**t, "calibration": f"assets/calibration/{t['name']}.npz"} if t["name"] in specs else t
        for t in sd.get("tactile", [])
    ]  # written in step 4 (simulated ball-press calibration)
    # The embedded scene says what a user would know: the object's name and symmetry, but neither its
    # shape nor its pose (both are ground truth, under gt/). Known-shape runs take the mesh from --mesh.
    sd["object"].update({"name": obj_name, "mesh": None, "scale": 1.0, "T_world_object": None})
    if object_mesh is not None:
        # an override mesh does not inherit the scene object's symmetry (it decides ADD-S vs ADD in scoring
        # and the hypotheses of global registration): measure it
        from vtrack.eval.pose_metrics import is_rotationally_symmetric

        sd["object"]["symmetric"] = is_rotationally_symmetric(obj.vertices, obj.faces)
    if sd.get("pipeline", {}).get("tracking") == "known_shape":
        sd["pipeline"]["tracking"] = "slam"
    for c in sd.get("cameras", []):
        c["look_at"] = None
        c["T_world_camera"] = {"matrix": T_cams[c["name"]].tolist()}
    sd["sim"] = sim.model_dump(mode="json")
    info = {
        "generator": "vtrack.sim.generate",
        "seed": sim.seed,
        "seconds": sim.seconds,
        "occlusion": sim.occlusion,
        "object_source": str(mesh_path),
        "T_source_object": obj.T_source_object.tolist(),
    }

    writer = SessionWriter(out_dir, sd, overwrite=overwrite, flush_every=16, info=info)
    try:
        (writer.path / GT_MESH).parent.mkdir(parents=True, exist_ok=True)
        obj.write_ply(writer.path / GT_MESH)
        writer.manifest["gt_files"] = {GT_MESH: {"role": "object_mesh", "frame": "object", "source": str(mesh_path)}}

        # 3. Joints and object pose.
        writer.add_stream("joints", joints_stream(hk.joint_names, sim.joint_rate_hz))
        writer.add_stream("gt/object_pose", pose_stream(rate_hz=sim.joint_rate_hz))
        q_meas = plan.q + (rng_joint.normal(0.0, sim.joint_noise, plan.q.shape) if sim.joint_noise > 0 else 0.0)
        for i, t in enumerate(t_joint):
            writer.append("joints", float(t), q=q_meas[i])
            writer.append("gt/object_pose", float(t), T_world_object=plan.T_world_object[i])

        # 4. Tactile: GT height maps (full resolution) and images.
        t0 = time.perf_counter()
        import shutil

        from vtrack.sim.grasp import gel_heights
        from vtrack.sim.presses import sensor_calibration, sensor_seed
        from vtrack.sim.tactile_optics import OpticalModel

        calib_cache: dict[str, Any] = {}
        controlled: dict[str, list[int]] = {}
        touching: dict[str, float] = {}
        for s, spec in specs.items():
            t_tac = _times(sim.seconds, spec.rate_hz)
            # Frames where the planner held the finger at its target depth (not re-grasping/lifted).
            near = np.clip(np.searchsorted(t_joint, t_tac), 0, len(t_joint) - 1)
            controlled[s] = plan.in_contact_phase[s][near].astype(int).tolist()
            T_wo = plan.object_pose_at(t_tac)
            T_ws = hk.sensor_poses(plan.q_at(t_tac))[s]
            heights = gel_heights(
                obj_rc, se3.invert(T_wo) @ T_ws, spec.width, spec.height, spec.mm_per_px, spec.gel_thickness_mm
            )
            bg = _load_background(spec)
            # each sensor is its own unit (seeded optical jitter), calibrated from simulated ball presses like
            # a real one; the session carries that calibration (the embedded scene points at it)
            model = OpticalModel.for_sensor(spec.type, sensor_seed(s))
            calib_dst = writer.path / "assets" / "calibration" / f"{s}.npz"
            calib_dst.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(calib_cache.setdefault(s, sensor_calibration(spec, sensor_seed(s))), calib_dst)
            writer.manifest["assets"][f"calibration/{s}.npz"] = {"role": "tactile_calibration", "sensor": s}
            writer.add_stream(f"tactile/{s}", tactile_stream(spec))
            writer.add_stream(f"gt/tactile/{s}", tactile_gt_stream(spec))
            touching[s] = float((heights.reshape(len(heights), -1).max(1) > spec.contact_threshold_mm).mean())
            for i, t in enumerate(t_tac):
                h = heights[i]
                img = _render_tactile(h, spec, bg, model, rng_tac, sim.tactile_noise)
                writer.append(f"tactile/{s}", float(t), image=img)
                writer.append(
                    f"gt/tactile/{s}", float(t), height_mm=h, contact=(h > spec.contact_threshold_mm).astype(np.uint8)
                )
        _log(progress, f"tactile {time.perf_counter() - t0:.2f} s")

        # 5. Cameras.
        t0 = time.perf_counter()
        link_meshes = decimated_link_meshes(hk) if cams else {}
        rgb_obj = object_colour(obj_name)
        for cam in cams:
            K = cam.intrinsics()
            rays = K.pixel_rays()
            T_wc = T_cams[cam.name]
            t_cam = _times(sim.seconds, cam.rate_hz)
            T_wo = plan.object_pose_at(t_cam)
            poses = hk.link_poses(plan.q_at(t_cam))
            writer.add_stream(f"camera/{cam.name}", camera_stream(cam, False, T_world_camera=T_wc))
            writer.add_stream(f"gt/camera/{cam.name}", camera_gt_stream(cam))
            hull = obj.vertices[_hull_indices(obj.vertices)]
            for i, t in enumerate(t_cam):
                hand_meshes = _hand_world_meshes(link_meshes, poses, i)
                hand_rc = Raycaster(hand_meshes)
                pts = np.concatenate([hull @ T_wo[i][:3, :3].T + T_wo[i][:3, 3]] + [v for v, _ in hand_meshes])
                win = projected_window(K.K, T_wc, pts, cam.width, cam.height)
                if win is None:
                    win = (0, 1, 0, 1)
                fr = render_geometry(rays, T_wc, obj_rc, T_wo[i], hand_rc, cam.depth_max, window=win)
                depth = add_depth_noise(fr.depth_m, fr.cos_incidence, rng_cam, sim.depth_noise)
                depth = np.where((depth >= cam.depth_min) & (depth <= cam.depth_max), depth, 0.0)
                depth_u16 = np.clip(np.rint(depth / cam.depth_scale), 0, 65535).astype(np.uint16)
                rgb = shade_rgb(fr, rgb_obj, rng_cam, noise=2.0 * sim.depth_noise)
                n_all = int(fr.object_unoccluded.sum())
                vis = float(fr.object_mask.sum()) / n_all if n_all else 0.0
                writer.append(f"camera/{cam.name}", float(t), rgb=rgb, depth=depth_u16)
                writer.append(
                    f"gt/camera/{cam.name}",
                    float(t),
                    visible_fraction=np.float32(vis),
                    mask=fr.object_mask.astype(np.uint8),
                )
        _log(progress, f"cameras {time.perf_counter() - t0:.2f} s")

        contact_frac = {s: float(plan.in_contact_phase[s].mean()) for s in hk.sensor_names}
        writer.set_info(
            contact_fraction=contact_frac,
            touching_fraction=touching,
            contact_controlled=controlled,
            penetration_mm=list(sim.penetration_mm),
            generate_seconds=time.perf_counter() - t_start,
        )
    except BaseException:
        writer.flush()
        raise
    writer.close()
    _log(progress, f"total {time.perf_counter() - t_start:.2f} s -> {out_dir}")
    return out_dir
