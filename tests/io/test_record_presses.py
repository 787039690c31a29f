"""``vtrack record presses`` from a video file (issue #21): background, press episodes, read-out, warnings."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest

R_MM, MPP, H, W = 2.0, 0.0634, 240, 320


def _press_video(
    path: Path,
    presses: list[tuple[float, float, float]],
    seed: int = 0,
    sensor: str = "gelsight_mini",
    hw: tuple[int, int] = (H, W),
    mpp: float = MPP,
    unrotate: bool = False,
) -> Path:
    """An MJPG video of a GelSight Mini (independent optical model): 20 untouched frames, then for each press
    (cx px, cy px, contact radius mm) a ramp in and out over 9 frames, 4 untouched frames between presses.
    ``unrotate``: render in the stored (portrait) frame and write the frames turned back counter-clockwise,
    the landscape format the DIGIT camera delivers."""
    import cv2

    from vtrack.sim.presses import ball_height, press_depth_mm
    from vtrack.sim.tactile_optics import OpticalModel

    h_, w_ = hw
    model = OpticalModel.for_sensor(sensor, seed)
    rng = np.random.default_rng(seed)
    bg = np.empty((h_, w_, 3), np.float32)
    bg[:] = (150, 140, 130)
    bg = (bg + np.linspace(-20, 20, w_)[None, :, None]).astype(np.uint8)
    size = (h_, w_) if unrotate else (w_, h_)
    vw = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 30.0, size)
    assert vw.isOpened()

    def put(img):
        vw.write(cv2.rotate(img, cv2.ROTATE_90_COUNTERCLOCKWISE) if unrotate else img)

    flat = np.zeros((h_, w_), np.float32)
    for _ in range(20):
        put(model.render(flat, mpp, bg, rng, 1.0))
    for cx, cy, a_mm in presses:
        d = press_depth_mm(R_MM, a_mm)
        for f in (0.3, 0.6, 0.85, 1.0, 1.0, 0.85, 0.6, 0.3, 0.0, 0.0, 0.0, 0.0):
            h = ball_height((h_, w_), (cx, cy), R_MM, f * d, mpp) if f > 0 else flat
            put(model.render(h, mpp, bg, rng, 1.0))
    vw.release()
    return path


def test_record_presses_from_video(tmp_path):
    from vtrack.io.recorders.presses import record_presses

    truth = [
        (160, 120, 1.2),
        (90, 80, 1.0),
        (230, 170, 1.3),
        (120, 160, 0.75),
        (304, 60, 1.1),
        (200, 90, 1.15),
        (100, 120, 1.25),
    ]
    video = _press_video(tmp_path / "presses.avi", truth)
    lines: list[str] = []
    rep = record_presses(
        str(video),
        tmp_path / "set",
        sensor="gelsight_mini",
        ball_radius_mm=R_MM,
        mm_per_px=MPP,
        n_presses=50,
        echo=lines.append,
    )
    # the 0.75 mm contact (depth 0.14 mm) is seen as an episode but too faint to label: not saved, with advice
    assert rep.background_frames == 15 and rep.episodes == len(truth) and rep.presses_saved == len(truth) - 1
    assert len(rep.warnings) == 2
    assert rep.warnings[0].startswith("episode 4: not saved: too shallow: press deeper")
    assert rep.warnings[1] == "press_03.png: off-centre: contact cut by the image border"
    assert sum("press " in ln and "/50" in ln for ln in lines) == len(truth) - 1
    truth = truth[:3] + truth[4:]
    root = tmp_path / "set"
    meta = json.loads((root / "meta.json").read_text())
    assert meta["sensor"] == "gelsight_mini" and meta["mm_per_px"] == MPP and meta["ball_radius_mm"] == R_MM
    rows = list(csv.DictReader(open(root / "labels.auto.csv")))
    for (cx, cy, a_mm), r in zip(truth, rows, strict=True):
        assert np.hypot(float(r["center_x_px"]) - cx, float(r["center_y_px"]) - cy) < 2.5, r
        assert float(r["contact_radius_px"]) == pytest.approx(a_mm / MPP, rel=0.15), r
    assert (root / "background.png").is_file() and len(list(root.glob("press_*.png"))) == len(truth)


def test_record_presses_refuses_non_empty_folder_and_short_video(tmp_path):
    from vtrack.errors import InputError
    from vtrack.io.recorders.presses import record_presses

    video = _press_video(tmp_path / "v.avi", [])
    d = tmp_path / "mine"
    d.mkdir()
    (d / "notes.txt").write_text("keep me")
    with pytest.raises(InputError, match="not empty"):
        record_presses(str(video), d, sensor="gelsight_mini", ball_radius_mm=2.0, mm_per_px=MPP)
    assert (d / "notes.txt").read_text() == "keep me"
    with pytest.raises(InputError, match="before the 30 background frames"):
        record_presses(
            str(video),
            tmp_path / "new",
            sensor="gelsight_mini",
            ball_radius_mm=2.0,
            mm_per_px=MPP,
            background_frames=30,
        )


def test_record_presses_uses_the_sensor_preset_orientation_and_pitch(tmp_path):
    """A DIGIT delivers landscape 320x240 frames; vtrack stores DIGIT frames portrait (``record tactile``,
    the scenes, the simulator). The press recorder once kept them landscape, so a calibration from them did
    not fit the sensor's sessions, and wrote the nominal pitch as if measured. Now: portrait 240x320, the
    preset's pitch at that size, flagged ``preset`` in meta.json and by the press-set loader."""
    from vtrack.io.recorders.presses import record_presses
    from vtrack.tactile.pressset import load_press_set
    from vtrack.tactile.sensors import sensor_preset

    pitch = sensor_preset("digit").pitch_at(240, 320)
    truth = [(120, 160, 1.6), (80, 100, 1.4), (160, 230, 1.5), (70, 250, 1.3), (170, 80, 1.45)]  # stored frame
    video = _press_video(tmp_path / "digit.avi", truth, sensor="digit", hw=(320, 240), mpp=pitch, unrotate=True)
    lines: list[str] = []
    rep = record_presses(str(video), tmp_path / "set", sensor="digit", ball_radius_mm=R_MM, echo=lines.append)
    assert rep.presses_saved == 5, rep.warnings
    assert any(f"pixel pitch: {pitch:.4f} mm/px (nominal digit preset at 240x320" in ln for ln in lines)
    ps = load_press_set(tmp_path / "set", labels="auto")
    assert ps.shape == (320, 240) and ps.sensor == "digit"
    assert ps.mm_per_px == pytest.approx(pitch) and ps.mm_per_px_source == "preset"
    for (cx, cy, a_mm), p in zip(truth, ps.presses, strict=True):
        assert np.hypot(p.center_xy_px[0] - cx, p.center_xy_px[1] - cy) < 2.5, p
        assert p.contact_radius_px == pytest.approx(a_mm / pitch, rel=0.15), p
    # a pitch given on the command line is the user's: not flagged
    assert load_press_set(tmp_path / "set", mm_per_px=0.08, labels="auto").mm_per_px_source == "given"
