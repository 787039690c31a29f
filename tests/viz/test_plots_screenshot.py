"""pyvista screenshots (image content checked) and the shared matplotlib plots."""

from __future__ import annotations

import numpy as np
import pytest

from vtrack.errors import InputError
from vtrack.viz.colors import TOUCH_RGB, VISION_RGB


def _count_near(img: np.ndarray, rgb, tol: int) -> int:
    return int((np.abs(img.astype(np.int32) - np.array(rgb)).max(-1) <= tol).sum())


@pytest.fixture(scope="module")
def demo_shot(view_fixture, tmp_path_factory):
    import cv2

    from vtrack.viz.screenshot import render_result

    out = render_result(view_fixture["demo"], tmp_path_factory.mktemp("shot") / "demo.png", size=(640, 480))
    return cv2.imread(str(out))[..., ::-1]


def test_screenshot_shows_cloud_mesh_and_panels(demo_shot):
    img = demo_shot
    assert img.shape[0] == 480 and img.shape[1] > 640  # 3D view + tactile panel column
    view = img[:, :640]
    non_white = (np.abs(view.astype(np.int32) - 255).max(-1) > 30).mean()
    assert non_white > 0.02, f"3D view nearly blank ({non_white:.4f})"
    assert _count_near(view, VISION_RGB, 40) > 100  # vision points
    assert _count_near(view, TOUCH_RGB, 40) > 20  # touch points
    panel = img[:, 640:]
    # Height maps are drawn with 'inferno': bright orange/yellow pixels exist only in the panel column.
    assert (panel.astype(np.int32)[..., 0] - panel[..., 2] > 120).sum() > 50
    # Contact masks: pure white blobs on black.
    assert (panel.max(-1) < 10).sum() > 100


def test_screenshot_session_only_and_first_frame(view_fixture, tmp_path):
    import cv2

    from vtrack.viz.screenshot import render_result

    out = render_result(view_fixture["session"], tmp_path / "s.png", frame=0, size=(320, 240))
    img = cv2.imread(str(out))
    assert img.shape[0] == 240
    assert (np.abs(img[:, :320].astype(np.int32) - 255).max(-1) > 30).mean() > 0.01
    with pytest.raises(InputError, match=".png"):
        render_result(view_fixture["session"], tmp_path / "s.jpg")


def test_cli_screenshot_and_bad_path(view_fixture, tmp_path):
    import subprocess
    import sys
    from pathlib import Path

    from typer.testing import CliRunner
    from vtrack_apps.cli import app

    # In-process for the screenshot (heavy modules are already imported), a real process for the error path.
    out = tmp_path / "cli.png"
    args = ["view", str(view_fixture["tracking"]), "--screenshot", str(out), "--size", "320x240"]
    res = CliRunner().invoke(app, args)
    assert res.exit_code == 0, res.output
    assert out.exists() and out.stat().st_size > 1000
    vtrack = Path(sys.executable).parent / "vtrack"
    r = subprocess.run([str(vtrack), "view", str(tmp_path / "nope")], capture_output=True, text=True, timeout=60)
    assert r.returncode == 2
    assert "path does not exist" in r.stderr and "Traceback" not in r.stderr
    from vtrack.viz.screenshot import parse_size

    assert parse_size("640x480") == (640, 480)
    for bad in ("big", "10x10", "640x"):
        with pytest.raises(InputError, match="--size"):
            parse_size(bad)


def test_plots(view_fixture, tmp_path):
    import cv2

    from vtrack.viz.plots import pareto_front, plot_error_over_time, plot_pose_errors, plot_speed_vs_error, pose_errors

    p = plot_pose_errors(view_fixture["tracking"] / "poses.csv", tmp_path / "err.png")
    assert cv2.imread(str(p)) is not None
    t = np.linspace(0, 1, 50)
    e = np.sin(t)
    e[10:15] = np.nan
    p2 = plot_error_over_time(tmp_path / "e2.png", t, {"a": e, "b": e * 2}, ylabel="mm")
    assert cv2.imread(str(p2)).shape[0] > 100
    with pytest.raises(InputError, match="lengths differ"):
        plot_error_over_time(tmp_path / "e3.png", t, {"a": e[:10]})
    rows = [
        {"method": "m1", "setting": s, "ms": ms, "error": err}
        for s, ms, err in (("a", 1.0, 5.0), ("b", 10.0, 2.0), ("c", 20.0, 3.0), ("d", 100.0, 1.0))
    ]
    rows.append({"method": "m2", "setting": "x", "ms": float("nan"), "error": 0.1})
    assert list(pareto_front([r["ms"] for r in rows], [r["error"] for r in rows])) == [True, True, False, True, False]
    assert list(pareto_front([1, 2], [0.9, 0.5], higher_is_better=True)) == [True, False]
    assert cv2.imread(str(plot_speed_vs_error(tmp_path / "p.png", rows))) is not None
    # Translation error is the 0.002 * k / 12 m drift of the fixture's estimate, in mm.
    from vtrack.io.poses import read_pose_table

    d = read_pose_table(view_fixture["tracking"] / "poses.csv")
    trans, rot = pose_errors(d["T_est"], d["T_gt"])
    assert np.allclose(trans, 2.0 * np.arange(12) / 12, atol=1e-4)
    assert np.all(rot < 1e-3)
