"""ORACLE: map from GT poses; at every frame, the data cost of the current frame along the GT per-frame motion
T(a) = M(t_prev) exp(a * xi), xi = log(M(t_prev)^-1 M(t)): a=1 is the truth, a=0 the previous pose."""

import json
import sys

import numpy as np
from slam_oracle_common import OracleMotion

from vtrack.testing.sim import ycb_session
from vtrack.tracking import run as R
from vtrack.tracking import window as W
from vtrack.tracking.window import _exp, _inv, _log

obj, occ, secs = sys.argv[1], sys.argv[2], float(sys.argv[3])
opts = json.loads(sys.argv[4]) if len(sys.argv) > 4 else {}
mods = tuple(opts.pop("modalities", ["vision"]))
p = ycb_session(obj, occ, secs)
oracle = OracleMotion(p)
g = oracle.g
A = np.array([-1, -0.5, 0, 0.5, 1, 1.5, 2, 3])
rows = []


M = oracle.pose


orig_step = W.WindowTracker.step


def step(self, frame):
    t = frame.t
    if self.t_last is not None and len(getattr(self, "map", [])) and len(rows) < 400:
        Tp, Tc = M(self.t_last), M(t)
        xi = _log(_inv(Tp) @ Tc)
        fr = self._gate(frame, Tc)
        costs = [self._frame_terms(Tp @ _exp(a * xi), fr)[2] for a in A]
        rows.append(costs)
    orig_step(self, frame)
    Tg = M(t)
    self.T = Tg.copy()
    for k in self.keyframes:
        k.T = M(k.t)
        k.T_prior = k.T.copy()
    return Tg.copy()


W.WindowTracker.step = step
oracle.install()
R.track_session(p, "", shape="slam", write=False, modalities=mods, **opts)
c = np.array(rows)
c = c - c[:, [4]]
print(obj, occ, secs, opts, "a =", A)
print("mean cost - cost(truth):", np.round(c.mean(0), 2))
print("argmin a per frame (counts):", {float(a): int((np.argmin(c, 1) == i).sum()) for i, a in enumerate(A)})
