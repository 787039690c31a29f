"""The same poses from a session and from its copy without ground truth (``vtrack session strip-gt``): SLAM blind,
with the frames built in process and through the prefetch children; prints each run's frames, its largest pose
difference from the full session's in-process run, and its score (None on the stripped copy: it has no ``gt/``).

Usage: ``python data_tools/stripped_pose_check.py FULL_SESSION STRIPPED_SESSION``.
"""

import sys

import numpy as np


def main(full: str, stripped: str) -> None:
    from vtrack.threads import limit_threads

    limit_threads(1)
    from vtrack.tracking.run import track_session

    out = {}
    for name, path in (("full", full), ("stripped", stripped)):
        for prefetch in ("off", "on"):
            m, (_, poses) = track_session(path, "", shape="slam", write=False, return_poses=True, prefetch=prefetch)
            out[(name, prefetch)] = (poses, m.get("motion_err_mm"))
    ref = out[("full", "off")][0]
    for key, (poses, err) in out.items():
        print(key, "frames", len(poses), "max |dT|", float(np.abs(poses - ref).max()), "motion_err_mm", err)


if __name__ == "__main__":  # spawned children re-import this file
    main(sys.argv[1], sys.argv[2])
