"""Position-structured MLP features of the calibration (issue #21)."""

from __future__ import annotations

import numpy as np


def test_relpoly_features_are_a_position_varying_linear_map_of_the_colour_change():
    """``relpoly``: every input is a colour change times a quadratic monomial of the position, so the flat gel
    (no change) gives no input at all wherever it is, and the inputs scale with the change at a fixed pixel and
    background (the first layer is a linear map of dI that varies smoothly over the gel)."""
    from vtrack.tactile.calibration import _mlp_features

    rng = np.random.default_rng(0)
    n, shape = 50, (120, 160)
    rows, cols = rng.integers(0, 120, n), rng.integers(0, 160, n)
    bg = rng.uniform(40, 200, (n, 3)).astype(np.float32)
    dI = rng.normal(0, 20, (n, 3)).astype(np.float32)
    f = _mlp_features(dI, bg + dI, rows, cols, shape, "relpoly")
    assert f.shape == (n, 36) and f.dtype == np.float32
    zero = _mlp_features(np.zeros_like(dI), bg, rows, cols, shape, "relpoly")
    assert not zero.any()  # no free position term: the model cannot learn "a normal at a place"
    np.testing.assert_allclose(_mlp_features(2 * dI, bg + 2 * dI, rows, cols, shape, "relpoly"), 2 * f, rtol=1e-5)
    # the blocks: dI / 64 times (1, x, y, x^2, xy, y^2), then 2 dI / (bg + 16) times the same
    x, y = cols * (2.0 / 160) - 1.0, rows * (2.0 / 120) - 1.0
    np.testing.assert_allclose(f[:, 0], dI[:, 0] / 64.0, rtol=1e-6)
    np.testing.assert_allclose(f[:, 4], dI[:, 0] / 64.0 * x * y, rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(f[:, 18 + 6 + 2], 2 * dI[:, 1] / (bg[:, 1] + 16.0) * y, rtol=1e-4, atol=1e-6)
    assert _mlp_features(dI, bg + dI, rows, cols, shape, "poly").shape == (n, 18)


def test_relpoly_calibration_round_trips_and_its_features_are_used(mini_small, tmp_path):
    import torch

    from vtrack.tactile.calibration import MLP_FEATURES, Calibration, TrainOptions, calibrate
    from vtrack.tactile.pressset import load_press_set

    torch.set_num_threads(1)
    ps = load_press_set(mini_small)
    small = {"mlp_epochs": 1, "mlp_hidden": 16, "inside_per_press": 800, "flat_per_press": 500}
    cal = calibrate(ps, "mlp", ps.presses[:3], TrainOptions(mlp_features="relpoly", **small))
    assert cal.params["W0"].shape == (36, 16)
    back = Calibration.load(cal.save(tmp_path / "relpoly.npz"))
    assert MLP_FEATURES[int(back.params["mlp_features"])] == "relpoly"
    img = ps.image(ps.presses[4])
    gx, gy = back.slopes(img)
    np.testing.assert_array_equal(gx, cal.slopes(img)[0])
    assert np.isfinite(gx).all() and np.isfinite(gy).all()
