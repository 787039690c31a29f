"""Fresh-press errors of a calibration by distance of the press to the image border (issue #21, DIGIT unit 7).

    python data_tools/calib_border_eval.py OUT.json NAME:SET:FRESH[:MODEL[:PLACEMENT]] ...

For each ``SET`` (unlabelled ball presses) the model ``MODEL`` (an ``AUTO_CANDIDATES`` name, default
``mlp-relpoly``) is trained on every press's auto circles at edge placement ``PLACEMENT`` (default 1.0), as
``vtrack calibrate --refit-all`` writes it once those were chosen, and scored on ``FRESH`` (presses of the same
simulated unit with their true circles in labels.csv) split by the distance from the press centre to the nearest
image border in contact radii (< 1.0: the contact disc crosses the border; 1.0-1.5; > 1.5). Evaluation tool:
the true circles are read only to score. Medians of |radius error| (%) and normal error (deg) per bin.
"""

from __future__ import annotations

import json
import sys


def border_bins(root: str, fresh: str, model: str = "mlp-relpoly", placement: float = 1.0) -> dict:
    """``{"all" | "border LO-HI r": [radius_abs_pct_median, normal_deg_median, n_presses]}`` for one set."""
    import numpy as np

    from vtrack.tactile.autolabel import AutoLabelOptions
    from vtrack.tactile.calibrate_set import AUTO_CANDIDATES, _with
    from vtrack.tactile.calibration import calibrate
    from vtrack.tactile.evaluation import evaluate_calibration
    from vtrack.tactile.pressset import load_press_set

    _, method, over = next(c for c in AUTO_CANDIDATES if c[0] == model)
    ps = load_press_set(root, labels="auto", autolabel_opts=AutoLabelOptions(edge_weight=placement))
    calib = calibrate(ps, method, ps.presses, _with(None, over))
    ref = load_press_set(fresh, labels="hand")
    rows = evaluate_calibration(ref, calib, ref.presses)["presses"]
    H, W = ref.shape
    d = np.array(
        [min(p.center_xy_px[0], W - p.center_xy_px[0], p.center_xy_px[1], H - p.center_xy_px[1]) for p in ref.presses]
    ) / np.array([p.contact_radius_px for p in ref.presses])
    n = np.array([r["normal_err_deg_median"] for r in rows])
    rad = np.abs([r["radius_err_pct"] for r in rows])
    out = {"all": [float(np.median(rad)), float(np.median(n)), len(n)]}
    for lo, hi in ((0.0, 1.0), (1.0, 1.5), (1.5, 99.0)):
        m = (d >= lo) & (d < hi)
        if m.any():
            out[f"border {lo:g}-{hi:g} r"] = [float(np.median(rad[m])), float(np.median(n[m])), int(m.sum())]
    return out


def main() -> None:
    if len(sys.argv) < 3:
        raise SystemExit(__doc__)
    from vtrack.threads import limit_threads

    limit_threads(1)
    res = {}
    for spec in sys.argv[2:]:
        name, root, fresh, *rest = spec.split(":")
        res[name] = border_bins(root, fresh, *(rest[:1] or ["mlp-relpoly"]), *(float(x) for x in rest[1:2]))
        print(name, json.dumps(res[name]), flush=True)
    from vtrack.io.jsonio import write_json

    write_json(sys.argv[1], res)


if __name__ == "__main__":
    main()
