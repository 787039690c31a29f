"""The simulator's independent tactile optics (vtrack.sim.tactile_optics) and simulated press calibration."""

from __future__ import annotations

import numpy as np
import pytest

MPP = 0.09
H, W = 320, 240


def _bg() -> np.ndarray:
    # smooth synthetic background (the real one is used in the generator; these tests need no shared data)
    yy, xx = np.mgrid[0:H, 0:W]
    base = np.stack([110 + 20 * xx / W, 120 + 10 * yy / H, 100 + 0 * xx], -1)
    return base.astype(np.uint8)


def _bump(amp: float, sigma_mm: float = 1.0, c=(120, 160)) -> np.ndarray:
    yy, xx = np.mgrid[0:H, 0:W]
    r2 = ((xx - c[0]) ** 2 + (yy - c[1]) ** 2) * MPP**2
    return (amp * np.exp(-r2 / (2 * sigma_mm**2))).astype(np.float32)


def test_flat_gel_renders_background():
    from vtrack.sim.tactile_optics import OpticalModel

    m = OpticalModel.for_sensor("digit", seed=1)
    bg = _bg()
    assert np.array_equal(m.render(np.zeros((H, W), np.float32), MPP, bg, rng=None), bg)
    noisy = m.render(np.zeros((H, W), np.float32), MPP, bg, rng=np.random.default_rng(0)).astype(float)
    d = noisy - bg
    assert abs(d.mean()) < 0.1 and 1.0 < d.std() < 2.5  # shot + read noise only (measured std ~1.8)


def test_colour_change_grows_with_slope_and_is_not_point_symmetric():
    from vtrack.sim.tactile_optics import OpticalModel

    m = OpticalModel.for_sensor("digit", seed=None)
    mags = [np.abs(m.colour_change(_bump(a), MPP)).sum() for a in (0.1, 0.3, 0.6)]
    assert mags[0] < mags[1] < mags[2]
    dI = m.colour_change(_bump(0.5), MPP)
    rot = dI[::-1, ::-1]  # the bump is centred and symmetric: a symmetric light ring would give rot == dI
    assert np.abs(dI - rot).mean() > 0.5 * np.abs(dI).mean()
    # two units of the same type differ (seeded jitter of the LEDs)
    a = OpticalModel.for_sensor("digit", seed=1).colour_change(_bump(0.5), MPP)
    b = OpticalModel.for_sensor("digit", seed=2).colour_change(_bump(0.5), MPP)
    assert np.abs(a - b).mean() > 0.05 * np.abs(a).mean()


def test_shadow_on_far_side_of_bump():
    from vtrack.sim.tactile_optics import OpticalModel

    m = OpticalModel.for_sensor("digit", seed=None)
    light = m.lights[0]  # azimuth 90 deg: the LED is towards +y (down the image)
    s = m._shadow(_bump(1.0, 0.4), MPP, light)
    # 1 mm bump (sigma 0.4 mm), LED elevation 30 deg: the far side (-y, 1 mm from the top) is in shadow,
    # the side facing the LED is lit
    far = s[160 - 11, 120]
    near = s[160 + 11, 120]
    assert far < 0.2 and near == pytest.approx(1.0)
    assert s[5, 5] == pytest.approx(1.0)


def test_bad_input_raises():
    from vtrack.errors import InputError
    from vtrack.sim.tactile_optics import OpticalModel

    with pytest.raises(InputError):
        OpticalModel.for_sensor("dome")
    with pytest.raises(InputError):
        OpticalModel.for_sensor("digit").render(np.zeros((10, 10)), MPP, _bg())


@pytest.fixture(scope="module")
def digit_press_calibration(tmp_path_factory, shared_data):
    from vtrack.sim.presses import SIM_PRESSES, render_press_set
    from vtrack.tactile.calibration import calibrate
    from vtrack.tactile.pressset import load_press_set

    # as many presses as the simulator's own sensor calibrations, over the whole gel (edges included)
    d = render_press_set(
        "digit", tmp_path_factory.mktemp("ps") / "digit", n=SIM_PRESSES, mm_per_px=MPP, width=W, height=H, seed=5
    )
    ps = load_press_set(d)
    train, test = ps.split("every:4:3")
    return ps, calibrate(ps, "mlp", train), test


def test_simulated_press_set_calibrates(digit_press_calibration):
    from vtrack.tactile.evaluation import evaluate_presses
    from vtrack.tactile.pipeline import TactilePipeline

    ps, calib, test = digit_press_calibration
    assert len(ps.presses) == 60 and ps.shape == (H, W) and ps.ball_radius_mm == 3.0
    # presses reach the gel's edges (partial circles): what the sessions' large contacts need
    edge = [
        p
        for p in ps.presses
        if min(p.center_xy_px[0], W - p.center_xy_px[0], p.center_xy_px[1], H - p.center_xy_px[1]) < p.contact_radius_px
    ]
    assert len(edge) >= 5
    res = evaluate_presses(ps, test, TactilePipeline(calib).height)
    # measured: 6.6 deg held-out median normal error (MLP; the elastomer blur rounds the ball edge)
    assert res["summary"]["normal_err_deg_median"] < 11.0
    # the pipeline inverting optical-model images (not its own Lambertian/inverse model) recovers the
    # indentation depth: measured median |depth error| 20 % of the true depth (13 % on presses away from
    # the edges; a press cut by the border loses part of its slopes)
    rel = [abs(r["max_depth_mm"] - r["true_depth_mm"]) / r["true_depth_mm"] for r in res["presses"]]
    assert float(np.median(rel)) < 0.25


def test_sim_vs_real_beats_background_baseline(shared_data):
    from vtrack.bench.simreal import score
    from vtrack.sim.tactile_optics import OpticalModel
    from vtrack.tactile.pressset import load_press_set

    ps = load_press_set(shared_data / "gelsight_ball_presses")
    s = score(OpticalModel.for_sensor("gelsight"), ps, [p for p in ps.presses if p.index % 2 == 1][:4])
    # measured on 8 held-out presses: preset MSE 170 vs background-only 350 (grey levels^2)
    assert s["mse"] < 0.8 * s["mse_bg"]


def test_session_carries_calibration_and_pipeline_recovers_height(tmp_path, shared_data):
    from vtrack.bench.simreal import session_tactile_accuracy
    from vtrack.io.session import open_session
    from vtrack.paths import default_scene_path
    from vtrack.scene import load_scene
    from vtrack.sim.generate import generate_session

    p = generate_session(load_scene(default_scene_path()), tmp_path / "s", seconds=0.2, seed=3)
    sc = open_session(p).scene(check_files=True)
    assert all(t.calibration == (p / "assets" / "calibration" / f"{t.name}.npz").resolve() for t in sc.tactile)
    acc = session_tactile_accuracy(p)
    # measured on a 0.5 s session (seed 3, 120 frames): height 0.30 mm, IoU 0.41, normals 4.9 deg
    assert acc["contact_pixels"] > 0
    assert acc["height_err_mm_median"] < 0.45
    assert acc["contact_iou"] > 0.3
    assert acc["normal_err_deg_median"] < 7.0
