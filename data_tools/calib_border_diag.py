"""Where the normal error of fresh presses comes from, by distance to the image border (issue #21, unit 7).

    python data_tools/calib_border_diag.py SET FRESH [MODEL] [OUT.json]

Trains ``MODEL`` (an ``AUTO_CANDIDATES`` name, default ``mlp-relpoly``) on the auto circles (placement 1.0) of the
training presses of ``SET`` (hold-out ``every:4:3``), and for every press of ``FRESH`` (true circles in labels.csv,
read only to score) reports the per-press median normal error of: ``pipe_n`` the pipeline's height map (as the
benchmark scores it), ``direct_n`` the model's per-pixel normals before integration, ``full_n`` the model's
slopes integrated at full resolution, ``truthint_n`` the TRUE slopes integrated by the same Poisson solver and
scored the same way (integration + scoring error alone); ``*_r`` the radius errors. Medians per bin of the press
centre's distance to the nearest border in contact radii. Evaluation tool.
"""

from __future__ import annotations

import json
import sys


def _angle_median(gx, gy, gxt, gyt, sel) -> float:
    import numpy as np

    from vtrack.tactile.evaluation import angle_deg

    a = np.column_stack([gx[sel], gy[sel], np.ones(sel.sum())])
    b = np.column_stack([gxt[sel], gyt[sel], np.ones(sel.sum())])
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    b /= np.linalg.norm(b, axis=1, keepdims=True)
    return float(np.median(angle_deg(a, b)))


def main() -> None:
    import numpy as np

    from vtrack.tactile.autolabel import AutoLabelOptions
    from vtrack.tactile.calibrate_set import AUTO_CANDIDATES, _with
    from vtrack.tactile.calibration import calibrate, normals_to_slopes
    from vtrack.tactile.evaluation import evaluate_press
    from vtrack.tactile.pipeline import TactilePipeline
    from vtrack.tactile.poisson import poisson_dct
    from vtrack.tactile.pressset import load_press_set, sphere_truth
    from vtrack.threads import limit_threads

    if len(sys.argv) < 3:
        raise SystemExit(__doc__)
    limit_threads(1)
    root, fresh = sys.argv[1], sys.argv[2]
    model = sys.argv[3] if len(sys.argv) > 3 else "mlp-relpoly"
    _, method, over = next(c for c in AUTO_CANDIDATES if c[0] == model)
    ps = load_press_set(root, labels="auto", autolabel_opts=AutoLabelOptions(edge_weight=1.0))
    train, _ = ps.split("every:4:3")
    calib = calibrate(ps, method, train, _with(None, over))
    ref = load_press_set(fresh, labels="hand")
    pipe = TactilePipeline(calib)
    H, W = ref.shape
    mm = ref.mm_per_px
    rows = []
    for p in ref.presses:
        img = ref.image(p)
        m = evaluate_press(pipe.height(img), p, ref.ball_radius_mm, mm)
        _, gxt, gyt, inside = sphere_truth(p, (H, W), ref.ball_radius_px)
        gx, gy = normals_to_slopes(*calib.normals(img))
        mt = evaluate_press(poisson_dct(gxt * mm, gyt * mm), p, ref.ball_radius_mm, mm)
        mf = evaluate_press(poisson_dct(gx * mm, gy * mm), p, ref.ball_radius_mm, mm)
        cx, cy = p.center_xy_px
        rows.append(
            {
                "file": p.file,
                "d": min(cx, W - cx, cy, H - cy) / p.contact_radius_px,
                "pipe_n": m["normal_err_deg_median"],
                "pipe_r": m["radius_err_pct"],
                "direct_n": _angle_median(gx, gy, gxt, gyt, inside),
                "full_n": mf["normal_err_deg_median"],
                "full_r": mf["radius_err_pct"],
                "truthint_n": mt["normal_err_deg_median"],
                "truthint_r": mt["radius_err_pct"],
            }
        )
    d = np.array([r["d"] for r in rows])
    keys = ("pipe_n", "pipe_r", "direct_n", "full_n", "full_r", "truthint_n", "truthint_r")
    out = {"rows": rows}
    for lo, hi in ((0, 1), (1, 1.5), (1.5, 99), (0, 99)):
        sel = [r for r, x in zip(rows, d, strict=True) if lo <= x < hi]
        out[f"{lo}-{hi} r"] = {k: round(float(np.median(np.abs([r[k] for r in sel]))), 2) for k in keys}
        out[f"{lo}-{hi} r"]["n"] = len(sel)
        print(f"{lo}-{hi} r", json.dumps(out[f"{lo}-{hi} r"]), flush=True)
    if len(sys.argv) > 4:
        from vtrack.io.jsonio import write_json

        write_json(sys.argv[4], out)


if __name__ == "__main__":
    main()
