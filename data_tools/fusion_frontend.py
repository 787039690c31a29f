"""The `bench fusion` front-end row under `track_session` option variants, on chosen 5 s YCB sessions.

The row: neural SDF (400 iterations) from vision + touch placed with the blind SLAM front end's poses, tracked with
the contact settings of `vtrack reconstruct` (``TOUCH_STRIDE`` / ``TOUCH_DOWNSAMPLE``), scored by F@5 mm against the GT
mesh placed by the first-frame alignment, as `bench fusion` does (GT for scoring only). One row costs ~1.5 min of CPU
instead of the bench's three (pose graph, front end, oracle).

Usage: python data_tools/fusion_frontend.py "obj|occ[|seed],..." '{track_session opts}' OUT.json
  e.g. python data_tools/fusion_frontend.py "011_banana|medium" '{"second_pass_s": 0}' /tmp/f.json"""

import json
import sys
import time

from vtrack.threads import limit_threads

limit_threads(1)
import numpy as np  # noqa: E402

from vtrack.bench.fusion import _score  # noqa: E402
from vtrack.eval.session_gt import SessionGroundTruth  # noqa: E402
from vtrack.fusion.observations import observations_from_frames  # noqa: E402
from vtrack.fusion.reconstruct import TOUCH_DOWNSAMPLE, TOUCH_STRIDE, reconstruct_observations  # noqa: E402
from vtrack.geometry import se3  # noqa: E402
from vtrack.io.mesh import load_mesh  # noqa: E402
from vtrack.io.poses import PoseTrack  # noqa: E402
from vtrack.testing.sim import ycb_session  # noqa: E402
from vtrack.tracking.run import track_session  # noqa: E402

cases = [c.split("|") for c in sys.argv[1].split(",")]
opts, out = json.loads(sys.argv[2]), sys.argv[3]
res: dict = {}
for o, occ, *seed in cases:
    path = ycb_session(o, occ, 5.0, seed=int(seed[0]) if seed else 0)
    gt = SessionGroundTruth.load(path)
    Vg, Fg = load_mesh(gt.mesh_path)
    kept: dict = {}
    c0 = time.process_time()
    m, (times, est) = track_session(
        path,
        "",
        shape="slam",
        write=False,
        return_poses=True,
        keep_frames=kept,
        keep_step=2,
        touch_stride=TOUCH_STRIDE,
        touch_downsample=TOUCH_DOWNSAMPLE,
        **opts,
    )
    V = se3.transform_points(se3.invert(est[0]) @ gt.poses_at(times[:1])[0], np.asarray(Vg, np.float64))
    obs = observations_from_frames(kept["frames"], kept["built"], PoseTrack(times, est)).observations
    r = reconstruct_observations([ob for ob in obs if ob.modality in (0, 1)], "neural_sdf", n_iters=400)
    s = _score(r["vertices"], r["faces"], V, Fg)
    key = "|".join([o, occ, *seed])
    res[key] = {"f5": s["fscore_5mm"], "motion_err_mm": m["motion_err_mm"], "cpu_s": time.process_time() - c0}
    print(key, round(s["fscore_5mm"], 3), round(m["motion_err_mm"], 3), flush=True)
    with open(out, "w") as fh:
        json.dump({"opts": opts, "res": res}, fh, indent=1)
