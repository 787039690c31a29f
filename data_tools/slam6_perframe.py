"""Per-fifth motion error (mm) and the final error rotation of blind SLAM on one session under option variants
(GT for scoring only), to see which term a loss comes from (e.g. touch off, colour off).

Usage: python data_tools/slam6_perframe.py SECONDS OBJ OCC '[{track_session opts}, ...]'"""

import json
import sys

import numpy as np

from vtrack.eval.session_gt import SessionGroundTruth
from vtrack.geometry import se3
from vtrack.testing.sim import ycb_session
from vtrack.tracking.run import track_session

secs, obj, occ = float(sys.argv[1]), sys.argv[2], sys.argv[3]
variants = json.loads(sys.argv[4])
path = ycb_session(obj, occ, secs)
gt = SessionGroundTruth.load(path)
for v in variants:
    m, (times, est) = track_session(path, "", shape="slam", write=False, return_poses=True, **dict(v))
    G = gt.poses_at(times)
    Tm = est @ se3.invert(est[0]) @ G[0]
    # error of the motion as a rigid transform in the object frame: E = G^-1 Tm
    ang, tr = [], []
    for a, b in zip(Tm, G, strict=True):
        E = se3.invert(b) @ a
        ang.append(np.degrees(np.arccos(np.clip((np.trace(E[:3, :3]) - 1) / 2, -1, 1))))
        tr.append(np.linalg.norm(a[:3, 3] - b[:3, 3]) * 1e3)
    ang, tr = np.array(ang), np.array(tr)
    fifths = [f"{x:.1f}" for x in (np.array_split(tr, 5) and [c.mean() for c in np.array_split(tr, 5)])]
    print(
        json.dumps(v),
        f"err {m['motion_err_mm']:.3f}",
        "centre mm per fifth",
        fifths,
        "rot deg per fifth",
        [f"{c.mean():.1f}" for c in np.array_split(ang, 5)],
        flush=True,
    )
