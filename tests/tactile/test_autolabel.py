"""Automatic contact labels and calibration without hand labels (issue #21), with the bad-input gates."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from vtrack.errors import InputError
from vtrack.tactile.autolabel import auto_label, detect_contact, review_sheet, write_auto_labels
from vtrack.tactile.pressset import load_press_set


def _unlabelled_copy(src: Path, dst: Path) -> Path:
    """The shared GelSight presses as a user would hand them in: images + background + meta, no labels."""
    dst.mkdir(parents=True)
    for p in src.glob("*.png"):
        shutil.copy(p, dst / p.name)
    (dst / "meta.json").write_text(json.dumps({"sensor": "gelsight", "mm_per_px": 0.0295, "ball_radius_mm": 2.0}))
    return dst


def _sim_press(shape=(240, 320), centres=((160.0, 120.0),), a_mm=1.2, R=2.0, mpp=0.0634, seed=0):
    """A press image of the independent optical model with known contact circles (px)."""
    from vtrack.sim.presses import ball_height, press_depth_mm
    from vtrack.sim.tactile_optics import OpticalModel

    model = OpticalModel.for_sensor("gelsight_mini", seed)
    rng = np.random.default_rng(seed)
    bg = np.full(shape + (3,), 0, np.uint8)
    bg[:] = (150, 140, 130)
    bg = (bg.astype(np.float32) + np.linspace(-20, 20, shape[1])[None, :, None]).astype(np.uint8)
    d = press_depth_mm(R, a_mm)
    h = np.zeros(shape, np.float32)
    for c in centres:
        h = np.maximum(h, ball_height(shape, c, R, d, mpp))
    img = model.render(h, mpp, bg, rng, 1.0)
    back = model.render(np.zeros(shape, np.float32), mpp, bg, rng, 1.0)
    return img, back, a_mm / mpp, R / mpp


def test_detects_simulated_press_circle():
    img, bg, a_px, R_px = _sim_press()
    d = detect_contact(img, bg, R_px, "p.png")
    assert d.ok, d.reason
    assert np.hypot(d.center_x_px - 160.0, d.center_y_px - 120.0) < 1.0
    assert abs(d.contact_radius_px / a_px - 1.0) < 0.08, (d.contact_radius_px, a_px)


def test_partial_press_at_the_border_kept_and_mostly_outside_dropped():
    img, bg, a_px, R_px = _sim_press(centres=((320 - 8.0, 120.0),))  # ~60 % of the circle in view
    d = detect_contact(img, bg, R_px)
    assert d.ok, d.reason
    assert abs(d.center_x_px - 312.0) < 2.5 and abs(d.contact_radius_px / a_px - 1.0) < 0.12
    img, bg, a_px, R_px = _sim_press(centres=((320 + 0.6 * 19, 120.0),))  # under a third in view
    d = detect_contact(img, bg, R_px)
    assert not d.ok and ("circle" in d.reason or "contact" in d.reason)


def test_two_contacts_no_contact_blank_saturated_and_too_large_are_dropped():
    img, bg, _, R_px = _sim_press(centres=((90.0, 120.0), (230.0, 120.0)))
    assert "more than one contact" in detect_contact(img, bg, R_px).reason
    _, bg, _, R_px = _sim_press()
    _, noisy_bg, _, _ = _sim_press(a_mm=0.01, seed=3)  # another no-contact frame: camera noise only
    assert detect_contact(noisy_bg, bg, R_px).reason.startswith("no contact")
    assert detect_contact(np.zeros_like(bg), bg, R_px).reason.startswith("blank")
    sat = bg.copy()
    sat[:60] = 255
    assert detect_contact(sat, bg, R_px).reason.startswith("saturated")
    img, bg, a_px, _ = _sim_press(a_mm=1.6)
    # the same press with a ball said to be much smaller than its contact: wrong meta, not a press of that ball
    assert "larger than the ball" in detect_contact(img, bg, 0.6 * a_px).reason


def test_one_press_split_into_two_lobes_is_one_contact():
    """A DIGIT press near the border: its lit and shadowed sides are two separate blobs at 0.3 of the peak
    change (areas 1431 and 783 px). They were called "more than one contact", which dropped 3 of 40 presses of
    a simulated DIGIT set; they are one contact, found within 1 px, while two presses 7 radii apart stay
    refused (test above)."""
    import cv2

    from vtrack.sim.presses import ball_height, press_depth_mm
    from vtrack.sim.tactile_optics import OpticalModel
    from vtrack.tactile.autolabel import change_magnitude
    from vtrack.tactile.sensors import default_background

    model, s, R = OpticalModel.for_sensor("digit", 3), 0.09, 3.0
    bg = default_background("digit", 240, 320)
    rng = np.random.default_rng(0)
    back = model.render(np.zeros((320, 240), np.float32), s, bg, rng)
    c, a = (31.0, 266.26), 27.0
    img = model.render(ball_height((320, 240), c, R, press_depth_mm(R, a * s), s), s, bg, rng)
    mag, _ = change_magnitude(img, back, R / s / 60.0)
    n, _, st, _ = cv2.connectedComponentsWithStats((mag > 0.3 * np.percentile(mag, 99.9)).astype(np.uint8))
    big = sorted(st[1:, cv2.CC_STAT_AREA])[::-1]
    assert len(big) >= 2 and big[1] > 0.35 * big[0]  # the precondition: two large lobes
    d = detect_contact(img, back, R / s)
    assert d.ok, d.reason
    assert np.hypot(d.center_x_px - c[0], d.center_y_px - c[1]) < 1.5 and abs(d.contact_radius_px / a - 1) < 0.05


def test_auto_labels_agree_with_hand_labels_on_shared_gelsight(shared_data):
    """Measured: 48/48 used; centre median 2.0 px (hand labels are integers); radius median +5 %."""
    ps = load_press_set(shared_data / "gelsight_ball_presses", labels="hand")
    dets = {d.file: d for d in auto_label(ps.root, ps.ball_radius_px)}
    assert all(d.ok for d in dets.values()), [d.reason for d in dets.values() if not d.ok]
    c = np.array(
        [
            np.hypot(dets[p.file].center_x_px - p.center_xy_px[0], dets[p.file].center_y_px - p.center_xy_px[1])
            for p in ps.presses
        ]
    )
    r = np.array([dets[p.file].contact_radius_px / p.contact_radius_px - 1.0 for p in ps.presses])
    assert np.median(c) < 2.5 and np.percentile(c, 90) < 5.0, np.percentile(c, [50, 90])
    assert abs(np.median(r)) < 0.07 and np.percentile(np.abs(r), 90) < 0.10, np.percentile(r, [10, 50, 90])


@pytest.mark.slow
def test_calibration_from_auto_labels_meets_hand_label_accuracy(shared_data, tmp_path):
    """Calibrate the shared set WITHOUT labels.csv, evaluate the held-out presses against the HAND labels.

    Measured: edge placement 0.75 chosen; 1.72 % radius / 3.43 deg (hand labels: 0.72 % / 3.19 deg);
    issue #21 target <= 3 % / <= 4 deg.
    """
    from vtrack.tactile.calibrate_set import calibrate_press_set
    from vtrack.tactile.evaluation import evaluate_presses
    from vtrack.tactile.pipeline import TactilePipeline

    root = _unlabelled_copy(shared_data / "gelsight_ball_presses", tmp_path / "mine")
    run = calibrate_press_set(root)
    assert run.press_set.labels_source == "auto" and len(run.press_set.presses) == 48
    assert len(run.edge_trials) == 3 and sum(t["chosen"] for t in run.edge_trials) == 1
    hand = load_press_set(shared_data / "gelsight_ball_presses", labels="hand")
    test = [p for p in hand.presses if p.file in {q.file for q in run.test}]
    assert len(test) == 12
    s = evaluate_presses(hand, test, TactilePipeline(run.calib).height)["summary"]
    assert s["radius_abs_err_pct_median"] <= 3.0 and s["normal_err_deg_median"] <= 4.0, s
    assert run.plausible


def test_auto_label_files_and_review_sheet(shared_data, tmp_path):
    import cv2

    root = _unlabelled_copy(shared_data / "gelsight_ball_presses", tmp_path / "mine")
    for i in range(3):  # a few bad presses among good ones are dropped with their reason, not fatal
        cv2.imwrite(str(root / f"press_{i:02d}.png"), np.zeros((480, 640, 3), np.uint8))
    ps = load_press_set(root)
    assert ps.labels_source == "auto" and len(ps.presses) == 45
    csv_path = write_auto_labels(tmp_path / "out" / "labels.auto.csv", ps.detections)
    lines = csv_path.read_text().splitlines()
    assert lines[0].startswith("file,center_x_px,center_y_px,contact_radius_px") and len(lines) == 49
    assert sum(",0,blank" in ln for ln in lines) == 3
    sheet = review_sheet(root, ps.detections, tmp_path / "sheet.png", tile_px=100, cols=8)
    img = cv2.imread(str(sheet))
    assert img.shape[1] == 800 and img.shape[0] == 6 * (75 + 16)
    red = (img[..., 2] > 200) & (img[..., 1] < 50) & (img[..., 0] < 50)
    green = (img[..., 1] > 150) & (img[..., 2] < 50) & (img[..., 0] < 50)
    assert red.sum() > 20 and green.sum() > 500


def test_too_few_usable_presses_names_the_reasons(shared_data, tmp_path):
    import cv2

    root = _unlabelled_copy(shared_data / "gelsight_ball_presses", tmp_path / "mine")
    bg = cv2.imread(str(root / "background.png"))
    for i, p in enumerate(sorted(root.glob("press_*.png"))):
        if i >= 4:
            cv2.imwrite(str(p), bg)  # no contact
    with pytest.raises(InputError, match=r"only 4 usable presses of 48 \(dropped: 44 x no contact"):
        load_press_set(root)
    with pytest.raises(InputError, match="labels"):
        load_press_set(root, labels="nonsense")
    with pytest.raises(InputError, match="labels.csv not found"):
        load_press_set(root, labels="hand")


@pytest.mark.slow
def test_method_auto_chooses_by_cross_validation_on_training_presses_only(shared_data):
    """``method="auto"``: 3-fold CV (whole presses per fold) on the 36 training presses; the 12 held-out
    presses stay untouched and check the choice.

    Measured with the full candidate list and training (shared GelSight, hand labels; docs/tactile.md): CV
    normal error mlp 3.55 deg, mlp-h32 3.65, mlp-h16 4.27, mlp-rel 3.53, lut 5.27, ps 10.23 -> mlp (tie within
    0.25 deg, smaller radius error), held out 0.72 % / 3.19 deg.
    """
    from vtrack.tactile.calibrate_set import AUTO_CANDIDATES, calibrate_press_set, cross_validate
    from vtrack.tactile.calibration import TrainOptions

    # the suite's lighter MLP training and a subset of the candidates (the widths are covered by
    # tests/tactile/test_calibrate_set.py's option test); the full list is measured in docs/tactile.md
    cands = tuple(c for c in AUTO_CANDIDATES if c[0] in ("mlp", "mlp-rel", "lut", "ps"))
    run = calibrate_press_set(
        shared_data / "gelsight_ball_presses",
        method="auto",
        opts=TrainOptions(mlp_epochs=6, inside_per_press=3000, flat_per_press=2000),
        candidates=cands,
    )
    # the four candidates, then the model they chose cross-validated at the other training resolution
    # (`choose_train_res`, `--train-res cv`): the winner of those two carries ``chosen``
    assert [r["model"] for r in run.cv[:4]] == ["mlp", "mlp-rel", "lut", "ps"]
    (first,) = [r["model"] for r in run.cv[:4] if r["model"] == run.cv[4]["model"].split("+")[0]]
    assert len(run.cv) == 5 and run.cv[4]["model"] in (f"{first}+work-res", f"{first}+full-res")
    assert all(r["n_presses"] == 36 and r["folds"] == 3 for r in run.cv)
    best_n = min(r["normal_err_deg_median"] for r in run.cv)
    (chosen,) = [r for r in run.cv if r["chosen"]]
    assert chosen["normal_err_deg_median"] <= best_n + 0.25  # the tie rule: within 0.25 deg, smaller radius error
    assert run.calib.info["model"] == chosen["model"] and run.calib.method == chosen["method"] == "mlp"
    # the chosen model was trained (the relative-colour MLP stores its feature set), not the default
    assert ("mlp_features" in run.calib.params) == chosen["model"].startswith("mlp-rel")
    assert set(run.calib.info["train_files"]) == {p.file for p in run.train}
    assert not set(run.calib.info["train_files"]) & {p.file for p in run.test}
    # the CV estimate predicts the held-out error (same sensor, same labels): within 1.5 deg
    assert abs(chosen["normal_err_deg_median"] - run.held_out["normal_err_deg_median"]) < 1.5, (chosen, run.held_out)
    # photometric stereo's single Lambertian model is clearly worse on this gel: CV must see it
    ps_row = next(r for r in run.cv if r["model"] == "ps")
    assert ps_row["normal_err_deg_median"] > best_n + 2.0
    assert run.plausible
    with pytest.raises(InputError, match="too few presses"):
        cross_validate(run.press_set, "lut", run.train[:1])
    with pytest.raises(InputError, match="unknown calibration method"):
        calibrate_press_set(shared_data / "gelsight_ball_presses", method="best")


def test_subpixel_rim_vertex_and_detection():
    """The sub-pixel rim option: the parabola vertex of sampled rows is recovered exactly (clipped to half a
    sample, 0 at the row ends), and on a simulated press the refined circle stays within 1 px / 8 % of the truth
    and within 0.5 px / 2 % of the sample-grid one."""
    from vtrack.tactile.autolabel import AutoLabelOptions, _parabola_offset

    x = np.arange(10.0)
    v = np.stack([(x - 4.3) ** 2, (x - 6.8) ** 2, (x - 0.2) ** 2, np.zeros(10)])
    off = _parabola_offset(v, np.argmin(v, axis=1))
    assert np.allclose(off, [0.3, -0.2, 0.0, 0.0]), off
    img, bg, a_px, R_px = _sim_press()
    d0 = detect_contact(img, bg, R_px, "p.png")
    d1 = detect_contact(img, bg, R_px, "p.png", AutoLabelOptions(subpixel=True))
    assert d1.ok, d1.reason
    assert np.hypot(d1.center_x_px - 160.0, d1.center_y_px - 120.0) < 1.0
    assert abs(d1.contact_radius_px / a_px - 1.0) < 0.08
    assert np.hypot(d1.center_x_px - d0.center_x_px, d1.center_y_px - d0.center_y_px) < 0.5
    assert abs(d1.contact_radius_px / d0.contact_radius_px - 1.0) < 0.02
