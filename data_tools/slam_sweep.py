"""Blind SLAM motion error over the 6 YCB objects x occlusions (GT for scoring only).

Usage: python data_tools/slam_sweep.py SECONDS none,medium '{"opt": value}' OUT.json [obj,obj]"""

import json
import sys
import time

from vtrack.testing.sim import ycb_session
from vtrack.tracking.run import track_session

OBJS = ["005_tomato_soup_can", "006_mustard_bottle", "010_potted_meat_can", "011_banana", "025_mug", "055_baseball"]
secs = float(sys.argv[1])
occs = sys.argv[2].split(",")
opts = json.loads(sys.argv[3])
out = sys.argv[4]
objs = sys.argv[5].split(",") if len(sys.argv) > 5 else OBJS
res = {}
for occ in occs:
    for o in objs:
        t0 = time.process_time()
        m = track_session(ycb_session(o, occ, secs), "", shape="slam", write=False, **opts)
        res[f"{o}|{occ}"] = {"motion_err_mm": m["motion_err_mm"], "cpu_ms_per_frame_mean": m["cpu_ms_per_frame_mean"]}
        print(o, occ, round(m["motion_err_mm"], 3), round(m["cpu_ms_per_frame_mean"], 1), flush=True)
        json.dump({"secs": secs, "opts": opts, "res": res}, open(out, "w"), indent=1)
