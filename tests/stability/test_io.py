"""Hard cases for recording and importing: kills at any moment, odd ROS encodings, degenerate
FeelSight logs, degenerate replays."""

from __future__ import annotations

import os
import pickle
import signal
import subprocess
import sys
import time
from types import SimpleNamespace

import numpy as np
import pytest

from vtrack.errors import InputError
from vtrack.io.session import open_session
from vtrack.testing.recordings import video_frame, write_feelsight, write_tactile_video

pytestmark = pytest.mark.stability


@pytest.mark.parametrize("delay", [0.05, 1.5])
def test_sigkill_at_any_moment_leaves_an_openable_or_absent_session(tmp_path, delay):
    """Killed before the writer exists -> no session (clear error); killed later -> every committed
    frame readable and exact."""
    import cv2

    vid = write_tactile_video(tmp_path / "v.avi", n=400)
    out = tmp_path / "rec"
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
            f"d={vid}:digit",
            "--flush-every",
            "3",
        ],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        env={**os.environ, "OMP_NUM_THREADS": "1"},
    )
    time.sleep(delay)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait(10)
    if not (out / "manifest.json").exists():
        with pytest.raises(InputError, match="rec"):
            open_session(out)
        return
    s = open_session(out)
    assert not s.complete
    if "tactile/d" in s:
        tac = s["tactile/d"]
        assert tac.n % 3 == 0
        idx = np.rint((tac.t - tac.t[0]) * 60.0).astype(int) if tac.n else []
        for k in range(tac.n):
            np.testing.assert_array_equal(tac["image"][k], cv2.rotate(video_frame(idx[k]), cv2.ROTATE_90_CLOCKWISE))


def _img(enc, h, w, data, step, big=0):
    return SimpleNamespace(
        encoding=enc, height=h, width=w, step=step, is_bigendian=big, data=np.frombuffer(data, np.uint8)
    )


def test_ros_image_decoding_edge_cases():
    from vtrack.io.importers.ros_messages import decode_image
    from vtrack.io.streams import encode_depth

    d = np.arange(12, dtype=">u2").reshape(3, 4)  # big-endian 16UC1
    out = decode_image(_img("16UC1", 3, 4, d.tobytes(), 8, big=1), "sensor_msgs/msg/Image", "t")
    np.testing.assert_array_equal(out, np.arange(12).reshape(3, 4))
    padded = np.zeros((2, 8), np.uint8)  # rows padded to 8 bytes, 2 px of rgb8
    padded[:, :6] = np.arange(6)
    out = decode_image(_img("rgb8", 2, 2, padded.tobytes(), 8), "sensor_msgs/Image", "t")
    np.testing.assert_array_equal(out[1, 1], [3, 4, 5])
    f = np.array([[0.5, np.nan], [np.inf, -1.0]], np.float32)
    out = encode_depth(decode_image(_img("32FC1", 2, 2, f.tobytes(), 8), "sensor_msgs/msg/Image", "t"))
    np.testing.assert_array_equal(out, [[500, 0], [0, 0]])
    with pytest.raises(InputError, match="truncated"):
        decode_image(_img("rgb8", 4, 4, b"\x00" * 10, 12), "sensor_msgs/msg/Image", "bag:/cam")
    with pytest.raises(InputError, match="encoding"):
        decode_image(_img("yuv422", 2, 2, b"\x00" * 8, 4), "sensor_msgs/msg/Image", "bag:/cam")
    bad = SimpleNamespace(format="jpeg", data=np.frombuffer(b"notajpeg", np.uint8))
    with pytest.raises(InputError, match="compressed"):
        decode_image(bad, "sensor_msgs/msg/CompressedImage", "bag:/cam")


def test_feelsight_degenerate_logs(tmp_path):
    from vtrack.io.importers.feelsight import import_feelsight

    src = write_feelsight(tmp_path / "a", n=6)
    data = pickle.loads((src / "data.pkl").read_bytes())
    data["time"][3] = data["time"][2]  # repeated timestamp
    data["allegro"]["joint_state"][4, 2] = np.nan  # sensor glitch
    (src / "data.pkl").write_bytes(pickle.dumps(data))
    rep = import_feelsight(src, tmp_path / "s")
    s = open_session(tmp_path / "s")
    assert rep.skipped["frames with non-increasing time"] == 1
    assert rep.skipped["joint rows with NaN/Inf"] == 1
    assert s["camera/front-left"].n == 5 and s["joints"].n == 4
    assert np.all(np.isfinite(s["joints"]["q"][:]))
    data["time"] = np.array([])
    (src / "data.pkl").write_bytes(pickle.dumps(data))
    with pytest.raises(InputError, match="data.pkl"):
        import_feelsight(src, tmp_path / "s2")
    (src / "data.pkl").write_bytes(pickle.dumps([1, 2, 3]))
    with pytest.raises(InputError, match="data.pkl.*dict"):
        import_feelsight(src, tmp_path / "s3")
    src2 = write_feelsight(tmp_path / "b", n=6)
    (src2 / "allegro" / "index" / "image" / "5.jpg").unlink()  # missing frame
    with pytest.raises(InputError, match="allegro/index/image"):
        import_feelsight(src2, tmp_path / "s4")


def test_replay_of_single_frame_and_empty_streams(tmp_path):
    from vtrack.io.session import SessionWriter
    from vtrack.io.streams import joints_stream
    from vtrack.live.pipeline import LivePipeline
    from vtrack.live.sources import SessionReplaySource

    with SessionWriter(tmp_path / "s", {"name": "x"}) as w:
        w.add_stream("joints", joints_stream(["a"]))
        w.add_stream("tactile/empty", joints_stream(["b"]))
        w.append("joints", 5.0, q=np.array([0.1]))
    res = LivePipeline(SessionReplaySource(tmp_path / "s"), []).run()
    so = res["source"]
    assert so["emitted"].get("joints", 0) + so["skipped_late"].get("joints", 0) == 1
    assert set(so["emitted"]) <= {"joints"}
    with pytest.raises(InputError, match="nothing to replay"):
        SessionReplaySource(tmp_path / "s", streams=["tactile/empty"])


def test_process_reader_replays_the_same_frames(tmp_path):
    from vtrack.live.pipeline import LivePipeline
    from vtrack.live.sources import SessionReplaySource
    from vtrack.testing.sessions import write_live_session

    live_session = write_live_session(tmp_path / "s", seconds=1.0, cam_hw=(48, 64), tac_hw=(32, 24))
    from vtrack.live.consumers import NullConsumer

    src = SessionReplaySource(live_session, streams=["joints", "tactile/digit_index"], reader="process", speed=2.0)
    res = LivePipeline(src, [NullConsumer()]).run()
    so = res["source"]
    assert so["emitted"].get("joints", 0) + so["skipped_late"].get("joints", 0) == 60
    assert so["emitted"]["joints"] >= 30
    with pytest.raises(InputError, match="reader"):
        SessionReplaySource(live_session, reader="fiber")
