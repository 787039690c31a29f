"""`vtrack import ...`, `vtrack record ...`, `vtrack live ...` end to end (in-process CLI runner; one
subprocess checks the user-facing exit status 2 and one-line error)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from vtrack.errors import InputError
from vtrack.io.session import open_session
from vtrack.testing.recordings import write_feelsight, write_mcap, write_tactile_video
from vtrack.testing.sessions import write_live_session


def invoke(*args):
    from vtrack_apps.cli import app

    return CliRunner().invoke(app, [str(a) for a in args])


def test_import_commands_and_clear_errors(tmp_path: Path) -> None:
    src = write_feelsight(tmp_path / "log", n=4)
    res = invoke("import", "feelsight", src, "--out", tmp_path / "s", "--json", tmp_path / "r.json")
    assert res.exit_code == 0, res.output
    assert json.loads((tmp_path / "r.json").read_text())["frames"]["joints"] == 4
    assert open_session(tmp_path / "s").complete
    again = invoke("import", "feelsight", src, "--out", tmp_path / "s")
    assert isinstance(again.exception, InputError) and "exists" in str(again.exception)
    mc = write_mcap(tmp_path / "x.mcap", n=4)
    res = invoke("import", "mcap", mc, "--out", tmp_path / "m", "--map", "/chatter=ignore")
    assert res.exit_code == 0, res.output
    assert "/notes: unsupported encoding" in res.output and "/chatter (std_msgs/msg/String): ignored" in res.output
    # The real console entry point: exit status 2, one line naming the file, no traceback.
    out = subprocess.run(
        [sys.executable, "-m", "vtrack_apps.cli", "import", "rosbag", str(mc), "--out", str(tmp_path / "b")],
        capture_output=True,
        text=True,
        timeout=120,
        env={**os.environ, "OMP_NUM_THREADS": "1"},
    )
    assert out.returncode == 2 and "x.mcap" in out.stderr and "vtrack import mcap" in out.stderr
    assert "Traceback" not in out.stderr


def test_record_commands(tmp_path: Path) -> None:
    vid = write_tactile_video(tmp_path / "d.avi", n=12)
    res = invoke("record", "tactile", "--out", tmp_path / "t", "--camera", f"digit_index={vid}:digit", "--no-realtime")
    assert res.exit_code == 0, res.output
    assert open_session(tmp_path / "t")["tactile/digit_index"].n == 12
    bad = invoke("record", "tactile", "--out", tmp_path / "t2", "--camera", "oops")
    assert isinstance(bad.exception, InputError) and "NAME=SOURCE" in str(bad.exception)
    pytest.importorskip("depthai")
    res = invoke(
        "record", "oak", "--simulate", "--out", tmp_path / "o", "--frames", "6", "--width", "64", "--height", "40"
    )
    assert res.exit_code == 0, res.output
    assert open_session(tmp_path / "o")["camera/oak"].n == 6


def test_live_command(tmp_path: Path) -> None:
    sess = write_live_session(tmp_path / "s", seconds=0.5, cam_hw=(48, 64), tac_hw=(32, 24))
    res = invoke("live", sess, "--consumer", "null", "--json", tmp_path / "live.json")
    assert res.exit_code == 0, res.output
    live = json.loads((tmp_path / "live.json").read_text())
    assert live["source"]["emitted"]["camera/cam0"] + live["source"]["skipped_late"].get("camera/cam0", 0) == 15
    bad = invoke("live", sess, "--consumer", "nonsense")
    assert isinstance(bad.exception, InputError) and "track|reconstruct|null" in str(bad.exception)
    # faster than the recording (what `bench live`'s headroom sweep does): 0.5 s of recording in ~1/4 of the time,
    # every frame scheduled (emitted, or skipped as late on a loaded machine)
    res = invoke("live", sess, "--consumer", "null", "--speed", 4, "--json", tmp_path / "fast.json")
    assert res.exit_code == 0, res.output
    fast = json.loads((tmp_path / "fast.json").read_text())
    assert fast["source"]["emitted"]["camera/cam0"] + fast["source"]["skipped_late"].get("camera/cam0", 0) == 15
    assert 0.08 < fast["active_s"] < 0.5 and fast["cpu"]["session_s"] == pytest.approx(4 * fast["active_s"], rel=1e-2)


def test_live_command_known_shape_and_given_poses(tmp_path: Path) -> None:
    """`vtrack live --consumer track --mesh M --init-pose P` tracks the known shape from that prior;
    `--consumer reconstruct --poses poses.csv` integrates in the object frame of those poses; a bad
    `--init-pose` is one clear error. Replayed at 0.2x: building the known-shape SDF takes the first frames.
    """
    pytest.importorskip("open3d")
    from vtrack.eval.session_gt import SessionGroundTruth
    from vtrack.io.poses import write_poses_csv
    from vtrack.testing.sessions import write_sphere_session

    sess = write_sphere_session(tmp_path / "sphere", seconds=1.0)
    mesh = tmp_path / "sphere_sphere.ply"
    gt = SessionGroundTruth.load(sess)  # scoring / test input only
    write_poses_csv(tmp_path / "poses.csv", gt.pose_times, gt.poses)
    res = invoke(
        "live", sess, "--consumer", "track", "--consumer", "reconstruct", "--mesh", mesh, "--speed", 0.2,
        "--init-pose", tmp_path / "poses.csv", "--poses", tmp_path / "poses.csv", "--json", tmp_path / "live.json",
    )  # fmt: skip
    assert res.exit_code == 0, res.output
    cons = json.loads((tmp_path / "live.json").read_text())["consumers"]
    tr, rc = cons["track"]["result"], cons["reconstruct"]["result"]
    assert tr["mode"] == "known_shape" and tr["steps"] >= 5
    assert tr["add_s_mm"] < 3.0  # a sphere: ADD-S (its spin is unobservable)
    # the offline loss check runs live too; on a clean replay a re-registration never replaces the tracker
    assert tr["reloc_successes"] == 0 and tr["reloc_attempts"] >= 0
    assert rc["integrated"] >= 5 and rc["mesh_vertices"] > 50
    bad = invoke("live", sess, "--consumer", "track", "--mesh", mesh, "--init-pose", "1,2,3")
    assert isinstance(bad.exception, InputError) and "--init-pose" in str(bad.exception)


def test_live_known_shape_uses_the_offline_contact_weight_and_loss_check(tmp_path: Path) -> None:
    """The live known-shape tracker weighs image contacts as offline `track_session` does with vision + touch
    (sigma 3 mm, the weak-vision regime) and carries the same re-localisation."""
    pytest.importorskip("open3d")
    from vtrack.live.consumers import TrackConsumer
    from vtrack.testing.sessions import write_sphere_session
    from vtrack.tracking.run import KNOWN_SIGMA_TOUCH_WITH_VISION, KNOWN_TOUCH_WEAK_VISION, Relocalisation

    sess = write_sphere_session(tmp_path / "sphere", seconds=0.2)
    tc = TrackConsumer(
        sess, mesh=tmp_path / "sphere_sphere.ply", init_pose=np.eye(4), touch_worker="off", frames_worker="inline"
    )
    assert "touch" in tc.sf.modalities
    tc._start(tc.sf.build(tc.sf.read(0)).tracking_frame())
    assert tc.tracker.opts.sigma_touch == KNOWN_SIGMA_TOUCH_WITH_VISION
    assert (tc.tracker.opts.touch_weak_vision, tc.tracker.opts.sigma_touch_weak) == KNOWN_TOUCH_WEAK_VISION
    assert isinstance(tc.reloc, Relocalisation)
    slam = TrackConsumer(sess, touch_worker="off", frames_worker="inline")
    assert slam.reloc is None


def test_live_command_rejects_an_unknown_touch_worker(tmp_path: Path) -> None:
    from vtrack.testing.sessions import write_sphere_session

    sess = write_sphere_session(tmp_path / "sphere", seconds=0.2)
    bad = invoke("live", sess, "--consumer", "track", "--touch-worker", "gpu")
    assert isinstance(bad.exception, InputError) and "touch_worker" in str(bad.exception)
