"""``vtrack bench tracking``: pose error against ms per frame, sweeping occlusion, depth noise and
objects, for the modes vision / touch / visuo-tactile (known shape), SLAM and the ICP baseline.

- quick (< 1 min): synthetic ray-cast sequences (:mod:`vtrack.tracking.synth`, no hand model),
  one object, occlusion none/heavy; operating points = tracker settings (window x iterations).
- full: simulated sessions of the default scene (``vtrack.sim.generate``) over objects x
  occlusion x depth noise, each tracked with every mode; plus the operating points.

Error column ``drift_mm`` = mean position error of the object centre (docs/tracking.md);
``ms`` = mean per-frame time (point extraction + tracker step, single thread).
"""

from __future__ import annotations

import time
from pathlib import Path

from vtrack.bench.harness import BenchTable, add_seed_means, bench_seeds
from vtrack.errors import InputError

#: operating points of our tracker: name -> options
OPERATING_POINTS = {
    "fast": {"window": 1, "iterations": 3, "max_vision_points": 150, "max_touch_points": 60},
    "default": {},
    "accurate": {"window": 4, "iterations": 10, "max_vision_points": 600, "max_touch_points": 200},
}

MODES = {"vision": ("vision",), "touch": ("touch",), "visuo-tactile": ("vision", "touch")}


def _timed(tracker, seq, drop=()):
    """Run a synthetic sequence; (errors m, CPU ms per frame, wall ms per frame)."""
    from vtrack.testing.sequences import run_sequence

    c0, t0 = time.process_time(), time.perf_counter()
    _, err = run_sequence(tracker, seq, drop=drop)
    n = len(seq.frames)
    return err, (time.process_time() - c0) * 1e3 / n, (time.perf_counter() - t0) * 1e3 / n


def _add_synth_row(table: BenchTable, method: str, setting: str, mesh: Path, occ: str, err, ms: float, wall: float):
    """One synthetic-sequence row: ``err`` = per-frame position errors (m), ``ms``/``wall`` per frame."""
    table.add(
        method=method,
        setting=setting,
        data="synthetic",
        object=mesh.stem,
        occlusion=occ,
        noise=1.0,
        ms=ms,
        wall_ms=wall,
        drift_mm=float(err.mean() * 1e3),
        drift_max_mm=float(err.max() * 1e3),
    )


def _synth_rows(table: BenchTable, quick: bool) -> None:
    from vtrack.paths import shared_data_dir
    from vtrack.testing.sequences import make_sequence
    from vtrack.tracking.icp import ICPTracker
    from vtrack.tracking.slam import SLAMTracker
    from vtrack.tracking.tracker import KnownShapeTracker

    mesh = shared_data_dir() / "objects" / "ycb" / "006_mustard_bottle.ply"
    n = 30 if quick else 90
    for occ in ("none", "heavy"):
        seq = make_sequence(mesh, n_frames=n, width=160, height=120, occlusion=occ, seed=7)
        drop_for = {"vision": ("touch",), "touch": ("vision",), "visuo-tactile": ()}
        for mode, drop in drop_for.items():
            points = OPERATING_POINTS if mode == "visuo-tactile" or not quick else {"default": {}}
            for op, opts in points.items():
                tr = KnownShapeTracker(mesh, seq.gt[0], **opts)
                _add_synth_row(table, f"known/{mode}", f"synth {occ} {op}", mesh, occ, *_timed(tr, seq, drop))
        for op, opts in {"icp20": {"iterations": 20}, "icp5": {"iterations": 5}, "icp50": {"iterations": 50}}.items():
            tr = ICPTracker(mesh, seq.gt[0], **opts)
            _add_synth_row(table, "icp/vision", f"synth {occ} {op}", mesh, occ, *_timed(tr, seq, ("touch",)))
        if not quick or occ == "none":
            for op, opts in {
                "refresh10": {"refresh_every": 10},
                "default": {},
                "refresh2": {"refresh_every": 2},
            }.items():
                tr = SLAMTracker(seq.gt[0], **opts)
                _add_synth_row(table, "slam/visuo-tactile", f"synth {occ} {op}", mesh, occ, *_timed(tr, seq))


def session_cases(quick: bool) -> list[tuple[str, str, str, float, int, Path]]:
    """(object, occlusion, setting, depth noise, seed, session dir) of the full benchmark.

    Every shared YCB object at occlusion none and medium (2 s sessions, the segmentation benchmark's) for each seed of
    :func:`~vtrack.bench.harness.bench_seeds`, plus the default object under heavy occlusion (5 s) and heavy
    occlusion with 3x depth noise (2 s), seed 0 only (the operating points run on them).
    """
    from vtrack.testing.sim import DEFAULT_OBJECT, tiny_session_path, ycb_objects, ycb_session

    cases = [
        (o, occ, 1.0, k, ycb_session(o, occ, 2.0, seed=k))
        for k in bench_seeds()
        for o in ycb_objects()
        for occ in ("none", "medium")
    ]
    cases.append((DEFAULT_OBJECT, "heavy", 1.0, 0, tiny_session_path(occlusion="heavy", seconds=5.0)))
    cases.append((DEFAULT_OBJECT, "heavy", 3.0, 0, ycb_session(DEFAULT_OBJECT, "heavy", 2.0, depth_noise=3.0)))
    return [(o, occ, f"{o[4:]} {occ} n{nz:g}" + (f" s{k}" if k else ""), nz, k, p) for o, occ, nz, k, p in cases]


def _add_session_row(
    table: BenchTable, method: str, setting: str, obj: str, occ: str, noise: float, m: dict, seed: int = 0
):
    """One simulated-session row from the metrics ``m`` of :func:`vtrack.tracking.run.track_session`."""
    table.add(
        method=method,
        setting=setting,
        data="sim",
        object=obj,
        occlusion=occ,
        noise=noise,
        seed=seed,
        ms=m["cpu_ms_per_frame_mean"],
        wall_ms=m["ms_per_frame_mean"],
        **{k: m[k] for k in ("drift_mm", "add_s_mm", "motion_err_mm", "rot_drift_deg", "drift_max_mm")},
        frames=m["frames"],
        poses_per_s=m["poses_per_s"],
        backend_s=m.get("backend_s", float("nan")),
    )


def add_object_means(table: BenchTable) -> None:
    """The issue's aggregate rows: every YCB object at occlusion none and medium (depth noise 1), the mean over objects
    per method, occlusion and seed, and with several seeds the mean and sd of those over seeds
    (:func:`~vtrack.bench.harness.add_seed_means`); ``setting`` reads e.g. ``all 6 objects medium, 3 seeds``."""
    sim = [
        r for r in table.rows if r.get("data") == "sim" and r["noise"] == 1.0 and r["occlusion"] in ("none", "medium")
    ]
    agg = BenchTable(stage=table.stage, error_key=table.error_key, rows=list(sim))  # a copy: its means are appended
    add_seed_means(
        agg,
        by=("method", "occlusion"),
        means=("ms", "wall_ms", "drift_mm", "add_s_mm", "motion_err_mm", "rot_drift_deg", "poses_per_s"),
        sums=("frames",),
    )
    several = len({r["seed"] for r in sim}) > 1
    for r in agg.rows[len(sim) :]:
        which = f", {r['n_seeds']} seeds" if r["seed"] == "all" else (f" seed {r['seed']}" if several else "")
        table.add(**r, setting=f"all {r['n_objects']} objects {r['occlusion']}{which}", data="sim", noise=1.0)


def _session_rows(table: BenchTable, quick: bool) -> None:
    """Blind rows (no ground truth in the pipeline: segmentation, touch from images, global registration for
    known shape, SLAM's own frame) and labelled oracle rows (GT first pose, GT masks and height maps)."""
    from vtrack.paths import shared_data_dir
    from vtrack.tracking.run import track_session

    oracle = dict(init="gt", tactile_source="gt", segmentation="gt")
    cases = session_cases(quick)
    for obj, occ, setting, noise, seed, sess in cases:
        mesh = shared_data_dir() / "objects" / "ycb" / f"{obj}.ply"
        runs = [
            ("known/" + m + " [blind]", dict(shape="known_shape", mesh=mesh, modalities=mods))
            for m, mods in MODES.items()
        ]
        runs.append(("slam/visuo-tactile [blind]", dict(shape="slam", refine=True)))
        runs.append(("slam/vision [blind]", dict(shape="slam", modalities=("vision",), refine=True)))
        runs.append(("known/visuo-tactile [oracle]", dict(shape="known_shape", mesh=mesh, **oracle)))
        runs.append(
            (
                "icp/vision [oracle init+masks]",
                dict(shape="known_shape", method="icp", mesh=mesh, init="gt", segmentation="gt"),
            )
        )
        runs.append(
            ("slam/visuo-tactile [oracle]", dict(shape="slam", tactile_source="gt", segmentation="gt", refine=True))
        )
        for name, kw in runs:
            try:
                m = track_session(sess, "", write=False, **kw)
            except InputError as e:  # e.g. global registration found nothing with touch only: a result too
                table.notes.append(f"{name} {setting}: {e}")
                continue
            if "frontend" in m:
                # one SLAM run, two rows: the front end's poses (the default, `slam/`) and the same run after the
                # keyframe pose graph with loop closure (`--refine`, `slam + pose graph/`)
                fe = {**m, **m["frontend"], "rot_drift_deg": float("nan"), "drift_max_mm": float("nan")}
                fe["backend_s"] = float("nan")
                _add_session_row(table, name, setting, obj, occ, noise, fe, seed)
                name = name.replace("slam/", "slam + pose graph/")
            _add_session_row(table, name, setting, obj, occ, noise, m, seed)
    add_object_means(table)
    # operating points on the heavy-occlusion default scene (blind known shape)
    obj, occ, setting, noise, _, sess = next(c for c in cases if c[1] == "heavy")
    mesh = shared_data_dir() / "objects" / "ycb" / f"{obj}.ply"
    for op, opts in OPERATING_POINTS.items():
        if op == "default":
            continue  # already in the table
        m = track_session(sess, "", write=False, shape="known_shape", mesh=mesh, **opts)
        _add_session_row(table, "known/visuo-tactile [blind]", f"{setting} {op}", obj, occ, noise, m)


def run(quick: bool = False) -> BenchTable:
    """Build the tracking benchmark table (see module docstring)."""
    from vtrack.threads import limit_threads

    limit_threads(1)
    table = BenchTable(stage="tracking", error_key="drift_mm", time_key="ms", threads=1)
    t0 = time.perf_counter()
    _synth_rows(table, quick)
    sim_ok = True
    try:
        import vtrack.sim.generate  # noqa: F401
    except Exception as e:  # the simulator is optional for the quick synthetic part
        sim_ok = False
        table.notes.append(f"simulated sessions skipped: {e}")
    if sim_ok and not quick:
        _session_rows(table, quick)
    table.notes += [
        f"{'quick' if quick else 'full'} run, {time.perf_counter() - t0:.0f} s wall; single thread. `ms` = CPU time "
        "per frame of this process (point extraction + tracker step); `wall_ms` = wall time, inflated when the "
        "machine is shared with other jobs.",
        "drift_mm = mean position error of the object centre (mm); motion_err_mm = error of the object's motion "
        "since the first frame (ADD-S for symmetric objects; the SLAM metric). [blind] rows: no ground truth in the "
        "pipeline (segmentation by FK hand removal, touch from tactile images, known shape initialised by global "
        "registration); [oracle] rows: GT first pose, GT masks and GT height maps (ablation).",
        "synthetic = ray-cast depth + surface contact patches of fixed fingertips (vtrack.tracking.synth); "
        "sim = vtrack.sim sessions of the default scene (Allegro + 4 DIGIT, independent tactile optics).",
        "operating points: fast (window 1, 3 it), default (window 3, 5 it), accurate (window 4, 10 it); "
        "ICP: 5/20/50 iterations; SLAM: grid refresh every 10/5/2 frames.",
    ]
    return table
