"""Blind SLAM with the default 5 LM iterations vs 3, alternated per session in one process (same load for both):
the 12 2 s and then the 12 5 s YCB sessions; CPU ms per frame (process time: segmentation, tactile pipelines,
tracker) and object-motion error (mm, scored against gt/ by eval code). Writes the JSON after each row as
``{"2": rows, "5": rows}``, a row = ``[object, occlusion, cpu default, error default, cpu it3, error it3]``.

Usage: ``python data_tools/slam_iterations_check.py OUT.json`` (docs/benchmarks/slam_speed_colour.json).
"""

import json
import sys

from vtrack.threads import limit_threads


def main() -> None:
    limit_threads(1)
    from vtrack.testing.sim import ycb_objects, ycb_session
    from vtrack.tracking.run import track_session

    out: dict[str, list] = {"2": [], "5": []}
    for secs in (2, 5):
        for occ in ("none", "medium"):
            for name in ycb_objects():
                p = ycb_session(name, occ, secs)
                row: list = [name, occ]
                for kw in ({}, {"iterations": 3}):
                    m = track_session(p, "", shape="slam", write=False, **kw)
                    row += [m["cpu_ms_per_frame_mean"], m["motion_err_mm"]]
                out[str(secs)].append(row)
                c0, e0, c1, e1 = row[2:]
                print(secs, name, occ, f"default {c0:.2f} ms {e0:.4f} mm | it3 {c1:.2f} ms {e1:.4f} mm", flush=True)
                with open(sys.argv[1], "w") as f:
                    json.dump(out, f, indent=1)


if __name__ == "__main__":
    main()
