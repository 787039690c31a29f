"""Interleaved CODE A/B of blind SLAM tracking between two source trees (a speed change that must not change poses).

Usage: ``python data_tools/code_ab.py TREE_A TREE_B "obj|occ|secs,..." ROUNDS [OPTS_JSON]``
e.g. ``git worktree add --detach /tmp/base COMMIT`` then
``python data_tools/code_ab.py /tmp/base . "010_potted_meat_can|medium|2,025_mug|medium|2" 2``.

Each (round, session, tree) runs ``track_session(..., shape="slam")`` in its own subprocess with
``PYTHONPATH=TREE:TREE/apps`` and one thread; the trees alternate per session (and swap order every round) so both
see the same machine load. Printed per session: CPU ms per frame (``cpu_ms_per_frame_mean``), its preparation part
(``ms_prep_mean``: segmentation + tactile + colour tracks), the motion error (mm, scored against ``gt/`` by the eval
code), and the largest difference of B's poses from A's (translation m, rotation-matrix entries): 0 means the
change is bit-identical. Under load the absolute times are inflated; the B/A ratios are what to read.
Children run with ``cwd=/tmp``: ``python -c`` puts the working folder first on ``sys.path``, so a child started
inside a source tree would import that tree whatever PYTHONPATH says. Uses the cached simulator sessions
(``vtrack.testing.sim.ycb_session``, seed 0).
"""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

CHILD = r"""
import json, sys
from vtrack.threads import limit_threads
limit_threads(1)
import numpy as np
from vtrack.testing.sim import ycb_session
from vtrack.tracking.run import track_session
o, occ, secs, out = sys.argv[1], sys.argv[2], float(sys.argv[3]), sys.argv[4]
opts = json.loads(sys.argv[5]) if len(sys.argv) > 5 else {}
m, (t, est) = track_session(ycb_session(o, occ, secs), "", shape="slam", write=False, return_poses=True, **opts)
np.save(out, est)
keys = ("cpu_ms_per_frame_mean", "ms_prep_mean", "ms_per_frame_mean", "motion_err_mm")
print(json.dumps({k: m[k] for k in keys}))
"""
KEYS = ("cpu_ms_per_frame_mean", "ms_prep_mean", "ms_per_frame_mean")
SHARED = Path(os.environ.get("VTRACK_SHARED") or Path(__file__).resolve().parents[2] / "shared").resolve()


def run_child(tree: str, case: tuple[str, str, str], out: str, opts: str) -> dict:
    """Track one session with the code of ``tree``; poses saved to ``out`` (.npy), metrics returned."""
    tree = str(Path(tree).resolve())
    # the shared data as this checkout resolves it: a tree elsewhere (a worktree) would look beside itself
    env = dict(os.environ, PYTHONPATH=f"{tree}:{tree}/apps", VTRACK_SHARED=str(SHARED))
    cmd = [sys.executable, "-c", CHILD, *case, out, opts]
    r = subprocess.run(cmd, env=env, cwd="/tmp", capture_output=True, text=True)
    if r.returncode:
        sys.exit(f"child failed in {tree}: {r.stderr[-2000:]}")
    return json.loads(r.stdout.strip().splitlines()[-1])


def main(a: str, b: str, cases: str, rounds: int, opts: str = "{}") -> None:
    trees = {"A": a, "B": b}
    tot: dict[str, list[dict]] = {"A": [], "B": []}
    npy = {k: f"/tmp/code_ab_{os.getpid()}_{k}.npy" for k in trees}
    for r in range(rounds):
        for c in cases.split(","):
            case = tuple(c.split("|"))
            res = {}
            for k in ("A", "B") if r % 2 == 0 else ("B", "A"):
                res[k] = run_child(trees[k], case, npy[k], opts)
                tot[k].append(res[k])
            ea, eb = np.load(npy["A"]), np.load(npy["B"])
            dt = float(np.abs(ea[:, :3, 3] - eb[:, :3, 3]).max())
            dr = float(np.abs(ea[:, :3, :3] - eb[:, :3, :3]).max())
            cols = " | ".join(
                f"{k}: cpu {res[k]['cpu_ms_per_frame_mean']:.1f} prep {res[k]['ms_prep_mean']:.1f} "
                f"err {res[k]['motion_err_mm']:.3f}"
                for k in ("A", "B")
            )
            print(r, *case, cols, f"| max dT {dt:.2e} m dR {dr:.2e}", flush=True)
    for key in KEYS:
        va = np.array([x[key] for x in tot["A"]])
        vb = np.array([x[key] for x in tot["B"]])
        print(f"{key}: A {va.mean():.2f}  B {vb.mean():.2f}  B/A {np.mean(vb / va):.3f}")


if __name__ == "__main__":
    if len(sys.argv) < 5:
        sys.exit(__doc__)
    main(*sys.argv[1:4], int(sys.argv[4]), *(sys.argv[5:6] or ["{}"]))
