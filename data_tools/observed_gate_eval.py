"""SLAM's observed-surface gate (``SLAMOptions.observed_gate``), evaluated: every session tracked blind with each gate
(0 = off, the old behaviour); per run the object-motion error, and the spin about the object's axis: the scene turns
every object about its first-frame z axis, so ``spin_ratio`` = estimated / true turn about that axis at the last
frame and ``spin_err_deg`` = the last frame's rotation error about it (negative: turned too little). Both are
scored against gt/ by eval code; the tracker sees none of it.

Usage: ``python data_tools/observed_gate_eval.py SECONDS OCCLUSION SEEDS [OBJECTS] [--vision] [--gates 0,0.0025]
[--out PREFIX]`` (2 processes, one thread each). ``--out`` writes PREFIX.csv (one row per run) and PREFIX.png (mean
error per object and gate).
"""

import json
from multiprocessing import Pool


def _run(args: tuple) -> dict:
    obj, occ, secs, seed, gate, mods = args
    from vtrack.threads import limit_threads

    limit_threads(1)
    import numpy as np
    from scipy.spatial.transform import Rotation

    from vtrack.eval.session_gt import SessionGroundTruth
    from vtrack.geometry import se3
    from vtrack.testing.sim import ycb_session
    from vtrack.tracking.run import track_session

    path = ycb_session(obj, occ, secs, seed=seed)
    m, (times, est) = track_session(
        path, "", shape="slam", modalities=mods, write=False, return_poses=True, observed_gate=gate
    )
    G = SessionGroundTruth.load(path).poses_at(times)
    motion = est @ se3.invert(est[0]) @ G[0]  # the estimate's motion, started at the true first pose
    true_z = Rotation.from_matrix((se3.invert(G[0]) @ G[-1])[:3, :3]).as_rotvec()[2]
    est_z = Rotation.from_matrix((se3.invert(G[0]) @ motion[-1])[:3, :3]).as_rotvec()[2]
    err_z = Rotation.from_matrix((se3.invert(G[-1]) @ motion[-1])[:3, :3]).as_rotvec()[2]
    return dict(
        obj=obj,
        seed=seed,
        gate=gate,
        err_mm=float(m["motion_err_mm"]),
        spin_ratio=float(est_z / true_z) if abs(true_z) > 1e-6 else float("nan"),
        spin_err_deg=float(np.degrees(err_z)),
        cpu_ms=float(m["cpu_ms_per_frame_mean"]),
    )


def _write(prefix: str, res: dict, objs: list[str], seeds: list[int], gates: list[float], title: str) -> None:
    import csv

    from ablation_plot import grouped_bars_png

    keys = ("err_mm", "spin_ratio", "spin_err_deg", "cpu_ms")
    with open(prefix + ".csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["object", "seed", "observed_gate_m", "motion_err_mm", "spin_ratio", "spin_err_deg", "cpu_ms"])
        for (o, q, g), v in sorted(res.items()):
            w.writerow([o, q, g, *(f"{v[k]:.4f}" for k in keys)])
    grouped_bars_png(
        prefix + ".png",
        objs,
        [str(g) for g in gates],
        lambda o, g: sum(res[(o, q, float(g))]["err_mm"] for q in seeds) / len(seeds),
        ylabel=f"object-motion error, mm (mean of seeds {','.join(map(str, seeds))})",
        title=title,
        label=lambda g: "gate off" if float(g) == 0 else f"observed_gate {float(g) * 1e3:g} mm",
        hline=2.0,
    )


def main(
    secs: float, occ: str, seeds: list[int], objs: list[str], mods: tuple, gates: list[float], out: str | None
) -> None:
    jobs = [(o, occ, secs, s, g, mods) for s in seeds for o in objs for g in gates]
    res: dict = {}
    with Pool(2) as p:
        for r in p.imap(_run, jobs):
            res[(r["obj"], r["seed"], r["gate"])] = r
            print(json.dumps(r), flush=True)
    for s in seeds + [None]:
        sess = [(o, q) for q in seeds for o in objs if s is None or q == s]
        line = []
        for g in gates:
            e = sum(res[(o, q, g)]["err_mm"] for o, q in sess) / len(sess)
            c = sum(res[(o, q, g)]["cpu_ms"] for o, q in sess) / len(sess)
            line.append(f"gate {g * 1e3:g} mm: {e:.3f} mm ({c:.1f} ms CPU/frame)")
        print(f"{'all' if s is None else f'seed {s}'}: " + "  ".join(line))
    turned = [o for o in objs if o not in ("005_tomato_soup_can", "055_baseball")]  # spin scored: not symmetric
    for g in gates:
        r = [res[(o, q, g)]["spin_ratio"] for q in seeds for o in turned]
        print(f"gate {g * 1e3:g} mm: spin ratio of the non-symmetric objects, mean {sum(r) / len(r):.3f}")
    if out:
        mode = "vision" if mods == ("vision",) else "vision + touch"
        _write(out, res, objs, seeds, gates, f"SLAM observed-surface gate: {secs:g} s {occ}, {mode}, blind")


if __name__ == "__main__":
    from sweep_cli import parse_sweep, sweep_parser

    ap = sweep_parser("SLAM observed-surface gate: off against on, per session.")
    ap.add_argument("--gates", default="0,0.0025", help="comma-separated gates, m (0 = off)")
    sw, a = parse_sweep(ap)
    main(sw.seconds, sw.occlusion, sw.seeds, sw.objects, sw.modalities, [float(g) for g in a.gates.split(",")], sw.out)
