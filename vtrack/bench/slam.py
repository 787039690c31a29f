"""``vtrack bench slam``: what the SLAM back end buys (keyframe pose graph, loop closure).

One SLAM front-end run per case, then the keyframe back end (:mod:`vtrack.tracking.posegraph`) in three
variants on the same keyframes: none (the front end's poses), pose graph without loop edges
(registration to the local map only), pose graph with loop closure, and with loop closure after the global
re-localisation of a lost spin (:func:`~vtrack.tracking.posegraph.relocalise_spin`; `vtrack track --refine`
runs this last one; the back end is off by default). Rows: object-motion
error (ADD, ADD-S for symmetric objects; first-frame alignment, GT for scoring only), back-end seconds
(CPU of this process, 1 thread), keyframes and edges.

Cases:
- simulator sessions, BLIND (segmentation and touch from the raw streams): the 5 s YCB sessions of the
  fusion benchmark (every shared object at occlusion none / medium), or ``VTRACK_BENCH_SLAM_CASES`` =
  ``"object|occlusion|session_dir;..."``; sessions >= 20 s (``vtrack generate --seconds 20``) turn more
  than once, so their faces come back;
- synthetic sequences (:func:`vtrack.tracking.synth.make_sequence`, ray-cast depth and contact patches,
  no segmentation): the mustard bottle turning 12 rad in 20 s, occlusion none and medium.
Quick mode: the synthetic sequences only, 12 s.
"""

from __future__ import annotations

import os
import time
from functools import partial
from pathlib import Path

import numpy as np

from vtrack.bench.harness import BenchTable

VARIANTS = {
    "slam (no refinement)": None,
    "slam + pose graph (no loops)": {"loop_closure": False, "spin_search": False},
    "slam + pose graph + loops": {"loop_closure": True, "spin_search": False},
    "slam + pose graph + loops + spin re-localisation": {"loop_closure": True, "spin_search": True},
}


def _variants(table: BenchTable, tracker, times, front, score, row: dict) -> None:
    """Add one row per back-end variant on the keyframes of ``tracker`` (``score(poses) -> metrics``)."""
    from vtrack.tracking.posegraph import BackendOptions, interpolate_corrections, refine_keyframes

    kfs = tracker.kf_graph
    kt = np.array([k.t for k in kfs])
    X0 = np.stack([k.T for k in kfs])
    for name, opts in VARIANTS.items():
        rep: dict = {}
        c0 = time.process_time()
        if opts is None:
            est = front
        else:
            o = BackendOptions.from_dict({**tracker.backend_opts.__dict__, **opts})
            X, rep = refine_keyframes(kfs, o)
            est = interpolate_corrections(kt, X0, X, times, front)
        m = score(est)
        table.add(
            method=name,
            **row,
            motion_err_mm=m["motion_err_mm"],
            drift_mm=m["drift_mm"],
            backend_s=time.process_time() - c0,
            keyframes=len(kfs),
            registration_edges=int(rep.get("registration_edges", 0)),
            loop_edges=int(rep.get("loop_edges", 0)),
            loop_rejected=int(rep.get("loop_rejected", 0)),
            spin_relocalised=int(rep.get("spin_relocalised", 0)),
        )


def _score_session(gt, times: np.ndarray, poses: np.ndarray) -> dict:
    """``score_trajectory``'s metrics of ``poses`` at ``times`` against the session's ground truth (scoring only)."""
    from vtrack.eval.session_gt import score_trajectory

    return score_trajectory(gt, times, poses)[0]


def _session_cases(seconds: float) -> list[tuple[str, str, Path]]:
    from vtrack.testing.sim import ycb_objects, ycb_session

    env = os.environ.get("VTRACK_BENCH_SLAM_CASES")
    if env:
        out = []
        for item in env.split(";"):
            name, occ, sess = (item.split("|") + ["", ""])[:3]
            out.append((name, occ, Path(sess) if sess else ycb_session(name, occ, seconds)))
        return out
    return [(n, occ, ycb_session(n, occ, seconds)) for n in ycb_objects() for occ in ("none", "medium")]


def _sessions(table: BenchTable, seconds: float) -> None:
    from vtrack.eval.session_gt import SessionGroundTruth
    from vtrack.tracking.run import track_session

    for name, occ, path in _session_cases(seconds):
        kept: dict = {}
        # refine=True: the back end is opt-in, and it is what this bench compares (keyframes are kept only then)
        m, (times, est) = track_session(
            path, "", shape="slam", write=False, return_poses=True, keep_frames=kept, refine=True
        )
        gt = SessionGroundTruth.find(None, path)
        tracker = kept["tracker"]
        row = dict(
            data="sim session (blind)",
            object=name,
            occlusion=occ,
            seconds=float(times[-1] - times[0]),
            ms=m["cpu_ms_per_frame_mean"],
            poses_per_s=m["poses_per_s"],
        )
        scorer = partial(_score_session, gt, times)
        if "poses_first_pass" in kept:
            # SLAM's second pass (default since 2026-11-26 night) is part of the front end's poses below; this row is
            # the forward pass alone, what the second pass and the back end start from
            m1 = scorer(kept["poses_first_pass"])
            table.add(
                method="slam first pass (no second pass)",
                **row,
                motion_err_mm=m1["motion_err_mm"],
                drift_mm=m1["drift_mm"],
                backend_s=0.0,
                keyframes=len(tracker.kf_graph),
            )
        _variants(table, tracker, times, kept["poses_frontend"], scorer, row)


def _synthetic(table: BenchTable, n_frames: int) -> None:
    from vtrack.paths import shared_data_dir
    from vtrack.tracking.slam import SLAMTracker
    from vtrack.tracking.synth import make_sequence, run_sequence

    mesh = shared_data_dir() / "objects" / "ycb" / "006_mustard_bottle.ply"
    for occ in ("none", "medium"):
        seq = make_sequence(
            mesh,
            n_frames=n_frames,
            fps=10.0,
            rot_speed=0.6,
            width=120,
            height=90,
            seed=1,
            axis=(0.2, 0.1, 1.0),
            occlusion=occ,
        )
        tr = SLAMTracker(seq.gt[0], refine=True)  # keep keyframes for the back-end variants
        c0 = time.process_time()
        front, _ = run_sequence(tr, seq)
        ms = 1e3 * (time.process_time() - c0) / len(seq.frames)
        times = np.array([f.t for f in seq.frames])
        P = seq.vertices[::20]

        def score(E, seq=seq, P=P):
            from vtrack.geometry import se3

            d = np.linalg.norm(
                np.einsum("kij,nj->kni", E[:, :3, :3], P)
                + E[:, None, :3, 3]
                - np.einsum("kij,nj->kni", seq.gt[:, :3, :3], P)
                - seq.gt[:, None, :3, 3],
                axis=2,
            )
            c = se3.transform_points(E, seq.centre[None])[:, 0] - se3.transform_points(seq.gt, seq.centre[None])[:, 0]
            return {"motion_err_mm": float(d.mean() * 1e3), "drift_mm": float(np.linalg.norm(c, axis=1).mean() * 1e3)}

        row = dict(
            data="synthetic",
            object="006_mustard_bottle",
            occlusion=occ,
            seconds=float(times[-1]),
            ms=ms,
            poses_per_s=1e3 / max(ms, 1e-9),
        )
        _variants(table, tr, times, front, score, row)


def run(quick: bool = False) -> BenchTable:
    """Build the SLAM back-end table (see the module docstring)."""
    from vtrack.threads import limit_threads

    limit_threads(1)
    table = BenchTable(stage="slam", error_key="motion_err_mm", time_key="backend_s", threads=1)
    n = 120 if quick else 200
    _synthetic(table, n)
    if not quick:
        seconds = float(os.environ.get("VTRACK_BENCH_SLAM_SECONDS", "5"))
        _sessions(table, seconds)
    table.notes.append(
        "motion_err_mm: ADD of the object's motion since the first frame (ADD-S for symmetric objects), GT for "
        "scoring only; backend_s: CPU seconds of the back end on 1 thread (0 for the front end's own poses); "
        "ms / poses_per_s: the front end's per-frame CPU cost. Synthetic: mustard bottle, ray-cast depth, "
        f"{n} frames at 10 fps turning 0.6 rad/s. Sessions: "
        + (os.environ.get("VTRACK_BENCH_SLAM_CASES") or "every shared YCB object, none / medium, 5 s")
    )
    return table
