"""Press-set format: metadata precedence, hold-out specs, converters and clear errors."""

import json
import shutil

import numpy as np
import pytest

from vtrack.errors import InputError
from vtrack.tactile.pressset import load_press_set, parse_holdout, sphere_truth


def _tiny_set(tmp_path, n=4, meta=True):
    import cv2

    d = tmp_path / "set"
    d.mkdir()
    cv2.imwrite(str(d / "background.png"), np.full((20, 30, 3), 100, np.uint8))
    rows = ["file,center_x_px,center_y_px,contact_radius_px"]
    for i in range(n):
        cv2.imwrite(str(d / f"p{i}.png"), np.full((20, 30, 3), 110 + i, np.uint8))
        rows.append(f"p{i}.png,15,10,4")
    (d / "labels.csv").write_text("\n".join(rows) + "\n")
    if meta:
        (d / "meta.json").write_text(json.dumps({"sensor": "x", "mm_per_px": 0.1, "ball_radius_mm": 1.0}))
    return d


def test_shared_set_uses_preset(gelsight_set):
    assert gelsight_set.mm_per_px == 0.0295 and gelsight_set.ball_radius_mm == 2.0
    assert len(gelsight_set.presses) == 48 and gelsight_set.shape == (480, 640)


def test_meta_precedence(tmp_path):
    d = _tiny_set(tmp_path)
    assert load_press_set(d).mm_per_px == 0.1
    m = tmp_path / "m.json"
    m.write_text(json.dumps({"mm_per_px": 0.2}))
    assert load_press_set(d, m).mm_per_px == 0.2
    assert load_press_set(d, m, mm_per_px=0.3).mm_per_px == 0.3


def test_missing_meta_and_files(tmp_path):
    d = _tiny_set(tmp_path, meta=False)
    with pytest.raises(InputError, match="ball_radius_mm"):
        load_press_set(d)
    assert load_press_set(d, sensor="s", mm_per_px=0.1, ball_radius_mm=1).sensor == "s"
    with pytest.raises(InputError, match="not found"):
        load_press_set(tmp_path / "nope")
    ps = load_press_set(d, sensor="s", mm_per_px=0.1, ball_radius_mm=1)
    (d / "p1.png").unlink()
    with pytest.raises(InputError, match="p1.png"):
        ps.image(ps.presses[1])
    with pytest.raises(InputError, match="must be a positive"):
        load_press_set(d, sensor="s", mm_per_px=-1, ball_radius_mm=1)
    (d / "labels.csv").write_text("file,x\np0.png,1\n")
    with pytest.raises(InputError, match="labels.csv"):
        load_press_set(d, sensor="s", mm_per_px=0.1, ball_radius_mm=1)


def test_holdout_specs(tmp_path):
    ps = load_press_set(_tiny_set(tmp_path, n=8))
    assert parse_holdout("every:4:3", ps.presses) == {3, 7}
    assert parse_holdout("idx:0,5", ps.presses) == {0, 5}
    assert parse_holdout("files:p2.png", ps.presses) == {2}
    assert parse_holdout("last:3", ps.presses) == {5, 6, 7}
    assert parse_holdout("none", ps.presses) == set()
    train, test = ps.split("every:2")
    assert len(train) == 4 and len(test) == 4
    for bad in ("every:1", "idx:99", "files:zz.png", "bogus"):
        with pytest.raises(InputError):
            parse_holdout(bad, ps.presses)


def test_sphere_truth_geometry():
    from vtrack.tactile.pressset import Press

    p = Press("x", (50.0, 40.0), 30.0)
    h, gx, gy, inside = sphere_truth(p, (80, 100), 50.0)
    assert h.max() == pytest.approx(50 - 40, abs=0.05)  # depth = R - sqrt(R^2 - r^2)
    assert h[~inside].max() == 0 and inside.sum() == pytest.approx(np.pi * 900, rel=0.02)
    assert gx[40, 60] < 0 < gx[40, 40]  # height falls away from the centre


def test_convert_taxim_npz(tmp_path, shared_data):
    import importlib.util

    from vtrack.paths import REPO_ROOT

    spec = importlib.util.spec_from_file_location("conv", REPO_ROOT / "data_tools" / "convert_taxim_npz.py")
    conv = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(conv)
    out = conv.convert(shared_data / "taxim_datapack_small" / "dataPack_small.npz", tmp_path / "small")
    ps = load_press_set(out)
    assert ps.mm_per_px == 0.1245 and len(ps.presses) == 49 and ps.shape == (120, 160)
    with np.load(shared_data / "taxim_datapack_small" / "dataPack_small.npz") as z:
        assert np.array_equal(ps.image(ps.presses[5]), z["imgs"][5])
        assert ps.presses[5].center_xy_px == tuple(float(v) for v in z["touch_center"][5])
    with pytest.raises(InputError):
        conv.convert(tmp_path / "missing.npz", tmp_path / "x")
    shutil.rmtree(out)
