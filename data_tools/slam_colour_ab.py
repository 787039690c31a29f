"""A/B of SLAM's colour term, interleaved (ABBA per object) so both configurations see the same machine load: per
session the object-motion error (GT for scoring only) and the CPU ms per frame of `track_session`.

Usage: python data_tools/slam_colour_ab.py OCC OUT.json [SECONDS]
"""

import json
import sys

import numpy as np

from vtrack.testing.sim import ycb_session
from vtrack.tracking.run import track_session

OBJS = ["005_tomato_soup_can", "006_mustard_bottle", "010_potted_meat_can", "011_banana", "025_mug", "055_baseball"]
occ, out = sys.argv[1], sys.argv[2]
secs = float(sys.argv[3]) if len(sys.argv) > 3 else 2.0
cfg = {"A": {"sigma_colour": 0.0}, "B": {"sigma_colour": 0.001}}
res: dict = {"A": {}, "B": {}}
for k, o in enumerate(OBJS):
    for c in "AB" if k % 2 == 0 else "BA":
        m = track_session(ycb_session(o, occ, secs), "", shape="slam", write=False, **cfg[c])
        res[c][o] = {"cpu_ms_per_frame_mean": m["cpu_ms_per_frame_mean"], "motion_err_mm": m["motion_err_mm"]}
        print(o, c, round(m["cpu_ms_per_frame_mean"], 2), round(m["motion_err_mm"], 3), flush=True)
        with open(out, "w") as f:
            json.dump({"occ": occ, "seconds": secs, "configs": cfg, "results": res}, f, indent=1)
a = np.mean([v["cpu_ms_per_frame_mean"] for v in res["A"].values()])
b = np.mean([v["cpu_ms_per_frame_mean"] for v in res["B"].values()])
print(f"{occ}: mean CPU ms/frame without {a:.2f}, with colour {b:.2f}, ratio {b / a:.3f}")
