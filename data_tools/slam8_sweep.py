"""[Since 2026-11-26 ~20:00 UTC the record's ``motion_err_mm`` (``score_trajectory``) is itself a dense ADD-S
(200 000 surface samples, docs/benchmarks/slam_adds_dense.md); this script's extra dense column predates that.]

Blind SLAM motion error of chosen sessions under option variants, with a dense ADD-S beside the record's metric
(GT for scoring only).

The record's ``motion_err_mm`` is ADD-S (symmetric objects) over 1000 sampled model points: on a body of revolution
a spin about the symmetry axis (unobservable, "not scored") still costs up to the samples' spacing (the soup can:
2.6-2.9 mm for a 10-90 deg spin). ``dense_mm`` is the same ADD-S against 40000 samples (the floor ~0.4 mm), to see
what is pose error and what is the metric's floor.

Usage: python data_tools/slam8_sweep.py SECONDS "obj|occ,..." '[{opts}, ...]' OUT.json"""

import json
import sys

import numpy as np
from scipy.spatial import cKDTree

from vtrack.eval.pose_metrics import sample_model_points
from vtrack.eval.session_gt import SessionGroundTruth
from vtrack.geometry import se3
from vtrack.testing.sim import ycb_session
from vtrack.tracking.run import track_session

secs = float(sys.argv[1])
cases = [c.split("|") for c in sys.argv[2].split(",")]
variants = json.loads(sys.argv[3])
out = sys.argv[4]
res: dict = {}
for v in variants:
    for o, occ in cases:
        path = ycb_session(o, occ, secs)
        m, (times, est) = track_session(path, "", shape="slam", write=False, return_poses=True, **dict(v))
        gt = SessionGroundTruth.load(path)
        dense = None
        if gt.symmetric:
            V, F = gt.model()
            G = gt.poses_at(times)
            Tm = est @ se3.invert(est[0]) @ G[0]
            P = sample_model_points(V, F, 40000, seed=0)
            tree = cKDTree(P)
            Q = P[::40]  # 1000 of them, moved by the error; their nearest among all 40000
            dense = 1e3 * float(
                np.mean(
                    [
                        tree.query(se3.transform_points(se3.invert(A) @ B, Q))[0].mean()
                        for A, B in zip(Tm, G, strict=True)
                    ]
                )
            )
        r = {
            "motion_err_mm": m["motion_err_mm"],
            "dense_add_s_mm": dense,
            "cpu_ms_per_frame_mean": m["cpu_ms_per_frame_mean"],
            "second_pass_cpu_s": m.get("second_pass_cpu_s"),
        }
        res.setdefault(json.dumps(v), {})[f"{o}|{occ}"] = r
        print(
            json.dumps(v), o, occ, {k: (round(x, 3) if isinstance(x, float) else x) for k, x in r.items()}, flush=True
        )
        with open(out, "w") as fh:
            json.dump({"secs": secs, "res": res}, fh, indent=1)
