"""strip-gt removes every trace of ground truth; poses.csv round trip and bad input."""

from __future__ import annotations

import json

import numpy as np
import pytest

from vtrack.errors import InputError


def test_strip_removes_all_ground_truth(tiny_session, blind_session):
    from vtrack.io.session import open_session

    r = open_session(blind_session)
    assert not [k for k in r.streams if k.startswith("gt")]
    assert not (blind_session / "gt").exists() and not (blind_session / "data.zarr" / "gt").exists()
    for k, s in r.streams.items():
        assert "mask" not in s.fields and "height_mm" not in s.fields, k
    man = json.loads((blind_session / "manifest.json").read_text())
    assert man["scene"]["object"]["mesh"] is None and man["scene"]["object"]["T_world_object"] is None
    assert "T_source_object" not in man["created"] and "object_source" not in man["created"]
    assert "gt_files" not in man
    # what a recording has is kept, frame for frame
    o = open_session(tiny_session)
    for k in ("joints", "camera/cam0", "tactile/digit_index"):
        assert r[k].n == o[k].n
    assert np.array_equal(r["camera/cam0"]["depth"][3], o["camera/cam0"]["depth"][3])
    # the calibrations are part of a recording
    sc = r.scene()
    assert all(t.calibration is not None and t.calibration.is_file() for t in sc.tactile)


def test_generated_session_keeps_gt_under_gt(tiny_session):
    from vtrack.io.session import open_session

    r = open_session(tiny_session)
    assert "mask" not in r["camera/cam0"].fields and "mask" in r["gt/camera/cam0"].fields
    assert (tiny_session / "gt" / "object.ply").is_file() and not (tiny_session / "assets" / "object.ply").exists()
    sc = r.scene()
    assert sc.object.mesh is None and sc.object.T_world_object is None


def test_strip_refuses_to_replace_user_folders(tiny_session, tmp_path):
    from vtrack.io.strip import strip_gt

    d = tmp_path / "d"
    d.mkdir()
    (d / "notes.txt").write_text("x")
    with pytest.raises(InputError, match="exists"):
        strip_gt(tiny_session, d)
    with pytest.raises(InputError, match="not a vtrack session"):
        strip_gt(tiny_session, d, overwrite=True)
    assert (d / "notes.txt").read_text() == "x"
    with pytest.raises(InputError, match="inside the source"):
        strip_gt(tiny_session, tiny_session / "sub")


def test_strip_cli(tiny_session, tmp_path):
    from typer.testing import CliRunner
    from vtrack_apps.cli import app

    r = CliRunner().invoke(app, ["session", "strip-gt", str(tiny_session), "--out", str(tmp_path / "b")])
    assert r.exit_code == 0, r.output
    assert "gt/object_pose" in r.output and (tmp_path / "b" / "manifest.json").is_file()


def test_poses_csv_round_trip_and_interpolation(tmp_path):
    from vtrack.geometry import se3
    from vtrack.io.poses import parse_pose, read_poses_csv, write_poses_csv

    t = np.array([0.0, 0.1, 0.2])
    T = np.stack([se3.make_transform(se3.so3_exp(np.array([0, 0, a])), np.array([a, 0, 0])) for a in (0, 0.2, 0.4)])
    write_poses_csv(tmp_path / "p.csv", t, T, extra={"status": ["ok"] * 3})
    tr = read_poses_csv(tmp_path / "p.csv")
    assert np.allclose(tr.T, T, atol=1e-6) and np.allclose(tr.t, t)
    mid = tr.at(np.array([0.05, -1.0, 9.0]))
    assert np.allclose(mid[0][:3, 3], [0.1, 0, 0], atol=1e-6)
    assert np.isclose(se3.rotation_angle(mid[0][:3, :3]), 0.1, atol=1e-6)
    assert np.allclose(mid[1], T[0]) and np.allclose(mid[2], T[2])  # held outside the range
    assert np.allclose(parse_pose(str(tmp_path / "p.csv")), T[0], atol=1e-6)
    assert np.allclose(parse_pose("1,2,3,0,0,0,1")[:3, 3], [1, 2, 3])


@pytest.mark.parametrize(
    "text,match",
    [
        ("t,x\n1,2\n", "header"),
        ("t,x,y,z,qx,qy,qz,qw\n0,0,0,0,0,0,0,0\n", "zero"),
        ("t,x,y,z,qx,qy,qz,qw\n0,a,0,0,0,0,0,1\n", "row 2 holds a non-numeric value 'a'"),
        ("t,x,y,z,qx,qy,qz,qw\n1,0,0,0,0,0,0,1\n0,0,0,0,0,0,0,1\n", "increasing"),
        ("t,x,y,z,qx,qy,qz,qw\n", "no rows"),
    ],
)
def test_bad_poses_file(tmp_path, text, match):
    from vtrack.io.poses import read_poses_csv

    p = tmp_path / "p.csv"
    p.write_text(text)
    with pytest.raises(InputError, match=match):
        read_poses_csv(p)
