"""Run selection of blind SLAM, evaluated: every session tracked with the default and with each setting of
``SLAM_SELECT_ALTERNATIVES``; per run the blind map-consistency score (``map_consistency_mm``, what
``select_runs=True`` minimises, by ``select_run``) and the object-motion error (scored against gt/ by eval
code). Prints one JSON line per run and, per seed, the mean error of the default, of the run the score picks,
and of the best run (oracle).

Usage: ``python data_tools/slam_select_eval.py SECONDS OCCLUSION SEEDS [OBJECTS] [--out PREFIX]``, e.g.
``... 5 medium 0,1,2 --out docs/benchmarks/slam_select_run`` (2 processes, one thread each); ``--out`` also writes
PREFIX.csv (one row per run) and PREFIX.png (per session: the default's error against the kept run's).
"""

import json
import sys
from multiprocessing import Pool


def _run(args: tuple) -> dict:
    obj, occ, secs, seed, k = args
    from vtrack.threads import limit_threads

    limit_threads(1)
    from vtrack.testing.sim import ycb_session
    from vtrack.tracking.run import track_session
    from vtrack.tracking.slam import SLAM_SELECT_ALTERNATIVES, map_consistency_mm, sphere_in_force

    alt = {} if k == 0 else dict(SLAM_SELECT_ALTERNATIVES[k - 1])
    kept: dict = {}
    path = ycb_session(obj, occ, secs, seed=seed)
    m, (_, est) = track_session(path, "", shape="slam", write=False, return_poses=True, keep_frames=kept, **alt)
    frames = [fr.tracking_frame() for _, fr in kept["built"]]
    score = map_consistency_mm(kept["tracker"], frames, est)
    sphere = sphere_in_force(kept["tracker"])
    return dict(obj=obj, seed=seed, run=k, cfg=alt, err_mm=m["motion_err_mm"], score_mm=score, sphere=sphere)


def _write(prefix: str, res: dict, kept: dict) -> None:
    import csv

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    with open(prefix + ".csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["object", "seed", "run", "setting", "motion_err_mm", "map_consistency_mm", "kept"])
        for (o, q, k), r in sorted(res.items()):
            w.writerow(
                [o, q, k, json.dumps(r["cfg"]), f"{r['err_mm']:.4f}", f"{r['score_mm']:.5f}", int(kept[(o, q)] == k)]
            )
    sess = sorted(kept)
    x = [res[(o, q, 0)]["err_mm"] for o, q in sess]
    y = [res[(o, q, kept[(o, q)])]["err_mm"] for o, q in sess]
    fig, ax = plt.subplots(figsize=(4.5, 4.5))
    ax.scatter(x, y, s=18)
    for (o, q), a, b in zip(sess, x, y, strict=True):
        if abs(a - b) > 0.3:
            ax.annotate(f"{o.split('_', 1)[1]} s{q}", (a, b), fontsize=7)
    top = max(x + y) * 1.05
    ax.plot([0, top], [0, top], "k--", lw=0.8)
    ax.set_xlabel("default run: motion error (mm)")
    ax.set_ylabel("kept run: motion error (mm)")
    ax.set_title("SLAM run selection (blind score)")
    fig.tight_layout()
    fig.savefig(prefix + ".png", dpi=120)


def main(secs: float, occ: str, seeds: list[int], objs: list[str], out: str | None = None) -> None:
    from vtrack.tracking.slam import SLAM_SELECT_ALTERNATIVES, select_run

    runs = range(1 + len(SLAM_SELECT_ALTERNATIVES))
    jobs = [(o, occ, secs, s, k) for s in seeds for o in objs for k in runs]
    res: dict = {}
    kept: dict = {}
    with Pool(2) as p:
        for r in p.imap(_run, jobs):
            res[(r["obj"], r["seed"], r["run"])] = r
            print(json.dumps(r), flush=True)
    for s in seeds + [None]:
        sess = [(o, q) for q in seeds for o in objs if s is None or q == s]
        default = [res[(o, q, 0)]["err_mm"] for o, q in sess]
        picked, oracle = [], []
        for o, q in sess:
            rs = [res[(o, q, k)] for k in runs]
            best = rs[select_run([r["score_mm"] for r in rs], [r["sphere"] for r in rs])]
            kept[(o, q)] = best["run"]
            picked.append(best["err_mm"])
            oracle.append(min(r["err_mm"] for r in rs))
        n = len(sess)
        name = "all" if s is None else f"seed {s}"
        d, p_, o_ = sum(default) / n, sum(picked) / n, sum(oracle) / n
        print(f"{name}: default {d:.3f}  selected {p_:.3f}  best (oracle) {o_:.3f}")
    if out:
        _write(out, res, kept)


if __name__ == "__main__":
    from vtrack.testing.sim import ycb_objects

    args = sys.argv[1:]
    out = None
    if "--out" in args:
        i = args.index("--out")
        out = args[i + 1]
        del args[i : i + 2]
    main(
        float(args[0]),
        args[1],
        [int(s) for s in args[2].split(",")],
        args[3].split(",") if len(args) > 3 else ycb_objects(),
        out,
    )
