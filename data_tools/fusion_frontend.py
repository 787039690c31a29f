"""The `bench fusion` front-end row under `track_session` option variants, on chosen 5 s YCB sessions.

The row: neural SDF (400 iterations) from vision + touch placed with the blind SLAM front end's poses, tracked with
the contact settings of `vtrack reconstruct`, scored by F@5 mm against the GT mesh placed by the first-frame alignment
(GT for scoring only): the bench's own ``_session_observations`` and ``_frontend_row``, without its pose-graph and
oracle rows.

Usage: python data_tools/fusion_frontend.py "obj|occ[|seed],..." '{track_session opts}' OUT.json
  e.g. python data_tools/fusion_frontend.py "011_banana|medium" '{"second_pass_s": 0}' /tmp/f.json"""

import json
import sys

from vtrack.threads import limit_threads

limit_threads(1)
from vtrack.bench.fusion import _frontend_row, _session_observations  # noqa: E402
from vtrack.bench.harness import BenchTable  # noqa: E402
from vtrack.testing.sim import ycb_session  # noqa: E402

cases = [c.split("|") for c in sys.argv[1].split(",")]
opts, out = json.loads(sys.argv[2]), sys.argv[3]
res: dict = {}
for o, occ, *seed in cases:
    path = ycb_session(o, occ, 5.0, seed=int(seed[0]) if seed else 0)
    _, Vg, Fg, load_s, info = _session_observations(path, True, opts)
    table = BenchTable(stage="fusion_frontend", error_key="fscore_5mm", time_key="ms", higher_is_better=True)
    _frontend_row(table, info, Vg, Fg, object_name=o, occlusion=occ, load_s=load_s, setting="iters=400")
    key = "|".join([o, occ, *seed])
    f5, err = table.rows[-1]["fscore_5mm"], info["motion_err_mm_frontend"]
    res[key] = {"f5": f5, "motion_err_mm": err, "s_session": table.rows[-1]["s_session"]}
    print(key, round(f5, 3), round(err, 3), flush=True)
    with open(out, "w") as fh:
        json.dump({"opts": opts, "res": res}, fh, indent=1)
