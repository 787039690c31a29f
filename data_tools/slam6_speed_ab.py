"""Interleaved A/B CPU cost of blind SLAM option variants: CPU ms per frame (``cpu_ms_per_frame_mean``: segmentation +
tactile + colour tracks + tracker, one thread) per session, the variants alternated per session, R rounds; and the
ratio to the first variant. Under load the absolute numbers are inflated; the ratios are what to read.

Usage: python data_tools/slam6_speed_ab.py SECONDS "obj|occ,..." '{"name": {opts}, ...}' R OUT.json"""

import json
import sys

import numpy as np

from vtrack.threads import limit_threads

limit_threads(1)
from vtrack.testing.sim import ycb_session  # noqa: E402
from vtrack.tracking.run import track_session  # noqa: E402

secs = float(sys.argv[1])
cases = [c.split("|") for c in sys.argv[2].split(",")]
conf = json.loads(sys.argv[3])
rounds = int(sys.argv[4])
out = sys.argv[5]
cpu: dict = {k: [] for k in conf}
for r in range(rounds):
    for o, occ in cases:
        p = ycb_session(o, occ, secs)
        for k, kw in conf.items():
            m = track_session(p, "", shape="slam", write=False, **json.loads(json.dumps(kw)))
            cpu[k].append(m["cpu_ms_per_frame_mean"])
            print(r, k, o, occ, round(m["cpu_ms_per_frame_mean"], 2), round(m["motion_err_mm"], 3), flush=True)
base = np.array(cpu[next(iter(conf))])
summ = {
    k: {"cpu_ms_mean": float(np.mean(v)), "ratio_to_first": float(np.mean(np.array(v) / base))} for k, v in cpu.items()
}
print(json.dumps(summ, indent=1))
with open(out, "w") as fh:
    json.dump({"cpu": cpu, "summary": summ}, fh, indent=1)
