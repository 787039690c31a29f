"""Accuracy of the colour feature tracks (vtrack.tracking.colour, built blind by the frames layer) against ground
truth, which this script reads ONLY to score them:

- lateral frame-to-frame motion recovered: regression of each track's observed displacement on the displacement
  the GT motion gives its previous point, both without their component along the viewing ray (1 = unbiased; < 1 =
  the tracks lag, e.g. held back by light-fixed shading or a window on the mask's static border);
- error of the observations in the camera frame (|dx|, |dy| lateral, |dz| depth) and the drift of a track in the
  object frame (GT poses) against its first observation, by track age.

Usage: python data_tools/slam_colour_tracks.py OBJ OCC SECONDS ['{"win": 9, ...}' (ColourOptions overrides)]
"""

import json
import sys

import numpy as np

from vtrack.eval.session_gt import SessionGroundTruth
from vtrack.frames.session import SessionFrames
from vtrack.geometry import se3
from vtrack.testing.sim import ycb_session

obj, occ, secs = sys.argv[1], sys.argv[2], float(sys.argv[3])
opts = json.loads(sys.argv[4]) if len(sys.argv) > 4 else None
p = ycb_session(obj, occ, secs)
sf = SessionFrames(p, colour=True, colour_opts=opts)
G = SessionGroundTruth.load(p).poses_at(sf.times)
c = sf.cams[0].T_wc[:3, 3]
R_wc = sf.cams[0].T_wc[:3, :3]
first: dict[int, tuple[int, np.ndarray]] = {}
prevp: dict[int, np.ndarray] = {}
num = den = 0.0
errs, ages, cam_err, ntr = [], [], [], []
for i in range(len(sf)):
    fr, _ = sf.frame(i)
    ntr.append(len(fr.colour_ids))
    for a, p_w in zip(fr.colour_ids.tolist(), fr.colour_points, strict=True):
        if a in prevp:
            pp = prevp[a]
            gtd = (G[i] @ se3.invert(G[i - 1]) @ np.r_[pp, 1.0])[:3] - pp
            od = p_w - pp
            ray = (pp - c) / np.linalg.norm(pp - c)
            gtd -= ray * (ray @ gtd)
            od -= ray * (ray @ od)
            num += od @ gtd
            den += gtd @ gtd
    prevp = dict(zip(fr.colour_ids.tolist(), fr.colour_points, strict=True))
    Q = se3.transform_points(se3.invert(G[i]), fr.colour_points) if len(fr.colour_ids) else np.zeros((0, 3))
    for a, q in zip(fr.colour_ids.tolist(), Q, strict=True):
        if a not in first:
            first[a] = (i, q)
        else:
            i0, q0 = first[a]
            errs.append(np.linalg.norm(q - q0))
            ages.append(i - i0)
            cam_err.append(np.abs(R_wc.T @ (G[i][:3, :3] @ (q - q0))))
errs, ages, cam_err = np.array(errs), np.array(ages), np.array(cam_err)
print(f"{obj} {occ} {secs:g} s: colour tracks per frame {np.mean(ntr):.0f}")
print(f"lateral frame-to-frame motion recovered (regression on GT): {num / max(den, 1e-12):.3f}")
print(
    "camera-frame error |dx|, |dy|, |dz| median mm, age 1:",
    np.round(np.median(cam_err[ages == 1], 0) * 1e3, 2),
    "all ages:",
    np.round(np.median(cam_err, 0) * 1e3, 2),
)
for lo, hi in [(1, 2), (2, 5), (5, 15), (15, 40), (40, 400)]:
    m = (ages >= lo) & (ages < hi)
    if m.any():
        print(
            f"  track age {lo}-{hi - 1} frames: n {m.sum()}, drift median {np.median(errs[m]) * 1e3:.2f} mm, "
            f"p90 {np.percentile(errs[m], 90) * 1e3:.2f}"
        )
