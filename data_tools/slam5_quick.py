"""Blind SLAM motion error of chosen sessions under tracker-option variants (GT for scoring only).

Usage: python data_tools/slam5_quick.py SECONDS "obj|occ,obj|occ" '[{"opt": v}, ...]' OUT.json [--detail]
  --detail: per session a dict instead of the error alone: ``motion_err_mm`` (the record's metric; ADD-S against a
  dense surface sample for symmetric objects since 2026-11-26 ~20:00 UTC), ``motion_add_s_1k_mm`` (the 1000-point
  ADD-S of the records before), CPU ms per frame and the second pass's CPU s (this replaced slam8_sweep.py)."""

import json
import sys

from vtrack.testing.sim import ycb_session
from vtrack.tracking.run import track_session

detail = "--detail" in sys.argv[5:]
secs = float(sys.argv[1])
cases = [c.split("|") for c in sys.argv[2].split(",")]
variants = json.loads(sys.argv[3])
out = sys.argv[4]
res: dict = {}
for v in variants:
    for o, occ in cases:
        m = track_session(ycb_session(o, occ, secs), "", shape="slam", write=False, **dict(v))
        r = m["motion_err_mm"]
        if detail:
            r = {
                "motion_err_mm": m["motion_err_mm"],
                "motion_add_s_1k_mm": m.get("motion_add_s_1k_mm"),
                "cpu_ms_per_frame_mean": m["cpu_ms_per_frame_mean"],
                "second_pass_cpu_s": m.get("second_pass_cpu_s"),
            }
        res.setdefault(json.dumps(v), {})[f"{o}|{occ}"] = r
        print(json.dumps(v), o, occ, round(r, 3) if not detail else r, flush=True)
        with open(out, "w") as fh:
            json.dump(res, fh, indent=1)
