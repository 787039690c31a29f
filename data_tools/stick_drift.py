"""Ground truth of the simulator's contact modes (scoring only): per YCB object, how far each contact travels over the
object during a contact phase (object frame), how much of the time the fingers are in contact, and how often at
least 3 of them are. Re-plans the sessions' grasps (``plan_grasp`` is deterministic given the seed).

Usage: python data_tools/stick_drift.py SECONDS OUT.json [MODES] [OBJECTS]   (MODES default slide,stick)
"""

import json
import sys

import numpy as np

from vtrack.threads import limit_threads

limit_threads(1)
from vtrack.geometry.raycast import Raycaster  # noqa: E402
from vtrack.kinematics.hand import HandKinematics  # noqa: E402
from vtrack.paths import default_scene_path, shared_data_dir  # noqa: E402
from vtrack.scene import load_scene  # noqa: E402
from vtrack.sim.generate import _times  # noqa: E402
from vtrack.sim.grasp import contact_drift_mm, plan_grasp  # noqa: E402
from vtrack.sim.objects import load_object_mesh  # noqa: E402
from vtrack.testing.sim import DEFAULT_OBJECT, ycb_objects  # noqa: E402

secs, out = float(sys.argv[1]), sys.argv[2]
modes = (sys.argv[3] if len(sys.argv) > 3 and sys.argv[3] else "slide,stick").split(",")
objs = sys.argv[4].split(",") if len(sys.argv) > 4 and sys.argv[4] else ycb_objects()
sc = load_scene(default_scene_path())
hk = HandKinematics.from_scene(sc)
specs = {m.sensor: sc.tactile_by_name(m.sensor) for m in sc.hand.sensors}
res = []
for o in objs:
    # as tiny_session_path / generate_session build them: the scene's object for the default one, else the mesh
    obj = (
        load_object_mesh(sc.object.mesh, sc.object.scale)
        if o == DEFAULT_OBJECT
        else load_object_mesh(shared_data_dir() / "objects" / "ycb" / f"{o}.ply", 1.0)
    )
    rc = Raycaster([(obj.vertices, obj.faces)])
    for mode in modes:
        sim = sc.sim.model_copy()
        sim.seconds, sim.contact_mode = secs, mode
        rng = np.random.default_rng(np.random.SeedSequence(sim.seed).spawn(4)[0])
        plan = plan_grasp(hk, obj, rc, sim, specs, _times(secs, sim.joint_rate_hz), rng)
        drift = contact_drift_mm(hk, rc, plan, specs)
        ph = np.stack([plan.in_contact_phase[s] for s in hk.sensor_names])
        d = [x for v in drift.values() for x in v]
        rec = dict(
            obj=o,
            mode=mode,
            seconds=secs,
            phases=len(d),
            drift_max_mm=float(max(d)) if d else None,
            drift_median_mm=float(np.median(d)) if d else None,
            contact_frac={s: float(plan.in_contact_phase[s].mean()) for s in hk.sensor_names},
            contact_frac_mean=float(ph.mean()),
            at_least_3=float((ph.sum(0) >= 3).mean()),
            at_least_2=float((ph.sum(0) >= 2).mean()),
        )
        print(json.dumps(rec), flush=True)
        res.append(rec)
with open(out, "w") as f:
    json.dump(res, f, indent=1)
