"""Measure ``vtrack calibrate``'s model choice (issue #21): the fixed default ``mlp`` vs ``--method auto``.

    python data_tools/calib_choice_eval.py SET auto|hand [--fresh FRESH_SET] [--json OUT.json] [--reselect [cv]]
        [--candidates NAMES] [--no-train-res]

``SET`` is calibrated as ``vtrack calibrate`` does (auto labels: edge placement chosen on common circles;
hold-out ``every:4:3``). Then the models are chosen by cross-validation over the training presses; with
``--reselect`` and auto labels the edge placement is then chosen again with the chosen model (the opt-in
``reselect_edge`` of ``calibrate_press_set``; ``--reselect cv``: by the ball-radius check cross-validated over the
training presses, also when the chosen model is the default, and the chosen placement's cross-validated errors
are reported as ``cv_expected`` beside the held-out ones). As ``vtrack calibrate``, the chosen model's training
resolution (full or the pipeline's working resolution) is then chosen by cross-validation too (``--no-train-res``:
skip that, the earlier default). Both the default ``mlp`` and the chosen model are scored:
- on ``FRESH_SET`` (e.g. 60 more presses of the same simulated unit, rendered with
  ``render_press_set(type, DIR, n=60, seed=S2, model=OpticalModel.for_sensor(type, S1))``), against its true
  circles;
- or, without ``--fresh``, on the held-out presses of ``SET`` against its hand labels (``labels.csv``).

This is an evaluation tool: it reads the labels only to score. Prints one JSON line (and writes it with
``--json``): edge trials, CV rows, chosen model, both scores, seconds.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path


def evaluate(
    root: str | Path,
    labels: str,
    fresh: str | Path | None = None,
    reselect: bool | str = False,
    candidates: tuple[str, ...] | None = None,
    train_res: bool = True,
) -> dict:
    """The comparison for one press set (see the module docstring). ``candidates``: names of
    ``AUTO_CANDIDATES`` to cross-validate (default all)."""
    from vtrack.tactile.calibrate_set import AUTO_CANDIDATES, _labelled_run, choose_model, choose_train_res
    from vtrack.tactile.calibration import calibrate
    from vtrack.tactile.evaluation import evaluate_calibration
    from vtrack.tactile.pressset import load_press_set

    t0 = time.time()
    kw = dict(
        holdout="every:4:3",
        labels=labels,
        edge_weights=(0.5, 0.75, 1.0),
        meta_file=None,
        sensor=None,
        mm_per_px=None,
        ball_radius_mm=None,
        downsample="auto",
    )
    run = _labelled_run(root, method="mlp", opts=None, **kw)
    if fresh:
        ref = load_press_set(fresh, labels="hand")
        presses, where = ref.presses, f"fresh {len(ref.presses)} presses vs true circles"
    else:
        ref = load_press_set(root, labels="hand")
        files = {p.file for p in run.test}
        presses = [p for p in ref.presses if p.file in files]
        where = f"held-out {len(presses)} presses vs hand labels"

    def score(calib) -> dict:
        d = evaluate_calibration(ref, calib, presses)["summary"]
        keys = ("radius_err_pct_median", "radius_abs_err_pct_median", "normal_err_deg_median")
        return {k: round(d[k], 2) for k in keys}

    out: dict = {"set": str(root), "labels": labels, "eval": where, "edge_trials": run.edge_trials}
    out["default_mlp"] = score(run.calib)
    cands = AUTO_CANDIDATES if not candidates else tuple(c for c in AUTO_CANDIDATES if c[0] in candidates)
    name, method, opts, rows = choose_model(run.press_set, run.train, candidates=cands)
    if train_res:  # as calibrate_press_set(train_res="cv"): the chosen model at the other training resolution
        name, opts = choose_train_res(run.press_set, run.train, name, method, opts, rows)
    out["cv"] = rows
    out["chosen"] = name
    if reselect == "cv" and run.edge_trials:  # as calibrate_press_set(reselect_edge="cv")
        rerun = _labelled_run(root, method=method, opts=opts, edge_cv=True, **kw)
        out["edge_trials_chosen_model"] = [{"model": name, **t} for t in rerun.edge_trials]
        chosen_trial = next(t for t in rerun.edge_trials if t["chosen"])
        out["cv_expected"] = chosen_trial["cv"]  # training presses, cross-validated
        out["held_out"] = {
            k: round(rerun.held_out[k], 2) for k in ("radius_abs_err_pct_median", "normal_err_deg_median")
        }
        out["auto"] = score(rerun.calib)
        if fresh:  # the same choices, the model refitted on every usable press (held-out ones too)
            out["auto_refit_all"] = score(calibrate(rerun.press_set, method, rerun.press_set.presses, opts))
    elif name == "mlp" and not opts.train_work_res:
        out["auto"] = out["default_mlp"]
    elif reselect and run.edge_trials:  # as calibrate_press_set(reselect_edge=True)
        rerun = _labelled_run(root, method=method, opts=opts, **kw)
        out["edge_trials_chosen_model"] = rerun.edge_trials
        out["auto"] = score(rerun.calib)
    else:
        out["auto"] = score(calibrate(run.press_set, method, run.train, opts))
    out["reselect_edge"] = reselect
    out["seconds"] = round(time.time() - t0)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("set", type=Path)
    ap.add_argument("labels", choices=("auto", "hand"))
    ap.add_argument("--fresh", type=Path, default=None, help="fresh presses of the same unit (true circles)")
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument(
        "--no-train-res",
        action="store_true",
        help="skip the training-resolution choice (the default before docs/benchmarks/calib_border.md)",
    )
    ap.add_argument(
        "--reselect",
        nargs="?",
        const="heldout",
        default=None,
        choices=("heldout", "cv"),
        help="choose the edge placement again with the chosen model, on the held-out presses or (cv) by "
        "cross-validation over the training presses",
    )
    ap.add_argument(
        "--candidates",
        default=None,
        help="comma-separated model names to cross-validate (default: all of AUTO_CANDIDATES; fewer to "
        "re-measure a set faster where the others are known to lose by > 0.25 deg)",
    )
    a = ap.parse_args()
    from vtrack.threads import limit_threads

    limit_threads(1)
    cands = tuple(a.candidates.split(",")) if a.candidates else None
    res = evaluate(
        a.set,
        a.labels,
        a.fresh,
        reselect={None: False, "heldout": True}.get(a.reselect, a.reselect),
        candidates=cands,
        train_res=not a.no_train_res,
    )
    res["candidates"] = list(cands) if cands else "all"
    print(json.dumps(res))
    if a.json:
        from vtrack.io.jsonio import write_json

        write_json(a.json, res)


if __name__ == "__main__":
    main()
