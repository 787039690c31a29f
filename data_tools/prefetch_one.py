"""One blind SLAM run of a cached YCB session with a frame-prefetch mode; prints a JSON line (poses/s over the loop
with the children's start, ``steady`` without the wait for the first frame, that wait ``first`` in s, CPU ms per frame
of build + step, the children's CPU ms per frame with their reads, motion error mm scored by eval code, the number of
child processes) and saves the poses to ``$VTRACK_AB_DIR/poses_<object>_<mode>.npy`` (default /tmp/vtrack_ab).

Usage: ``python data_tools/prefetch_one.py OBJECT SECONDS MODE`` (MODE: off | on | single), run with
``PYTHONPATH=TREE`` to time another source tree (``data_tools/prefetch_tree_ab.sh``).
"""

import json
import os
import sys

import numpy as np

from vtrack.threads import limit_threads

if __name__ == "__main__":
    limit_threads(1)
    from vtrack.testing.sim import ycb_session
    from vtrack.tracking.run import track_session, warm_up

    warm_up("slam", write=False)
    obj, secs, mode = sys.argv[1], float(sys.argv[2]), sys.argv[3]
    sess = ycb_session(obj, "medium", secs, seed=0)
    m, (_, T) = track_session(sess, "", shape="slam", write=False, prefetch=mode, return_poses=True)
    out = os.environ.get("VTRACK_AB_DIR", "/tmp/vtrack_ab")
    os.makedirs(out, exist_ok=True)
    np.save(os.path.join(out, f"poses_{obj}_{mode}.npy"), T)
    n, loop, first = m["frames"], m["frames_wall_s"], m["first_wait_s"]
    row = dict(
        pps=round(n / loop, 2),
        steady=round((n - 1) / (loop - first), 2),
        first=round(first, 2),
        cpu=round(m["cpu_ms_per_frame_mean"], 2),
        child=round(m.get("prefetch_child_cpu_s", 0) / n * 1e3, 2),
        err=round(m["motion_err_mm"], 4),
        procs=m.get("prefetch_processes"),
    )
    print(json.dumps(row))
