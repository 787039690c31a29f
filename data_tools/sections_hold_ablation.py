"""Reconstruction F@5 of the blind front-end row under shape-prior settings of the neural SDF (issue #20 ablation).

The row is the ``bench fusion`` "slam (no refinement)" one: neural SDF, 400 iterations, vision + touch placed with
the blind SLAM front end's poses (``vtrack.bench.fusion._session_observations``), scored by F@5 mm against the GT
mesh (GT for scoring only). Settings (``NeuralSDFConfig`` fields):

- ``before``: ``sections_grow=0, prior_weight=0`` (the elliptic sections trust no short seen arc; the residual
  network is free everywhere), the defaults until 2026-11-27 evening;
- ``grow``: ``prior_weight=0`` (short-arc sections accepted when their size agrees with a neighbour's);
- ``default``: the current defaults (also the sections' completion held where nothing was observed).

Usage: ``python data_tools/sections_hold_ablation.py SEEDS [--occlusion medium] [--settings a,b] [--cache DIR]
[--out PREFIX]`` (2 processes, one thread each). ``--cache DIR`` keeps each session's front-end observations as
``DIR/obs_<object>_<seed>.pkl`` and reuses them (clear it when the tracker or the frames layer change); ``--out``
writes PREFIX.csv (one row per run) and PREFIX.png (mean F@5 per setting and object).
"""

import argparse
import json
import os
import pickle
from multiprocessing import Pool

SETTINGS = {
    "before": {"sections_grow": 0.0, "prior_weight": 0.0},
    "grow": {"prior_weight": 0.0},
    "default": {},
}


def _observations(obj: str, occ: str, seed: int, cache: str | None) -> tuple:
    """(front-end observations (vision + touch), GT vertices, GT faces) of the 5 s session, from the cache if there."""
    fn = os.path.join(cache, f"obs_{obj}_{seed}.pkl") if cache else None
    if fn and os.path.exists(fn):
        with open(fn, "rb") as f:
            return pickle.load(f)
    from vtrack.bench.fusion import MODS, _session_observations
    from vtrack.testing.sim import ycb_session

    path = ycb_session(obj, occ, 5.0, seed=seed)
    _, Vg, Fg, _, info = _session_observations(path, True, {})
    out = ([o for o in info["observations_frontend"] if o.modality in MODS["vision+touch"]], Vg, Fg)
    if fn:
        os.makedirs(cache, exist_ok=True)
        with open(fn, "wb") as f:
            pickle.dump(out, f)
    return out


def _run(args: tuple) -> list[dict]:
    obj, occ, seed, settings, cache = args
    from vtrack.threads import limit_threads

    limit_threads(1)
    from vtrack.bench.fusion import _score
    from vtrack.fusion.reconstruct import reconstruct_observations

    obs, Vg, Fg = _observations(obj, occ, seed, cache)
    rows = []
    for name in settings:
        out = reconstruct_observations(obs, "neural_sdf", n_iters=400, **SETTINGS[name])
        sc = _score(out["vertices"], out["faces"], Vg, Fg)
        m = out["model"]
        prior = "revolution" if m.revolution is not None else "box" if m.box is not None else "hull"
        prior = f"sections ({len(m.sections.s)} slabs)" if m.sections is not None else prior
        rows.append(
            dict(
                obj=obj,
                seed=seed,
                setting=name,
                prior=prior,
                **{k: float(sc[k]) for k in ("fscore_5mm", "precision", "recall", "chamfer_mm")},
            )
        )
    return rows


def _write(prefix: str, rows: list[dict], settings: list[str]) -> None:
    import csv

    import numpy as np
    from ablation_plot import grouped_bars_png

    with open(prefix + ".csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["object", "seed", "setting", "prior", "fscore_5mm", "precision", "recall", "chamfer_mm"])
        for r in sorted(rows, key=lambda r: (r["obj"], r["seed"], settings.index(r["setting"]))):
            w.writerow(
                [r["obj"], r["seed"], r["setting"], r["prior"]]
                + [f"{r[k]:.4f}" for k in ("fscore_5mm", "precision", "recall", "chamfer_mm")]
            )
    grouped_bars_png(
        prefix + ".png",
        sorted({r["obj"] for r in rows}),
        settings,
        lambda o, g: float(np.mean([r["fscore_5mm"] for r in rows if r["obj"] == o and r["setting"] == g])),
        ylabel="F@5 mm, mean over seeds (blind)",
        title="neural SDF shape prior: elliptic sections, short arcs and holding the unseen back",
        ylim=(0.6, 1.0),
        hline=0.9,
    )


def main() -> None:
    from vtrack.testing.sim import ycb_objects

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("seeds", help="comma-separated, e.g. 0,1,2")
    ap.add_argument("--occlusion", default="medium")
    ap.add_argument("--settings", default=",".join(SETTINGS), help="comma-separated subset of " + ",".join(SETTINGS))
    ap.add_argument("--cache", help="directory for the sessions' front-end observations (reused when present)")
    ap.add_argument("--out", help="write PREFIX.csv and PREFIX.png")
    a = ap.parse_args()
    settings = [g.strip() for g in a.settings.split(",") if g.strip()]
    if not settings or set(settings) - set(SETTINGS):
        ap.error(f"--settings: expected a subset of {','.join(SETTINGS)}, got {a.settings}")
    seeds = [int(s) for s in a.seeds.split(",")]
    jobs = [(o, a.occlusion, s, settings, a.cache) for s in seeds for o in ycb_objects()]
    rows: list[dict] = []
    with Pool(2) as p:
        for rs in p.imap_unordered(_run, jobs):
            rows += rs
            for r in rs:
                print(json.dumps(r), flush=True)
    for g in settings:
        v = [r["fscore_5mm"] for r in rows if r["setting"] == g]
        print(f"{g}: F@5 mean {sum(v) / len(v):.4f} over {len(v)} runs")
    if a.out:
        _write(a.out, rows, settings)


if __name__ == "__main__":
    main()
