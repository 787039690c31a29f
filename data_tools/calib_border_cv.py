"""Training variants cross-validated over a set's training presses, by distance to the border (issue #21).

    python data_tools/calib_border_cv.py SET FRESH VARIANT[,VARIANT...] [MIN_COVERAGE [extra]]

``VARIANT`` = an MLP feature set plus TrainOptions overrides, e.g. ``relpoly``, ``relpoly+mlp_ensemble=3``,
``relpoly+train_work_res=1``, ``relpoly+mlp_epochs=24``. The training presses are those ``vtrack calibrate``
trains on (auto circles at placement 1.0, without the held-out presses of the middle placement); 3-fold CV
(interleaved whole presses) scored against those auto circles is what a choice may use. The same variant
trained on every training press is also scored on ``FRESH`` (true circles, evaluation only). ``MIN_COVERAGE``:
the auto labeller's ``min_coverage`` (0.5 default; lower keeps more presses cut by the border); with ``extra``
the presses it adds only ever train (the CV folds and scored presses stay those of 0.5). Prints per variant: CV
and fresh [median |radius error| %, median normal error deg, presses] overall and by the press centre's
distance to the nearest border in contact radii (< 1: the disc crosses it).
"""

from __future__ import annotations

import json
import sys
import time


def bins(ps, presses, rows) -> dict:
    """Medians [|radius error| %, normal error deg, n] overall and per border-distance bin."""
    import numpy as np

    H, W = ps.shape
    c = [p.center_xy_px for p in presses]
    d = np.array([min(x, W - x, y, H - y) for x, y in c]) / np.array([p.contact_radius_px for p in presses])
    n = np.array([r["normal_err_deg_median"] for r in rows])
    rad = np.abs([r["radius_err_pct"] for r in rows])
    out = {"all": (round(float(np.median(rad)), 2), round(float(np.median(n)), 2), len(n))}
    for lo, hi in ((0, 1), (1, 1.5), (1.5, 99)):
        m = (d >= lo) & (d < hi)
        if m.any():
            out[f"{lo}-{hi}"] = (round(float(np.median(rad[m])), 2), round(float(np.median(n[m])), 2), int(m.sum()))
    return out


def main() -> None:
    from dataclasses import fields

    from vtrack.tactile.autolabel import AutoLabelOptions
    from vtrack.tactile.calibration import TrainOptions, calibrate
    from vtrack.tactile.evaluation import evaluate_calibration
    from vtrack.tactile.pressset import load_press_set
    from vtrack.threads import limit_threads

    if len(sys.argv) < 4:
        raise SystemExit(__doc__)
    limit_threads(1)
    root, fresh, variants = sys.argv[1], sys.argv[2], sys.argv[3].split(",")
    mincov = float(sys.argv[4]) if len(sys.argv) > 4 else 0.5
    extra_only = len(sys.argv) > 5 and sys.argv[5] == "extra"
    types = {f.name: type(f.default) for f in fields(TrainOptions)}
    mid = load_press_set(root, labels="auto", autolabel_opts=AutoLabelOptions(edge_weight=0.75))
    test_files = {p.file for p in mid.split("every:4:3")[1]}
    base = load_press_set(root, labels="auto", autolabel_opts=AutoLabelOptions(edge_weight=1.0))
    ps = load_press_set(root, labels="auto", autolabel_opts=AutoLabelOptions(edge_weight=1.0, min_coverage=mincov))
    train = [p for p in ps.presses if p.file not in test_files]
    extra = []
    if extra_only:
        keep = {p.file for p in base.presses}
        extra = [p for p in train if p.file not in keep]
        train = [p for p in train if p.file in keep]
    ref = load_press_set(fresh, labels="hand")
    for v in variants:
        feat, *over = v.split("+")
        kw = {k: types[k](int(x) if types[k] is bool else x) for k, x in (o.split("=") for o in over)}
        opts = TrainOptions(mlp_features=feat, **kw)
        t0 = time.time()
        rows, order = [], []
        for f in range(3):
            fold = train[f::3]
            calib = calibrate(ps, "mlp", [p for i, p in enumerate(train) if i % 3 != f] + extra, opts)
            rows += evaluate_calibration(ps, calib, fold)["presses"]
            order += fold
        calib = calibrate(ps, "mlp", train + extra, opts)
        res = {
            "cv": bins(ps, order, rows),
            "fresh": bins(ref, ref.presses, evaluate_calibration(ref, calib, ref.presses)["presses"]),
            "s": round(time.time() - t0),
        }
        tag = f"mincov {mincov}" + (" (extra presses train only)" if extra_only else "")
        print(root.rstrip("/").split("/")[-1], v, tag, "scored", len(train), "extra", len(extra), json.dumps(res))


if __name__ == "__main__":
    main()
