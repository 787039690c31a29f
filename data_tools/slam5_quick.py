"""Blind SLAM motion error of chosen sessions under tracker-option variants (GT for scoring only).

Usage: python data_tools/slam5_quick.py SECONDS "obj|occ,obj|occ" '[{"opt": v}, ...]' OUT.json"""

import json
import sys

from vtrack.testing.sim import ycb_session
from vtrack.tracking.run import track_session

secs = float(sys.argv[1])
cases = [c.split("|") for c in sys.argv[2].split(",")]
variants = json.loads(sys.argv[3])
out = sys.argv[4]
res: dict = {}
for v in variants:
    for o, occ in cases:
        m = track_session(ycb_session(o, occ, secs), "", shape="slam", write=False, **dict(v))
        res.setdefault(json.dumps(v), {})[f"{o}|{occ}"] = m["motion_err_mm"]
        print(json.dumps(v), o, occ, round(m["motion_err_mm"], 3), flush=True)
        with open(out, "w") as fh:
            json.dump(res, fh, indent=1)
