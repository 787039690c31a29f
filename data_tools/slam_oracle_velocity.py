"""ORACLE ablation: the tracker's prediction gets the true body velocity (GT) before each step; the data and the
window stay blind. Scoring / ablation only, not pipeline code. Options JSON may hold "modalities" and "no_oracle"."""

import json
import sys

from slam_oracle_common import OracleMotion

from vtrack.testing.sim import ycb_session
from vtrack.tracking import run as R
from vtrack.tracking.window import _inv, _log

obj, occ, secs = sys.argv[1], sys.argv[2], float(sys.argv[3])
opts = json.loads(sys.argv[4]) if len(sys.argv) > 4 else {}
p = ycb_session(obj, occ, secs)
oracle = OracleMotion(p)
orig = R.build_tracker


def give_velocity(tr):
    step = tr.step

    def s(frame):
        dt = 1 / 30
        tr.velocity = _log(_inv(oracle.pose(frame.t - dt)) @ oracle.pose(frame.t)) / dt
        return step(frame)

    tr.step = s


oracle.install(give_velocity)
mods = tuple(opts.pop("modalities", ["vision", "touch"]))
if opts.pop("no_oracle", False):
    R.build_tracker = orig
m = R.track_session(p, "", shape="slam", write=False, modalities=mods, **opts)
print("ORACLE velocity", obj, occ, secs, opts, round(m["motion_err_mm"], 2))
