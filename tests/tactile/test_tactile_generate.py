"""Controllable tactile generation (vtrack.tactile.generate, issue #24): shipped weights, control, bad input."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from vtrack.errors import InputError
from vtrack.tactile.generate import data as gd

W, H, MPP = 320, 240, 0.059  # GelSight at half resolution


@pytest.fixture(scope="module")
def scene():
    """A simulated 2 mm ball press (independent optical model) on the shipped GelSight background."""
    from vtrack.sim.presses import ball_height
    from vtrack.sim.tactile_optics import OpticalModel
    from vtrack.tactile.sensors import default_background

    bg = default_background("gelsight", W, H)
    model = OpticalModel.for_sensor("gelsight", seed=7)
    h = ball_height((H, W), (140.0, 110.0), 2.0, 0.8, MPP)
    ref = model.render(h, MPP, bg, np.random.default_rng(0))
    return ref, bg


@pytest.fixture(scope="module")
def gen():
    from vtrack.tactile.generate.generator import TactileGenerator

    return TactileGenerator(threads=1)


def test_shipped_weights_load_and_never_saw_held_out_presses(gen):
    data = gen.meta["data"]
    assert gen.path.stat().st_size < 3_000_000
    assert len(data["real_held_out"]) == 24 and len(data["real_train"]) == 24
    assert not set(data["real_held_out"]) & set(data["real_train"])
    assert {"stage1", "stage2"} <= {r["stage"] for r in gen.meta["log"]}


def test_generate_shapes_finite_and_moves_the_contact(scene, gen):
    ref, bg = scene
    out = gen.generate(ref, bg, ref_depth_mm=0.8, target_depth_mm=0.8, target_pose=gd.Pose(220.0, 150.0))
    assert out.shape == ref.shape and out.dtype == np.uint8
    change = np.abs(out.astype(np.float32) - bg).sum(2)
    # the contact is now around (220, 150) and gone from (140, 110)
    assert change[140:160, 210:230].mean() > 5 * max(change[100:120, 130:150].mean(), 1.0)
    cx, cy = np.average(np.mgrid[0:H, 0:W][::-1].reshape(2, -1), axis=1, weights=change.ravel() ** 2)
    assert abs(cx - 220) < 8 and abs(cy - 150) < 8


def test_depth_control_is_monotone(scene, gen):
    """Deeper target -> stronger colour change in the contact crop (mean |image - background|)."""
    ref, bg = scene
    energy = []
    for d in (0.3, 0.8, 1.3):
        out = gen.generate(ref, bg, ref_depth_mm=0.8, target_depth_mm=d)
        energy.append(float(np.abs(out.astype(np.float32) - bg)[60:160, 90:190].mean()))
    assert energy[0] < energy[1] < energy[2], energy
    assert energy[2] > 1.1 * energy[0]


def test_modes_batch_and_shift_baseline(scene):
    from vtrack.tactile.generate.generator import TactileGenerator

    ref, bg = scene
    shift = TactileGenerator(mode="shift")
    req = shift.prepare(ref, bg, ref_depth_mm=0.8, target_depth_mm=0.8, target_pose=gd.Pose(200.0, 120.0, 30.0))
    assert req.x.shape == (6, gd.CROP_PX, gd.CROP_PX) and np.isfinite(req.x).all()
    a = shift.generate_many([req], bg)[0]
    b = shift.compose(req, bg, np.zeros((gd.CROP_PX, gd.CROP_PX, 3), np.float32))
    assert np.array_equal(a, b)
    for mode in ("stage1", "hybrid"):
        out = TactileGenerator(mode=mode, threads=1).generate_many([req, req], bg)
        assert len(out) == 2 and np.array_equal(out[0], out[1])


def test_bad_inputs(scene, gen):
    ref, bg = scene
    with pytest.raises(InputError, match="no contact"):
        gen.generate(bg.copy(), bg, ref_depth_mm=0.5, target_depth_mm=0.8)
    with pytest.raises(InputError, match="outside the gel"):
        gen.generate(ref, bg, ref_depth_mm=0.8, target_depth_mm=0.8, target_pose=gd.Pose(400.0, 50.0))
    with pytest.raises(InputError, match="outside the gel"):
        gen.generate(ref, bg, ref_depth_mm=0.8, target_depth_mm=0.8, target_mask=np.zeros((H, W), np.uint8))
    with pytest.raises(InputError, match="mask size"):
        gen.generate(ref, bg, ref_depth_mm=0.8, target_depth_mm=0.8, target_mask=np.ones((10, 10), np.uint8))
    with pytest.raises(InputError, match="non-negative"):
        gen.generate(ref, bg, ref_depth_mm=0.8, target_depth_mm=-0.1)
    with pytest.raises(InputError, match="force"):
        gd.hertz_depth_mm(-1.0, 2.0)
    with pytest.raises(InputError, match="weights"):
        type(gen)("/nonexistent/generator.pt")


def test_geometry_helpers():
    assert gd.hertz_depth_mm(gd.hertz_force_n(0.7, 2.0), 2.0) == pytest.approx(0.7)
    m = np.zeros((100, 120), np.uint8)
    m[45:55, 20:80] = 1  # a bar along x
    p = gd.mask_pose(m)
    assert (p.x, p.y, p.theta_deg) == pytest.approx((49.5, 49.5, 0.0), abs=1e-6)
    M = gd.relative_transform(p, gd.Pose(70.0, 40.0, 90.0))
    q = gd.mask_pose(gd.warp(m, M))
    assert q.x == pytest.approx(70.0, abs=1.0) and q.y == pytest.approx(40.0, abs=1.0)
    assert abs(abs(q.theta_deg) - 90.0) < 2.0
    h = gd.indenter_height("cross", (H, W), gd.Pose(160, 120, 0), 1.0, MPP)
    assert h.max() == pytest.approx(1.0, abs=0.05) and math.isfinite(float(h.sum()))


def test_cli_generate_and_eval_on_tiny_set(tmp_path, scene):
    import cv2
    from typer.testing import CliRunner
    from vtrack_apps.cli import app

    from vtrack.sim.presses import render_press_set

    ref, bg = scene
    runner = CliRunner()
    cv2.imwrite(str(tmp_path / "ref.png"), ref)
    cv2.imwrite(str(tmp_path / "background.png"), bg)
    out = tmp_path / "out.png"
    r = runner.invoke(app, ["tactile", "generate", str(tmp_path / "ref.png"), "--depth", "1.0",
                            "--position", "180,130,0", "--out", str(out)])  # fmt: skip
    assert r.exit_code == 0, r.output
    assert cv2.imread(str(out)).shape == (H, W, 3)
    r = runner.invoke(app, ["tactile", "generate", str(tmp_path / "ref.png"), "--force", "-1", "--out", str(out)])
    assert r.exit_code != 0 and isinstance(r.exception, InputError)
    ps = render_press_set("gelsight", tmp_path / "set", n=4, width=W, height=H, mm_per_px=MPP, background=bg, seed=3)
    js = tmp_path / "eval.json"
    r = runner.invoke(app, ["tactile", "generate-eval", str(ps), "--holdout", "all", "--json", str(js)])
    assert r.exit_code == 0, r.output
    res = json.loads(js.read_text())
    assert res["n"] == 3 and res["ms_per_image"] > 0
    for k in ("generator", "shift", "copy", "background"):
        assert set(res[k]) >= {"crop_mse", "crop_ssim", "crop_psnr", "full_mse", "full_ssim"}
        assert all(math.isfinite(res[k][m]) for m in ("crop_mse", "crop_ssim", "full_mse", "full_ssim"))
    # moving the patch beats copying the reference unchanged on the contact crops
    assert res["shift"]["crop_mse"] < res["copy"]["crop_mse"]
    assert res["trained_on_targets"] == 0  # another press set: nothing of it was trained on


def test_eval_flags_scores_over_training_presses():
    from vtrack.tactile.generate.evaluate import _trained_on

    meta = {"data": {"press_set": "/elsewhere/gelsight_ball_presses", "real_train": ["a.png", "b.png"]}}
    assert _trained_on(meta, "/data/gelsight_ball_presses", ["a.png", "c.png"]) == 1  # same set, other copy
    assert _trained_on(meta, "/data/other_set", ["a.png"]) == 0


class _Boom:
    """Unpickling this calls ``os.system``: a weights file must never be able to run code."""

    def __init__(self, marker):
        self.marker = str(marker)

    def __reduce__(self):
        import os

        return (os.system, (f"touch {self.marker}",))


def test_weights_file_cannot_run_code(tmp_path):
    import torch

    from vtrack.tactile.generate.generator import TactileGenerator

    p = tmp_path / "evil.pt"
    marker = tmp_path / "pwned"
    torch.save({"meta": _Boom(marker)}, p)
    with pytest.raises(InputError, match="cannot load generator weights"):
        TactileGenerator(weights=p)
    assert not marker.exists()  # the payload did not run
