"""Calibrate a press set end to end: labels (hand or automatic), training, held-out check, plausibility gate.

This is what ``vtrack calibrate`` runs. With hand labels (``labels.csv``) it trains on the non-held-out
presses and evaluates the held-out ones. Without them the contact circles are detected automatically
(:mod:`vtrack.tactile.autolabel`); where on the rim profile the edge is put (``edge_weight``) depends on the
sensor's optics (a soft real gel blurs the rim more than a sharp one), so it is chosen per press set by the
physical consistency of the held-out reconstructions: the sphere fitted to each reconstructed press must
have the radius of the ball the user pressed (``ball_radius_mm``), which no label choice can fake.

A calibration whose held-out normal error is implausible (> ``max_normal_err_deg``, 15 deg by default: a
flat-gel guess scores about 25-40 deg on ball presses) is refused with the numbers instead of written.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from vtrack.errors import InputError

#: Edge placements tried on automatically labelled sets (0 = ring peak, 1 = steepest fall; see autolabel).
EDGE_WEIGHTS = (0.5, 0.75, 1.0)
#: Held-out median normal error above which a calibration is not written (deg).
MAX_NORMAL_ERR_DEG = 15.0


@dataclass
class CalibrationRun:
    """Outcome of :func:`calibrate_press_set`."""

    calib: Any  # vtrack.tactile.calibration.Calibration
    press_set: Any  # vtrack.tactile.pressset.PressSet (the one trained on)
    train: list
    test: list
    held_out: dict[str, float] | None  # evaluate_presses summary on the held-out presses (None: no hold-out)
    edge_trials: list[dict[str, Any]] = field(default_factory=list)  # auto labels: one row per edge weight

    @property
    def plausible(self) -> bool:
        return self.held_out is None or self.held_out["normal_err_deg_median"] <= MAX_NORMAL_ERR_DEG


def calibrate_press_set(root, *, method: str = "mlp", holdout: str | None = "every:4:3", opts=None,
                        labels: str = "hand_or_auto", edge_weights: tuple[float, ...] = EDGE_WEIGHTS,
                        meta_file=None, sensor: str | None = None, mm_per_px: float | None = None,
                        ball_radius_mm: float | None = None, downsample: int | str = "auto") -> CalibrationRun:
    """Label (hand or auto), train ``method`` on the non-held-out presses and evaluate the held-out ones.

    With automatic labels, each of ``edge_weights`` is tried and the one whose held-out reconstructions best
    match the ball radius (median |fitted radius - ball radius|) is kept. Raises InputError when the split
    leaves nothing to train on; the plausibility of the result is :attr:`CalibrationRun.plausible`.
    ``downsample``: working-resolution factor of the held-out evaluation (``auto``: the pipeline's default).
    """
    from vtrack.tactile.autolabel import AutoLabelOptions
    from vtrack.tactile.calibration import calibrate
    from vtrack.tactile.evaluation import evaluate_calibration
    from vtrack.tactile.pressset import load_press_set

    def held_out(ps, calib, test) -> dict[str, float]:
        return evaluate_calibration(ps, calib, test, downsample=downsample)["summary"]

    def load(w: float):
        return load_press_set(root, meta_file, sensor=sensor, mm_per_px=mm_per_px, ball_radius_mm=ball_radius_mm,
                              labels=labels, autolabel_opts=AutoLabelOptions(edge_weight=w))

    if not edge_weights:
        raise InputError("no edge placement to try", field="edge_weights", expected="at least one value")
    mid = edge_weights[len(edge_weights) // 2]
    ps = load(mid)  # the hand-labelled set, or the auto-labelled one at the middle placement (reused below)
    if ps.labels_source != "auto":
        train, test = ps.split(holdout)
        calib = calibrate(ps, method, train, opts)
        return CalibrationRun(calib, ps, train, test, held_out(ps, calib, test) if test else None)
    train, test = ps.split(holdout)
    if not test:  # nothing held out: no basis for choosing, keep the middle placement
        calib = calibrate(ps, method, train, opts)
        calib.info["autolabel_edge_weight"] = mid
        return CalibrationRun(calib, ps, train, test, None, [])
    runs: list[CalibrationRun] = []
    trials = []
    for w in edge_weights:
        ps_w = ps if w == mid else load(w)
        train, test = ps_w.split(holdout)
        calib = calibrate(ps_w, method, train, opts)
        calib.info["autolabel_edge_weight"] = w
        summ = held_out(ps_w, calib, test)
        trials.append({"edge_weight": w, "n_presses": len(ps_w.presses),
                       "radius_abs_err_pct_median": summ["radius_abs_err_pct_median"],
                       "normal_err_deg_median": summ["normal_err_deg_median"]})
        runs.append(CalibrationRun(calib, ps_w, train, test, summ))
    # a placement that drops many presses (e.g. rims put beyond the ball radius) is judged on fewer, easier
    # presses: only placements keeping >= 80 % of the best-kept count compete
    n_max = max(len(r.press_set.presses) for r in runs)
    pool = [r for r in runs if len(r.press_set.presses) >= 0.8 * n_max]
    best = min(pool, key=lambda r: r.held_out["radius_abs_err_pct_median"])
    for t in trials:
        t["chosen"] = t["edge_weight"] == best.calib.info["autolabel_edge_weight"]
    best.edge_trials = trials
    return best
