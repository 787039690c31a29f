"""Re-run SLAM's pose-graph back end offline on dumped keyframes (data_tools/slam5_dump.py) with other options.

GT is read for scoring only. Usage: python data_tools/slam5_backend.py DUMPDIR SECONDS '[{"opt": v}, ...]' [OUT.json]
Prints, per session, the front end's and each variant's motion error (mm) and the means per occlusion."""

import json
import pickle
import sys
from pathlib import Path

import numpy as np

from vtrack.eval.session_gt import SessionGroundTruth, score_trajectory
from vtrack.testing.sim import ycb_session
from vtrack.tracking.posegraph import BackendOptions, interpolate_corrections, refine_keyframes

d = Path(sys.argv[1])
secs = float(sys.argv[2])
variants = json.loads(sys.argv[3])
out = sys.argv[4] if len(sys.argv) > 4 else None
res: dict = {}
for f in sorted(d.glob("*.kf.pkl")):
    o, occ = f.name[: -len(".kf.pkl")].rsplit("_", 1)
    z = pickle.loads(f.read_bytes())
    gt = SessionGroundTruth.load(ycb_session(o, occ, secs))
    kfs, times, front = z["kf_graph"], z["times"], z["front"]
    row = {"front": score_trajectory(gt, times, front)[0]["motion_err_mm"]}
    if not kfs:  # no keyframe (e.g. the object hidden: touch only): the back end returns the front end
        row.update({f"v{n}": row["front"] for n in range(len(variants))})
        res[f"{o}|{occ}"] = row
        print(f"{o[:14]:14s} {occ:6s} no keyframes", flush=True)
        continue
    X_old = np.stack([kf.T for kf in kfs])
    kt = np.array([kf.t for kf in kfs])
    for n, v in enumerate(variants):
        opts = BackendOptions.from_dict({"refine": True, **v})
        X_new, rep = refine_keyframes(kfs, opts)
        est = interpolate_corrections(kt, X_old, X_new, times, front)
        row[f"v{n}"] = score_trajectory(gt, times, est)[0]["motion_err_mm"]
        row[f"v{n}_loops"] = rep.get("loop_edges", 0)
    res[f"{o}|{occ}"] = row
    print(f"{o[:14]:14s} {occ:6s} " + " ".join(f"{k}={v:.2f}" for k, v in row.items() if "loops" not in k), flush=True)
for occ in sorted({k.split("|")[1] for k in res}):
    rows = [r for k, r in res.items() if k.endswith("|" + occ)]
    print(occ, "mean", " ".join(f"{k}={np.mean([r[k] for r in rows]):.3f}" for k in rows[0] if "loops" not in k))
if out:
    Path(out).write_text(json.dumps({"variants": variants, "res": res}, indent=1))
