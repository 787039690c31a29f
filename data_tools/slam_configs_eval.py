"""Named SLAM settings side by side, per session: every YCB session tracked blind with each setting; the object-motion
error per run, scored against gt/ by eval code (the tracker sees none of it).

Usage: ``python data_tools/slam_configs_eval.py SECONDS OCCLUSION SEEDS [OBJECTS] --configs JSON [--contacts
slide|stick] [--out PREFIX]`` (2 processes, one thread each). ``JSON`` maps a setting's name to its
``track_session`` keyword arguments, plus optional ``"mods"`` (``v`` vision only, ``t`` touch only, ``vt`` both, the
default) and ``"preset"`` (the name of a dict in :mod:`vtrack.tracking.slam`, e.g. ``SLAM_STICKING_CONTACTS``), e.g.
``'{"vision": {"mods": "v"}, "both": {}, "stick": {"preset": "SLAM_STICKING_CONTACTS"}}'``. ``--contacts``: the
simulator's ``sim.contact_mode`` of the sessions (stick sessions are generated once and cached). ``--out`` writes
PREFIX.csv (one row per run) and PREFIX.png (mean error per object and setting). A session where SLAM finds no object
in its first frames is a row with the error message (the hidden baseball at medium occlusion, vision only). The
modalities come from each setting (``--vision`` of the shared command line is not used).
"""

import json
from multiprocessing import Pool

MODS = {"v": ("vision",), "t": ("touch",), "vt": ("vision", "touch")}


def _run(args: tuple) -> dict:
    obj, occ, secs, seed, contacts, name, cfg = args
    from vtrack.threads import limit_threads

    limit_threads(1)
    import vtrack.tracking.slam as slam
    from vtrack.errors import InputError
    from vtrack.testing.sim import ycb_session
    from vtrack.tracking.run import track_session

    opts = dict(cfg)
    mods = MODS[opts.pop("mods", "vt")]
    if "preset" in opts:
        opts = {**getattr(slam, opts.pop("preset")), **opts}
    rec = dict(obj=obj, seed=seed, setting=name)
    path = ycb_session(obj, occ, secs, contact_mode=contacts, seed=seed)
    try:
        m = track_session(path, "", shape="slam", modalities=mods, write=False, **opts)
    except InputError as e:
        return {**rec, "error": str(e)}
    return {**rec, "err_mm": float(m["motion_err_mm"]), "cpu_ms": float(m["cpu_ms_per_frame_mean"])}


def _mean(rows: list[dict]) -> float:
    return sum(r["err_mm"] for r in rows) / len(rows) if rows else float("nan")


def main() -> None:
    from sweep_cli import parse_sweep, sweep_parser

    ap = sweep_parser("Named SLAM settings side by side, per session.")
    ap.add_argument("--configs", required=True, help="JSON: setting name -> track_session options")
    ap.add_argument("--contacts", default="slide", choices=("slide", "stick"), help="the sessions' sim.contact_mode")
    sw, a = parse_sweep(ap)
    configs = json.loads(a.configs)
    jobs = [
        (o, sw.occlusion, sw.seconds, s, a.contacts, n, c)
        for s in sw.seeds
        for o in sw.objects
        for n, c in configs.items()
    ]
    res: list[dict] = []
    with Pool(2) as p:
        for r in p.imap(_run, jobs):
            res.append(r)
            print(json.dumps(r), flush=True)
    ok = [r for r in res if "err_mm" in r]
    for n in configs:
        per_seed = " / ".join(f"{_mean([r for r in ok if r['setting'] == n and r['seed'] == s]):.3f}" for s in sw.seeds)
        rows = [r for r in ok if r["setting"] == n]
        print(f"{n}: {_mean(rows):.3f} mm over {len(rows)} runs (seeds {per_seed})")
    if sw.out:
        import csv

        from ablation_plot import grouped_bars_png

        with open(sw.out + ".csv", "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(["object", "seed", "setting", "motion_err_mm", "cpu_ms", "error"])
            for r in res:
                err = f"{r['err_mm']:.4f}" if "err_mm" in r else ""
                cpu = f"{r['cpu_ms']:.2f}" if "cpu_ms" in r else ""
                w.writerow([r["obj"], r["seed"], r["setting"], err, cpu, r.get("error", "")])
        grouped_bars_png(
            sw.out + ".png",
            sw.objects,
            list(configs),
            lambda o, g: _mean([r for r in ok if r["obj"] == o and r["setting"] == g]),
            ylabel=f"object-motion error, mm (mean of seeds {','.join(map(str, sw.seeds))})",
            title=f"SLAM settings: {sw.seconds:g} s {sw.occlusion}, {a.contacts} fingers, blind",
        )


if __name__ == "__main__":
    main()
