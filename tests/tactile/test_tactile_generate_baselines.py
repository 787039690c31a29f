"""Generator baselines of issue #24: separate force-then-position, few-step rectified flow, their training pairs."""

from __future__ import annotations

import numpy as np
import pytest

from vtrack.errors import InputError
from vtrack.tactile.generate import data as gd

W, H, MPP = 320, 240, 0.059


@pytest.fixture(scope="module")
def scene():
    from vtrack.sim.presses import ball_height
    from vtrack.sim.tactile_optics import OpticalModel
    from vtrack.tactile.sensors import default_background

    bg = default_background("gelsight", W, H)
    h = ball_height((H, W), (140.0, 110.0), 2.0, 0.8, MPP)
    ref = OpticalModel.for_sensor("gelsight", seed=7).render(h, MPP, bg, np.random.default_rng(0))
    return ref, bg


def _exact_velocity(y):
    """The exact rectified-flow velocity towards a fixed target ``y``: ``(y - z) / (1 - t)``."""

    def v(x, cond, z, t):
        return (y - z) / (1 - t)[:, None, None, None]

    return v


def test_flow_sampler_and_loss_follow_the_rectified_flow_convention():
    """With the exact velocity field of a known target, the loss is 0 and 1, 2, 4 or 8 Euler steps land on it
    (a sign or time-direction slip in either breaks this)."""
    import torch

    from vtrack.tactile.generate.model import Flow

    torch.manual_seed(0)
    x = torch.randn(2, 6, 16, 16)
    cond = torch.zeros(2, 3)
    y = torch.randn(2, 3, 16, 16) * 0.2
    flow = Flow(sigma=0.3)
    flow.velocity = _exact_velocity(y)
    assert float(flow.loss(x, cond, y, torch.ones(1, 1, 16, 16))) == pytest.approx(0.0, abs=1e-8)
    for steps in (1, 2, 4, 8):
        flow.steps = steps
        assert torch.allclose(flow(x, cond, torch.zeros(2, 5)), y, atol=1e-5)
    # a wrong field (the target's negative) is penalised and sampled wrong
    flow.velocity = _exact_velocity(-y)
    assert float(flow.loss(x, cond, y, torch.ones(1, 1, 16, 16))) > 0.01
    assert not torch.allclose(flow(x, cond, torch.zeros(2, 5)), y, atol=1e-2)
    # x0 (target) parametrisation: a net that outputs the target gives loss 0 and lands on it
    fx = Flow(sigma=0.3, predict="target")
    fx._out = lambda x, cond, z, t: y
    assert float(fx.loss(x, cond, y, torch.ones(1, 1, 16, 16))) == pytest.approx(0.0, abs=1e-8)
    for steps in (1, 3, 8):
        fx.steps = steps
        assert torch.allclose(fx(x, cond, torch.zeros(2, 5)), y, atol=1e-5)


def test_position_pairs_are_same_depth_other_pose_same_group():
    from vtrack.tactile.generate.train import _position_pairs

    n = 6
    m = np.zeros((20, 20), np.uint8)
    m[8:12, 8:12] = 1
    bank = gd.PressBank.build(
        [np.zeros((20, 20, 3))] * n,
        [m] * n,
        [(10.0, 10.0, 0.0)] * n,
        depths=[0.5, 0.55, 0.9, 0.5, 0.52, 0.5],
        groups=[0, 0, 0, 0, 1, 1],
        sites=[0, 1, 1, 0, 2, 3],
        real=False,
    )
    got = {tuple(p) for p in _position_pairs(bank, 0.1)}
    # (0,1) and (1,3): other site, same group, |dd| <= 0.1; (0,3) share a site; 2 is too deep; 4,5 their own group
    assert got == {(0, 1), (1, 0), (1, 3), (3, 1), (4, 5), (5, 4)}


def test_shipped_weights_hold_the_baselines_trained_at_matched_steps():
    import torch

    from vtrack.tactile.generate import default_weights_path

    state = torch.load(default_weights_path(), map_location="cpu", weights_only=True)
    assert {"base", "control", "hybrid", "position", "flow", "flowx"} <= set(state)
    steps = {r["stage"]: r["steps"] for r in state["meta"]["log"]}
    # per-compute comparisons: flow vs stage 1 and position vs hybrid got the same optimiser steps
    assert steps["flow"] == steps["flowx"] == steps["stage1"] and steps["position"] == steps["hybrid"]
    assert state["meta"]["data"]["position_pairs"] > state["meta"]["data"]["position_real_pairs"] > 0


def test_separate_baseline_moves_the_force_output(scene):
    """separate = stage 1 at the reference pose, then the position model moves its output: the contact ends up
    at the target and the result differs from the two-stage model's."""
    from vtrack.tactile.generate.generator import TactileGenerator

    ref, bg = scene
    kw = {"ref_depth_mm": 0.8, "target_depth_mm": 1.1, "target_pose": gd.Pose(220.0, 150.0)}
    sep = TactileGenerator(mode="separate", threads=1)
    out = sep.generate(ref, bg, **kw)
    change = np.abs(out.astype(np.float32) - bg).sum(2)
    cx, cy = np.average(np.mgrid[0:H, 0:W][::-1].reshape(2, -1), axis=1, weights=change.ravel() ** 2)
    assert abs(cx - 220) < 8 and abs(cy - 150) < 8
    two = TactileGenerator(mode="two_stage", threads=1).generate(ref, bg, **kw)
    assert np.abs(out.astype(np.float32) - two).mean() > 0.05
    # the position step must not be skipped: batched and single calls agree
    req = sep.prepare(ref, bg, **kw)
    assert np.array_equal(sep.generate_many([req], bg)[0], out)
    # a target mostly off the gel is refused when the request is prepared, not after the force step
    with pytest.raises(InputError, match="outside"):
        sep.prepare(ref, bg, ref_depth_mm=0.8, target_depth_mm=0.8, target_pose=gd.Pose(319.0, 1.0))


def test_flow_modes_are_reproducible_and_cost_more_with_steps(scene):
    from vtrack.tactile.generate.generator import TactileGenerator

    ref, bg = scene
    kw = {"ref_depth_mm": 0.8, "target_depth_mm": 1.1, "target_pose": gd.Pose(200.0, 140.0)}
    g1 = TactileGenerator(mode="flow1", threads=1)
    g4 = TactileGenerator(mode="flow4", threads=1)
    a, b = g4.generate(ref, bg, **kw), g4.generate(ref, bg, **kw)
    assert np.array_equal(a, b)  # fixed-seed noise
    assert (
        np.isfinite(a.astype(np.float32)).all() and np.abs(a.astype(np.float32) - g1.generate(ref, bg, **kw)).max() > 0
    )


def test_missing_baseline_in_weights_is_a_clear_error(tmp_path):
    import torch

    from vtrack.tactile.generate import default_weights_path
    from vtrack.tactile.generate.generator import TactileGenerator

    state = torch.load(default_weights_path(), map_location="cpu", weights_only=True)
    for k in ("position", "flow", "flowx"):
        state.pop(k, None)
    p = tmp_path / "old.pt"
    torch.save(state, p)
    for mode in ("separate", "flow4", "flowx2"):
        with pytest.raises(InputError, match="baseline"):
            TactileGenerator(p, mode=mode)
    assert TactileGenerator(p).available == {"base", "control", "hybrid"}


def test_generate_train_refuses_bad_extras(tmp_path):
    from typer.testing import CliRunner
    from vtrack_apps.cli import app

    from vtrack.tactile.generate import default_weights_path
    from vtrack.tactile.generate.train import TrainConfig, train

    runner = CliRunner()
    r = runner.invoke(app, ["tactile", "generate-train", "--update", str(default_weights_path())])
    assert r.exit_code != 0 and isinstance(r.exception, InputError) and "--extras" in str(r.exception)
    r = runner.invoke(app, ["tactile", "generate-train", "--update", str(tmp_path / "no.pt"), "--extras", "flow"])
    assert r.exit_code != 0 and isinstance(r.exception, InputError)
    with pytest.raises(InputError, match="extra"):
        train(TrainConfig(extras=("diffusion",)), out=tmp_path / "x.pt")
