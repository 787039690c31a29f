"""End to end on a tiny simulator session: result folder, metrics keys, CLI, lazy imports."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from vtrack.io.export import read_ply_points

KEYS = {"fscore", "precision", "recall", "chamfer_mm", "seconds", "modalities", "method"}


@pytest.fixture(scope="module")
def tsdf_result(tiny_session, tmp_path_factory):
    from vtrack.fusion.reconstruct import reconstruct_session

    out = tmp_path_factory.mktemp("rec_tsdf")
    return out, reconstruct_session(tiny_session, out, method="tsdf")


def test_tsdf_session_result_folder(tsdf_result):
    out, m = tsdf_result
    for f in ("mesh.ply", "cloud.ply", "metrics.json", "result.json", "screenshot.png"):
        assert (out / f).exists(), f
    disk = json.loads((out / "metrics.json").read_text())
    assert KEYS <= set(disk)
    assert set(disk["fscore"]) == {"1mm", "2mm", "5mm", "10mm"}
    assert disk["method"] == "tsdf" and disk["modalities"] == ["vision", "touch"]
    assert disk["tactile_source"] == "gt"
    assert 0.5 < disk["fscore"]["5mm"] <= 1.0 and disk["precision"] > 0.8
    assert json.loads((out / "result.json").read_text())["kind"] == "reconstruction"
    cloud = read_ply_points(out / "cloud.ply")
    mods = set(np.unique(cloud["modality"]).tolist())
    assert mods == {0, 1}, "both modalities in the unified cloud"
    assert np.isfinite(cloud["x"]).all()


def test_touch_only_session_is_partial_but_on_surface(tiny_session, tmp_path):
    from vtrack.fusion.reconstruct import reconstruct_session

    m = reconstruct_session(tiny_session, tmp_path, method="tsdf", modalities="touch", screenshot=False)
    assert m["points"]["vision"] == 0 and m["points"]["touch"] > 0
    assert m["precision"] > 0.7 and m["recall"] < 0.6


def test_neural_sdf_session_and_cli(tiny_session, tmp_path):
    from typer.testing import CliRunner
    from vtrack_apps.cli import app

    r = CliRunner().invoke(app, ["reconstruct", str(tiny_session), "--out", str(tmp_path / "n"), "--method",
                                 "neural_sdf", "--iters", "60", "--no-screenshot", "--json",
                                 str(tmp_path / "m.json")])
    assert r.exit_code == 0, r.output
    m = json.loads((tmp_path / "m.json").read_text())
    assert KEYS <= set(m) and m["method"] == "neural_sdf" and m["iterations"] == 60
    assert m["fscore"]["10mm"] > 0.5


def test_bad_input_is_one_line_error(tmp_path):
    from typer.testing import CliRunner
    from vtrack_apps.cli import app

    r = CliRunner().invoke(app, ["reconstruct", str(tmp_path / "nope"), "--out", str(tmp_path / "o")])
    assert r.exit_code != 0
    from vtrack.errors import InputError
    from vtrack.fusion.reconstruct import reconstruct_session

    with pytest.raises(InputError):
        reconstruct_session(tmp_path / "nope", tmp_path / "o")
    with pytest.raises(InputError):
        reconstruct_session(tmp_path / "nope", tmp_path / "o", modalities="smell")


def test_tsdf_session_path_does_not_import_torch(tiny_session, tmp_path):
    code = ("import sys\n"
            "from vtrack.fusion.reconstruct import reconstruct_session\n"
            f"reconstruct_session({str(tiny_session)!r}, {str(tmp_path)!r}, method='tsdf', screenshot=False)\n"
            "assert 'torch' not in sys.modules, 'torch imported'\n")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
