"""Quiet-machine CPU cost and accuracy of SLAM's colour term.

The 12 blind 2 s YCB sessions, each tracked without colour, with the default colour term and with 40 instead of 80
features, in turn (so that drift in the machine's speed hits all three alike). Prints CPU ms per frame (segmentation +
tactile pipelines + tracker, one thread) and object-motion error (mm, scored against gt/ by eval code) per session and
the means over none / medium occlusion.

Usage: ``python data_tools/slam_colour_cost.py``
"""

import numpy as np

from vtrack.threads import limit_threads

CONFIGS = {"off": {"sigma_colour": 0.0}, "default": {}, "mf40": {"colour_opts": {"max_features": 40}}}


def main() -> None:
    limit_threads(1)
    from vtrack.testing.sim import ycb_objects, ycb_session
    from vtrack.tracking.run import track_session

    res = {k: {"cpu": [], "err": []} for k in CONFIGS}
    for occ in ("none", "medium"):
        for name in ycb_objects():
            p = ycb_session(name, occ, 2)
            for k, opts in CONFIGS.items():
                kw = {key: dict(v) if isinstance(v, dict) else v for key, v in opts.items()}  # track_session pops
                m = track_session(p, "", shape="slam", write=False, **kw)
                res[k]["cpu"].append(m["cpu_ms_per_frame_mean"])
                res[k]["err"].append(m["motion_err_mm"])
            row = {k: (round(res[k]["cpu"][-1], 1), round(res[k]["err"][-1], 2)) for k in CONFIGS}
            print(name, occ, row, flush=True)
    for k in CONFIGS:
        c, e = np.array(res[k]["cpu"]), np.array(res[k]["err"])
        print(k, "cpu ms none / medium", c[:6].mean().round(2), c[6:].mean().round(2), end=" ")
        print("error mm", e[:6].mean().round(3), e[6:].mean().round(3))


if __name__ == "__main__":
    main()
