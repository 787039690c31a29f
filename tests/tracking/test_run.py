"""End to end on a simulated session: track_session result folders, CLI, modes."""

import csv
import json

import numpy as np
import pytest

from vtrack.errors import InputError


@pytest.fixture(scope="module")
def known_run(tiny_session, tmp_path_factory):
    from vtrack.tracking.run import track_session

    out = tmp_path_factory.mktemp("track_known")
    return out, track_session(tiny_session, out)


def test_known_shape_result_folder(known_run):
    out, m = known_run
    for f in ("poses.csv", "metrics.json", "result.json", "error.png"):
        assert (out / f).exists(), f
    disk = json.loads((out / "metrics.json").read_text())
    for k in ("add_s_mm", "drift_mm", "rot_drift_deg", "ms_per_frame_mean", "mode", "modalities"):
        assert k in disk
    assert disk["mode"] == "known" and disk["modalities"] == ["vision", "touch"]
    assert m["drift_mm"] < 2.3 and m["add_s_mm"] < 3.0
    assert json.loads((out / "result.json").read_text())["kind"] == "tracking"
    rows = list(csv.DictReader(open(out / "poses.csv")))
    assert len(rows) == m["frames"] > 10
    assert {"t", "x", "y", "z", "qx", "qy", "qz", "qw", "gt_x", "gt_qw", "status"} <= set(rows[0])
    q = np.array([[float(r[k]) for k in ("qx", "qy", "qz", "qw")] for r in rows])
    assert np.allclose(np.linalg.norm(q, axis=1), 1, atol=1e-5)


@pytest.mark.parametrize("kw", [dict(shape="slam"), dict(method="icp"), dict(modalities=("touch",)),
                                dict(init_perturb=(0.005, 0.05))])
def test_other_modes(tiny_session, kw):
    from vtrack.tracking.run import track_session

    m = track_session(tiny_session, "", write=False, **kw)
    assert np.isfinite(m["drift_mm"]) and m["frames"] > 10
    assert m["drift_mm"] < (4.7 if kw.get("shape") == "slam" else 5.0)


def test_cli(tiny_session, tmp_path):
    from typer.testing import CliRunner
    from vtrack_apps.cli import app

    r = CliRunner().invoke(app, ["track", str(tiny_session), "--modalities", "vision", "--window", "2",
                                 "--max-frames", "8", "--out", str(tmp_path / "o"), "--json", str(tmp_path / "m.json")])
    assert r.exit_code == 0, r.output
    m = json.loads((tmp_path / "m.json").read_text())
    assert m["frames"] == 8 and m["modalities"] == ["vision"]
    bad = CliRunner().invoke(app, ["track", str(tiny_session), "--modalities", "smell", "--out", str(tmp_path)])
    assert isinstance(bad.exception, InputError)


def test_bad_session(tmp_path):
    from vtrack.tracking.run import track_session

    with pytest.raises(InputError):
        track_session(tmp_path / "missing", tmp_path / "out")
    with pytest.raises(InputError):
        track_session(tmp_path, tmp_path / "out", shape="banana")
