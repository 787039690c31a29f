"""Fixtures of the tactile tests: the real GelSight press set and calibrations trained on it (cached)."""

from __future__ import annotations

import pytest

#: Small but honest MLP training config for tests (held-out presses never seen in training).
TEST_MLP = {"mlp_epochs": 6, "inside_per_press": 3000, "flat_per_press": 2000}


@pytest.fixture(scope="session")
def gelsight_set(shared_data):
    from vtrack.tactile.pressset import load_press_set

    return load_press_set(shared_data / "gelsight_ball_presses")


@pytest.fixture(scope="session")
def lut_calib(gelsight_set):
    from vtrack.tactile.calibration import cached_calibration

    return cached_calibration(gelsight_set, "lut", "every:4:3")


@pytest.fixture(scope="session")
def mlp_calib(gelsight_set):
    import torch

    from vtrack.tactile.calibration import TrainOptions, cached_calibration

    torch.set_num_threads(1)
    return cached_calibration(gelsight_set, "mlp", "every:4:3", TrainOptions(**TEST_MLP))


@pytest.fixture(scope="session")
def mini_small(tmp_path_factory):
    """A small simulated GelSight Mini press set (6 presses, seed 4): read only, shared by the calibration tests."""
    from vtrack.sim.presses import render_press_set

    return render_press_set("gelsight_mini", tmp_path_factory.mktemp("mini_small") / "set", n=6, seed=4)
