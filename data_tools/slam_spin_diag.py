"""Diagnosis (GT used for scoring only): per-frame handle points, error decomposition for SLAM on a YCB session."""

import json
import sys
import time

import numpy as np

from vtrack.eval.session_gt import SessionGroundTruth
from vtrack.geometry import se3
from vtrack.testing.sim import ycb_session
from vtrack.tracking import window as W
from vtrack.tracking.run import track_session

obj, occ, secs = sys.argv[1], sys.argv[2], float(sys.argv[3])
opts = json.loads(sys.argv[4]) if len(sys.argv) > 4 else {}
every = int(sys.argv[5]) if len(sys.argv) > 5 else 5
p = ycb_session(obj, occ, secs)
kf = {}

SPEC = {}
_orig = W.WindowTracker._degeneracy


def _deg(self, H, n_vision=0):
    o = self.opts
    L = o.object_radius
    S = np.diag([1.0] * 3 + [1.0 / L] * 3)
    Hs = S @ H @ S
    lam, U = np.linalg.eigh(0.5 * (Hs + Hs.T))
    SPEC[len(self.history)] = (lam[0] / max(lam[-1], 1e-12), lam[1] / max(lam[-1], 1e-12), U[:, 0].copy())
    return _orig(self, H, n_vision)


W.WindowTracker._degeneracy = _deg
t0 = time.process_time()
m, (times, est) = track_session(p, "", shape="slam", write=False, return_poses=True, keep_frames=kf, **opts)
print(
    "motion_err_mm",
    round(m["motion_err_mm"], 3),
    "cpu",
    round(time.process_time() - t0, 1),
    "status",
    m["status_counts"],
)
g = SessionGroundTruth.load(p)
Tg = g.poses_at(times)
Tm = est @ se3.invert(est[0]) @ Tg[0]
tr = kf["tracker"]
hist = tr.history
built = dict(kf["built"])
for i in range(0, len(times), every):
    E = se3.invert(Tg[i]) @ Tm[i]
    rv = se3.so3_log(E[:3, :3]) if hasattr(se3, "so3_log") else None
    # GT spin angle since frame 0 and estimated
    Rg = Tg[i][:3, :3] @ Tg[0][:3, :3].T
    Re = Tm[i][:3, :3] @ Tg[0][:3, :3].T
    ag = np.linalg.norm(se3.so3_log(Rg))
    ae = np.linalg.norm(se3.so3_log(Re))
    tf = built[i].tracking_frame()
    V = tf.vision_points if tf.vision_points is not None else np.zeros((0, 3))
    q = se3.transform_points(se3.invert(Tg[i]), V) if len(V) else V
    nh = 0
    if obj == "025_mug" and len(q):
        r = np.hypot(q[:, 0] + 0.0064, q[:, 1])
        nh = int(((r > 0.049) & (q[:, 0] > 0.03)).sum())
    h = hist[i]
    sp = SPEC.get(i)
    if sp is not None:
        # weakest direction's rotation part expressed in GT object frame (est frame = world axes at start)
        u = sp[2]
        rot = u[3:] / max(np.linalg.norm(u[3:]), 1e-12)
        ro = Tg[0][:3, :3].T @ rot
        spec = f"w1={sp[0]:.4f} w2={sp[1]:.4f} rotfrac={np.linalg.norm(u[3:]):.2f} axis_obj={ro.round(2)}"
    else:
        spec = ""
    print(
        f"{i:3d} t={times[i]:.2f} nv={len(V):4d} handle={nh:3d} st={h.status[:5]} dd={h.degenerate_dims} "
        f"rot_err(obj)={np.degrees(rv).round(1)} trans_err_mm={(E[:3, 3] * 1e3).round(1)} "
        f"gt_ang={np.degrees(ag):.1f} est_ang={np.degrees(ae):.1f} {spec}"
    )
