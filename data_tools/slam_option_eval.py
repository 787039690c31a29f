"""One SLAM option at several values, evaluated per session: every session tracked blind with each value; per run
the object-motion error and the spin about the object's axis: the scene turns every object about its first-frame z
axis, so ``spin_ratio`` = estimated / true turn about that axis at the last frame and ``spin_err_deg`` = the last
frame's rotation error about it (negative: turned too little). Both are scored against gt/ by eval code; the tracker
sees none of it.

Usage: ``python data_tools/slam_option_eval.py SECONDS OCCLUSION SEEDS [OBJECTS] --option NAME --values A,B
[--vision] [--out PREFIX]`` (2 processes, one thread each), e.g. ``--option few_touch_points --values 0,12``.
``--out`` writes PREFIX.csv (one row per run) and PREFIX.png (mean error per object and value). Values are parsed as
int when they look like one, else float.
"""

import json
from multiprocessing import Pool


def _value(s: str) -> int | float:
    try:
        return int(s)
    except ValueError:
        return float(s)


def _run(args: tuple) -> dict:
    obj, occ, secs, seed, option, value, mods = args
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
        path, "", shape="slam", modalities=mods, write=False, return_poses=True, **{option: value}
    )
    G = SessionGroundTruth.load(path).poses_at(times)
    motion = est @ se3.invert(est[0]) @ G[0]  # the estimate's motion, started at the true first pose
    true_z = Rotation.from_matrix((se3.invert(G[0]) @ G[-1])[:3, :3]).as_rotvec()[2]
    est_z = Rotation.from_matrix((se3.invert(G[0]) @ motion[-1])[:3, :3]).as_rotvec()[2]
    err_z = Rotation.from_matrix((se3.invert(G[-1]) @ motion[-1])[:3, :3]).as_rotvec()[2]
    return dict(
        obj=obj,
        seed=seed,
        value=value,
        err_mm=float(m["motion_err_mm"]),
        spin_ratio=float(est_z / true_z) if abs(true_z) > 1e-6 else float("nan"),
        spin_err_deg=float(np.degrees(err_z)),
        cpu_ms=float(m["cpu_ms_per_frame_mean"]),
    )


def _write(
    prefix: str, res: dict, objs: list[str], seeds: list[int], values: list, title: str, label, column: str
) -> None:
    import csv

    from ablation_plot import grouped_bars_png

    keys = ("err_mm", "spin_ratio", "spin_err_deg", "cpu_ms")
    with open(prefix + ".csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["object", "seed", column, "motion_err_mm", "spin_ratio", "spin_err_deg", "cpu_ms"])
        for (o, q, g), v in sorted(res.items()):
            w.writerow([o, q, g, *(f"{v[k]:.4f}" for k in keys)])
    grouped_bars_png(
        prefix + ".png",
        objs,
        [str(g) for g in values],
        lambda o, g: sum(res[(o, q, _value(g))]["err_mm"] for q in seeds) / len(seeds),
        ylabel=f"object-motion error, mm (mean of seeds {','.join(map(str, seeds))})",
        title=title,
        label=lambda g: label(_value(g)),
        hline=2.0,
    )


def main(
    secs: float,
    occ: str,
    seeds: list[int],
    objs: list[str],
    mods: tuple,
    option: str,
    values: list,
    out: str | None,
    what: str | None = None,
    label=None,
    column: str | None = None,
) -> None:
    """Track every (object, seed, value) session (2 processes); print per-seed means and the spin ratio; write
    ``out``.csv / .png. ``what`` names the option in the plot's title, ``label`` a value in the plot and the printout,
    ``column`` is the CSV's value column (all three default to the option's name)."""
    label = label or (lambda v: f"{option}={v:g}")
    jobs = [(o, occ, secs, s, option, v, mods) for s in seeds for o in objs for v in values]
    res: dict = {}
    with Pool(2) as p:
        for r in p.imap(_run, jobs):
            res[(r["obj"], r["seed"], r["value"])] = r
            print(json.dumps(r), flush=True)
    for s in seeds + [None]:
        sess = [(o, q) for q in seeds for o in objs if s is None or q == s]
        line = []
        for v in values:
            e = sum(res[(o, q, v)]["err_mm"] for o, q in sess) / len(sess)
            c = sum(res[(o, q, v)]["cpu_ms"] for o, q in sess) / len(sess)
            line.append(f"{label(v)}: {e:.3f} mm ({c:.1f} ms CPU/frame)")
        print(f"{'all' if s is None else f'seed {s}'}: " + "  ".join(line))
    turned = [o for o in objs if o not in ("005_tomato_soup_can", "055_baseball")]  # spin scored: not symmetric
    for v in values if turned else []:
        r = [res[(o, q, v)]["spin_ratio"] for q in seeds for o in turned]
        print(f"{label(v)}: spin ratio of the non-symmetric objects, mean {sum(r) / len(r):.3f}")
    if out:
        mode = "vision" if mods == ("vision",) else "vision + touch"
        title = f"SLAM {what or option}: {secs:g} s {occ}, {mode}, blind"
        _write(out, res, objs, seeds, values, title, label, column or option)


def cli(
    option: str | None = None,
    default_values: str | None = None,
    description: str = "",
    values_flag: str = "--values",
    **kw,
) -> None:
    """Command line: the shared sweep arguments (sweep_cli) plus ``--option`` / ``values_flag`` (a wrapper passes
    ``option`` and may rename the values flag; it then defaults to ``default_values``); ``kw``: :func:`main`'s
    ``what`` / ``label`` / ``column``."""
    from sweep_cli import parse_sweep, sweep_parser

    ap = sweep_parser(description or "One SLAM option at several values, per session.")
    if option is None:
        ap.add_argument("--option", required=True, help="a track_session / SLAM option name")
    ap.add_argument(
        values_flag,
        dest="values",
        default=default_values,
        required=default_values is None,
        help="comma-separated values",
    )
    sw, a = parse_sweep(ap)
    name = option or a.option
    main(
        sw.seconds,
        sw.occlusion,
        sw.seeds,
        sw.objects,
        sw.modalities,
        name,
        [_value(v) for v in a.values.split(",")],
        sw.out,
        **kw,
    )


if __name__ == "__main__":
    cli()
