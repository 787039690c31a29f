"""Dump blind SLAM poses (front end and pose-graph refined) + GT of sessions for offline diagnosis.

GT is read for scoring only. Usage:
  python data_tools/slam5_dump.py SECONDS none,medium '{"opt": value}' OUTDIR [obj,obj] [--fusion]
--fusion: the tactile settings of `bench fusion` / `vtrack reconstruct` (TOUCH_STRIDE / TOUCH_DOWNSAMPLE).
Writes OUTDIR/<obj>_<occ>.npz (times, est, front, gt) and OUTDIR/summary.json."""

import json
import pickle
import sys
import time
from pathlib import Path

import numpy as np

from vtrack.eval.session_gt import SessionGroundTruth
from vtrack.testing.sim import ycb_session
from vtrack.tracking.run import track_session

OBJS = ["005_tomato_soup_can", "006_mustard_bottle", "010_potted_meat_can", "011_banana", "025_mug", "055_baseball"]
args = [a for a in sys.argv[1:] if not a.startswith("--")]
fusion = "--fusion" in sys.argv
secs = float(args[0])
occs = args[1].split(",")
opts = json.loads(args[2])
out = Path(args[3])
objs = args[4].split(",") if len(args) > 4 else OBJS
out.mkdir(parents=True, exist_ok=True)
extra = {}
if fusion:
    from vtrack.fusion.reconstruct import TOUCH_DOWNSAMPLE, TOUCH_STRIDE

    extra = dict(touch_stride=TOUCH_STRIDE, touch_downsample=TOUCH_DOWNSAMPLE)
summ = {}
for occ in occs:
    for o in objs:
        path = ycb_session(o, occ, secs)
        kept: dict = {}
        t0 = time.process_time()
        m, (times, est) = track_session(
            path,
            "",
            shape="slam",
            write=False,
            return_poses=True,
            keep_frames=kept,
            keep_step=10**9,
            refine=True,
            **extra,
            **opts,
        )
        gt = SessionGroundTruth.load(path)
        np.savez(out / f"{o}_{occ}.npz", times=times, est=est, front=kept["poses_frontend"], gt=gt.poses_at(times))
        # the back end's input, so its options can be re-run offline (data_tools/slam5_backend.py)
        with open(out / f"{o}_{occ}.kf.pkl", "wb") as fh:
            pickle.dump({"kf_graph": kept["tracker"].kf_graph, "times": times, "front": kept["poses_frontend"]}, fh)
        # not refined (no keyframes: e.g. the object hidden) -> the output is the front end
        fe = m.get("frontend", {}).get("motion_err_mm", m["motion_err_mm"])
        summ[f"{o}|{occ}"] = {
            "refined": m["motion_err_mm"],
            "frontend": fe,
            "cpu_s": time.process_time() - t0,
            "loop_edges": m.get("loop_edges"),
            "keyframes": m.get("keyframes"),
        }
        print(o, occ, "front", round(fe, 3), "refined", round(m["motion_err_mm"], 3), flush=True)
        (out / "summary.json").write_text(
            json.dumps({"secs": secs, "opts": opts, "fusion": fusion, "res": summ}, indent=1)
        )
