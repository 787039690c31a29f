"""ORACLE ablation: the tracker's prediction gets the true body velocity (GT) before each step; the data and the
window stay blind. Scoring / ablation only, not pipeline code. Options JSON may hold "modalities" and "no_oracle"."""

import json
import sys

import numpy as np

from vtrack.eval.session_gt import SessionGroundTruth
from vtrack.geometry import se3
from vtrack.testing.sim import ycb_session
from vtrack.tracking import run as R
from vtrack.tracking.window import _inv, _log

obj, occ, secs = sys.argv[1], sys.argv[2], float(sys.argv[3])
opts = json.loads(sys.argv[4]) if len(sys.argv) > 4 else {}
p = ycb_session(obj, occ, secs)
g = SessionGroundTruth.load(p)
orig = R.build_tracker


def bt(shape, mesh, T_init, **kw):
    tr = orig(shape, mesh, T_init, **kw)
    T0 = T_init.copy()
    t0 = [None]
    step = tr.step

    def s(frame):
        if t0[0] is None:
            t0[0] = frame.t
        t = frame.t
        dt = 1 / 30
        Ta, Tb = g.poses_at(np.array([t - dt, t]))
        G0 = g.poses_at(np.array([t0[0]]))[0]
        Ma, Mb = Ta @ se3.invert(G0) @ T0, Tb @ se3.invert(G0) @ T0
        tr.velocity = _log(_inv(Ma) @ Mb) / dt
        return step(frame)

    tr.step = s
    return tr


R.build_tracker = bt
mods = tuple(opts.pop("modalities", ["vision", "touch"]))
if opts.pop("no_oracle", False):
    R.build_tracker = orig
m = R.track_session(p, "", shape="slam", write=False, modalities=mods, **opts)
print("ORACLE velocity", obj, occ, secs, opts, round(m["motion_err_mm"], 2))
