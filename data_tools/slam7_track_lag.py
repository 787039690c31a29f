"""Per-track lag of the colour feature tracks (GT for diagnosis only): the distribution over tracks, not the pooled
regression of ``slam6_lag.py``.

For every observation of a track, its world point now (p) against where the object's true motion carries the
track's first world point (p*), both lateral to the viewing ray; per track, the lag = regression of the slip
-(p - p*) on the true displacement (p* - p0) over its life (0: object-fixed, 1: world-fixed, e.g. light-fixed
shading or the hand). Tracks whose summed squared displacement is below 3 mm^2 are left out (noise-dominated).

Usage: python data_tools/slam7_track_lag.py OBJ OCC [SECONDS]"""

import sys

import numpy as np
from track_lag_common import lateral_slip

from vtrack.eval.session_gt import SessionGroundTruth
from vtrack.frames.session import SessionFrames
from vtrack.testing.sim import ycb_session

obj, occ = sys.argv[1], sys.argv[2]
secs = float(sys.argv[3]) if len(sys.argv) > 3 else 5.0
p = ycb_session(obj, occ, secs)
sf = SessionFrames(p, colour=True, colour_opts={})
G = SessionGroundTruth.load(p).poses_at(sf.times)
c = sf.cams[0].T_wc[:3, 3]
first: dict[int, tuple[int, np.ndarray]] = {}
obs: dict[int, list[tuple[float, float]]] = {}
for i in range(len(sf)):
    fr, _ = sf.frame(i)
    for a, pw in zip(fr.colour_ids.tolist(), fr.colour_points, strict=True):
        if a not in first:
            first[a] = (i, pw)
            continue
        i0, p0 = first[a]
        m, e, _ = lateral_slip(G, i, i0, p0, pw, c)
        obs.setdefault(a, []).append((float(-(e @ m)), float(m @ m)))
rows = []
for L in obs.values():
    A = np.array(L)
    if A[:, 1].sum() >= 3e-6:
        rows.append((len(A), A[:, 0].sum() / A[:, 1].sum()))
R = np.array(rows)
print(f"{obj} {occ}: {len(R)} tracks with >= 3 mm^2 of motion, median life {np.median(R[:, 0]):.0f} frames")
print("lag percentiles 10/25/50/75/90:", np.percentile(R[:, 1], [10, 25, 50, 75, 90]).round(3).tolist())
print(f"share with lag >= 0.9: {np.mean(R[:, 1] >= 0.9):.3f}, >= 0.5: {np.mean(R[:, 1] >= 0.5):.3f}")
hist, edges = np.histogram(np.clip(R[:, 1], -0.5, 0.999), bins=15, range=(-0.5, 1.0))
print(
    "histogram (lower edge: count; the ends hold the clipped tails):",
    dict(zip(edges[:-1].round(1).tolist(), hist.tolist(), strict=True)),
)
