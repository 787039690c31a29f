"""Lag of the colour feature tracks behind the object's motion, per ColourOptions variant (GT for scoring only).

For every observation of a track, its world point now (p) against where the object's true motion carries the
track's first world point (p*): the lag fraction is the regression of -(p - p*) on the true displacement since the
first sight (p* - p0), both lateral to the viewing ray (0 = object-fixed, 1 = world-fixed, e.g. light-fixed
shading). Also its frame-to-frame counterpart and the median lateral error of the anchored tracks.

Usage: python data_tools/slam6_lag.py SECONDS "obj|occ,obj|occ" '[{colour opts}, ...]' [OUT.json] [--frames N]"""

import json
import sys

import numpy as np
from track_lag_common import lateral_slip

from vtrack.eval.session_gt import SessionGroundTruth
from vtrack.frames.session import SessionFrames
from vtrack.geometry import se3
from vtrack.testing.sim import ycb_session

args = [a for a in sys.argv[1:] if not a.startswith("--")]
secs = float(args[0])
cases = [c.split("|") for c in args[1].split(",")]
variants = json.loads(args[2])
out = args[3] if len(args) > 3 else None
res: dict = {}
for v in variants:
    for obj, occ in cases:
        p = ycb_session(obj, occ, secs)
        sf = SessionFrames(p, colour=True, colour_opts=v)
        G = SessionGroundTruth.load(p).poses_at(sf.times)
        c = sf.cams[0].T_wc[:3, 3]
        first: dict[int, tuple[int, np.ndarray]] = {}
        prev: dict[int, np.ndarray] = {}
        num = den = num1 = den1 = 0.0
        lat, ntr = [], []
        for i in range(len(sf)):
            fr, _ = sf.frame(i)
            ntr.append(len(fr.colour_ids))
            for a, pw in zip(fr.colour_ids.tolist(), fr.colour_points, strict=True):
                if a not in first:
                    first[a] = (i, pw)
                    continue
                i0, p0 = first[a]
                m, e, ray = lateral_slip(G, i, i0, p0, pw, c)
                num -= e @ m
                den += m @ m
                lat.append(np.linalg.norm(e))
                if a in prev:
                    pp = prev[a]
                    g = (G[i] @ se3.invert(G[i - 1]) @ np.r_[pp, 1.0])[:3] - pp
                    od = pw - pp
                    g -= ray * (ray @ g)
                    od -= ray * (ray @ od)
                    num1 += od @ g
                    den1 += g @ g
            prev = dict(zip(fr.colour_ids.tolist(), fr.colour_points, strict=True))
        r = {
            "lag_frac": num / max(den, 1e-12),
            "f2f_recovered": num1 / max(den1, 1e-12),
            "lateral_err_mm_median": float(np.median(lat) * 1e3) if lat else float("nan"),
            "tracks_per_frame": float(np.mean(ntr)),
        }
        res.setdefault(json.dumps(v), {})[f"{obj}|{occ}"] = r
        print(json.dumps(v), obj, occ, {k: round(x, 3) for k, x in r.items()}, flush=True)
        if out:
            with open(out, "w") as fh:
                json.dump(res, fh, indent=1)
