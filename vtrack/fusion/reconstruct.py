"""``reconstruct_session``: session -> object-frame mesh, unified cloud, metrics, screenshot.

Mapping only: object poses are KNOWN (``gt/object_pose``); every observation is accumulated in the
object frame, and the result is compared with the session's GT mesh ``assets/object.ply`` (object
frame) when it exists.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np

from vtrack.errors import InputError
from vtrack.io.jsonio import write_json

METHODS = ("neural_sdf", "tsdf")

#: per-method default options (overridable through ``**opts``)
NEURAL_DEFAULTS: dict[str, Any] = {"n_iters": 400}


def _parse_modalities(modalities: Any) -> tuple[str, ...]:
    if isinstance(modalities, str):
        modalities = [m for m in modalities.replace("+", ",").split(",") if m.strip()]
    mods = tuple(dict.fromkeys(m.strip().lower() for m in modalities))
    if not mods or set(mods) - {"vision", "touch"}:
        raise InputError("unknown modalities", field="modalities", expected="vision and/or touch", got=list(mods))
    return mods


def reconstruct_observations(obs: list, method: str = "neural_sdf", *, online: bool = False,
                             frame_budget_ms: float = 25.0, **opts: Any) -> dict[str, Any]:
    """Run a reconstructor on object-frame observations. Returns mesh, timing and the model.

    Neural SDF options: ``n_iters`` (offline iterations), ``time_budget_s``, plus any
    :class:`~vtrack.fusion.neural_sdf.NeuralSDFReconstructor` argument. ``online=True`` feeds frames
    one by one with ``step(time_budget_ms=frame_budget_ms)`` and reports ms per frame.
    TSDF options: any :class:`~vtrack.fusion.tsdf.TSDFReconstructor` argument.
    """
    if method not in METHODS:
        raise InputError("unknown reconstruction method", field="method", expected=" or ".join(METHODS), got=method)
    t0 = time.perf_counter()
    out: dict[str, Any] = {"method": method, "online": online}
    if method == "tsdf":
        from vtrack.fusion.tsdf import TSDFReconstructor

        rec = TSDFReconstructor(**opts)
        frame_ms = []
        for o in obs:
            ti = time.perf_counter()
            rec.integrate_observation(o)
            frame_ms.append((time.perf_counter() - ti) * 1e3)
        t_int = time.perf_counter()
        V, F = rec.extract_mesh()
        out.update(frames=dict(rec.frames), ms_per_frame=float(np.mean(frame_ms)) if frame_ms else 0.0,
                   mesh_seconds=time.perf_counter() - t_int)
    else:
        from vtrack.fusion.neural_sdf import NeuralSDFReconstructor

        o2 = {**NEURAL_DEFAULTS, **opts}
        n_iters = int(o2.pop("n_iters"))
        budget = o2.pop("time_budget_s", None)
        rec = NeuralSDFReconstructor(**o2)
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
            out.update(ms_per_frame=float(np.mean(frame_ms)) if frame_ms else 0.0,
                       ms_per_frame_p95=float(np.percentile(frame_ms, 95)) if frame_ms else 0.0,
                       cpu_ms_per_frame=float(np.mean(cpu_ms)) if cpu_ms else 0.0)
        else:
            info = rec.fit(obs, n_iters=n_iters, time_budget_s=budget)
            out.update(train=info, ms_per_frame=1e3 * info["seconds"] / max(1, len(obs)))
        out["iterations"] = rec.iterations
        t_int = time.perf_counter()
        V, F = rec.extract_mesh()
        out["mesh_seconds"] = time.perf_counter() - t_int
    out.update(vertices=V, faces=F, model=rec, seconds=time.perf_counter() - t0)
    return out


def reconstruct_session(session_dir: str | Path, out_dir: str | Path, method: str = "neural_sdf",
                        modalities: Any = ("vision", "touch"), *, tactile_source: str = "auto",
                        online: bool = False, screenshot: bool = True, vision_frame_step: int = 2,
                        touch_frame_step: int = 2, vision_stride: int = 4, touch_stride: int = 6,
                        threads: int | None = 1, **opts: Any) -> dict[str, Any]:
    """Reconstruct a session's object (known object poses) and write the result folder.

    Writes ``mesh.ply``, ``cloud.ply`` (object-frame unified cloud with ``modality``, ``sensor_id``,
    ``t``, ``confidence``, ``tactile_value``), ``metrics.json``, ``result.json`` and ``screenshot.png``
    into ``out_dir``. Returns the metrics dict (also in ``metrics.json``): ``fscore`` at 1/2/5/10 mm,
    ``precision``, ``recall`` (at 5 mm; per threshold under ``precision_at`` / ``recall_at``),
    ``chamfer_mm``, ``normal_consistency``, ``seconds`` (whole reconstruction incl. loading),
    ``modalities``, ``method``, and what was used (``tactile_source``, frames, points).
    """
    from vtrack.fusion.observations import load_observations
    from vtrack.io.export import export_mesh
    from vtrack.io.session import open_session

    t_start = time.perf_counter()
    cpu_start = time.process_time()
    if threads and method == "neural_sdf":
        import torch

        torch.set_num_threads(int(threads))
    mods = _parse_modalities(modalities)
    if method not in METHODS:
        raise InputError("unknown reconstruction method", field="method", expected=" or ".join(METHODS), got=method)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    reader = open_session(session_dir)
    so = load_observations(reader, mods, tactile_source=tactile_source, vision_stride=vision_stride,
                           vision_frame_step=vision_frame_step, touch_stride=touch_stride,
                           touch_frame_step=touch_frame_step, keep_depth=(method == "tsdf"))
    t_loaded = time.perf_counter()
    cloud = so.cloud()
    n_pts = cloud.counts()
    res = reconstruct_observations(so.observations, method, online=online, **opts)
    V, F = res["vertices"], res["faces"]
    seconds = time.perf_counter() - t_start
    gt_path = reader.path / "assets" / "object.ply"
    metrics: dict[str, Any] = {"method": method, "modalities": list(mods), "online": online,
                               "seconds": seconds, "cpu_seconds": time.process_time() - cpu_start,
                               "load_seconds": t_loaded - t_start,
                               "reconstruct_seconds": res["seconds"], "ms_per_frame": res.get("ms_per_frame"),
                               "frames": len(so.observations), "points": n_pts,
                               "tactile_source": so.info.get("tactile_source", "none"),
                               "n_vertices": int(len(V)), "n_faces": int(len(F)),
                               "session": str(reader.path)}
    for k in ("iterations", "ms_per_frame_p95", "cpu_ms_per_frame"):
        if k in res:
            metrics[k] = res[k]
    if gt_path.exists():
        from vtrack.eval.reconstruction import load_mesh, mesh_metrics

        Vg, Fg = load_mesh(gt_path)
        m = mesh_metrics(V, F, Vg, Fg)
        metrics.update(fscore=m["fscore"], precision=m["precision"]["5mm"], recall=m["recall"]["5mm"],
                       precision_at=m["precision"], recall_at=m["recall"], chamfer_mm=m["chamfer_mm"],
                       accuracy_mm=m["accuracy_mm"], completeness_mm=m["completeness_mm"],
                       normal_consistency=m["normal_consistency"], empty=m["empty"])
    else:
        metrics.update(fscore=None, precision=None, recall=None, chamfer_mm=None,
                       note="session has no assets/object.ply: no ground truth to score against")
    # outputs
    if len(F):
        export_mesh(out / "mesh.ply", V, F)
    else:
        _write_empty_mesh(out / "mesh.ply")
    cloud.to_ply(out / "cloud.ply")
    if screenshot:
        try:
            save_screenshot(out / "screenshot.png", V, F, cloud, title=f"{method} ({'+'.join(mods)})",
                            gt_path=gt_path if gt_path.exists() else None)
            metrics["screenshot"] = "screenshot.png"
        except Exception as e:  # no display / VTK problem must not lose the reconstruction
            metrics["screenshot_error"] = f"{type(e).__name__}: {e}"
    write_json(out / "metrics.json", metrics)
    write_json(out / "result.json", {"kind": "reconstruction", "session": str(reader.path), "method": method,
                                      "modalities": list(mods), "mesh": "mesh.ply", "cloud": "cloud.ply",
                                      "metrics": "metrics.json"})
    return metrics


def warm_up(method: str = "neural_sdf", screenshot: bool = True, **_: Any) -> None:
    """Import what :func:`reconstruct_session` will use (batch workers call this before timing starts)."""
    import importlib

    mods = ["vtrack.fusion.observations", "vtrack.io.session", "vtrack.io.export", "vtrack.eval.reconstruction",
            "vtrack.kinematics.hand", "vtrack.scene.load", "vtrack.tactile.pipeline", "scipy.spatial", "trimesh",
            "yourdfpy", "zarr"]
    mods += ["vtrack.fusion.tsdf", "open3d"] if method == "tsdf" else ["vtrack.fusion.neural_sdf", "torch"]
    if screenshot:
        mods.append("pyvista")
    for m in mods:
        importlib.import_module(m)


def _write_empty_mesh(path: Path) -> None:
    path.write_text("ply\nformat ascii 1.0\ncomment vtrack: empty reconstruction\nelement vertex 0\n"
                    "property float x\nproperty float y\nproperty float z\nelement face 0\n"
                    "property list uchar int vertex_indices\nend_header\n")


def save_screenshot(path: str | Path, vertices: np.ndarray, faces: np.ndarray, cloud: Any = None,
                    title: str = "", gt_path: Path | None = None, size: tuple[int, int] = (900, 600)) -> Path:
    """Off-screen pyvista render: reconstructed mesh, GT wireframe, vision (blue) / touch (red) points."""
    import pyvista as pv

    pl = pv.Plotter(off_screen=True, window_size=size)
    if len(faces):
        fa = np.hstack([np.full((len(faces), 1), 3), faces]).astype(np.int64).ravel()
        pl.add_mesh(pv.PolyData(np.asarray(vertices), fa), color="lightgray", smooth_shading=True)
    if gt_path is not None:
        gt = pv.read(str(gt_path))
        pl.add_mesh(gt, style="wireframe", color="green", opacity=0.15)
    if cloud is not None and len(cloud):
        from vtrack.fusion.cloud import TOUCH

        rng = np.random.default_rng(0)
        for mod, colour in ((0, "royalblue"), (TOUCH, "red")):
            P = cloud.xyz[cloud.modality == mod]
            if len(P) > 20000:
                P = P[rng.choice(len(P), 20000, replace=False)]
            if len(P):
                pl.add_points(P, color=colour, point_size=2 if mod == 0 else 3, render_points_as_spheres=False)
    pl.add_text(title, font_size=10)
    pl.view_isometric()
    pl.screenshot(str(path))
    pl.close()
    return Path(path)
