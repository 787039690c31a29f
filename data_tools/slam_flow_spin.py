"""Feasibility: does the RGB texture observe the mug's spin? LK flow of object pixels between consecutive frames,
back-projected with depth, rigid fit (RANSAC + Kabsch) -> per-frame rotation about the spin axis vs GT.
Mask: gt/camera/cam0 mask (segmentation oracle, for this feasibility check only); GT for scoring only."""

import sys

import cv2
import numpy as np

from vtrack.eval.session_gt import SessionGroundTruth
from vtrack.geometry import se3
from vtrack.io.session import open_session
from vtrack.testing.sim import ycb_session

obj, occ, secs = sys.argv[1], sys.argv[2], float(sys.argv[3])
p = ycb_session(obj, occ, secs)
r = open_session(p)
s = r.streams["camera/cam0"]
gs = r.streams["gt/camera/cam0"]
a = s.attrs
K = np.asarray(a["K"])
Twc = np.asarray(a["T_world_camera"])
dscale = float(a.get("depth_scale", 0.001))
print("fields", list(s.fields) if hasattr(s, "fields") else None, list(gs.fields) if hasattr(gs, "fields") else None)
g = SessionGroundTruth.load(p)
t = np.asarray(s.t)
G = g.poses_at(t)
ax = se3.so3_log(g.poses[-1][:3, :3] @ g.poses[0][:3, :3].T)
ax /= np.linalg.norm(ax)


def frame(i):
    rgb = np.asarray(s["rgb"][i])
    dep = np.asarray(s["depth"][i]).astype(np.float64) * dscale
    m = np.asarray(gs["mask"][i]) > 0
    return cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY), dep, m


def backproject(uv, dep):
    u, v = uv[:, 0], uv[:, 1]
    ui, vi = (
        np.clip(np.round(u).astype(int), 0, dep.shape[1] - 1),
        np.clip(np.round(v).astype(int), 0, dep.shape[0] - 1),
    )
    z = dep[vi, ui]
    X = np.stack([(u - K[0, 2]) * z / K[0, 0], (v - K[1, 2]) * z / K[1, 1], z], 1)
    return se3.transform_points(Twc, X), z > 0


def kabsch(A, B):
    ca, cb = A.mean(0), B.mean(0)
    U, _, Vt = np.linalg.svd((A - ca).T @ (B - cb))
    D = np.diag([1, 1, np.sign(np.linalg.det(Vt.T @ U.T))])
    R = Vt.T @ D @ U.T
    return R, cb - R @ ca


rng = np.random.default_rng(0)
prev = frame(0)
est, gtv, nfeat = [], [], []
for i in range(1, len(t)):
    cur = frame(i)
    pts = cv2.goodFeaturesToTrack(prev[0], 200, 0.01, 4, mask=prev[2].astype(np.uint8) * 255)
    if pts is None or len(pts) < 6:
        est.append(np.nan)
        gtv.append(np.nan)
        nfeat.append(0)
        prev = cur
        continue
    nxt, st, _ = cv2.calcOpticalFlowPyrLK(prev[0], cur[0], pts, None, winSize=(15, 15), maxLevel=2)
    ok = st.ravel() == 1
    A, va = backproject(pts[ok, 0], prev[1])
    B, vb = backproject(nxt[ok, 0], cur[1])
    v = va & vb
    A, B = A[v], B[v]
    best = None
    for _ in range(100):
        idx = rng.choice(len(A), 3, replace=False) if len(A) >= 3 else None
        if idx is None:
            break
        R, tt = kabsch(A[idx], B[idx])
        inl = np.linalg.norm(A @ R.T + tt - B, axis=1) < 0.002
        if best is None or inl.sum() > best.sum():
            best = inl
    if best is None or best.sum() < 6:
        est.append(np.nan)
        gtv.append(np.nan)
        nfeat.append(0)
        prev = cur
        continue
    R, tt = kabsch(A[best], B[best])
    Rg = G[i][:3, :3] @ G[i - 1][:3, :3].T
    est.append(float(se3.so3_log(R) @ ax))
    gtv.append(float(se3.so3_log(Rg) @ ax))
    nfeat.append(int(best.sum()))
    prev = cur
est, gtv = np.degrees(np.array(est)), np.degrees(np.array(gtv))
ok = np.isfinite(est)
print(f"{obj} {occ} {secs}s: frames with a flow fit {ok.sum()}/{len(est)}, inliers median {np.median(nfeat):.0f}")
print(
    f"spin per frame deg: GT mean {np.nanmean(gtv):.3f}, flow mean {np.nanmean(est):.3f}, "
    f"|err| median {np.nanmedian(np.abs(est - gtv)):.3f}"
)
print(f"integrated spin over the session: GT {np.nansum(gtv):.1f} deg, flow {np.nansum(est[ok]):.1f} deg")
