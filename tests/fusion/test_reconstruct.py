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
def tsdf_result(tiny_session, blind_session, tmp_path_factory):
    """TSDF on the session WITHOUT ground truth: poses from SLAM tracking, scored against the original."""
    from vtrack.fusion.reconstruct import reconstruct_session

    out = tmp_path_factory.mktemp("rec_tsdf")
    return out, reconstruct_session(blind_session, out, method="tsdf", gt=tiny_session)


def test_tsdf_blind_session_result_folder(tsdf_result):
    out, m = tsdf_result
    for f in ("mesh.ply", "poses.csv", "cloud.ply", "metrics.json", "result.json", "screenshot.png"):
        assert (out / f).exists(), f
    disk = json.loads((out / "metrics.json").read_text())
    assert KEYS <= set(disk)
    assert set(disk["fscore"]) == {"1mm", "2mm", "5mm", "10mm"}
    assert disk["method"] == "tsdf" and disk["modalities"] == ["vision", "touch"]
    assert disk["tactile_source"] == "pipeline" and disk["segmentation"] == "pipeline" and disk["blind"]
    assert disk["poses"] == "tracking (slam)" and disk["alignment"] == "first_frame"
    assert 0.5 < disk["fscore"]["5mm"] <= 1.0 and disk["precision"] > 0.7
    assert json.loads((out / "result.json").read_text())["kind"] == "reconstruction"
    cloud = read_ply_points(out / "cloud.ply")
    mods = set(np.unique(cloud["modality"]).tolist())
    assert mods == {0, 1}, "both modalities (touch from tactile images) in the unified cloud"
    assert np.isfinite(cloud["x"]).all()


def test_poses_file_reproduces_the_tracked_reconstruction(tsdf_result, blind_session, tmp_path):
    """poses.csv + mesh.ply place the object in the world; fusing with that file gives the same mesh."""
    from vtrack.fusion.reconstruct import reconstruct_session
    from vtrack.io.mesh import load_mesh
    from vtrack.io.poses import read_poses_csv

    out, m = tsdf_result
    tr = read_poses_csv(out / "poses.csv")
    assert len(tr) == len(read_poses_csv(out / "tracking" / "poses.csv").t[::2])
    m2 = reconstruct_session(blind_session, tmp_path, method="tsdf", poses=out / "poses.csv", screenshot=False)
    assert m2["poses"].startswith("file") and m2["fscore"] is None  # blind and nothing to score against
    Va, Vb = load_mesh(out / "mesh.ply")[0], load_mesh(tmp_path / "mesh.ply")[0]
    assert len(Va) > 100 and abs(len(Va) - len(Vb)) <= 0.01 * len(Va)
    from scipy.spatial import cKDTree

    # the file rounds poses to 0.1 um / 1e-7: the same surface to far below a voxel (Open3D orders vertices freely)
    assert np.percentile(cKDTree(Va).query(Vb)[0], 99) < 1e-4


def test_oracle_poses_are_labelled(tiny_session, tmp_path):
    from vtrack.fusion.reconstruct import reconstruct_session

    m = reconstruct_session(tiny_session, tmp_path, method="tsdf", poses="gt", screenshot=False)
    assert m["oracle"] == ["poses"] and not m["blind"] and m["alignment"] == "mesh"
    assert m["fscore"]["5mm"] > 0.6


def test_touch_only_session_is_partial_but_on_surface(tiny_session, tmp_path):
    from vtrack.fusion.reconstruct import reconstruct_session

    m = reconstruct_session(tiny_session, tmp_path, method="tsdf", modalities="touch", poses="gt", screenshot=False)
    assert m["points"]["vision"] == 0 and m["points"]["touch"] > 0
    assert m["precision"] > 0.5 and m["recall"] < 0.6


def test_neural_sdf_session_and_cli(tiny_session, blind_session, tmp_path):
    from typer.testing import CliRunner
    from vtrack_apps.cli import app

    r = CliRunner().invoke(
        app,
        [
            "reconstruct",
            str(blind_session),
            "--out",
            str(tmp_path / "n"),
            "--method",
            "neural_sdf",
            "--iters",
            "60",
            "--no-screenshot",
            "--gt",
            str(tiny_session),
            "--json",
            str(tmp_path / "m.json"),
        ],
    )
    assert r.exit_code == 0, r.output
    m = json.loads((tmp_path / "m.json").read_text())
    assert KEYS <= set(m) and m["method"] == "neural_sdf" and m["iterations"] == 60 and m["blind"]
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
    code = (
        "import sys\n"
        "from vtrack.fusion.reconstruct import reconstruct_session\n"
        f"reconstruct_session({str(tiny_session)!r}, {str(tmp_path)!r}, method='tsdf', poses='gt', "
        "screenshot=False)\n"
        "assert 'torch' not in sys.modules, 'torch imported'\n"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]


def test_pose_refinement_writes_the_corrected_poses(tiny_session, tmp_path):
    """pose_rounds=1: poses.csv holds the refined poses (first frame unchanged), the metrics say what moved."""
    from vtrack.eval.session_gt import SessionGroundTruth
    from vtrack.fusion.reconstruct import reconstruct_session
    from vtrack.io.poses import read_poses_csv

    m = reconstruct_session(
        tiny_session,
        tmp_path,
        "neural_sdf",
        "vision",
        poses="gt",
        frame_step=5,
        n_iters=20,
        pose_rounds=1,
        pose_iters=20,
        mesh_cell_mm=4.0,
        screenshot=False,
    )
    rounds = m["pose_refine"]["rounds"]
    assert len(rounds) == 1 and rounds[0]["frames"] > 1 and np.isfinite(rounds[0]["shift_mm_max"])
    tr = read_poses_csv(tmp_path / "poses.csv")
    gt = SessionGroundTruth.load(tiny_session)
    T_gt = gt.poses_at(tr.t)
    assert np.allclose(tr.T[0], T_gt[0], atol=1e-5)
    # GT poses only need small corrections (< 2 cm anywhere), and every pose is rigid and finite
    assert np.all(np.isfinite(tr.T)) and np.max(np.linalg.norm(tr.T[:, :3, 3] - T_gt[:, :3, 3], axis=1)) < 0.02


def test_colour_grow_flag_reaches_tracking_and_is_checked(tmp_path, monkeypatch):
    """``vtrack reconstruct --colour-grow N`` hands the segmenter option to tracking (with the second pass when given);
    a negative value, or growth without tracked poses, is an InputError naming the flag."""
    from typer.testing import CliRunner
    from vtrack_apps.cli import app

    import vtrack.fusion.reconstruct as rec

    seen = {}

    class Stop(Exception):
        pass

    def fake(session, out, **kw):
        seen.update(kw)
        raise Stop

    monkeypatch.setattr(rec, "reconstruct_session", fake)
    base = ["reconstruct", str(tmp_path), "--out", str(tmp_path / "o")]
    r = CliRunner().invoke(app, [*base, "--colour-grow", "1", "--second-pass", "2"])
    assert isinstance(r.exception, Stop)
    # the CLI's frame prefetch (default auto; the library's default is off) goes along with the tracking options
    assert seen["track_opts"] == {
        "second_pass_s": 2.0,
        "segmentation_opts": {"colour_grow_px": 1},
        "prefetch": "auto",
    }
    seen.clear()
    r = CliRunner().invoke(app, base)
    assert isinstance(r.exception, Stop) and seen["track_opts"] == {"prefetch": "auto"}
    from vtrack.errors import InputError

    for extra in (["--colour-grow", "-1"], ["--colour-grow", "1", "--poses", "gt"]):
        r = CliRunner().invoke(app, [*base, *extra])
        # InputError: the entry point prints it as one line and exits 2 (tests/hostile)
        assert isinstance(r.exception, InputError) and "--colour-grow" in str(r.exception), r.output
