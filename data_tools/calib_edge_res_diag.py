"""Diagnose the edge placement chosen with working-resolution training (issue #21, calib4).

    python data_tools/calib_edge_res_diag.py SET FRESH MODEL OUT.json

For each edge placement 0.75 and 1.0 of ``SET`` (auto labels, hold-out ``every:4:3`` of the middle placement as
``vtrack calibrate``), the ``MODEL`` of ``AUTO_CANDIDATES`` is trained on that placement's training presses at
full and at working resolution, and scored on the fresh presses of the same unit ``FRESH`` twice: against their
true circles (what the benchmark reports) and against their own automatic circles at the middle placement (what
the cross-validated radius check of ``vtrack calibrate`` scores on). Evaluation only: true circles read to score.
"""

from __future__ import annotations

import json
import sys
from dataclasses import replace


def main() -> None:
    root, fresh, model, out = sys.argv[1:5]
    from vtrack.tactile.autolabel import AutoLabelOptions
    from vtrack.tactile.calibrate_set import AUTO_CANDIDATES, _with
    from vtrack.tactile.calibration import calibrate
    from vtrack.tactile.evaluation import evaluate_calibration
    from vtrack.tactile.pressset import load_press_set
    from vtrack.threads import limit_threads

    limit_threads(1)
    _, method, over = next(c for c in AUTO_CANDIDATES if c[0] == model)
    base = _with(None, over)

    def load(path, w):
        return load_press_set(path, labels="auto", autolabel_opts=AutoLabelOptions(edge_weight=w))

    mid = load(root, 0.75)
    _, test = mid.split("every:4:3")
    test_files = {p.file for p in test}
    ref_true = load_press_set(fresh, labels="hand")
    ref_auto = load(fresh, 0.75)
    keys = ("radius_err_pct_median", "radius_abs_err_pct_median", "normal_err_deg_median")
    rows = []
    for w in (0.75, 1.0):
        ps_w = mid if w == 0.75 else load(root, w)
        train = [p for p in ps_w.presses if p.file not in test_files]
        for work in (False, True):
            calib = calibrate(ps_w, method, train, replace(base, train_work_res=work))
            row = {"edge_weight": w, "work_res": work, "n_train": len(train)}
            for tag, ref in (("true", ref_true), ("auto075", ref_auto)):
                s = evaluate_calibration(ref, calib, ref.presses)["summary"]
                row[tag] = {k: round(s[k], 2) for k in keys}
            print(json.dumps(row), flush=True)
            rows.append(row)
    with open(out, "w") as f:
        json.dump({"set": root, "fresh": fresh, "model": model, "rows": rows}, f, indent=1)


if __name__ == "__main__":
    main()
