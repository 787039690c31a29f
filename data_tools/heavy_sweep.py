"""Heavy-occlusion sweep, one JSON line per (object, row): blind tracking of the 6 shared YCB objects (2 s sessions by
default), SLAM / known shape x vision / touch / both, ground truth for scoring only.

Usage: python data_tools/heavy_sweep.py OCC SECONDS OUT.jsonl [ROWS] [OPTS_JSON] [OBJECTS] [TAG] [CONTACT_MODE]
  ROWS: comma list of slam-v, slam-t, slam-vt, known-v, known-t, known-vt (default all but known-t)
  OPTS_JSON: extra ``track_session`` keyword arguments (e.g. '{"touch_weak_vision": 150}'); a key "slam" or "known"
  holding a dict applies to that shape only.
  CONTACT_MODE: the simulator's ``sim.contact_mode`` of the sessions: slide (default: the cached sessions of every
  earlier benchmark) or stick (fingers follow the object; generated once and cached, see vtrack.sim.grasp).
"""

import json
import sys
import time

from vtrack.threads import limit_threads

limit_threads(1)
from vtrack.errors import InputError  # noqa: E402
from vtrack.paths import shared_data_dir  # noqa: E402
from vtrack.testing.sim import ycb_objects, ycb_session  # noqa: E402
from vtrack.tracking.run import track_session  # noqa: E402

occ, secs, out = sys.argv[1], float(sys.argv[2]), sys.argv[3]
rows = (sys.argv[4] if len(sys.argv) > 4 and sys.argv[4] else "slam-v,slam-t,slam-vt,known-v,known-vt").split(",")
extra = json.loads(sys.argv[5]) if len(sys.argv) > 5 and sys.argv[5] else {}
objs = sys.argv[6].split(",") if len(sys.argv) > 6 and sys.argv[6] else ycb_objects()
tag = sys.argv[7] if len(sys.argv) > 7 else ""
contact_mode = sys.argv[8] if len(sys.argv) > 8 and sys.argv[8] else "slide"
per_shape = {k: extra.pop(k) for k in ("slam", "known") if k in extra}
M = {"v": ("vision",), "t": ("touch",), "vt": ("vision", "touch")}
for o in objs:
    sess = ycb_session(o, occ, secs, contact_mode=contact_mode)
    mesh = shared_data_dir() / "objects" / "ycb" / f"{o}.ply"
    for r in rows:
        shape, mod = r.split("-")
        kw = dict(shape="slam") if shape == "slam" else dict(shape="known_shape", mesh=mesh)
        kw.update(extra)
        kw.update(per_shape.get(shape, {}))
        t0 = time.time()
        try:
            m = track_session(sess, "", write=False, modalities=M[mod], **kw)
        except InputError as e:
            rec = dict(obj=o, occ=occ, s=secs, row=r, tag=tag, sim=contact_mode, error=str(e))
        else:
            rec = dict(
                obj=o,
                occ=occ,
                s=secs,
                row=r,
                tag=tag,
                sim=contact_mode,
                motion=m["motion_err_mm"],
                adds=m["add_s_mm"],
                drift=m["drift_mm"],
                cpu=m["cpu_ms_per_frame_mean"],
                wall=time.time() - t0,
            )
        print(json.dumps(rec), flush=True)
        with open(out, "a") as f:
            f.write(json.dumps(rec) + "\n")
