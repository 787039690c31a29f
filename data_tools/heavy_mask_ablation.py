"""Where heavy-occlusion SLAM loses its accuracy: the segmentation mask's two uses, one at a time (ORACLE ablation).

The blind pipeline's object mask feeds the tracker twice: the depth points inside it, and the colour feature tracks
(KLT on the object pixels, the term that sees a spin depth cannot). This tool tracks every session blind
(``pipeline``; ``grow1``: the opt-in colour mask grown by one pixel, ``SegmentationOptions.colour_grow_px``) and with
the simulator's mask given to one use (``gt_points``: depth points; ``gt_colour``: colour tracks) or both (``gt``).
The ``gt*`` rows are ORACLE ablations; ground truth is read by the scoring and by those oracle masks only.

Usage: ``python data_tools/heavy_mask_ablation.py SECONDS OCCLUSION SEEDS [--vision] [--settings a,b] [--out PREFIX]``
(2 processes, one thread each; ``--vision``: vision only, else vision + touch; ``--settings``: a subset of
pipeline,grow1,gt_points,gt_colour,gt). ``--out`` writes PREFIX.csv (one row per run) and PREFIX.png (mean
object-motion error per setting and object).
"""

import argparse
import json
from multiprocessing import Pool

MASKS = ("pipeline", "grow1", "gt_points", "gt_colour", "gt")


def _run(args: tuple) -> dict:
    obj, occ, secs, seed, seg, mods = args
    from vtrack.threads import limit_threads

    limit_threads(1)
    from vtrack.testing.sim import ycb_session
    from vtrack.tracking.run import track_session

    path = ycb_session(obj, occ, secs, seed=seed)
    kw: dict = {"segmentation_opts": {"colour_grow_px": 1}} if seg == "grow1" else {"segmentation": seg}
    m = track_session(path, "", shape="slam", modalities=mods, write=False, **kw)
    return dict(obj=obj, seed=seed, segmentation=seg, blind=bool(m["blind"]), err_mm=float(m["motion_err_mm"]))


def _write(prefix: str, rows: list[dict]) -> None:
    import csv

    import numpy as np
    from ablation_plot import grouped_bars_png

    with open(prefix + ".csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["object", "seed", "segmentation", "blind", "motion_err_mm"])
        for r in sorted(rows, key=lambda r: (r["obj"], r["seed"], MASKS.index(r["segmentation"]))):
            w.writerow([r["obj"], r["seed"], r["segmentation"], int(r["blind"]), f"{r['err_mm']:.4f}"])
    grouped_bars_png(
        prefix + ".png",
        sorted({r["obj"] for r in rows}),
        [g for g in MASKS if any(r["segmentation"] == g for r in rows)],
        lambda o, g: float(np.mean([r["err_mm"] for r in rows if r["obj"] == o and r["segmentation"] == g])),
        ylabel="object-motion error (mm), mean over seeds",
        title="SLAM under occlusion: which use of the mask costs the error",
        label=lambda g: f"{g} (oracle)" if g.startswith("gt") else f"{g} (blind)",
    )


def main() -> None:
    from vtrack.testing.sim import ycb_objects

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("seconds", type=float)
    ap.add_argument("occlusion")
    ap.add_argument("seeds", help="comma-separated, e.g. 0,1,2")
    ap.add_argument("--vision", action="store_true", help="vision only (default: vision + touch)")
    ap.add_argument("--settings", default=",".join(MASKS), help="comma-separated subset of " + ",".join(MASKS))
    ap.add_argument("--out", help="write PREFIX.csv and PREFIX.png")
    a = ap.parse_args()
    settings = [g.strip() for g in a.settings.split(",") if g.strip()]
    if not settings or set(settings) - set(MASKS):
        ap.error(f"--settings: expected a subset of {','.join(MASKS)}, got {a.settings}")
    mods = ("vision",) if a.vision else ("vision", "touch")
    seeds = [int(s) for s in a.seeds.split(",")]
    jobs = [(o, a.occlusion, a.seconds, s, g, mods) for s in seeds for o in ycb_objects() for g in settings]
    rows = []
    with Pool(2) as p:
        for r in p.imap(_run, jobs):
            rows.append(r)
            print(json.dumps(r), flush=True)
    for g in settings:
        v = [r["err_mm"] for r in rows if r["segmentation"] == g]
        print(f"{g}: mean {sum(v) / len(v):.3f} mm over {len(v)} runs")
    if a.out:
        _write(a.out, rows)


if __name__ == "__main__":
    main()
