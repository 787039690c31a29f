"""Blind SLAM motion error of the 6 YCB objects over simulator seeds (GT for scoring only).

Seed 0 is the session every other benchmark uses; other seeds are new sessions of the same object and occlusion
(``ycb_session(..., seed=k)``: the same object trajectory, another pressure schedule of the fingers, hence other
joints and contacts, and other joint / tactile / camera noise), so a mean that holds only on seed 0 shows here.
Rows: SLAM vision + touch (the default) and, with ``--vision``, SLAM vision only (the heavy-occlusion comparison of
issue #20). ``OPTS`` are extra ``track_session`` keyword arguments of every run.

Usage: python data_tools/slam_seeds.py SECONDS OCC[,OCC] SEEDS OUT.json ['{opts}'] [--vision]
  e.g. python data_tools/slam_seeds.py 2 none,medium 0,1,2 /tmp/seeds.json
Prints one line per run, then per occlusion and row: the mean over objects for each seed, and the mean and
standard deviation of those per-seed means."""

import json
import sys
import time

from vtrack.threads import limit_threads

limit_threads(1)
import numpy as np  # noqa: E402

from vtrack.testing.sim import ycb_objects, ycb_session  # noqa: E402
from vtrack.tracking.run import track_session  # noqa: E402

args = [a for a in sys.argv[1:] if not a.startswith("--")]
secs, occs, seeds, out = float(args[0]), args[1].split(","), [int(s) for s in args[2].split(",")], args[3]
opts = json.loads(args[4]) if len(args) > 4 else {}
rows = {"slam-vt": ("vision", "touch")}
if "--vision" in sys.argv:
    rows["slam-v"] = ("vision",)
res: dict = {}
for occ in occs:
    for seed in seeds:
        for o in ycb_objects():
            path = ycb_session(o, occ, secs, seed=seed)
            for row, mods in rows.items():
                c0 = time.process_time()
                m = track_session(path, "", shape="slam", write=False, modalities=mods, **opts)
                res[f"{row}|{occ}|{seed}|{o}"] = {
                    "motion_err_mm": m["motion_err_mm"],
                    "cpu_ms_per_frame_mean": m["cpu_ms_per_frame_mean"],
                    "cpu_s": time.process_time() - c0,
                }
                print(row, occ, seed, o, round(m["motion_err_mm"], 3), flush=True)
                json.dump({"secs": secs, "opts": opts, "res": res}, open(out, "w"), indent=1)

print("\n| row | occlusion | " + " | ".join(f"seed {s}" for s in seeds) + " | mean ± sd over seeds |")
print("|---|---|" + "---|" * len(seeds) + "---|")
for row in rows:
    for occ in occs:
        per_seed = []
        for s in seeds:
            v = [r["motion_err_mm"] for k, r in res.items() if k.startswith(f"{row}|{occ}|{s}|")]
            per_seed.append(float(np.mean(v)) if v else float("nan"))
        cells = " | ".join(f"{v:.3f}" for v in per_seed)
        sd = f"{np.std(per_seed, ddof=1):.3f}" if len(per_seed) > 1 else "n/a (one seed)"
        print(f"| {row} | {occ} | {cells} | {np.mean(per_seed):.3f} ± {sd} |")
