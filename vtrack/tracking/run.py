"""Track a recorded session end to end and write the result folder.

``track_session(SESSION, OUT)`` writes (see docs/tracking.md):

- ``poses.csv``: ``t, x, y, z, qx, qy, qz, qw`` (estimate) + ``gt_*`` columns when the session has
  ground truth, + ``status`` and ``ms`` per frame;
- ``metrics.json``: ``add_s_mm``, ``drift_mm`` (mean position error of the object centre),
  ``rot_drift_deg``, ``ms_per_frame_mean`` (point extraction + tracker step, disk reads excluded),
  ``mode``, ``modalities`` and more;
- ``result.json`` (``{"kind": "tracking", ...}``) and ``error.png`` (error over time).

Initialisation: the first ground-truth pose (the documented protocol, as in NeuralFeels'
tracking experiments), optionally perturbed by ``init_perturb = (metres, radians)``; without
ground truth, the scene's ``object.T_world_object``.
"""

from __future__ import annotations

import csv
import time
from pathlib import Path
from typing import Any

import numpy as np

from vtrack.errors import InputError
from vtrack.geometry import se3
from vtrack.io.jsonio import write_json

SHAPES = ("known", "slam")
METHODS = ("ours", "icp")


def perturb_pose(T: np.ndarray, trans_m: float, rot_rad: float, seed: int = 0) -> np.ndarray:
    """``T`` moved by exactly ``trans_m`` along a random direction and rotated by ``rot_rad`` about a
    random axis through the object origin (object frame)."""
    rng = np.random.default_rng(seed)
    u = rng.normal(size=3)
    u /= np.linalg.norm(u)
    a = rng.normal(size=3)
    a /= np.linalg.norm(a)
    out = np.asarray(T, dtype=np.float64) @ se3.make_transform(se3.so3_exp(a * rot_rad))
    out[:3, 3] += u * trans_m
    return out


def build_tracker(shape: str, mesh: Path | None, T_init: np.ndarray, method: str = "ours",
                  scene: Any = None, **opts: Any):
    """The tracker for a mode: ``ours`` known/slam or the ``icp`` baseline."""
    if method == "icp":
        if mesh is None:
            raise InputError("the ICP baseline needs the object mesh", field="mesh")
        from vtrack.tracking.icp import ICPTracker

        return ICPTracker(mesh, T_init, **opts)
    if method != "ours":
        raise InputError("unknown method", field="method", expected="|".join(METHODS), got=method)
    if shape == "known":
        from vtrack.tracking.tracker import KnownShapeTracker

        if mesh is None:
            raise InputError("known-shape tracking needs the object mesh (session assets/object.ply)",
                             field="mesh")
        return KnownShapeTracker(mesh, T_init, **opts)
    if shape == "slam":
        from vtrack.tracking.slam import SLAMTracker

        return SLAMTracker(T_init, **opts)
    raise InputError("unknown shape mode", field="shape", expected="known|slam", got=shape)


def warm_up(shape: str = "known", method: str = "ours", write: bool = True, **_: Any) -> None:
    """Import what :func:`track_session` will use (batch workers call this before timing starts)."""
    import importlib

    mods = ["vtrack.tracking.frontend", "vtrack.eval.pose_metrics", "vtrack.tracking.sdf_grid", "vtrack.io.session",
            "vtrack.kinematics.hand", "vtrack.scene.load", "scipy.spatial", "trimesh", "yourdfpy", "zarr", "open3d"]
    if method == "icp":
        mods.append("vtrack.tracking.icp")
    else:
        mods.append("vtrack.tracking.slam" if shape == "slam" else "vtrack.tracking.tracker")
    if write:
        mods.append("matplotlib.pyplot")
    for m in mods:
        importlib.import_module(m)


def track_session(session_dir: str | Path, out_dir: str | Path, shape: str = "known",
                  modalities: tuple[str, ...] | list[str] = ("vision", "touch"), method: str = "ours",
                  init_perturb: tuple[float, float] | None = None, max_frames: int = 0, seed: int = 0,
                  depth_stride: int = 4, touch_stride: int = 6, write: bool = True, **opts: Any) -> dict:
    """Run a tracker over a session; return the metrics dict (also written to ``out_dir``).

    Args:
        session_dir: session directory (``vtrack.io.session`` format).
        out_dir: result folder (created).
        shape: ``known`` (SDF of ``assets/object.ply``) or ``slam`` (shape reconstructed online).
        modalities: ("vision",), ("touch",) or both.
        method: ``ours`` or ``icp`` (Open3D point-to-plane baseline, vision only).
        init_perturb: (metres, radians) applied to the first ground-truth pose.
        max_frames: track only the first frames (0 = all).
        **opts: tracker options (:class:`~vtrack.tracking.window.TrackerOptions` fields, ...).
    """
    from vtrack.tracking.frontend import SessionFrames

    if shape not in SHAPES:
        raise InputError("unknown shape mode", field="shape", expected="known|slam", got=shape)
    modalities = tuple(modalities)
    if method == "icp":
        modalities = ("vision",)
    frames = SessionFrames(session_dir, modalities=modalities, depth_stride=depth_stride,
                           touch_stride=touch_stride, max_frames=max_frames)
    mesh = frames.mesh_path if frames.mesh_path.exists() else None
    if frames.gt is not None:
        T_init = frames.gt[0].copy()
        init_from = "ground truth (first frame)"
    else:
        T_init = frames.scene.object.T_world_object.as_matrix()
        init_from = "scene object.T_world_object"
    if init_perturb is not None:
        T_init = perturb_pose(T_init, float(init_perturb[0]), float(init_perturb[1]), seed)
        init_from += f" perturbed by {init_perturb[0] * 1e3:.1f} mm / {np.degrees(init_perturb[1]):.1f} deg"
    tracker = build_tracker(shape, mesh, T_init, method=method, **opts)
    n = len(frames)
    est = np.zeros((n, 4, 4))
    ms = np.zeros(n)
    ms_prep = np.zeros(n)
    cpu_ms = np.zeros(n)
    status: list[str] = []
    for i in range(n):
        raw = frames.read(i)  # disk read + decompression: not part of the per-frame tracking cost
        c0, t0 = time.process_time(), time.perf_counter()
        fr = frames.build(float(frames.times[i]), raw)
        t1 = time.perf_counter()
        est[i] = tracker.step(fr)
        ms[i] = (time.perf_counter() - t0) * 1e3
        ms_prep[i] = (t1 - t0) * 1e3
        cpu_ms[i] = (time.process_time() - c0) * 1e3
        status.append(tracker.last_info.status if tracker.last_info else "ok")
    if not np.all(np.isfinite(est)):
        raise RuntimeError("tracker produced non-finite poses")  # guarded against; should never happen
    metrics: dict[str, Any] = {
        "mode": "icp" if method == "icp" else shape,
        "method": method,
        "modalities": list(modalities),
        "frames": n,
        "init": init_from,
        "ms_per_frame_mean": float(ms.mean()),
        "ms_per_frame_median": float(np.median(ms)),
        "ms_per_frame_p95": float(np.percentile(ms, 95)),
        "ms_prep_mean": float(ms_prep.mean()),
        # CPU time of this process: a steadier measure than wall time on a shared machine
        "cpu_ms_per_frame_mean": float(cpu_ms.mean()),
        "poses_per_s": float(1e3 / max(ms.mean(), 1e-9)),
        "status_counts": {s: status.count(s) for s in sorted(set(status))},
        "session": str(Path(session_dir)),
    }
    errors = None
    if frames.gt is not None:
        from vtrack.eval.pose_metrics import (
            mesh_symmetry_axis,
            sample_model_points,
            summarize,
            trajectory_errors,
        )
        from vtrack.tracking.sdf_grid import load_mesh_arrays

        if mesh is None:
            raise InputError("metrics need the object mesh", path=frames.path / "assets" / "object.ply")
        V, F = load_mesh_arrays(mesh)
        pts = sample_model_points(V, F, 1000, seed=0)
        errors = trajectory_errors(est, frames.gt, pts, symmetric=bool(frames.scene.object.symmetric),
                                   centre=0.5 * (V.min(0) + V.max(0)), axis=mesh_symmetry_axis(V, F))
        metrics.update(summarize(errors))
        metrics["symmetric"] = bool(frames.scene.object.symmetric)
    if hasattr(tracker, "map_metrics"):
        metrics.update(tracker.map_metrics())
    if write:
        _write_outputs(Path(out_dir), frames, est, ms, status, metrics, errors)
    return metrics


def _write_outputs(out: Path, frames, est, ms, status, metrics, errors) -> None:
    from vtrack.eval.pose_metrics import plot_errors

    out.mkdir(parents=True, exist_ok=True)
    q = se3.matrix_to_quat(est[:, :3, :3])
    cols = ["t", "x", "y", "z", "qx", "qy", "qz", "qw"]
    gt = frames.gt
    if gt is not None:
        cols += ["gt_x", "gt_y", "gt_z", "gt_qx", "gt_qy", "gt_qz", "gt_qw"]
        qg = se3.matrix_to_quat(gt[:, :3, :3])
    cols += ["status", "ms"]
    with open(out / "poses.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(cols)
        for i, t in enumerate(frames.times):
            row = [f"{t:.6f}", *[f"{v:.7f}" for v in est[i, :3, 3]], *[f"{v:.7f}" for v in q[i]]]
            if gt is not None:
                row += [*[f"{v:.7f}" for v in gt[i, :3, 3]], *[f"{v:.7f}" for v in qg[i]]]
            row += [status[i], f"{ms[i]:.3f}"]
            w.writerow(row)
    write_json(out / "metrics.json", metrics)
    write_json(out / "result.json", {"kind": "tracking", "session": str(frames.path.resolve()),
                                     "mode": metrics["mode"], "modalities": metrics["modalities"],
                                     "files": ["poses.csv", "metrics.json", "error.png"]})
    if errors is not None:
        lost = np.array([s in ("lost",) for s in status])
        plot_errors(frames.times, errors, out / "error.png",
                    title=f"{metrics['mode']} / {'+'.join(metrics['modalities'])}: "
                          f"drift {metrics['drift_mm']:.2f} mm, ADD-S {metrics['add_s_mm']:.2f} mm", lost=lost)


