"""Calibration near the gel's border (issue #21, docs/benchmarks/calib_border.md): MLP ensembles."""

from __future__ import annotations

import numpy as np
import pytest


def _net(rng, dims):
    p = {"n_layers": np.int64(len(dims) - 1)}
    for i in range(len(dims) - 1):
        p[f"W{i}"] = rng.normal(0, 0.5, (dims[i], dims[i + 1])).astype(np.float32)
        p[f"b{i}"] = rng.normal(0, 0.1, dims[i + 1]).astype(np.float32)
    return p


def test_ensemble_forward_is_the_mean_of_its_members():
    from vtrack.tactile.calibration import _mlp_forward

    rng = np.random.default_rng(3)
    a, b, c = (_net(rng, [8, 5, 5, 2]) for _ in range(3))
    x = rng.normal(0, 1, (40, 8)).astype(np.float32)
    ens = dict(a)
    ens.update({f"m1_{k}": v for k, v in b.items() if k != "n_layers"})
    ens.update({f"m2_{k}": v for k, v in c.items() if k != "n_layers"})
    ens["n_members"] = np.int64(3)
    want = (_mlp_forward(a, x) + _mlp_forward(b, x) + _mlp_forward(c, x)) / 3.0
    got = _mlp_forward(ens, x)
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-6)
    assert np.abs(got - _mlp_forward(a, x)).max() > 1e-3  # the other members do count
    assert np.abs(got).max() < 1.0  # still a mean of tanh outputs: bounded normals


def test_options_key_keeps_the_old_cache_keys():
    """A calibration cached before ``mlp_ensemble`` existed keeps its key (and so do the sessions built on the
    simulator's cached calibrations); another ensemble size is another key."""
    from vtrack.tactile.calibration import TrainOptions, options_key

    k1 = options_key(TrainOptions())
    assert "mlp_ensemble" not in k1 and k1["mlp_hidden"] == 64 and k1["mlp_features"] == "raw"
    assert options_key(TrainOptions(mlp_ensemble=3))["mlp_ensemble"] == 3


def test_ensemble_calibration_round_trips_and_averages_its_nets(mini_small, tmp_path):
    import torch

    from vtrack.tactile.calibration import Calibration, TrainOptions, _mlp_forward, calibrate
    from vtrack.tactile.pressset import load_press_set

    torch.set_num_threads(1)
    ps = load_press_set(mini_small)
    small = {"mlp_epochs": 1, "mlp_hidden": 16, "inside_per_press": 800, "flat_per_press": 500}
    one = calibrate(ps, "mlp", ps.presses[:3], TrainOptions(mlp_features="relpoly", **small))
    two = calibrate(ps, "mlp", ps.presses[:3], TrainOptions(mlp_features="relpoly", mlp_ensemble=2, **small))
    assert int(two.params["n_members"]) == 2 and two.params["m1_W0"].shape == (36, 16)
    # member 0 is the single net (same seed, same data); member 1 differs (another seed)
    np.testing.assert_array_equal(two.params["W0"], one.params["W0"])
    assert not np.allclose(two.params["m1_W0"], two.params["W0"])
    back = Calibration.load(two.save(tmp_path / "ens.npz"))
    img = ps.image(ps.presses[4])
    nx, ny = back.normals(img)
    np.testing.assert_array_equal(nx, two.normals(img)[0])
    assert np.isfinite(nx).all() and np.isfinite(ny).all() and np.abs(nx).max() > 0.05
    # the prediction is the mean of the two nets
    rng = np.random.default_rng(0)
    x = rng.normal(0, 0.3, (30, 36)).astype(np.float32)
    m1 = {"n_layers": two.params["n_layers"], **{k[3:]: v for k, v in two.params.items() if k.startswith("m1_")}}
    np.testing.assert_allclose(
        _mlp_forward(two.params, x), 0.5 * (_mlp_forward(one.params, x) + _mlp_forward(m1, x)), rtol=1e-5, atol=1e-6
    )


def test_training_at_the_working_resolution_uses_the_downscaled_presses(mini_small):
    """``train_work_res``: samples come from the presses at the pipeline's default working resolution (the
    Mini's 320x240 frames: 160x120), with the circles scaled, and only from the training presses."""
    import torch

    from vtrack.tactile.calibration import TrainOptions, _training_set, calibrate
    from vtrack.tactile.pipeline import auto_downsample
    from vtrack.tactile.pressset import load_press_set

    torch.set_num_threads(1)
    ps = load_press_set(mini_small)
    H, W = ps.shape
    f = auto_downsample((H, W))
    assert f == 2
    same, tr = _training_set(ps, ps.presses[:3], TrainOptions())
    assert same is ps and tr == ps.presses[:3]
    small, tr = _training_set(ps, ps.presses[:3], TrainOptions(train_work_res=True))
    assert small.shape == (H // 2, W // 2) and small.mm_per_px == 2 * ps.mm_per_px
    assert [p.file for p in tr] == [p.file for p in ps.presses[:3]]
    p0, q0 = ps.presses[0], tr[0]
    assert q0.contact_radius_px == p0.contact_radius_px / 2
    assert abs(q0.center_xy_px[0] - ((p0.center_xy_px[0] + 0.5) / 2 - 0.5)) < 1e-9
    small_opts = {"mlp_epochs": 1, "mlp_hidden": 16, "inside_per_press": 800, "flat_per_press": 500}
    full = calibrate(ps, "mlp", ps.presses[:3], TrainOptions(mlp_features="relpoly", **small_opts))
    work = calibrate(ps, "mlp", ps.presses[:3], TrainOptions(mlp_features="relpoly", train_work_res=True, **small_opts))
    assert work.shape == full.shape  # the calibration keeps the full-resolution background
    assert work.info["n_train_pixels"] < full.info["n_train_pixels"]  # a quarter of the disc pixels
    gx, gy = work.slopes(ps.image(ps.presses[4]))
    assert np.isfinite(gx).all() and np.abs(gx).max() > 0.05


def test_training_resolution_is_chosen_by_cross_validation_on_the_same_presses(mini_small):
    """``choose_train_res``: the chosen model is cross-validated again at the other training resolution and
    wins or loses by the model choice's rule; its row is added to the CV rows with exactly one ``chosen``."""
    from vtrack.tactile.calibrate_set import choose_train_res, cross_validate
    from vtrack.tactile.calibration import TrainOptions
    from vtrack.tactile.pressset import load_press_set

    ps = load_press_set(mini_small)
    real = cross_validate(ps, "lut", ps.presses, TrainOptions(), name="lut")
    for fake_n, alt_wins in ((90.0, True), (0.0, False)):  # a hopeless / a perfect full-resolution row
        rows = [{**real, "normal_err_deg_median": fake_n, "chosen": True}]
        name, opts = choose_train_res(ps, ps.presses, "lut", "lut", TrainOptions(), rows)
        assert [r["model"] for r in rows] == ["lut", "lut+work-res"]
        assert [r["chosen"] for r in rows] == [not alt_wins, alt_wins]
        assert opts.train_work_res is alt_wins and name == ("lut+work-res" if alt_wins else "lut")
        # the work-resolution row is a real cross-validation over the same presses (not the full-res one)
        assert rows[1]["n_presses"] == real["n_presses"] and rows[1]["folds"] == real["folds"]
        assert 1.0 < rows[1]["normal_err_deg_median"] < 30.0
        assert rows[1]["normal_err_deg_median"] != real["normal_err_deg_median"]


def test_press_set_training_resolution_option(mini_small):
    from vtrack.errors import InputError
    from vtrack.tactile.calibrate_set import calibrate_press_set

    with pytest.raises(InputError, match="unknown training resolution"):
        calibrate_press_set(mini_small, method="lut", train_res="half")
    full = calibrate_press_set(mini_small, method="lut", train_res="full")
    work = calibrate_press_set(mini_small, method="lut", train_res="work")
    assert work.calib.info["options"]["train_work_res"] and not full.calib.info["options"]["train_work_res"]
    assert work.calib.info["n_train_pixels"] < full.calib.info["n_train_pixels"]
    assert work.calib.shape == full.calib.shape and work.held_out is not None


def test_cli_rejects_a_bad_training_resolution_or_working_factor_with_one_line(mini_small, tmp_path):
    from typer.testing import CliRunner
    from vtrack_apps.cli import app

    from vtrack.errors import InputError

    out = str(tmp_path / "c.npz")
    for extra, field in ((["--train-res", "half"], "train_res"), (["--downsample", "x"], "--downsample")):
        r = CliRunner().invoke(app, ["calibrate", str(mini_small), "--out", out, *extra])
        # an InputError: the CLI's entry point prints it as one line and exits 2
        assert isinstance(r.exception, InputError) and r.exception.field == field, repr(r.exception)
    assert not (tmp_path / "c.npz").exists()
