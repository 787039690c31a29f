"""Recorders without hardware: OAK-D through a host-only depthai pipeline, tactile cameras from a
video file, joint-state sources, and crash safety under SIGKILL."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from vtrack.errors import InputError
from vtrack.io.session import open_session
from vtrack.testing.recordings import video_frame, write_tactile_video


def test_oak_host_pipeline_records_synced_rgbd_imu_and_calibration(tmp_path):
    pytest.importorskip("depthai")
    from vtrack.io.recorders.oakd import OakConfig, record_oak_simulated, synthetic_frame

    cfg = OakConfig(name="oak", width=64, height=40, fps=30.0, imu=True)
    stats = record_oak_simulated(tmp_path / "s", cfg, n_frames=20, flush_every=4, status=False)
    s = open_session(tmp_path / "s")
    cam = s["camera/oak"]
    assert s.complete and cam.n == stats.written["camera/oak"]
    # Every written frame is one of the synthetic frames, in order, at its device timestamp.
    idx = [int(cam["rgb"][k][0, -1, 0]) for k in range(cam.n)]
    assert idx == sorted(idx) and cam.n + stats.dropped.get("camera/oak", 0) == 20
    for k, i in enumerate(idx):
        bgr, depth = synthetic_frame(i, 64, 40)
        np.testing.assert_array_equal(cam["rgb"][k], bgr[..., ::-1])  # stored as RGB
        np.testing.assert_array_equal(cam["depth"][k], depth)
        assert cam.t[k] == pytest.approx(10.0 + i / 30.0, abs=1e-6)
    cal = cam.attrs["calibration"]
    np.testing.assert_allclose(cam.attrs["K"], [[51.2, 0, 32], [0, 51.2, 20], [0, 0, 1]])
    np.testing.assert_allclose(np.asarray(cal["T_rgb_left"])[:3, 3], [0.0375, 0, 0])  # cm -> m
    imu = s["imu/oak"]
    assert imu.n >= 4 * (cam.n - 1)
    np.testing.assert_allclose(imu["accel"][0], [0, 0, 9.81], atol=1e-5)
    assert np.all(np.diff(imu.t) > 0)
    assert s.scene().cameras[0].name == "oak"


def test_oak_group_conversion_rejects_misaligned_depth():
    dai = pytest.importorskip("depthai")
    from vtrack.io.recorders.oakd import group_to_frame

    class G(dict):
        pass

    f = dai.ImgFrame()
    f.setCvFrame(np.zeros((40, 64, 3), np.uint8), dai.ImgFrame.Type.BGR888i)
    d = dai.ImgFrame()
    d.setFrame(np.zeros((20, 32), np.uint16))
    d.setType(dai.ImgFrame.Type.RAW16)
    d.setWidth(32)
    d.setHeight(20)
    with pytest.raises(InputError, match="not aligned"):
        group_to_frame(G(rgb=f, depth=d))


def test_tactile_recorder_from_video_file_with_csv_joints(tmp_path):
    from vtrack.io.recorders.joints import CsvJointSource
    from vtrack.io.recorders.tactile import TactileCamera, record_tactile

    vid = write_tactile_video(tmp_path / "digit.avi", n=24)
    names = [f"joint_{j}.0" for j in range(16)]
    rows = ["t," + ",".join(names)] + [f"{k / 100:.2f}," + ",".join(["0.5"] * 16) for k in range(60)]
    (tmp_path / "q.csv").write_text("\n".join(rows) + "\n")
    stats = record_tactile(
        tmp_path / "s",
        [TactileCamera("digit_index", str(vid), "digit")],
        joints=CsvJointSource(tmp_path / "q.csv"),
        flush_every=5,
        status=False,
        realtime=False,
    )
    s = open_session(tmp_path / "s")
    tac = s["tactile/digit_index"]
    assert tac.n == 24 == stats.written["tactile/digit_index"]
    assert tac["image"].shape[1:] == (320, 240, 3)  # DIGIT landscape frames stored portrait
    import cv2

    for i in (0, 7, 23):
        np.testing.assert_array_equal(tac["image"][i], cv2.rotate(video_frame(i), cv2.ROTATE_90_CLOCKWISE))
    assert tac.t[1] - tac.t[0] == pytest.approx(1 / 60, abs=1e-3)
    j = s["joints"]
    # Media clock: CSV rows up to the last frame time (23/60 s = 0.383 s) -> t = 0.00 ... 0.38
    assert j.n == 39 and j.attrs["joint_names"] == names
    assert (j.t - j.t[0])[1] == pytest.approx(0.01, abs=1e-6)  # CSV times kept (relative to start)
    sc = s.scene()
    assert (sc.tactile[0].width, sc.tactile[0].height, sc.tactile[0].type) == (240, 320, "digit")


def test_tactile_source_errors(tmp_path):
    from vtrack.io.recorders.joints import CsvJointSource
    from vtrack.io.recorders.tactile import TactileCamera, record_tactile, resolve_source

    with pytest.raises(InputError, match="nope.avi"):
        resolve_source(str(tmp_path / "nope.avi"))
    with pytest.raises(InputError, match="serial"):
        resolve_source("serial:D20999-does-not-exist")
    (tmp_path / "bad.avi").write_bytes(b"\x00" * 100)
    with pytest.raises(InputError):
        record_tactile(tmp_path / "s", [TactileCamera("d", str(tmp_path / "bad.avi"))], status=False)
    (tmp_path / "q.csv").write_text("t,a,b\n0.1,1,2\n0.1,1,2\n")
    with pytest.raises(InputError, match="q.csv.*increasing"):
        CsvJointSource(tmp_path / "q.csv")
    (tmp_path / "q2.csv").write_text("t,a,b\n0.1,1,nan\n")
    with pytest.raises(InputError, match="q2.csv"):
        CsvJointSource(tmp_path / "q2.csv")
    (tmp_path / "q3.csv").write_text("a,b\n1,2\n")
    with pytest.raises(InputError, match="q3.csv.*header"):
        CsvJointSource(tmp_path / "q3.csv")


def _committed(session, stream):
    p = session / "data.zarr" / stream / "zarr.json"
    try:
        return int(json.loads(p.read_text())["attributes"]["n_committed"])
    except (FileNotFoundError, KeyError, json.JSONDecodeError):
        return 0


def test_sigkill_mid_recording_keeps_every_flushed_frame(tmp_path):
    """kill -9 a real `vtrack record tactile` process; the session opens and holds every frame up
    to the last flush, bit-exact."""
    import cv2

    vid = write_tactile_video(tmp_path / "digit.avi", n=600)  # 10 s at 60 fps, paced in real time
    out = tmp_path / "rec"
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "vtrack_apps.cli",
            "record",
            "tactile",
            "--out",
            str(out),
            "--camera",
            f"digit_index={vid}:digit",
            "--flush-every",
            "5",
        ],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        env=env,
    )
    try:
        t_end = time.time() + 60
        seen = 0
        while time.time() < t_end and seen < 40 and proc.poll() is None:
            seen = _committed(out, "tactile/digit_index")
            time.sleep(0.02)
        assert proc.poll() is None, proc.stderr.read().decode()[-2000:]
        assert seen >= 40
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(10)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == -signal.SIGKILL
    s = open_session(out)
    tac = s["tactile/digit_index"]
    assert not s.complete
    assert tac.n >= seen and tac.n % 5 == 0 and tac.n < 600
    # Frames are stamped with the file's frame times, so each stored frame names its source frame
    # (a real-time recorder may drop frames when the machine is busy; none may be corrupted).
    idx = np.rint((tac.t - tac.t[0]) * 60.0).astype(int)
    assert np.all(np.diff(idx) > 0)
    for k in range(tac.n):
        np.testing.assert_array_equal(tac["image"][k], cv2.rotate(video_frame(idx[k]), cv2.ROTATE_90_CLOCKWISE))
