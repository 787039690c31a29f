"""Micro A/B of the SLAM grid refresh's surfel SDF (``vtrack.tracking.sdf_grid.surfel_band_sdf``), an older code
snapshot vs this tree, interleaved in ONE process on the same inputs: the calls SLAM makes on the blind 2 s mug
(medium) session are recorded once, then replayed through both with the same kd-trees (the query is the same code
on both sides). Prints CPU ms per call per round, whether the values are bit-identical, and the medians.

Usage: ``python data_tools/slam_grid_micro_ab.py OLD_DIR [ROUNDS]`` with OLD_DIR a snapshot holding ``vtrack/``
(e.g. ``git archive 083a3c6 vtrack | tar -x -C OLD_DIR``).
"""

from __future__ import annotations

import sys
import time

import numpy as np
from snapshot_module import load as load_snapshot


def main() -> None:
    from vtrack.threads import limit_threads

    limit_threads(1)
    from scipy.spatial import cKDTree

    import vtrack.tracking.slam as slam
    from vtrack.testing.sim import ycb_session
    from vtrack.tracking.run import track_session
    from vtrack.tracking.sdf_grid import surfel_band_sdf as new

    old_dir, rounds = sys.argv[1], int(sys.argv[2]) if len(sys.argv) > 2 else 5
    old_mod = load_snapshot(f"{old_dir}/vtrack/tracking/sdf_grid.py", "old_sdf_grid")
    calls = []

    def record(*a, **k):
        calls.append(a)
        return new(*a, **k)

    slam.surfel_band_sdf = record
    track_session(ycb_session("025_mug", "medium", seconds=2), "", shape="slam", write=False)
    slam.surfel_band_sdf = new
    trees = [cKDTree(a[1], leafsize=32, balanced_tree=False, compact_nodes=False) for a in calls]
    t_old, t_new = [], []
    for r in range(rounds):
        res = []
        for fn, acc in ((old_mod.surfel_band_sdf, t_old), (new, t_new)):
            c0, out = time.process_time(), []
            for a, tree in zip(calls, trees, strict=True):
                out.append(fn(*a, tree=tree))
            acc.append((time.process_time() - c0) / len(calls) * 1e3)
            res.append(out)
        same = all(
            np.array_equal(x[0].view(np.uint32), y[0].view(np.uint32)) and np.array_equal(x[1], y[1])
            for x, y in zip(*res, strict=True)
        )
        print(f"round {r}: old {t_old[-1]:.2f} new {t_new[-1]:.2f} ms per call, bit-identical {same}", flush=True)
    mx = np.mean([len(a[0]) for a in calls])
    print(
        f"median: old {np.median(t_old):.2f} new {np.median(t_new):.2f} ms per call "
        f"(x{np.median(t_new) / np.median(t_old):.3f}); {len(calls)} calls, {mx:.0f} band voxels per call"
    )


if __name__ == "__main__":
    main()
