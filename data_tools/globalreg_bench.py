"""Success rate and time to first pose of :func:`vtrack.tracking.globalreg.global_register`.

Synthetic single views (``vtrack.testing.views.synthetic_frame``: hidden-point-removal view, 1 mm noise,
10 % "hand" outliers, 4 contacts, 20 free gel points) of YCB meshes at seeded random poses.
Success: ADD-S < 5 mm for symmetric objects (soup can), ADD < 5 mm otherwise, on the best
hypothesis. Ground truth only scores. Run on one core:

    OMP_NUM_THREADS=1 .venv/bin/python data_tools/globalreg_bench.py --seeds 10
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

OBJECTS = {"005_tomato_soup_can": True, "006_mustard_bottle": False, "025_mug": False}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--objects", nargs="*", default=list(OBJECTS))
    ap.add_argument("--touch-only", action="store_true", help="drop vision points (touch-only path)")
    ap.add_argument("--json", default=None)
    args = ap.parse_args()

    from vtrack.eval.pose_metrics import add, add_s, sample_model_points
    from vtrack.io.mesh import load_mesh
    from vtrack.paths import shared_data_dir
    from vtrack.testing.views import synthetic_frame
    from vtrack.tracking.globalreg import global_register, random_pose

    out = {}
    for name in args.objects:
        sym = OBJECTS.get(name, False)
        V, F = load_mesh(shared_data_dir() / "objects" / "ycb" / f"{name}.ply")
        M = sample_model_points(V, F, 1000)
        errs, times, cpu, top5 = [], [], [], []
        for s in range(args.seeds):
            T_gt = random_pose(1000 + s, centre=np.array([0.0, 0.0, 0.1]))
            fr = synthetic_frame(V, F, T_gt, seed=s)
            if args.touch_only:
                fr.vision_points = None
            t0, c0 = time.perf_counter(), time.process_time()
            hyps = global_register(V, F, [fr], symmetric=sym)
            times.append(time.perf_counter() - t0)
            cpu.append(time.process_time() - c0)
            metric = add_s if sym else add
            e = [float(metric(h.T_world_object[None], T_gt[None], M)[0]) for h in hyps] or [np.inf]
            errs.append(e[0])
            top5.append(min(e))
        errs, top5 = np.array(errs), np.array(top5)
        out[name] = {
            "success": float(np.mean(errs < 0.005)),
            "success_top5": float(np.mean(top5 < 0.005)),
            "median_err_mm": float(np.median(errs) * 1000),
            "median_s": float(np.median(times)),
            "max_s": float(np.max(times)),
            "median_cpu_s": float(np.median(cpu)),
            "metric": "ADD-S" if sym else "ADD",
            "seeds": args.seeds,
        }
        print(name, json.dumps(out[name]), flush=True)
    if args.json:
        with open(args.json, "w") as f:
            json.dump(out, f, indent=1)


if __name__ == "__main__":
    main()
