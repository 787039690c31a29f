"""``vtrack bench fusion``: reconstruction ablation (vision / touch / visuo-tactile x TSDF / neural SDF).

Full mode: simulator sessions (``vtrack.sim.fixtures.tiny_session_path``, cached) of the default
scene over the occlusion sweep (none / medium / heavy) for the soup can, plus two more YCB objects
without occlusion; known object poses; GT tactile height maps. Extra operating points (TSDF voxel
size, neural SDF iterations, online neural SDF at a 25 ms frame budget) on the unoccluded soup can.
Quick mode (< 1 min): ray-cast observations (:mod:`vtrack.fusion.synthetic`, no simulator) of the
soup can, full ring of views vs a 60 deg arc (occluded), touch on the unseen side.

Columns: ``fscore_5mm`` (error column, higher is better), ``fscore_1mm/2mm/10mm``, ``precision``,
``recall`` (5 mm), ``chamfer_mm``, ``s_session`` (load + reconstruct + mesh, s), ``ms`` = ms per
frame (reconstruction time / frames; online: measured per frame).
"""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Any

import numpy as np

from vtrack.bench.harness import BenchTable

MODS = {"vision": (0,), "touch": (1,), "vision+touch": (0, 1)}


def _score(V, F, Vg, Fg) -> dict[str, Any]:
    from vtrack.eval.reconstruction import mesh_metrics

    m = mesh_metrics(V, F, Vg, Fg)
    return {"fscore_1mm": m["fscore"]["1mm"], "fscore_2mm": m["fscore"]["2mm"], "fscore_5mm": m["fscore"]["5mm"],
            "fscore_10mm": m["fscore"]["10mm"], "precision": m["precision"]["5mm"], "recall": m["recall"]["5mm"],
            "chamfer_mm": m["chamfer_mm"] if m["chamfer_mm"] is not None else float("nan")}


def _run(table: BenchTable, obs: list, Vg, Fg, *, method: str, mods: str, setting: str, object_name: str,
         occlusion: str, load_s: float, online: bool = False, **opts: Any) -> None:
    from vtrack.fusion.reconstruct import reconstruct_observations

    sel = [o for o in obs if o.modality in MODS[mods]]
    t0 = time.perf_counter()
    res = reconstruct_observations(sel, method, online=online, **opts)
    rec_s = time.perf_counter() - t0
    frames = max(1, len(sel))
    ms = res.get("ms_per_frame", 1e3 * rec_s / frames) if online else 1e3 * rec_s / frames
    table.add(method=f"{method}/{mods}", setting=setting, object=object_name, occlusion=occlusion,
              frames=len(sel), **_score(res["vertices"], res["faces"], Vg, Fg),
              s_session=load_s + rec_s, ms=ms)


def _quick(table: BenchTable) -> None:
    from vtrack.fusion.synthetic import make_observations
    from vtrack.paths import shared_data_dir

    mesh = shared_data_dir() / "objects" / "ycb" / "005_tomato_soup_can.ply"
    for occ, kw in (("none", dict(n_views=6, arc_deg=360.0)), ("heavy", dict(n_views=2, arc_deg=60.0))):
        t0 = time.perf_counter()
        obs, V, F = make_observations(mesh, n_touch=30, touch_region="unseen", seed=0, **kw)
        load_s = time.perf_counter() - t0
        for mods in MODS:
            _run(table, obs, V, F, method="tsdf", mods=mods, setting="voxel=2mm", object_name="soup_can",
                 occlusion=occ, load_s=load_s, voxel_size=0.002)
            _run(table, obs, V, F, method="neural_sdf", mods=mods, setting="iters=100", object_name="soup_can",
                 occlusion=occ, load_s=load_s, n_iters=100, mesh_cell_mm=2.5)
        if occ == "heavy":
            for vs in (0.0015, 0.003):
                _run(table, obs, V, F, method="tsdf", mods="vision+touch", setting=f"voxel={vs * 1e3:g}mm",
                     object_name="soup_can", occlusion=occ, load_s=load_s, voxel_size=vs)
            for it in (40, 200):
                _run(table, obs, V, F, method="neural_sdf", mods="vision+touch", setting=f"iters={it}",
                     object_name="soup_can", occlusion=occ, load_s=load_s, n_iters=it, mesh_cell_mm=2.5)


def _full(table: BenchTable, seconds: float) -> None:
    from vtrack.eval.reconstruction import load_mesh
    from vtrack.fusion.observations import load_observations
    from vtrack.paths import shared_data_dir
    from vtrack.sim.fixtures import tiny_session_path

    ycb = shared_data_dir() / "objects" / "ycb"
    cases = [("005_tomato_soup_can", occ, None, None) for occ in ("none", "medium", "heavy")]
    cases += [(name, "none", ycb / f"{name}.ply", None) for name in ("010_potted_meat_can", "006_mustard_bottle")]
    env = os.environ.get("VTRACK_BENCH_FUSION_CASES")
    if env:
        # "object|occlusion|session_dir;..." (empty session_dir = generate/cached simulator session)
        cases = []
        for item in env.split(";"):
            name, occ, sess = (item.split("|") + ["", ""])[:3]
            cases.append((name, occ, ycb / f"{name}.ply" if name != "005_tomato_soup_can" else None,
                          Path(sess) if sess else None))
    for name, occ, mesh, sess in cases:
        path = sess or tiny_session_path(occlusion=occ, seconds=seconds, object=mesh)
        t0 = time.perf_counter()
        so = load_observations(path, ("vision", "touch"), vision_frame_step=2, touch_frame_step=2)
        load_s = time.perf_counter() - t0
        Vg, Fg = load_mesh(path / "assets" / "object.ply")
        short = name.split("_", 1)[1]
        main = name == "005_tomato_soup_can"
        for mods in MODS:
            _run(table, so.observations, Vg, Fg, method="tsdf", mods=mods, setting="voxel=2mm", object_name=short,
                 occlusion=occ, load_s=load_s, voxel_size=0.002)
            if main or mods != "touch":  # touch-only neural SDF only for the main object (time)
                _run(table, so.observations, Vg, Fg, method="neural_sdf", mods=mods, setting="iters=600",
                     object_name=short, occlusion=occ, load_s=load_s, n_iters=600)
        if name == "005_tomato_soup_can" and occ == "none":
            for vs in (0.0015, 0.003):
                _run(table, so.observations, Vg, Fg, method="tsdf", mods="vision+touch",
                     setting=f"voxel={vs * 1e3:g}mm", object_name=short, occlusion=occ, load_s=load_s,
                     voxel_size=vs)
            for it in (300,):
                _run(table, so.observations, Vg, Fg, method="neural_sdf", mods="vision+touch", setting=f"iters={it}",
                     object_name=short, occlusion=occ, load_s=load_s, n_iters=it)
            _run(table, so.observations, Vg, Fg, method="neural_sdf", mods="vision+touch", setting="online 25ms",
                 object_name=short, occlusion=occ, load_s=load_s, online=True, frame_budget_ms=25.0)


def run(quick: bool = False) -> BenchTable:
    """Run the fusion ablation; see the module docstring."""
    import torch

    torch.set_num_threads(1)
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    table = BenchTable(stage="fusion", error_key="fscore_5mm", time_key="ms", higher_is_better=True, threads=1)
    seconds = float(os.environ.get("VTRACK_BENCH_FUSION_SECONDS", "3"))
    if quick:
        _quick(table)
        table.notes.append("quick mode: ray-cast observations (vtrack.fusion.synthetic), soup can; 'heavy' = two "
                           "views on a 60 deg arc, 30 touch patches on the unseen side.")
    else:
        _full(table, seconds)
        table.notes.append("full mode: simulator sessions of the default scene (known object poses, GT tactile "
                           "height maps, every 2nd camera/tactile frame); cases: "
                           + (os.environ.get("VTRACK_BENCH_FUSION_CASES") or f"default sweep, {seconds:g} s"))
    table.notes.append("ms = reconstruction ms per frame (camera and tactile frames); s_session includes loading "
                       "and meshing. Timings on a shared 2-core machine (other jobs running): noisy.")
    table.notes.append("Command: `vtrack bench fusion" + (" --quick`" if quick else "`"))
    for r in table.rows:
        for k, v in list(r.items()):
            if isinstance(v, float) and not np.isfinite(v):
                r[k] = float("nan")
    return table
