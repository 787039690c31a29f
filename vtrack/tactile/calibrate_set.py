"""Calibrate a press set end to end: labels (hand or automatic), training, held-out check, plausibility gate.

This is what ``vtrack calibrate`` runs. With hand labels (``labels.csv``) it trains on the non-held-out
presses and evaluates the held-out ones. Without them the contact circles are detected automatically
(:mod:`vtrack.tactile.autolabel`); where on the rim profile the edge is put (``edge_weight``) depends on the
sensor's optics (a soft real gel blurs the rim more than a sharp one), so it is chosen per press set by the
physical consistency of the held-out reconstructions: the sphere fitted to each reconstructed press must
have the radius of the ball the user pressed (``ball_radius_mm``), which no label choice can fake. Every
placement is scored on the SAME held-out presses and contact discs (those of the middle placement): scored
on its own circles, a placement that draws them too small hid its poorly reconstructed rim from its own
score (simulated GelSight Mini: 0.5 chosen, 13.3 % against the true circles, where 1.0 gives 4.8 %).

``method="auto"`` then chooses the model (:data:`AUTO_CANDIDATES`: MLP of three widths, MLP on the colour
change relative to the background, MLP on the colour change times position monomials, colour LUT,
photometric stereo) by k-fold cross-validation over the
training presses (folds of whole presses, never of pixels) and reports the cross-validated errors as what to
expect on new presses of this sensor.

A calibration whose held-out normal error is implausible (> ``max_normal_err_deg``, 15 deg by default: a
flat-gel guess scores about 25-40 deg on ball presses) is refused with the numbers instead of written.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import partial
from typing import Any

from vtrack.errors import InputError

#: Edge placements tried on automatically labelled sets (0 = ring peak, 1 = steepest fall; see autolabel).
EDGE_WEIGHTS = (0.5, 0.75, 1.0)
#: Held-out median normal error above which a calibration is not written (deg).
MAX_NORMAL_ERR_DEG = 15.0
#: Models ``method="auto"`` chooses among by cross-validation on the training presses: (name, method,
#: TrainOptions fields it overrides). The narrower MLPs are its capacity regularisation (fewer presses or
#: another sensor's optics may favour a smaller net); ``mlp-rel`` normalises the colour change against the
#: sensor's own background, ``mlp-relpoly`` multiplies it by quadratic monomials of the position instead of
#: giving the position as free inputs (see ``TrainOptions.mlp_features``).
AUTO_CANDIDATES: tuple[tuple[str, str, dict[str, Any]], ...] = (
    ("mlp", "mlp", {}),
    ("mlp-h32", "mlp", {"mlp_hidden": 32}),
    ("mlp-h16", "mlp", {"mlp_hidden": 16}),
    ("mlp-rel", "mlp", {"mlp_features": "rel"}),
    ("mlp-relpoly", "mlp", {"mlp_features": "relpoly"}),
    ("lut", "lut", {}),
    ("ps", "ps", {}),
)
#: The method names of :data:`AUTO_CANDIDATES` (kept for callers of the first version).
AUTO_METHODS = ("mlp", "lut", "ps")
#: Folds of that cross-validation (each fold's presses are predicted by a model trained on the others).
CV_FOLDS = 3


@dataclass
class CalibrationRun:
    """Outcome of :func:`calibrate_press_set`."""

    calib: Any  # vtrack.tactile.calibration.Calibration
    press_set: Any  # vtrack.tactile.pressset.PressSet (the one trained on)
    train: list
    test: list
    held_out: dict[str, float] | None  # evaluate_presses summary on the held-out presses (None: no hold-out)
    edge_trials: list[dict[str, Any]] = field(default_factory=list)  # auto labels: one row per edge weight
    cv: list[dict[str, Any]] = field(default_factory=list)  # method="auto": one cross-validation row per method

    @property
    def plausible(self) -> bool:
        """Held-out and (``method="auto"``) cross-validated median normal errors within MAX_NORMAL_ERR_DEG
        (the cross-validated one also gates a run without hold-out)."""
        errs = [] if self.held_out is None else [self.held_out["normal_err_deg_median"]]
        errs += [r["normal_err_deg_median"] for r in self.cv if r.get("chosen")]
        return all(e <= MAX_NORMAL_ERR_DEG for e in errs)


#: Training resolutions ``calibrate_press_set(train_res=...)`` knows: ``cv`` = chosen by cross-validation for the
#: chosen model (``method="auto"``), ``full`` = the full-resolution presses, ``work`` = the presses at the tactile
#: pipeline's working resolution (``TrainOptions.train_work_res``).
TRAIN_RES = ("cv", "full", "work")


def _with(opts, overrides: dict[str, Any]):
    """``opts`` (default TrainOptions) with ``overrides`` applied."""
    from dataclasses import replace

    from vtrack.tactile.calibration import TrainOptions

    return replace(opts or TrainOptions(), **overrides)


def _pick(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """The row with the lowest cross-validated median normal error; a tie (within 0.25 deg) goes to the smaller
    radius error (normals are what a calibration learns; the radius follows from integrating them)."""
    best_n = min(r["normal_err_deg_median"] for r in rows)
    return min(
        (r for r in rows if r["normal_err_deg_median"] <= best_n + 0.25), key=lambda r: r["radius_abs_err_pct_median"]
    )


def cross_validate(
    ps,
    method: str,
    presses: list,
    opts=None,
    *,
    folds: int = CV_FOLDS,
    downsample: int | str = "auto",
    name: str | None = None,
) -> dict[str, Any]:
    """K-fold cross-validation of ``method`` over ``presses`` (interleaved folds of whole presses: press i is
    in fold i % k; pixels of one press never sit on both sides).

    Every press is predicted once by a model trained on the other folds; the per-press errors are pooled
    (medians over all presses, not means of fold medians, so a small fold does not weigh more). Returns the
    row ``{"model", "method", "folds", "n_presses", "radius_abs_err_pct_median", "normal_err_deg_median",
    "train_seconds"}`` - the errors a user can expect from this model on new presses of this sensor.
    """
    import numpy as np

    from vtrack.tactile.calibration import calibrate
    from vtrack.tactile.evaluation import evaluate_calibration

    k = min(folds, len(presses))
    if k < 2:
        raise InputError("too few presses to cross-validate", field="presses", expected=">= 2", got=len(presses))
    rows, secs = [], 0.0
    for f in range(k):
        test = presses[f::k]
        train = [p for i, p in enumerate(presses) if i % k != f]
        calib = calibrate(ps, method, train, opts)
        secs += calib.info["train_seconds"]
        rows += evaluate_calibration(ps, calib, test, downsample=downsample)["presses"]
    return {
        "model": name or method,
        "method": method,
        "folds": k,
        "n_presses": len(rows),
        "radius_abs_err_pct_median": float(np.median([abs(r["radius_err_pct"]) for r in rows])),
        "normal_err_deg_median": float(np.median([r["normal_err_deg_median"] for r in rows])),
        "train_seconds": secs / k,
    }


def choose_model(
    ps,
    presses: list,
    opts=None,
    *,
    candidates: tuple[tuple[str, str, dict[str, Any]], ...] = AUTO_CANDIDATES,
    folds: int = CV_FOLDS,
    downsample: int | str = "auto",
) -> tuple[str, str, Any, list[dict[str, Any]]]:
    """The candidate with the lowest cross-validated median normal error on ``presses`` (the training
    presses: the held-out ones stay unseen, so their errors remain an honest check of the choice).

    Returns ``(name, method, train_options, rows)``; ``rows`` are the cross-validation rows (``chosen`` marks
    the winner). Normals are what a calibration learns; the fitted radius follows from integrating them, so
    a tie (within 0.25 deg) goes to the smaller radius error. ``opts``: the user's options, which each
    candidate's overrides replace field by field.
    """
    if not candidates:
        raise InputError("no candidate model to choose from", field="candidates", expected="at least one")
    rows = [
        cross_validate(ps, method, presses, _with(opts, over), folds=folds, downsample=downsample, name=name)
        for name, method, over in candidates
    ]
    best = _pick(rows)
    for r in rows:
        r["chosen"] = r is best
    name, method, over = next(c for c in candidates if c[0] == best["model"])
    return name, method, _with(opts, over), rows


def choose_train_res(
    ps,
    presses: list,
    name: str,
    method: str,
    opts,
    rows: list[dict[str, Any]],
    *,
    folds: int = CV_FOLDS,
    downsample: int | str = "auto",
) -> tuple[str, Any]:
    """The training resolution of the model :func:`choose_model` chose (``name``, ``method``, ``opts``; ``rows``
    its cross-validation rows): the same model trained on the presses at the other resolution
    (``TrainOptions.train_work_res`` flipped) is cross-validated on the same folds and kept when it wins by the
    same rule (:func:`_pick`). Its row is appended to ``rows`` (``chosen`` moved to it when it wins). Returns
    ``(name, opts)`` of the winner (``name + "+work-res"`` / ``"+full-res"`` when the other resolution won).

    Why (docs/benchmarks/calib_border.md): the pipeline applies the model to its working image (a 320x240 DIGIT
    frame at half resolution: 2 x 2 area averages, half the camera noise); a net trained on full-resolution
    pixels has learnt to shrink its slopes for noise that image no longer has, most near the border where the
    LEDs' fall-off and the vignetting leave the least signal. On the 640x480 real GelSight set (working image a
    quarter of the size) the full-resolution training is better, so it is chosen per sensor."""
    alt = _with(opts, {"train_work_res": not opts.train_work_res})
    tag = "work-res" if alt.train_work_res else "full-res"
    row = cross_validate(ps, method, presses, alt, folds=folds, downsample=downsample, name=f"{name}+{tag}")
    best = next(r for r in rows if r.get("chosen"))
    won = _pick([best, row]) is row
    row["chosen"] = won
    best["chosen"] = not won
    rows.append(row)
    return (row["model"], alt) if won else (name, opts)


def choose_method(
    ps,
    presses: list,
    opts=None,
    *,
    methods: tuple[str, ...] = AUTO_METHODS,
    folds: int = CV_FOLDS,
    downsample: int | str = "auto",
) -> tuple[str, list[dict[str, Any]]]:
    """:func:`choose_model` among plain ``methods`` (default options each): ``(method, rows)``."""
    _, method, _, rows = choose_model(
        ps, presses, opts, candidates=tuple((m, m, {}) for m in methods), folds=folds, downsample=downsample
    )
    return method, rows


def calibrate_press_set(
    root,
    *,
    method: str = "mlp",
    holdout: str | None = "every:4:3",
    opts=None,
    labels: str = "hand_or_auto",
    edge_weights: tuple[float, ...] = EDGE_WEIGHTS,
    meta_file=None,
    sensor: str | None = None,
    mm_per_px: float | None = None,
    ball_radius_mm: float | None = None,
    downsample: int | str = "auto",
    candidates: tuple[tuple[str, str, dict[str, Any]], ...] = AUTO_CANDIDATES,
    reselect_edge: bool | str = "cv",
    refit_all: bool = False,
    train_res: str = "cv",
) -> CalibrationRun:
    """Label (hand or auto), train ``method`` on the non-held-out presses and evaluate the held-out ones.

    ``train_res``: resolution of the training pixels (:data:`TRAIN_RES`). ``"cv"`` (default): with
    ``method="auto"`` the chosen model is cross-validated again trained on the presses at the tactile pipeline's
    working resolution (``TrainOptions.train_work_res``) and the better one is kept (:func:`choose_train_res`;
    a fixed ``method`` keeps ``opts`` as given); ``"full"`` / ``"work"`` force one. DIGIT unit 7 (60 fresh
    presses): 3.99 % / 5.02 -> 2.11 % / 4.31 deg; the 640x480 real GelSight set keeps full resolution by CV
    (docs/benchmarks/calib_border.md).

    ``refit_all``: once every choice is made (labels, placement, model) and the held-out presses have checked
    it, train the calibration that is returned again on every usable press, held-out ones included (more
    presses, lower error; the held-out errors then describe the model trained without them, and
    ``calib.info["refit_all"]`` says so). Off by default.

    ``method="auto"``: the model is chosen among ``candidates`` by :func:`choose_model` (cross-validation
    on the training presses only); the rows are :attr:`CalibrationRun.cv`, the winner's name is
    ``calib.info["model"]``. With automatic labels, ``reselect_edge`` then chooses the edge placement again
    with the chosen model (:attr:`CalibrationRun.edge_trials` are that trial's rows, each naming its ``model``):
    - ``"cv"`` (default): by the ball-radius check cross-validated over the training presses
      (:func:`edge_cross_validate`; every placement on the same presses and middle-placement circles; also when
      the chosen model is the default ``mlp``). The chosen placement's cross-validated errors are
      ``calib.info["cv_expected"]``: what to expect on new presses. Over the eight simulated and real sets of
      docs/benchmarks/calib_edge_cv.md it fixes the one the ``mlp`` trial got wrong (100-press DIGIT unit 3,
      radius 6.95 -> 3.46 %) and changes no other result;
    - ``True``: the same choice on the held-out presses (fixed that set too but broke the Taxim-style one,
      1.99 -> 5.94 %: ~10 held-out presses are too few; docs/benchmarks/calib_digit_seeds.md);
    - ``False``: keep the ``mlp`` trial's placement.

    With automatic labels, each of ``edge_weights`` is tried and the one whose held-out reconstructions best
    match the ball radius (median |fitted radius - ball radius| on the middle placement's held-out circles,
    the same presses and discs for every placement) is kept. Raises InputError when the split leaves nothing
    to train on; the plausibility of the result is :attr:`CalibrationRun.plausible`.
    ``downsample``: working-resolution factor of the held-out evaluation (``auto``: the pipeline's default).
    """
    run = _calibrate_press_set(
        root,
        method=method,
        holdout=holdout,
        opts=opts,
        labels=labels,
        edge_weights=edge_weights,
        meta_file=meta_file,
        sensor=sensor,
        mm_per_px=mm_per_px,
        ball_radius_mm=ball_radius_mm,
        downsample=downsample,
        candidates=candidates,
        reselect_edge=reselect_edge,
        train_res=train_res,
    )
    if refit_all and run.test:
        from vtrack.tactile.calibration import TrainOptions, calibrate

        info = run.calib.info
        calib = calibrate(run.press_set, run.calib.method, run.press_set.presses, TrainOptions(**info["options"]))
        keep = ("autolabel_edge_weight", "model", "method_choice", "cv", "cv_expected")
        calib.info.update({k: info[k] for k in keep if k in info})
        calib.info["refit_all"] = True
        calib.info["held_out_model_train_files"] = info["train_files"]
        run.calib = calib
    return run


def _calibrate_press_set(
    root,
    *,
    method,
    holdout,
    opts,
    labels,
    edge_weights,
    meta_file,
    sensor,
    mm_per_px,
    ball_radius_mm,
    downsample,
    candidates,
    reselect_edge,
    train_res="cv",
) -> CalibrationRun:
    """:func:`calibrate_press_set` without the final refit."""
    from vtrack.tactile.calibration import METHODS

    if train_res not in TRAIN_RES:
        raise InputError(
            "unknown training resolution", field="train_res", expected=" | ".join(TRAIN_RES), got=train_res
        )
    opts = _with(opts, {} if train_res == "cv" else {"train_work_res": train_res == "work"})
    if reselect_edge not in (False, True, "cv"):
        raise InputError(
            "unknown edge re-selection", field="reselect_edge", expected="False | True | cv", got=reselect_edge
        )
    if method != "auto" and method not in METHODS:
        raise InputError(
            "unknown calibration method", field="method", expected=" | ".join(METHODS + ("auto",)), got=method
        )
    # one press set, held-out split and label source for every run below; only the model changes
    labelled_run = partial(
        _labelled_run,
        root,
        holdout=holdout,
        labels=labels,
        edge_weights=edge_weights,
        meta_file=meta_file,
        sensor=sensor,
        mm_per_px=mm_per_px,
        ball_radius_mm=ball_radius_mm,
        downsample=downsample,
    )
    run = labelled_run(method="mlp" if method == "auto" else method, opts=opts)
    run.calib.info["model"] = run.calib.method
    if method != "auto":
        return run
    if len(run.train) < 2 * CV_FOLDS:  # too few presses to split: keep the default method, say so
        run.calib.info["method_choice"] = f"default (only {len(run.train)} training presses to cross-validate)"
        return run
    name, chosen, copts, run.cv = choose_model(
        run.press_set, run.train, opts, candidates=candidates, downsample=downsample
    )
    if train_res == "cv":
        name, copts = choose_train_res(run.press_set, run.train, name, chosen, copts, run.cv, downsample=downsample)
    by_cv = reselect_edge == "cv"
    changed = (chosen, copts) != (run.calib.method, _with(opts, {}))
    if (changed or by_cv) and reselect_edge and run.edge_trials:
        cv = run.cv
        run = labelled_run(method=chosen, opts=copts, edge_cv=by_cv)
        run.cv = cv
        for t in run.edge_trials:
            t["model"] = name
            if t.get("chosen") and "cv" in t:  # what to expect on new presses: the chosen placement's CV
                run.calib.info["cv_expected"] = t["cv"]
        if run.test:  # as below: the held-out check on the chosen placement's own circles
            from vtrack.tactile.evaluation import evaluate_calibration

            run.held_out = evaluate_calibration(run.press_set, run.calib, run.test, downsample=downsample)["summary"]
    elif changed:
        from vtrack.tactile.calibration import calibrate
        from vtrack.tactile.evaluation import evaluate_calibration

        info = {k: v for k, v in run.calib.info.items() if k == "autolabel_edge_weight"}
        run.calib = calibrate(run.press_set, chosen, run.train, copts)
        run.calib.info.update(info)
        if run.test:
            run.held_out = evaluate_calibration(run.press_set, run.calib, run.test, downsample=downsample)["summary"]
    run.calib.info["model"] = name
    run.calib.info["method_choice"] = "cross-validation"
    run.calib.info["cv"] = run.cv
    return run


def edge_cross_validate(
    ref_ps,
    ps_w,
    train: list,
    exclude: set[str],
    method: str,
    opts=None,
    *,
    folds: int = CV_FOLDS,
    downsample: int | str = "auto",
) -> dict[str, Any]:
    """Cross-validated ball-radius check of one edge placement: errors a model trained on ``ps_w``'s circles
    can be expected to make on new presses of this sensor.

    ``train`` are the training presses of ``ref_ps`` (the middle placement's auto circles); press i of it is in
    fold i % k. Each fold is reconstructed by a model trained on ``ps_w``'s circles of every other press
    (except ``exclude``, the held-out files, which stay unseen) and scored on ``ref_ps``'s circles, so every
    placement is judged on the same presses and discs. The radius error is the sphere fitted to each
    reconstruction against the ball the user pressed (no label can fake it); the normal error is against
    that press's circle. Pooled medians over all predicted presses (as :func:`cross_validate`).
    """
    import numpy as np

    from vtrack.tactile.calibration import calibrate
    from vtrack.tactile.evaluation import evaluate_calibration

    k = min(folds, len(train))
    if k < 2:
        raise InputError("too few presses to cross-validate", field="presses", expected=">= 2", got=len(train))
    rows = []
    for f in range(k):
        fold = train[f::k]
        skip = exclude | {p.file for p in fold}
        calib = calibrate(ps_w, method, [p for p in ps_w.presses if p.file not in skip], opts)
        rows += evaluate_calibration(ref_ps, calib, fold, downsample=downsample)["presses"]
    return {
        "folds": k,
        "n_presses": len(rows),
        "radius_abs_err_pct_median": float(np.median([abs(r["radius_err_pct"]) for r in rows])),
        "radius_err_pct_median": float(np.median([r["radius_err_pct"] for r in rows])),
        "normal_err_deg_median": float(np.median([r["normal_err_deg_median"] for r in rows])),
    }


def _labelled_run(
    root,
    *,
    method,
    holdout,
    opts,
    labels,
    edge_weights,
    meta_file,
    sensor,
    mm_per_px,
    ball_radius_mm,
    downsample,
    edge_cv: bool = False,
) -> CalibrationRun:
    """:func:`calibrate_press_set` for one fixed method (edge placement chosen for auto labels; ``edge_cv``:
    by the cross-validated ball-radius check over the training presses instead of the held-out one)."""
    from vtrack.tactile.autolabel import AutoLabelOptions
    from vtrack.tactile.calibration import calibrate
    from vtrack.tactile.evaluation import evaluate_calibration
    from vtrack.tactile.pressset import load_press_set

    opts = _with(opts, {})

    def held_out(ps, calib, test) -> dict[str, float]:
        return evaluate_calibration(ps, calib, test, downsample=downsample)["summary"]

    def load(w: float):
        return load_press_set(
            root,
            meta_file,
            sensor=sensor,
            mm_per_px=mm_per_px,
            ball_radius_mm=ball_radius_mm,
            labels=labels,
            autolabel_opts=AutoLabelOptions(edge_weight=w),
        )

    if not edge_weights:
        raise InputError("no edge placement to try", field="edge_weights", expected="at least one value")
    mid = edge_weights[len(edge_weights) // 2]
    ps = load(mid)  # the hand-labelled set, or the auto-labelled one at the middle placement (reused below)
    train, test = ps.split(holdout)
    if ps.labels_source != "auto":
        calib = calibrate(ps, method, train, opts)
        return CalibrationRun(calib, ps, train, test, held_out(ps, calib, test) if test else None)
    if not test:  # nothing held out: no basis for choosing, keep the middle placement
        calib = calibrate(ps, method, train, opts)
        calib.info["autolabel_edge_weight"] = mid
        return CalibrationRun(calib, ps, train, test, None, [])
    # every placement is trained without the middle placement's held-out presses and scored on exactly those
    # presses and circles: its own (smaller or larger) circles would change what its score looks at
    test_files = {p.file for p in test}
    runs: list[CalibrationRun] = []
    trials = []
    for w in edge_weights:
        ps_w = ps if w == mid else load(w)
        train_w = [p for p in ps_w.presses if p.file not in test_files]
        calib = calibrate(ps_w, method, train_w, opts)
        calib.info["autolabel_edge_weight"] = w
        summ = held_out(ps, calib, test)
        trial = {
            "edge_weight": w,
            "n_presses": len(ps_w.presses),
            "radius_abs_err_pct_median": summ["radius_abs_err_pct_median"],
            "normal_err_deg_median": summ["normal_err_deg_median"],
        }
        if edge_cv:
            trial["cv"] = edge_cross_validate(ps, ps_w, train, test_files, method, opts, downsample=downsample)
        trials.append(trial)
        runs.append(CalibrationRun(calib, ps_w, train_w, test, summ))
    # a placement that drops many presses (e.g. rims put beyond the ball radius) trains on fewer, easier
    # presses: only placements keeping >= 80 % of the best-kept count compete
    n_max = max(len(r.press_set.presses) for r in runs)
    pool = [(r, t) for r, t in zip(runs, trials, strict=True) if len(r.press_set.presses) >= 0.8 * n_max]

    # the ball-radius check: on the held-out presses, or (edge_cv) cross-validated over the training presses
    def radius_check(rt) -> float:
        return (rt[1]["cv"] if edge_cv else rt[0].held_out)["radius_abs_err_pct_median"]

    best = min(pool, key=radius_check)[0]
    for t in trials:
        t["chosen"] = t["edge_weight"] == best.calib.info["autolabel_edge_weight"]
    best.edge_trials = trials
    return best
