"""``vtrack bench globalreg``: known shape without an initial pose — global registration over seeds, then tracking.

Blind: the pipeline sees what a recording has (segmented depth without ground truth, touch from the tactile
images through each sensor's calibration) and the mesh; ground truth only scores.

- **Registration rows** (``globalreg/...``): for every shared YCB object x occlusion none / medium (the 2 s
  sessions of ``bench tracking``, :func:`vtrack.testing.sim.ycb_session`) x seed ``s`` in 0..4, the first pose is
  registered (:func:`vtrack.tracking.run.register_known_shape`, the default of ``vtrack track S --mesh M``) from
  the 3 frames starting at frame ``10 s`` (a different view and pose of the object in the hand) with
  ``GlobalRegOptions(seed=s)`` (RANSAC sampling). Success: ADD-S of the first pose < 5 mm (``success_5mm``);
  also reported < 2 mm, ADD (asymmetric objects), the rank of the first hypothesis under 2 mm, and the CPU time
  to the first pose (``ms``: building the 3 frames, segmentation and tactile pipeline included, + registration).
- **Tracking rows** (``track/...``, seed 0): the whole session tracked from that pose, visuo-tactile and
  vision-only, beside the same tracker started at the ground-truth first pose (NeuralFeels' protocol, labelled
  ``[oracle init]``); the blind run counts as a success when its ADD-S is below 2x the oracle-start run's.
- Means per occlusion (``all ...`` rows): success rates, mean ADD-S, mean ms.
"""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

import numpy as np

from vtrack.bench.harness import BenchTable
from vtrack.errors import InputError

#: first frame of seed s is START_STEP * s
START_STEP = 10
N_SEEDS = 5


def _register_rows(table: BenchTable, obj: str, occ: str, sess, mesh, seeds: int) -> None:
    from vtrack.eval.pose_metrics import add, add_s, sample_model_points
    from vtrack.eval.session_gt import SessionGroundTruth
    from vtrack.frames.session import SessionFrames
    from vtrack.io.mesh import load_mesh
    from vtrack.tracking.globalreg import GlobalRegOptions, global_register
    from vtrack.tracking.run import TRACK_TOUCH_DOWNSAMPLE, TRACK_TOUCH_STRIDE

    frames = SessionFrames(
        sess,
        modalities=("vision", "touch"),
        depth_stride=4,
        touch_stride=TRACK_TOUCH_STRIDE,
        touch_downsample=TRACK_TOUCH_DOWNSAMPLE,
    )
    gt = SessionGroundTruth.load(sess)
    _, T_mg = gt.alignment(mesh)
    M = sample_model_points(*gt.model(), 1000)
    symmetric = bool(frames.scene.object.symmetric)
    V, F = load_mesh(mesh)
    for s in range(seeds):
        k = START_STEP * s
        frames.reset()
        c0 = time.process_time()
        tfs = [frames.frame(i)[0].tracking_frame() for i in range(k, min(k + 3, len(frames)))]
        # the same call as `vtrack track S --mesh M` (run.register_known_shape), with the seed varied
        hyps = global_register(V, F, tfs, symmetric=symmetric, options=GlobalRegOptions(seed=s))
        cpu_ms = (time.process_time() - c0) * 1e3
        T_gt = gt.poses_at(frames.times[k : k + 1])
        errs = [float(add_s((h.T_world_object @ T_mg)[None], T_gt, M)[0] * 1e3) for h in hyps]
        e = errs[0] if errs else float("inf")
        e_add = float(add((hyps[0].T_world_object @ T_mg)[None], T_gt, M)[0] * 1e3) if hyps else float("inf")
        rank = next((i + 1 for i, x in enumerate(errs) if x < 2.0), 0)
        table.add(
            method="globalreg [blind]",
            setting=f"{obj[4:]} {occ} seed{s}",
            object=obj,
            occlusion=occ,
            seed=s,
            start_frame=k,
            ms=cpu_ms,
            add_s_mm=e,
            add_mm=e_add if not symmetric else float("nan"),
            success_5mm=float(e < 5.0),
            success_2mm=float(e < 2.0),
            rank_2mm=rank,
            hypotheses=len(hyps),
            source=hyps[0].source if hyps else "",
        )


def _track_rows(table: BenchTable, obj: str, occ: str, sess, mesh) -> None:
    from vtrack.tracking.run import track_session

    runs = {
        "track/visuo-tactile [blind]": dict(modalities=("vision", "touch")),
        "track/vision [blind]": dict(modalities=("vision",)),
        "track/visuo-tactile [oracle init]": dict(modalities=("vision", "touch"), init="gt"),
        "track/vision [oracle init]": dict(modalities=("vision",), init="gt"),
    }
    res, rows = {}, {}
    for name, kw in runs.items():
        try:
            m = track_session(sess, "", shape="known_shape", mesh=mesh, write=False, **kw)
        except InputError as e:  # e.g. vision only and the object hidden: no first pose is a result too (a failure)
            table.notes.append(f"{name} {obj[4:]} {occ}: {e}")
            rows[name] = dict(method=name, setting=f"{obj[4:]} {occ} seed0", object=obj, occlusion=occ, seed=0)
            rows[name].update(failed=1.0, success_track=0.0 if "[blind]" in name else float("nan"))
            continue
        res[name] = m
        rows[name] = dict(
            method=name,
            setting=f"{obj[4:]} {occ} seed0",
            object=obj,
            occlusion=occ,
            seed=0,
            start_frame=0,
            ms=m["cpu_ms_per_frame_mean"],
            add_s_mm=m["add_s_mm"],
            add_mm=m.get("add_mm", float("nan")),
            init_ms=1e3 * m.get("init_seconds", float("nan")),
            reloc_attempts=m.get("reloc_attempts", 0),
        )
    for mod in ("visuo-tactile", "vision"):
        blind, orc = res.get(f"track/{mod} [blind]"), res.get(f"track/{mod} [oracle init]")
        if blind is not None and orc is not None:
            rows[f"track/{mod} [blind]"]["success_track"] = float(blind["add_s_mm"] < 2.0 * orc["add_s_mm"])
    for row in rows.values():
        table.add(**row)


def run(quick: bool = False) -> BenchTable:
    """Build the global-registration benchmark table (module docstring)."""
    from vtrack.paths import shared_data_dir
    from vtrack.testing.sim import ycb_objects, ycb_session
    from vtrack.threads import limit_threads

    limit_threads(1)
    table = BenchTable(stage="globalreg", error_key="add_s_mm", time_key="ms", threads=1)
    t0 = time.perf_counter()
    objs = ycb_objects()[:2] if quick else ycb_objects()
    if os.environ.get("VTRACK_BENCH_GLOBALREG_OBJECTS"):  # a subset (e.g. to run halves in parallel)
        objs = [o for o in objs if o in os.environ["VTRACK_BENCH_GLOBALREG_OBJECTS"].split(",")]
    occs = ("none",) if quick else ("none", "medium")
    seeds = 2 if quick else N_SEEDS
    merge = os.environ.get("VTRACK_BENCH_GLOBALREG_MERGE")  # folders of earlier runs' globalreg.json to merge
    if merge:
        objs = []
        for d in merge.split(","):
            got = json.loads((Path(d) / "globalreg.json").read_text())["rows"]
            # the JSON holds NaN as null
            nan = float("nan")
            table.rows += [
                {k: nan if v is None else v for k, v in r.items() if k != "pareto"}
                for r in got
                if r.get("object") != "all"
            ]
            table.notes.append(f"merged from {d}/globalreg.json")
    for obj in objs:
        mesh = shared_data_dir() / "objects" / "ycb" / f"{obj}.ply"
        for occ in occs:
            sess = ycb_session(obj, occ, 2.0)
            _register_rows(table, obj, occ, sess, mesh, seeds)
            if not quick:
                _track_rows(table, obj, occ, sess, mesh)
    means = ("ms", "add_s_mm", "add_mm", "success_5mm", "success_2mm", "success_track", "init_ms")
    for r in table.rows:  # every row has every averaged column (NaN where it does not apply)
        for k in means:
            r.setdefault(k, float("nan"))
    table.add_group_means(
        by=("method", "occlusion"),
        means=means,
        min_rows=2,
        where=lambda r: r.get("object") != "all",
        label=lambda key, rows: {
            "setting": f"all {len(rows)} runs {key[1]}",
            "object": "all",
            "add_s_max_mm": float(np.nanmax([r["add_s_mm"] for r in rows])),
            "failed": float(sum(r.get("failed", 0.0) for r in rows)),
        },
    )
    table.add_group_means(
        by=("method",),
        means=("ms", "add_s_mm", "success_5mm", "success_2mm", "success_track"),
        min_rows=2,
        where=lambda r: r.get("object") != "all" and r["method"] == "globalreg [blind]",
        label=lambda key, rows: {
            "setting": f"all {len(rows)} runs",
            "object": "all",
            "occlusion": "none+medium",
            "add_s_max_mm": float(np.nanmax([r["add_s_mm"] for r in rows])),
            "failed": float(sum(r.get("failed", 0.0) for r in rows)),
        },
    )
    table.notes += [
        f"{'merged' if merge else 'quick' if quick else 'full'} run, {time.perf_counter() - t0:.0f} s wall; "
        "single thread. `ms`: CPU ms to "
        "the first pose (3 frames built: segmentation + tactile pipeline, then global registration) for "
        "`globalreg` rows; CPU ms per frame for `track/` rows (`init_ms`: wall ms to the first pose in that run).",
        f"seed s: registration from frames {START_STEP}s..{START_STEP}s+2 of the 2 s session, RANSAC seed s. "
        "success_5mm / success_2mm: ADD-S of the best hypothesis below 5 / 2 mm; rank_2mm: rank of the first "
        "hypothesis below 2 mm (0: none); add_mm: ADD for the asymmetric objects.",
        "track rows: the whole 2 s session from the registered first pose (blind) or from the GT first pose "
        "([oracle init], NeuralFeels' protocol); success_track: blind ADD-S < 2x the oracle-start run's.",
        "Ground truth only scores; the pipeline reads no gt/.",
    ]
    return table
