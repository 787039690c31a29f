"""The colour term on an object WITHOUT colour texture (the real YCB mug is plain red).

Generates the session of ``OBJ`` with the simulator's object-fixed albedo pattern switched off (uniform base colour;
the light-fixed shading and the mesh's own relief stay, as on a real plain object), in a PRIVATE cache (never the
shared session cache: the session hash does not know about the patch), then runs blind SLAM with and without the
colour term and prints the motion errors and the colour tracks per frame. GT for scoring only.

Usage: python data_tools/slam_colour_uniform.py OBJ OCC SECONDS '{"sigma_colour": 0.001}' [CACHE_DIR]
"""

import json
import os
import sys
from pathlib import Path

obj, occ, secs = sys.argv[1], sys.argv[2], float(sys.argv[3])
opts = json.loads(sys.argv[4])
cache = Path(sys.argv[5] if len(sys.argv) > 5 else "/tmp/vtrack_uniform_cache")
os.environ["VTRACK_CACHE"] = str(cache)  # before vtrack resolves its cache

import numpy as np  # noqa: E402

import vtrack.sim.rgbd as rgbd  # noqa: E402


def _uniform(points_obj: np.ndarray, base_rgb: np.ndarray) -> np.ndarray:
    return np.broadcast_to(base_rgb, (*points_obj.shape[:-1], 3)).astype(np.float64)


rgbd._albedo_object = _uniform  # the pattern off for this process only

from vtrack.frames.session import SessionFrames  # noqa: E402
from vtrack.testing.sim import ycb_session  # noqa: E402
from vtrack.tracking.run import track_session  # noqa: E402

path = ycb_session(obj, occ, secs)
print("session", path, flush=True)
sf = SessionFrames(path, colour=True, colour_opts=opts.get("colour_opts"))
n = [len(sf.frame(i)[0].colour_ids) for i in range(len(sf))]
print(f"colour tracks per frame: mean {np.mean(n):.1f}, max {max(n)}", flush=True)
for o in ({"sigma_colour": 0.0}, opts):
    m = track_session(path, "", shape="slam", write=False, **o)
    print(json.dumps(o), f"motion error {m['motion_err_mm']:.3f} mm", flush=True)
