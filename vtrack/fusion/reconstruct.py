"""``reconstruct_session``: session -> object-frame mesh, poses, unified cloud, metrics, screenshot.

Works on a recording without ground truth: the object poses come from the tracker run on the same
session (``poses="track"``: SLAM for an unknown object, known-shape tracking when ``mesh`` is given),
from a ``poses.csv`` file, or - as a labelled ORACLE ablation - from the simulator (``poses="gt"``).
Every observation (frames layer: segmented depth, contacts from tactile images) is moved into the object
frame of those poses and fused. The result is scored against ground truth only when it is available
(``gt=`` session, or the session's own ``gt/``), after aligning the estimate's object frame to the GT's
(:mod:`vtrack.eval.session_gt`).
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np

from vtrack.errors import InputError
from vtrack.io.jsonio import write_json

METHODS = ("neural_sdf", "tsdf")

#: Tactile pipeline settings of the mapping run (point stride; working resolution from the image size): denser
#: contacts than tracking's own (``vtrack.tracking.run.TRACK_TOUCH_STRIDE`` / ``TRACK_TOUCH_DOWNSAMPLE``).
TOUCH_STRIDE = 3
TOUCH_DOWNSAMPLE = "auto"

#: Offline neural SDF: rounds of per-frame pose refinement against the fitted SDF (0 = fuse the poses as given).
POSE_ROUNDS = 0
#: Iterations of the fits that only serve the pose refinement (the final fit uses ``n_iters``).
POSE_ITERS = 400


def _parse_modalities(modalities: Any) -> tuple[str, ...]:
    if isinstance(modalities, str):
        modalities = [m for m in modalities.replace("+", ",").split(",") if m.strip()]
    mods = tuple(dict.fromkeys(m.strip().lower() for m in modalities))
    if not mods or set(mods) - {"vision", "touch"}:
        raise InputError("unknown modalities", field="modalities", expected="vision and/or touch", got=list(mods))
    return mods


def reconstruct_observations(
    obs: list, method: str = "neural_sdf", *, online: bool = False, frame_budget_ms: float = 25.0, **opts: Any
) -> dict[str, Any]:
    """Run a reconstructor on object-frame observations. Returns mesh, timing and the model.

    Neural SDF options: ``n_iters`` (offline iterations), ``time_budget_s``, ``pose_rounds`` (offline joint pose
    and shape, :mod:`vtrack.fusion.posefit`: rounds of fit -> align every frame to the SDF -> fit again; default
    :data:`POSE_ROUNDS`; the first fits use ``pose_iters`` iterations), plus any
    :class:`~vtrack.fusion.neural_sdf.NeuralSDFReconstructor` argument. The result's ``pose_corrections`` =
    ``(times, (K, 4, 4))`` object-frame corrections per observation time (:func:`~vtrack.fusion.posefit.
    corrected_poses` turns them into poses); ``observations`` = the observations as finally fused.
    ``online=True`` feeds frames one by one with ``step(time_budget_ms=frame_budget_ms)`` and reports ms per frame.
    TSDF options: any :class:`~vtrack.fusion.tsdf.TSDFReconstructor` argument.
    """
    if method not in METHODS:
        raise InputError("unknown reconstruction method", field="method", expected=" or ".join(METHODS), got=method)
    t0 = time.perf_counter()
    out: dict[str, Any] = {"method": method, "online": online}
    from vtrack import registry

    cls = registry.load(f"reconstruction.{method}")
    if method == "tsdf":
        rec = cls(**opts)
        frame_ms = []
        for o in obs:
            ti = time.perf_counter()
            rec.integrate_observation(o)
            frame_ms.append((time.perf_counter() - ti) * 1e3)
        t_int = time.perf_counter()
        V, F = rec.extract_mesh()
        out.update(
            frames=dict(rec.frames),
            ms_per_frame=float(np.mean(frame_ms)) if frame_ms else 0.0,
            mesh_seconds=time.perf_counter() - t_int,
        )
    else:
        o2 = dict(opts)
        n_iters = o2.pop("n_iters", None)
        if n_iters is None:  # the offline default lives with the reconstructor
            from vtrack.fusion.neural_sdf import OFFLINE_ITERS

            n_iters = OFFLINE_ITERS
        n_iters = int(n_iters)
        budget = o2.pop("time_budget_s", None)
        rounds = 0 if online else int(o2.pop("pose_rounds", POSE_ROUNDS))
        pose_iters = int(o2.pop("pose_iters", POSE_ITERS))
        if rounds > 0 and budget is None:
            from vtrack.fusion.posefit import align_frames, apply_corrections

            t_p = time.perf_counter()
            C_all = None
            pose_info: list[dict] = []
            for _ in range(rounds):
                pre = cls(**o2)
                pre.fit(obs, n_iters=pose_iters)
                times_c, C, info = align_frames(pre.query, obs)
                obs = apply_corrections(obs, times_c, C)
                C_all = C if C_all is None else np.einsum("nij,njk->nik", C, C_all)
                pose_info.append(info)
            out.update(pose_corrections=(times_c, C_all), pose_refine=pose_info, pose_seconds=time.perf_counter() - t_p)
        rec = cls(**o2)
        if online:
            pts = [o.points for o in obs if len(o)]
            if pts and "bounds" not in o2:
                # The SLAM mapper would fix a generous box at start; here size it from all data.
                rec.set_bounds(rec.bounds_from_points(np.concatenate(pts)))
            frame_ms, cpu_ms = [], []
            for o in obs:
                ti, ci = time.perf_counter(), time.process_time()
                rec.integrate_observation(o)
                rec.step(time_budget_ms=frame_budget_ms)
                frame_ms.append((time.perf_counter() - ti) * 1e3)
                cpu_ms.append((time.process_time() - ci) * 1e3)
            # wall time per frame, and CPU time (what the frame costs without other processes competing)
            out.update(
                ms_per_frame=float(np.mean(frame_ms)) if frame_ms else 0.0,
                ms_per_frame_p95=float(np.percentile(frame_ms, 95)) if frame_ms else 0.0,
                cpu_ms_per_frame=float(np.mean(cpu_ms)) if cpu_ms else 0.0,
            )
        else:
            info = rec.fit(obs, n_iters=n_iters, time_budget_s=budget)
            out.update(train=info, ms_per_frame=1e3 * info["seconds"] / max(1, len(obs)))
        out["iterations"] = rec.iterations
        t_int = time.perf_counter()
        V, F = rec.extract_mesh()
        out["mesh_seconds"] = time.perf_counter() - t_int
    out.update(vertices=V, faces=F, model=rec, observations=obs, seconds=time.perf_counter() - t0)
    return out


def reconstruct_session(
    session_dir: str | Path,
    out_dir: str | Path,
    method: str = "neural_sdf",
    modalities: Any = ("vision", "touch"),
    *,
    poses: str | Path = "track",
    mesh: str | Path | None = None,
    gt: str | Path | None = None,
    tactile_source: str = "pipeline",
    segmentation: str = "pipeline",
    online: bool = False,
    screenshot: bool = True,
    frame_step: int = 2,
    vision_stride: int = 4,
    touch_stride: int = TOUCH_STRIDE,
    threads: int | None = 1,
    track_opts: dict | None = None,
    **opts: Any,
) -> dict[str, Any]:
    """Reconstruct a session's object and write the result folder.

    Args:
        poses: ``track`` (run the tracker: SLAM, or known shape with ``mesh``), ``gt`` (ORACLE ablation) or
            the path of a ``poses.csv`` (``T_world_object`` over time, :mod:`vtrack.io.poses`).
        mesh: known object shape for tracking (object frame, m); the reconstruction is then in its frame.
        gt: session with ground truth to SCORE against (default: this session if it has ``gt/``).
        frame_step: fuse every k-th frame of the time base (the first camera's frames).
        track_opts: options of :func:`vtrack.tracking.run.track_session`.

    Writes ``mesh.ply`` (object frame), ``poses.csv`` (the poses of the frames used, same object frame),
    ``cloud.ply`` (object-frame unified cloud with ``modality``, ``sensor_id``, ``t``, ``confidence``,
    ``tactile_value``), ``metrics.json``, ``result.json`` and ``screenshot.png``; with ground truth
    ``fscore`` at 1/2/5/10 mm, ``precision``, ``recall``, ``chamfer_mm``, ``normal_consistency``.
    """
    from vtrack.eval.session_gt import SessionGroundTruth
    from vtrack.frames.session import ORACLE_SEGMENTATIONS, SessionFrames
    from vtrack.fusion.observations import SessionObservations, observations_from_frames
    from vtrack.io.export import export_mesh
    from vtrack.io.poses import PoseTrack, read_poses_csv, write_poses_csv

    t_start = time.perf_counter()
    cpu_start = time.process_time()
    if threads and method == "neural_sdf":
        import torch

        torch.set_num_threads(int(threads))
    mods = _parse_modalities(modalities)
    if method not in METHODS:
        raise InputError("unknown reconstruction method", field="method", expected=" or ".join(METHODS), got=method)
    out = Path(out_dir)
    gt_data = SessionGroundTruth.find(gt, session_dir)
    oracle = (["tactile"] if tactile_source == "gt" else []) + (
        ["segmentation"] if segmentation in ORACLE_SEGMENTATIONS else []
    )
    track_metrics: dict[str, Any] | None = None
    mesh_frame: Path | None = None
    if str(poses) == "track":
        from vtrack.tracking.run import track_session

        kept: dict[str, Any] = {}
        shape = "known_shape" if mesh is not None else "slam"
        track_metrics, (times, est) = track_session(
            session_dir,
            out / "tracking",
            shape=shape,
            modalities=mods,
            mesh=mesh,
            gt=gt,
            tactile_source=tactile_source,
            segmentation=segmentation,
            write=True,
            return_poses=True,
            keep_frames=kept,
            keep_step=frame_step,
            **{"touch_stride": touch_stride, "touch_downsample": TOUCH_DOWNSAMPLE, **(track_opts or {})},
        )
        frames, built = kept["frames"], kept["built"]
        track = PoseTrack(times, est)
        mesh_frame = Path(mesh) if mesh is not None else None
        pose_source = f"tracking ({shape})"
    else:
        frames = SessionFrames(
            session_dir, mods, tactile_source=tactile_source, segmentation=segmentation, touch_stride=touch_stride
        )
        built = [(i, frames.frame(i)[0]) for i in range(0, len(frames), max(1, int(frame_step)))]
        if str(poses) == "gt":
            if gt_data is None:
                raise InputError(
                    "poses 'gt' (oracle) need ground truth",
                    path=session_dir,
                    field="--poses",
                    expected="track | FILE, or --gt SESSION",
                )
            track = PoseTrack(gt_data.pose_times, gt_data.poses)
            mesh_frame = gt_data.mesh_path
            pose_source = "ground truth [oracle]"
            oracle.append("poses")
        else:
            track = read_poses_csv(poses)
            mesh_frame = Path(mesh) if mesh is not None else None
            pose_source = f"file {poses}"
    t_loaded = time.perf_counter()
    so = observations_from_frames(frames, built, track, vision_stride=vision_stride, keep_depth=(method == "tsdf"))
    if not so.observations:
        raise InputError(
            "no object observations in the session (no segmented depth, no contact)",
            path=frames.path,
            expected="frames where the object is seen or touched",
        )
    cloud = so.cloud()
    n_pts = cloud.counts()
    res = reconstruct_observations(so.observations, method, online=online, **opts)
    V, F = res["vertices"], res["faces"]
    seconds = time.perf_counter() - t_start
    used_t = np.array([frames.times[i] for i, _ in built])
    if "pose_corrections" in res:
        # joint pose and shape: the fused frames were re-aligned to the SDF; their poses move with them (the first
        # frame's correction is the identity, so the object frame is the one the poses defined)
        from vtrack.fusion.posefit import corrected_poses

        tc, C = res["pose_corrections"]
        track = PoseTrack(used_t, corrected_poses(used_t, track.at(used_t), tc, C))
        cloud = SessionObservations(res["observations"], so.sensor_names, so.info).cloud()
    metrics: dict[str, Any] = {
        "method": method,
        "modalities": list(mods),
        "online": online,
        "poses": pose_source,
        "oracle": oracle,
        "blind": not oracle,
        "seconds": seconds,
        "cpu_seconds": time.process_time() - cpu_start,
        "load_seconds": t_loaded - t_start,
        "reconstruct_seconds": res["seconds"],
        "ms_per_frame": res.get("ms_per_frame"),
        "frames": len(so.observations),
        "points": n_pts,
        "tactile_source": so.info.get("tactile_source", "none"),
        "segmentation": so.info.get("segmentation", "none"),
        "n_vertices": int(len(V)),
        "n_faces": int(len(F)),
        "session": str(frames.path),
    }
    if track_metrics is not None:
        metrics["tracking"] = {
            k: v
            for k, v in track_metrics.items()
            if k
            in (
                "mode",
                "init",
                "motion_err_mm",
                "motion_drift_mm",
                "add_s_mm",
                "drift_mm",
                "poses_per_s",
                "ms_per_frame_mean",
                "status_counts",
                "alignment",
            )
        }
    if "pose_refine" in res:
        metrics["pose_refine"] = {"rounds": res["pose_refine"], "seconds": res["pose_seconds"]}
    for k in ("iterations", "ms_per_frame_p95", "cpu_ms_per_frame", "mesh_seconds"):
        if k in res:
            metrics[k] = res[k]
    if gt_data is not None and gt_data.mesh_path is not None:
        from vtrack.eval.reconstruction import mesh_metrics
        from vtrack.eval.session_gt import align_mesh_to_gt
        from vtrack.io.mesh import load_mesh

        Vg, Fg = load_mesh(gt_data.mesh_path)
        Va, how = align_mesh_to_gt(gt_data, V, mesh_frame, used_t, track.at(used_t))
        m = mesh_metrics(Va, F, Vg, Fg)
        metrics.update(
            fscore=m["fscore"],
            precision=m["precision"]["5mm"],
            recall=m["recall"]["5mm"],
            precision_at=m["precision"],
            recall_at=m["recall"],
            chamfer_mm=m["chamfer_mm"],
            accuracy_mm=m["accuracy_mm"],
            completeness_mm=m["completeness_mm"],
            normal_consistency=m["normal_consistency"],
            empty=m["empty"],
            alignment=how,
            scored_against=str(gt_data.path),
        )
    else:
        metrics.update(
            fscore=None,
            precision=None,
            recall=None,
            chamfer_mm=None,
            note="no ground truth to score against (pass --gt SESSION to score)",
        )
    # outputs
    out.mkdir(parents=True, exist_ok=True)
    if len(F):
        export_mesh(out / "mesh.ply", V, F)
    else:
        _write_empty_mesh(out / "mesh.ply")
    write_poses_csv(out / "poses.csv", used_t, track.at(used_t))
    cloud.to_ply(out / "cloud.ply")
    if screenshot:
        try:
            from vtrack.viz.screenshot import save_mesh_cloud_screenshot

            save_mesh_cloud_screenshot(out / "screenshot.png", V, F, cloud, title=f"{method} ({'+'.join(mods)})")
            metrics["screenshot"] = "screenshot.png"
        except Exception as e:  # no display / VTK problem must not lose the reconstruction
            metrics["screenshot_error"] = f"{type(e).__name__}: {e}"
    write_json(out / "metrics.json", metrics)
    write_json(
        out / "result.json",
        {
            "kind": "reconstruction",
            "session": str(frames.path),
            "method": method,
            "modalities": list(mods),
            "mesh": "mesh.ply",
            "poses": "poses.csv",
            "cloud": "cloud.ply",
            "metrics": "metrics.json",
        },
    )
    return metrics


def warm_up(method: str = "neural_sdf", screenshot: bool = True, **_: Any) -> None:
    """Import what :func:`reconstruct_session` will use (batch workers call this before timing starts)."""
    import importlib

    mods = [
        "vtrack.fusion.observations",
        "vtrack.io.session",
        "vtrack.io.export",
        "vtrack.eval.reconstruction",
        "vtrack.kinematics.hand",
        "vtrack.scene.load",
        "vtrack.tactile.pipeline",
        "scipy.spatial",
        "trimesh",
        "yourdfpy",
        "zarr",
    ]
    mods += ["vtrack.fusion.tsdf", "open3d"] if method == "tsdf" else ["vtrack.fusion.neural_sdf", "torch"]
    if screenshot:
        mods.append("pyvista")
    for m in mods:
        importlib.import_module(m)


def _write_empty_mesh(path: Path) -> None:
    path.write_text(
        "ply\nformat ascii 1.0\ncomment vtrack: empty reconstruction\nelement vertex 0\n"
        "property float x\nproperty float y\nproperty float z\nelement face 0\n"
        "property list uchar int vertex_indices\nend_header\n"
    )
