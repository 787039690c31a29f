"""SLAM's second pass under option variants, replayed on one first pass per session (GT for scoring only).

Runs the first pass once (``track_session(..., second_pass_s=1e3, keep_frames=...)`` keeps every tracking frame and
the first pass's poses), then re-runs only :meth:`~vtrack.tracking.slam.SLAMTracker.retrack_start` per variant (a
second or two instead of a re-track). A variant's ``second_pass_s`` limits the re-tracked frames as in
``track_session``. Scores: ``score_trajectory``'s ``motion_err_mm`` (the record's metric: ADD-S against a dense
surface sample for symmetric objects since 2026-11-26 ~20:00 UTC) and ``motion_add_s_1k_mm`` (the 1000-point ADD-S of
the records before; this script's own 40000-sample column, which predated the fix, is gone).

Usage: python data_tools/slam8_replay.py SECONDS "obj|occ[|seed],..." '[{second-pass opts}, ...]' OUT.json ['{kw}']
  kw: extra track_session keyword arguments of the first pass (e.g. '{"modalities": ["vision"]}')"""

import json
import sys
import time
from dataclasses import replace

import numpy as np

from vtrack.eval.session_gt import SessionGroundTruth, score_trajectory
from vtrack.testing.sim import ycb_session
from vtrack.tracking.run import track_session

secs = float(sys.argv[1])
cases = [c.split("|") for c in sys.argv[2].split(",")]
variants = json.loads(sys.argv[3])
out = sys.argv[4]
extra = json.loads(sys.argv[5]) if len(sys.argv) > 5 else {}
res: dict = {}


def score(gt, times, T: np.ndarray) -> dict:
    """The record's motion error and the former 1000-point ADD-S (mm), both from ``score_trajectory``."""
    m = score_trajectory(gt, times, T)[0]
    return {"motion_err_mm": m["motion_err_mm"], "add_s_1k_mm": m["motion_add_s_1k_mm"]}


for o, occ, *seed in cases:
    path = ycb_session(o, occ, secs, seed=int(seed[0]) if seed else 0)
    kept: dict = {}
    track_session(path, "", shape="slam", write=False, keep_frames=kept, second_pass_s=1e3, **extra)
    tr, early, P1 = kept["tracker"], kept["second_pass_frames"], kept["poses_first_pass"]
    times = kept["frames"].times
    gt = SessionGroundTruth.load(path)

    base_opts = tr.slam_opts
    rows = {"first pass": score(gt, times, P1)}
    for v in variants:
        tr.slam_opts = replace(base_opts, **v)
        n = int(np.sum(times - times[0] <= tr.slam_opts.second_pass_s))
        c0 = time.process_time()
        T = P1.copy()
        T[:n] = tr.retrack_start(early[:n], P1[:n])
        rows[json.dumps(v)] = {
            **score(gt, times, T),
            "cpu_s": time.process_time() - c0,
            "max_move_mm": tr.second_pass_report["max_move_mm"],
            "max_rms_move_mm": tr.second_pass_report["max_rms_move_mm"],
            "rejected": tr.second_pass_report["rejected"],
            "degenerate_rise": tr.second_pass_report.get("degenerate_rise", 0.0),
        }
    res["|".join([o, occ, *seed])] = rows
    for k, r in rows.items():
        print(o, occ, k, {a: round(b, 3) if isinstance(b, float) else b for a, b in r.items()}, flush=True)
    with open(out, "w") as fh:
        json.dump({"secs": secs, "res": res}, fh, indent=1)
