"""The window anchor's refresh (``TrackerOptions.anchor_refresh``, SLAM's default since 2026-11-27), evaluated: every
session tracked blind with the stale anchor (``anchor_refresh=False``, the old default) and the refreshed one; per
run the object-motion error and the frame-to-frame rotation jitter, both scored against gt/ by eval code. Jitter
(deg) is the mean over consecutive frames of | |rotation of the estimated step| - |rotation of the true step| |:
a tracker whose even and odd frames disagree scores high even when its mean error is low.

Usage: ``python data_tools/anchor_refresh_eval.py SECONDS OCCLUSION SEEDS [OBJECTS] [--vision] [--out PREFIX]``
(2 processes, one thread each; ``--vision``: vision only). ``--out`` writes PREFIX.csv (one row per run) and
PREFIX.png (per session: the stale anchor's error and jitter against the refreshed one's).
"""

import json
from multiprocessing import Pool


def _run(args: tuple) -> dict:
    obj, occ, secs, seed, refresh, mods = args
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
        path, "", shape="slam", modalities=mods, write=False, return_poses=True, anchor_refresh=refresh
    )
    G = SessionGroundTruth.load(path).poses_at(times)

    def step_angle(T: np.ndarray) -> np.ndarray:
        D = se3.invert(T[:-1]) @ T[1:]
        return Rotation.from_matrix(D[:, :3, :3]).magnitude()

    jitter = float(np.degrees(np.mean(np.abs(step_angle(est) - step_angle(G)))))
    return dict(obj=obj, seed=seed, refresh=refresh, err_mm=float(m["motion_err_mm"]), jitter_deg=jitter)


def _write(prefix: str, res: dict) -> None:
    import csv

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    with open(prefix + ".csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["object", "seed", "anchor_refresh", "motion_err_mm", "jitter_deg"])
        for (o, q, r), v in sorted(res.items()):
            w.writerow([o, q, int(r), f"{v['err_mm']:.4f}", f"{v['jitter_deg']:.4f}"])
    sess = sorted({(o, q) for o, q, _ in res})
    fig, axes = plt.subplots(1, 2, figsize=(9, 4.5))
    for ax, key, unit in zip(axes, ("err_mm", "jitter_deg"), ("motion error (mm)", "jitter (deg)"), strict=True):
        x = [res[(o, q, False)][key] for o, q in sess]
        y = [res[(o, q, True)][key] for o, q in sess]
        ax.scatter(x, y, s=18)
        for (o, q), a, b in zip(sess, x, y, strict=True):
            if abs(a - b) > 0.25 * max(a, b, 1e-9):
                ax.annotate(f"{o.split('_', 1)[1]} s{q}", (a, b), fontsize=7)
        top = max(x + y) * 1.05
        ax.plot([0, top], [0, top], "k--", lw=0.8)
        ax.set_xlabel(f"stale anchor: {unit}")
        ax.set_ylabel(f"refreshed anchor: {unit}")
    fig.suptitle("SLAM window anchor refresh, per session")
    fig.tight_layout()
    fig.savefig(prefix + ".png", dpi=120)


def main(secs: float, occ: str, seeds: list[int], objs: list[str], mods: tuple, out: str | None) -> None:
    jobs = [(o, occ, secs, s, r, mods) for s in seeds for o in objs for r in (False, True)]
    res: dict = {}
    with Pool(2) as p:
        for r in p.imap(_run, jobs):
            res[(r["obj"], r["seed"], r["refresh"])] = r
            print(json.dumps(r), flush=True)
    for s in seeds + [None]:
        sess = [(o, q) for q in seeds for o in objs if s is None or q == s]
        n = len(sess)
        line = []
        for r in (False, True):
            e = sum(res[(o, q, r)]["err_mm"] for o, q in sess) / n
            j = sum(res[(o, q, r)]["jitter_deg"] for o, q in sess) / n
            line.append(f"{'refreshed' if r else 'stale'} {e:.3f} mm jitter {j:.3f} deg")
        print(f"{'all' if s is None else f'seed {s}'}: " + "  ".join(line))
    if out:
        _write(out, res)


if __name__ == "__main__":
    from sweep_cli import parse_sweep, sweep_parser

    sw, _ = parse_sweep(sweep_parser("SLAM window anchor: stale against refreshed, per session."))
    main(sw.seconds, sw.occlusion, sw.seeds, sw.objects, sw.modalities, sw.out)
