"""Sensor presets (issue #21 item 4): one table used by scenes, press sets / calibrate, the simulator and the
recorder."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from vtrack.errors import InputError
from vtrack.tactile.sensors import SENSOR_PRESETS, sensor_preset


def test_presets_pitch_scales_with_image_size_and_orientation():
    mini = SENSOR_PRESETS["gelsight_mini"]
    assert mini.pitch_at(320, 240) == pytest.approx(0.0634)
    assert mini.pitch_at(640, 480) == pytest.approx(0.0317)  # same field of view, twice the pixels
    digit = SENSOR_PRESETS["digit"]
    assert digit.stored_size == (240, 320)  # stored portrait
    assert digit.pitch_at(240, 320) == pytest.approx(digit.pitch_at(320, 240)) == pytest.approx(0.09)
    with pytest.raises(InputError, match="unknown tactile sensor type"):
        sensor_preset("geltouch")
    with pytest.raises(InputError, match="image size must be positive"):
        digit.pitch_at(0, 10)


def test_scene_tactile_entry_defaults_from_the_preset():
    from pydantic import ValidationError

    from vtrack.scene.schema import TactileSpec

    t = TactileSpec(name="index", type="digit")
    assert (t.width, t.height, t.mm_per_px, t.gel_thickness_mm, t.rate_hz) == (240, 320, 0.09, 3.0, 60.0)
    t = TactileSpec(name="m", type="gelsight_mini", width=640, height=480)
    assert t.mm_per_px == pytest.approx(0.0317) and t.rate_hz == 25.0
    t = TactileSpec(name="g", type="gelsight", mm_per_px=0.03, width=640, height=480, rate_hz=15)
    assert t.mm_per_px == 0.03 and t.rate_hz == 15  # given values win
    with pytest.raises(ValidationError, match="width"):
        TactileSpec(name="d", type="dome")  # no preset: the size must be given


def test_press_set_without_pitch_uses_the_flagged_preset_pitch(shared_data, tmp_path):
    from vtrack.tactile.pressset import load_press_set

    src = shared_data / "gelsight_ball_presses"
    root = tmp_path / "mine"
    root.mkdir()
    for p in list(src.glob("press_0*.png"))[:6] + [src / "background.png", src / "labels.csv"]:
        shutil.copy(p, root / p.name)
    (root / "meta.json").write_text(json.dumps({"sensor": "gelsight", "ball_radius_mm": 2.0}))
    ps = load_press_set(root)
    assert ps.mm_per_px == pytest.approx(0.0295) and ps.mm_per_px_source == "preset"
    ps = load_press_set(root, mm_per_px=0.03)
    assert ps.mm_per_px == 0.03 and ps.mm_per_px_source == "given"
    (root / "meta.json").write_text(json.dumps({"sensor": "my_sensor", "ball_radius_mm": 2.0}))
    with pytest.raises(InputError, match="mm_per_px"):
        load_press_set(root)  # unknown type and no pitch: nothing to fall back on


def test_simulated_press_set_defaults_to_the_preset_geometry(tmp_path):
    import cv2

    from vtrack.sim.presses import render_press_set
    from vtrack.tactile.pressset import load_press_set

    root = render_press_set("digit", tmp_path / "d", n=4, seed=1)
    bg = cv2.imread(str(root / "background.png"))
    assert bg.shape == (320, 240, 3)
    ps = load_press_set(root)
    assert ps.mm_per_px == pytest.approx(0.09) and ps.mm_per_px_source == "given"
    assert np.isfinite([p.contact_radius_px for p in ps.presses]).all()


def test_simulator_optics_follow_the_preset_light_layout():
    """The simulator's per-type optical model (vtrack.sim.tactile_optics) lights the gel with the LEDs the
    preset lists (count, azimuths, dominant colour), so a simulated DIGIT / Mini / GelSight looks like the
    hardware the preset describes; every preset type has an optical model."""
    from vtrack.sim.tactile_optics import OpticalModel

    channel = {"blue": 0, "green": 1, "red": 2}  # BGR
    for name, preset in SENSOR_PRESETS.items():
        model = OpticalModel.for_sensor(name, seed=None)
        assert len(model.lights) == len(preset.lights), name
        for light, (colour, az) in zip(model.lights, preset.lights, strict=True):
            assert light.azimuth_deg == pytest.approx(az), (name, colour)
            c = np.asarray(light.colour_bgr)
            if colour == "white":
                assert c.max() - c.min() < 0.1, (name, c)
            else:
                assert int(np.argmax(c)) == channel[colour], (name, colour, c)


def test_gelsight_preset_lights_match_the_real_presses(gelsight_set):
    """Photometric stereo fitted to 16 of the real GelSight presses recovers one light direction per colour
    channel; the preset's LED azimuths must agree (within 30 deg). The fitted vector points away from the LED
    in this normal convention (checked on the simulator, whose LEDs are known), hence the 180 deg."""
    from vtrack.tactile.calibration import TrainOptions, fit_ps, training_samples

    data = training_samples(gelsight_set, gelsight_set.presses[::3], TrainOptions())  # 16 presses suffice
    L = fit_ps(data["dI"], data["n"])["lights"]  # rows B, G, R: (x, y, z)
    fitted = (np.degrees(np.arctan2(L[:, 1], L[:, 0])) + 180.0) % 360.0
    preset = dict(SENSOR_PRESETS["gelsight"].lights)
    for k, colour in enumerate(("blue", "green", "red")):
        diff = (fitted[k] - preset[colour] + 180.0) % 360.0 - 180.0
        assert abs(diff) < 30.0, (colour, fitted[k], preset[colour])


def test_calibrate_warns_when_press_images_are_not_in_the_stored_orientation(tmp_path):
    """A DIGIT press set recorded landscape by another tool would give a calibration that does not fit the
    portrait DIGIT frames vtrack records: `vtrack calibrate` says so (and still calibrates)."""
    from typer.testing import CliRunner
    from vtrack_apps.cli import app

    from vtrack.sim.presses import render_press_set
    from vtrack.tactile.sensors import orientation_warning

    assert orientation_warning("digit", 240, 320) is None and orientation_warning("gelsight", 640, 480) is None
    assert "portrait" in orientation_warning("digit", 320, 240) and orientation_warning("unknown", 320, 240) is None
    root = render_press_set("digit", tmp_path / "landscape", n=6, seed=1, width=320, height=240)
    out = tmp_path / "c.npz"
    res = CliRunner().invoke(app, ["calibrate", str(root), "--out", str(out), "--method", "lut", "--holdout", "none"])
    assert res.exit_code == 0, res.output
    assert "warning: digit images are 320x240 but vtrack stores digit frames 240x320 (portrait)" in res.output
    assert out.is_file()


def test_press_count_warning_asks_a_digit_for_more_presses():
    """The DIGIT preset asks for 100 presses (its shading changes fastest near the gel's border), the others
    for 60; fewer usable presses give a warning naming the count, enough give none, an unknown type none."""
    from vtrack.tactile.sensors import press_count_warning

    assert SENSOR_PRESETS["digit"].calib_presses == 100
    assert SENSOR_PRESETS["gelsight_mini"].calib_presses == SENSOR_PRESETS["gelsight"].calib_presses == 60
    w = press_count_warning("digit", 57)
    assert w is not None and "only 57 usable presses" in w and "record 100" in w
    assert press_count_warning("digit", 100) is None
    assert press_count_warning("gelsight_mini", 57) is not None and press_count_warning("gelsight_mini", 60) is None
    assert press_count_warning("unknown_sensor", 3) is None
