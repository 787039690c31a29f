"""bench slam's synthetic 20 s mustard runs (its sequence and scoring): back-end variants on the same keyframes.

Usage: python data_tools/slam5_synth.py '[{"loop_max_rot_rate": 0.05}, ...]'
Prints per occlusion the front end's motion error (mm) and each variant's, with its loop edges / rejected loops."""

import json
import sys

import numpy as np

from vtrack.paths import shared_data_dir
from vtrack.tracking.posegraph import BackendOptions, interpolate_corrections, refine_keyframes
from vtrack.tracking.slam import SLAMTracker
from vtrack.tracking.synth import make_sequence, run_sequence


def _score(E: np.ndarray, gt: np.ndarray, P: np.ndarray) -> float:
    """Mean ADD (mm) of poses E against gt on the model points P (as bench slam's synthetic rows)."""
    a = np.einsum("kij,nj->kni", E[:, :3, :3], P) + E[:, None, :3, 3]
    b = np.einsum("kij,nj->kni", gt[:, :3, :3], P) + gt[:, None, :3, 3]
    return float(np.linalg.norm(a - b, axis=2).mean() * 1e3)


variants = json.loads(sys.argv[1])
mesh = shared_data_dir() / "objects" / "ycb" / "006_mustard_bottle.ply"
for occ in ("none", "medium"):
    seq = make_sequence(
        mesh, n_frames=200, fps=10.0, rot_speed=0.6, width=120, height=90, seed=1, axis=(0.2, 0.1, 1.0), occlusion=occ
    )
    tr = SLAMTracker(seq.gt[0], refine=True)
    front, _ = run_sequence(tr, seq)
    times = np.array([f.t for f in seq.frames])
    P = seq.vertices[::20]
    kfs = tr.kf_graph
    kt = np.array([k.t for k in kfs])
    X0 = np.stack([k.T for k in kfs])
    out = [f"front {_score(front, seq.gt, P):.2f}"]
    for v in variants:
        X, rep = refine_keyframes(kfs, BackendOptions.from_dict({**tr.backend_opts.__dict__, **v}))
        err = _score(interpolate_corrections(kt, X0, X, times, front), seq.gt, P)
        out.append(f"{json.dumps(v)} {err:.2f} loops {rep.get('loop_edges')} rej {rep.get('loop_rejected')}")
    print(occ, " | ".join(out), flush=True)
