"""ORACLE diagnosis: the map is built from GT-motion poses; before each step the tracker sits at the GT pose with the
GT velocity (keyframes too); we record how far one step of the window tracker moves away from GT: spin about the
GT body axis and the rest. Shows whether the data (at a correct map) pulls the spin."""

import json
import os
import sys

import numpy as np
from slam_oracle_common import OracleMotion

from vtrack.geometry import se3
from vtrack.testing.sim import ycb_session
from vtrack.tracking import run as R
from vtrack.tracking import window as W
from vtrack.tracking.window import _inv, _log

obj, occ, secs = sys.argv[1], sys.argv[2], float(sys.argv[3])
opts = json.loads(sys.argv[4]) if len(sys.argv) > 4 else {}
mods = tuple(opts.pop("modalities", ["vision", "touch"]))
p = ycb_session(obj, occ, secs)
oracle = OracleMotion(p)
g = oracle.g
rows = []


M = oracle.pose


orig_step = W.WindowTracker.step


def step(self, frame):
    t = frame.t
    dt = 1 / 30
    if self.t_last is not None:
        self.T = M(self.t_last)
        self.velocity = _log(_inv(M(t - dt)) @ M(t)) / dt
        for k in self.keyframes:
            k.T = M(k.t)
            k.T_prior = k.T.copy()
            if os.environ.get("FIXV", "1") == "1":
                k.v = _log(_inv(M(k.t - dt)) @ M(k.t)) / dt
    out = orig_step(self, frame)
    Tg = M(t)
    E = _inv(Tg) @ out
    ax = se3.so3_log(g.poses[-1][:3, :3] @ g.poses[0][:3, :3].T)
    ax = ax / np.linalg.norm(ax)
    axis_o = Tg[:3, :3].T @ ax
    rv = se3.so3_log(E[:3, :3])
    rows.append(
        (
            t,
            float(rv @ axis_o),
            float(np.linalg.norm(rv - (rv @ axis_o) * axis_o)),
            self.last_info.n_vision,
            np.linalg.norm(E[:3, 3]),
        )
    )
    self.T = Tg.copy()
    return Tg.copy()


W.WindowTracker.step = step
oracle.install()
m = R.track_session(p, "", shape="slam", write=False, modalities=mods, **opts)
a = np.array(rows)
print(obj, occ, secs, opts, mods, "motion_err (should be ~0)", round(m["motion_err_mm"], 2))
for i in range(1, len(a), int(os.environ.get("EVERY", "10"))):
    print(
        f"t={a[i, 0]:.2f} spin_step_err_deg={np.degrees(a[i, 1]):+.3f} other={np.degrees(a[i, 2]):.3f} "
        f"trans_mm={a[i, 4] * 1e3:.2f} nv={int(a[i, 3])}"
    )
print(
    "mean spin step err deg",
    np.degrees(a[1:, 1]).mean(),
    "abs",
    np.degrees(np.abs(a[1:, 1])).mean(),
    "other",
    np.degrees(a[1:, 2]).mean(),
    "gt spin per frame deg",
    np.degrees(0.45 / 30),
)
