# Usage: python data_tools/slam8_mapscore.py "obj|occ,..."  (5 s sessions)
"""The matured SLAM map against the GT mesh (scoring only): map surfels -> world by frame 0's pose (first pass or
second pass) -> GT object frame by the GT pose of frame 0; distance to dense GT surface samples (mm)."""

import sys

import numpy as np
from scipy.spatial import cKDTree

from vtrack.eval.pose_metrics import sample_model_points
from vtrack.eval.session_gt import SessionGroundTruth
from vtrack.geometry import se3
from vtrack.testing.sim import ycb_session
from vtrack.tracking.run import track_session

for case in sys.argv[1].split(","):
    o, occ = case.split("|")
    path = ycb_session(o, occ, 5)
    kept = {}
    m, (times, est) = track_session(
        path, "", shape="slam", write=False, return_poses=True, keep_frames=kept, second_pass_s=1e3
    )
    tr, P1 = kept["tracker"], kept["poses_first_pass"]
    gt = SessionGroundTruth.load(path)
    G0 = gt.poses_at(times[:1])[0]
    V, F = gt.model()
    tree = cKDTree(sample_model_points(V, F, 60000, seed=0))
    S = tr.map.surfels()[0]
    for name, T0 in (("first pass frame 0", P1[0]), ("second pass frame 0", est[0])):
        d = tree.query(se3.transform_points(se3.invert(G0) @ T0, S))[0] * 1e3
        print(
            o,
            occ,
            name,
            f"map surfels {len(S)}: distance to GT surface median {np.median(d):.2f}",
            f"p90 {np.percentile(d, 90):.2f} mean {d.mean():.2f} mm",
            flush=True,
        )
