"""``vtrack bench fusion``: reconstruction ablation (vision / touch / visuo-tactile x TSDF / neural SDF).

Full mode: simulator sessions (``vtrack.testing.sim.ycb_session``, cached; 5 s: 2 s ones cover too
little of the object, oracle F@5 0.71) of the default scene holding each shared YCB object at
occlusion none and medium, plus the soup can under heavy occlusion; BLIND by default (poses from SLAM,
segmentation and touch from the raw streams), with GT-fed rows labelled ``[oracle]`` as an ablation.
Seeds: ``vtrack bench fusion --seeds 0,1,2``; occlusions: ``VTRACK_BENCH_FUSION_OCC`` (default none,medium,heavy).
Extra operating points (TSDF voxel size, neural SDF iterations, online neural SDF at a 25 ms frame
budget) on the unoccluded soup can.
Quick mode (< 1 min): ray-cast observations (:mod:`vtrack.testing.observations`, no simulator) of the
soup can, full ring of views vs a 60 deg arc (occluded), touch on the unseen side.

Columns: ``fscore_5mm`` (error column, higher is better), ``fscore_1mm/2mm/10mm``, ``precision``,
``recall`` (5 mm), ``chamfer_mm``, ``s_session`` (load + reconstruct + mesh, s), ``ms`` = ms per
frame (reconstruction time / frames; online: measured per frame).
"""

from __future__ import annotations

import os
import time
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from vtrack.bench.harness import BenchTable, add_seed_means, bench_seeds

MODS = {"vision": (0,), "touch": (1,), "vision+touch": (0, 1)}


def _score(V, F, Vg, Fg) -> dict[str, Any]:
    from vtrack.eval.reconstruction import mesh_metrics

    m = mesh_metrics(V, F, Vg, Fg)
    return {
        "fscore_1mm": m["fscore"]["1mm"],
        "fscore_2mm": m["fscore"]["2mm"],
        "fscore_5mm": m["fscore"]["5mm"],
        "fscore_10mm": m["fscore"]["10mm"],
        "precision": m["precision"]["5mm"],
        "recall": m["recall"]["5mm"],
        "chamfer_mm": m["chamfer_mm"] if m["chamfer_mm"] is not None else float("nan"),
    }


def _run(
    table: BenchTable,
    obs: list,
    Vg,
    Fg,
    *,
    method: str,
    mods: str,
    setting: str,
    object_name: str,
    occlusion: str,
    load_s: float,
    online: bool = False,
    **opts: Any,
) -> None:
    from vtrack.fusion.reconstruct import reconstruct_observations

    sel = [o for o in obs if o.modality in MODS[mods]]
    t0 = time.perf_counter()
    res = reconstruct_observations(sel, method, online=online, **opts)
    rec_s = time.perf_counter() - t0
    frames = max(1, len(sel))
    ms = res.get("ms_per_frame", 1e3 * rec_s / frames) if online else 1e3 * rec_s / frames
    table.add(
        method=f"{method}/{mods}",
        setting=setting,
        object=object_name,
        occlusion=occlusion,
        frames=len(sel),
        **_score(res["vertices"], res["faces"], Vg, Fg),
        s_session=load_s + rec_s,
        ms=ms,
    )


def _frontend_row(
    table: BenchTable,
    info: dict,
    Vg,
    Fg,
    *,
    object_name: str,
    occlusion: str,
    load_s: float,
    setting: str = "iters=400 slam (no refinement)",
) -> None:
    """The neural SDF (400 iterations, vision + touch) fused with the SLAM front end's poses
    (``info["observations_frontend"]`` of :func:`_session_observations`): what `vtrack reconstruct` does."""
    _run(
        table,
        info["observations_frontend"],
        Vg,
        Fg,
        method="neural_sdf",
        mods="vision+touch",
        setting=setting,
        object_name=object_name,
        occlusion=occlusion,
        load_s=load_s,
        n_iters=400,
    )


def _operating_points(run, voxels: tuple[float, ...], iters: tuple[int, ...], **neural_opts: Any) -> None:
    """Visuo-tactile rows at other TSDF voxel sizes (m) and neural SDF iteration counts; ``run`` is
    :func:`_run` bound to one case (table, observations, GT mesh, object, occlusion, load time)."""
    for vs in voxels:
        run(method="tsdf", mods="vision+touch", setting=f"voxel={vs * 1e3:g}mm", voxel_size=vs)
    for it in iters:
        run(method="neural_sdf", mods="vision+touch", setting=f"iters={it}", n_iters=it, **neural_opts)


def _quick(table: BenchTable) -> None:
    from vtrack.paths import shared_data_dir
    from vtrack.testing.observations import make_observations

    mesh = shared_data_dir() / "objects" / "ycb" / "005_tomato_soup_can.ply"
    for occ, kw in (("none", dict(n_views=6, arc_deg=360.0)), ("heavy", dict(n_views=2, arc_deg=60.0))):
        t0 = time.perf_counter()
        obs, V, F = make_observations(mesh, n_touch=30, touch_region="unseen", seed=0, **kw)
        run = partial(_run, table, obs, V, F, object_name="soup_can", occlusion=occ, load_s=time.perf_counter() - t0)
        for mods in MODS:
            run(method="tsdf", mods=mods, setting="voxel=2mm", voxel_size=0.002)
            run(method="neural_sdf", mods=mods, setting="iters=100", n_iters=100, mesh_cell_mm=2.5)
        if occ == "heavy":
            _operating_points(run, (0.0015, 0.003), (40, 200), mesh_cell_mm=2.5)


def _session_observations(
    path: Path, blind: bool, track_opts: dict | None = None
) -> tuple[list, np.ndarray, np.ndarray, float, dict]:
    """Observations of a simulator session and the GT mesh in the frame of their poses.

    Blind (default): SLAM poses refined by the keyframe pose graph (``--refine``; not the CLI default),
    segmentation and touch from the raw streams; the GT mesh is moved into the SLAM object frame by the
    first-frame alignment (scoring only); ``info["observations_frontend"]`` holds the same observations placed
    with the front end's poses (the ``slam (no refinement)`` row: what ``vtrack reconstruct`` does by default).
    Oracle: GT poses, GT masks, GT height maps. ``track_opts``: extra ``track_session`` keyword arguments of the blind
    SLAM run (``data_tools/fusion_frontend.py`` compares option variants with them).
    """
    from vtrack.eval.session_gt import SessionGroundTruth
    from vtrack.frames.session import SessionFrames
    from vtrack.fusion.observations import observations_from_frames
    from vtrack.fusion.reconstruct import TOUCH_DOWNSAMPLE, TOUCH_STRIDE
    from vtrack.geometry import se3
    from vtrack.io.mesh import load_mesh
    from vtrack.io.poses import PoseTrack
    from vtrack.tracking.run import track_session

    gt = SessionGroundTruth.load(path)
    Vg, Fg = load_mesh(gt.mesh_path)
    t0 = time.perf_counter()
    info: dict = {}
    if blind:
        kept: dict = {}
        # the tactile settings of `vtrack reconstruct` (denser contacts than tracking's own), so the front-end row
        # is what the CLI does
        m, (times, est) = track_session(
            path,
            "",
            shape="slam",
            write=False,
            return_poses=True,
            keep_frames=kept,
            keep_step=2,
            refine=True,
            touch_stride=TOUCH_STRIDE,
            touch_downsample=TOUCH_DOWNSAMPLE,
            **(track_opts or {}),
        )
        info = {
            "motion_err_mm": m.get("motion_err_mm"),
            "motion_err_mm_frontend": m.get("frontend", {}).get("motion_err_mm", float("nan")),
            "backend_s": m.get("backend_s", float("nan")),
        }
        frames, built, track = kept["frames"], kept["built"], PoseTrack(times, est)
        T_est_gt = se3.invert(est[0]) @ gt.poses_at(times[:1])[0]  # GT object frame in the SLAM frame
        Vg = se3.transform_points(T_est_gt, np.asarray(Vg, np.float64))
        if "poses_frontend" in kept:  # the refinement keeps the first pose, so the same GT alignment holds
            front = observations_from_frames(frames, built, PoseTrack(times, kept["poses_frontend"]))
            info["observations_frontend"] = front.observations
    else:
        frames = SessionFrames(path, ("vision", "touch"), tactile_source="gt", segmentation="gt")
        built = [(i, frames.frame(i)[0]) for i in range(0, len(frames), 2)]
        track = PoseTrack(gt.pose_times, gt.poses)
    so = observations_from_frames(frames, built, track)
    return so.observations, Vg, Fg, time.perf_counter() - t0, info


def _default_prior() -> str:
    from vtrack.fusion.neural_sdf import NeuralSDFConfig

    return NeuralSDFConfig().prior


def _full(table: BenchTable, seconds: float) -> None:
    from vtrack.testing.sim import DEFAULT_OBJECT, ycb_objects, ycb_session

    # every shared YCB object at occlusion none / medium (the targets) for each seed, the default object also
    # heavy (seed 0); VTRACK_BENCH_FUSION_OCC (comma-separated, default none,medium,heavy) picks the occlusions
    occs = os.environ.get("VTRACK_BENCH_FUSION_OCC", "none,medium,heavy").split(",")
    bad = sorted(set(occs) - {"none", "medium", "heavy"})
    if bad:
        from vtrack.errors import InputError

        raise InputError(
            "unknown occlusion", field="VTRACK_BENCH_FUSION_OCC", expected="none, medium and/or heavy", got=bad
        )
    seeds = bench_seeds()
    sweep = [o for o in ("none", "medium") if o in occs]
    cases = [(name, occ, None, k) for k in seeds for name in ycb_objects() for occ in sweep]
    if "heavy" in occs:
        cases.append((DEFAULT_OBJECT, "heavy", None, 0))
    env = os.environ.get("VTRACK_BENCH_FUSION_CASES")
    if env:
        # "object|occlusion|session_dir;..." (empty session_dir = generate/cached simulator session, one per seed)
        cases = []
        for item in env.split(";"):
            name, occ, sess = (item.split("|") + ["", ""])[:3]
            if sess and seeds != [0]:
                from vtrack.errors import InputError

                # a given session has its own seed: labelling its rows with the requested ones would be wrong
                raise InputError(
                    "a session folder in VTRACK_BENCH_FUSION_CASES cannot be combined with --seeds",
                    field="VTRACK_BENCH_FUSION_CASES",
                    expected="object|occlusion| (no folder) to run every seed",
                    got=item,
                )
            cases += [(name, occ, Path(sess), 0)] if sess else [(name, occ, None, k) for k in seeds]
    # "headline": only the neural SDF, vision + touch, blind (pose graph and front end) and oracle — the issue's
    # figures, in about a third of the time of the full ablation
    headline = os.environ.get("VTRACK_BENCH_FUSION_ROWS", "all") == "headline"
    for name, occ, sess, seed in cases:
        path = sess or ycb_session(name, occ, seconds, seed=seed)
        short = name.split("_", 1)[1]
        main = name == DEFAULT_OBJECT
        for blind in (True, False):
            obs, Vg, Fg, load_s, info = _session_observations(path, blind)
            tag = "" if blind else " [oracle: GT poses, masks, height maps]"
            n0 = len(table.rows)
            run = partial(_run, table, obs, Vg, Fg, object_name=short, occlusion=occ, load_s=load_s)
            for mods in ("vision+touch",) if headline else MODS:
                if not headline:
                    run(method="tsdf", mods=mods, setting="voxel=2mm" + tag, voxel_size=0.002)
                if (main or mods != "touch") and (blind or mods == "vision+touch"):
                    run(method="neural_sdf", mods=mods, setting="iters=400" + tag, n_iters=400)
            # ablation: the neural SDF's shape prior (default: NeuralSDFConfig.prior) against the others
            for prior in () if headline else ("sphere", "hull", "blend", "symmetric"):
                if prior != _default_prior():
                    run(method="neural_sdf", mods="vision+touch", setting=f"iters=400 prior={prior}" + tag, prior=prior)
            if blind and "observations_frontend" in info:
                # ablation: the same fusion with the SLAM front end's poses (before the keyframe pose graph)
                _frontend_row(table, info, Vg, Fg, object_name=short, occlusion=occ, load_s=load_s)
            if blind and main and occ == "none" and not headline:
                _operating_points(run, (0.0015, 0.003), (300, 600))
            for r in table.rows[n0:]:  # the SLAM run these blind reconstructions used
                r["seed"] = seed
                r["slam_motion_err_mm"] = info.get("motion_err_mm", float("nan")) if blind else float("nan")
                r["slam_motion_err_mm_frontend"] = info.get("motion_err_mm_frontend", float("nan"))
                r["slam_backend_s"] = info.get("backend_s", float("nan"))


def run(quick: bool = False) -> BenchTable:
    """Run the fusion ablation; see the module docstring."""

    from vtrack.threads import limit_threads

    limit_threads(1)  # after importing torch: caps its pool too
    table = BenchTable(stage="fusion", error_key="fscore_5mm", time_key="ms", higher_is_better=True, threads=1)
    seconds = float(os.environ.get("VTRACK_BENCH_FUSION_SECONDS", "5"))
    if quick:
        _quick(table)
        table.notes.append(
            "quick mode: ray-cast observations (vtrack.testing.observations), soup can; 'heavy' = two "
            "views on a 60 deg arc, 30 touch patches on the unseen side."
        )
    else:
        _full(table, seconds)
        # the aggregate: mean over the objects per (method, setting, occlusion) and seed, none / medium, and
        # with several seeds the mean and sd of those over seeds
        add_seed_means(
            table,
            by=("method", "setting", "occlusion"),
            means=(
                "fscore_1mm",
                "fscore_2mm",
                "fscore_5mm",
                "fscore_10mm",
                "precision",
                "recall",
                "chamfer_mm",
                "s_session",
                "ms",
            ),
            sums=("frames",),
            where=lambda r: r["occlusion"] in ("none", "medium"),
            extra=lambda rows: {"fscore_5mm_min": float(min(r["fscore_5mm"] for r in rows))},
            min_objects=2,  # as before: no "mean" of the operating points run on one object
        )
        table.notes.append(
            "full mode: simulator sessions of the default scene, BLIND by default (SLAM poses, "
            "segmentation and touch from the raw streams; scored after first-frame alignment); "
            "rows tagged [oracle] use GT poses, masks and height maps; every 2nd frame; cases: "
            + (os.environ.get("VTRACK_BENCH_FUSION_CASES") or f"default sweep, {seconds:g} s")
            + (
                "; rows: headline (VTRACK_BENCH_FUSION_ROWS=headline)"
                if os.environ.get("VTRACK_BENCH_FUSION_ROWS") == "headline"
                else ""
            )
        )
    table.notes.append(
        "ms = reconstruction ms per frame (camera and tactile frames); s_session includes loading "
        "and meshing. Timings on a shared 2-core machine (other jobs running): noisy."
    )
    table.notes.append("Command: `vtrack bench fusion" + (" --quick`" if quick else "`"))
    for r in table.rows:
        for k, v in list(r.items()):
            if isinstance(v, float) and not np.isfinite(v):
                r[k] = float("nan")
    return table
