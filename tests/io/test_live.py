"""Live pipeline: real-time session replay, drop-not-queue consumers, tracking / TSDF per frame."""

from __future__ import annotations

import time

import numpy as np
import pytest

from vtrack.errors import InputError
from vtrack.live.pipeline import Consumer, LivePipeline
from vtrack.live.sources import SessionReplaySource
from vtrack.testing.sessions import write_live_session, write_sphere_session


@pytest.fixture(scope="module")
def live_session(tmp_path_factory):
    # Real sizes: 640x480 RGB-D at 30 Hz, 4 DIGIT 240x320 at 60 Hz, joints at 60 Hz.
    return write_live_session(tmp_path_factory.mktemp("live") / "s", seconds=1.0)


class Slow(Consumer):
    """Takes 50 ms per camera frame (a consumer slower than the 30 Hz input)."""

    name = "slow"

    def __init__(self) -> None:
        self.seen: list[int] = []

    def wants(self, stream: str) -> bool:
        return stream.startswith("camera/")

    def process(self, ev) -> None:
        self.seen.append(ev.index)
        time.sleep(0.05)


def test_replay_keeps_real_time_rate(live_session):
    from vtrack.live.consumers import NullConsumer

    src = SessionReplaySource(live_session)
    res = LivePipeline(src, [NullConsumer()]).run()
    so = res["source"]
    total = {"camera/cam0": 30, "tactile/digit_index": 60, "joints": 60}
    for k, n in total.items():
        assert so["emitted"].get(k, 0) + so["skipped_late"].get(k, 0) == n
        assert so["emitted"][k] >= 0.8 * n  # keeps up (noisy shared machine: allow some skips)
    # Real time: 1 s of data takes ~1 s (not faster, and not much slower).
    assert 0.9 <= res["active_s"] <= 1.3
    assert so["emitted_rate_hz"]["camera/cam0"] == pytest.approx(30.0, rel=0.2)
    assert so["emitted_rate_hz"]["tactile/digit_thumb"] == pytest.approx(60.0, rel=0.2)
    null = res["consumers"]["null"]
    assert null["processed_total"] + null["dropped_total"] == sum(so["emitted"].values())


def test_slow_consumer_drops_frames_instead_of_falling_behind(live_session):
    slow = Slow()
    res = LivePipeline(SessionReplaySource(live_session, streams=["camera/cam0"]), [slow]).run()
    r = res["consumers"]["slow"]
    st = r["streams"]["camera/cam0"]
    assert st["received"] == res["source"]["emitted"]["camera/cam0"]
    assert st["dropped"] >= 5 and st["processed"] + st["dropped"] == st["received"]
    assert st["processed"] <= 1.3 / 0.05  # 50 ms per frame over ~1 s
    # Always the newest frame: indices increase, latency stays ~ one step (no queue build-up).
    assert np.all(np.diff(slow.seen) > 0)
    assert r["latency_ms_p95"] < 200


def test_replay_speed_and_errors(live_session, tmp_path):
    src = SessionReplaySource(live_session, streams=["joints"], speed=4.0)
    res = LivePipeline(src, []).run()
    assert res["source"]["emitted"]["joints"] + res["source"]["skipped_late"].get("joints", 0) == 60
    assert res["active_s"] < 0.5
    with pytest.raises(InputError, match="no such stream"):
        SessionReplaySource(live_session, streams=["camera/nope"])
    with pytest.raises(InputError, match="speed"):
        SessionReplaySource(live_session, speed=0.0)


def test_live_tracking_and_reconstruction_on_replay(tmp_path):
    pytest.importorskip("open3d")
    from vtrack.live.consumers import ReconstructConsumer, TrackConsumer, replay_streams

    sess = write_sphere_session(tmp_path / "sphere", seconds=1.0)
    cons = [TrackConsumer(sess), ReconstructConsumer(sess, voxel_size=0.004)]
    src = SessionReplaySource(sess, streams=replay_streams(sess, cons))
    res = LivePipeline(src, cons).run()
    tr = res["consumers"]["track"]
    assert "first_error" not in tr, tr.get("first_error")
    assert tr["result"]["steps"] >= 5
    # blind SLAM (no mesh, no pose given), scored after the run against the session's ground truth; a
    # sphere's spin is unobservable, so ADD-S (measured 1.6 mm; ADD 5.1 mm)
    assert tr["result"]["mode"] == "slam" and tr["result"]["motion_add_s_mm"] < 4.0
    rc = res["consumers"]["reconstruct"]
    assert "first_error" not in rc, rc.get("first_error")
    assert rc["result"]["integrated"] >= 5 and rc["result"]["mesh_vertices"] > 50


def test_recorder_feeds_live_consumers_while_writing(tmp_path):
    """A recorder's on_frame hook -> QueueSource -> consumers, while the session is being written."""
    pytest.importorskip("depthai")
    import threading

    from vtrack.io.recorders.oakd import OakConfig, record_oak_simulated
    from vtrack.live.consumers import NullConsumer
    from vtrack.live.sources import QueueSource

    src = QueueSource()
    pipe = LivePipeline(src, [NullConsumer()])
    out: dict = {}
    th = threading.Thread(target=lambda: out.update(pipe.run()))
    th.start()
    try:
        stats = record_oak_simulated(
            tmp_path / "s", OakConfig(width=64, height=40), n_frames=15, status=False, on_frame=src.push
        )
    finally:
        src.close()
        th.join(30)
    null = out["consumers"]["null"]
    assert out["source"]["emitted"]["camera/oak"] == stats.written["camera/oak"] == 15
    assert null["processed_total"] + null["dropped_total"] == 15


def test_summary_says_whether_the_pipeline_keeps_up_and_what_it_dropped(live_session):
    """A consumer twice as slow as the camera (50 ms per 30 Hz frame) has a real-time factor near 1/1.5 and
    drops camera frames; the null consumer keeps up. Only the requested fields are decoded and emitted."""
    from vtrack.live.consumers import NullConsumer
    from vtrack.live.pipeline import live_summary

    seen: list[set] = []

    class Fields(NullConsumer):
        name = "fields"

        def process(self, ev) -> None:
            seen.append(set(ev.data))
            super().process(ev)

    src = SessionReplaySource(
        live_session, streams=["camera/cam0", "tactile/digit_index"], fields={"camera/cam0": ["depth"]}
    )
    res = LivePipeline(src, [Fields(), Slow()]).run()
    assert seen and all(s in ({"depth"}, {"image"}) for s in seen)  # camera: depth only; tactile: all fields
    sm = res["summary"]
    assert sm == live_summary(res, ["fields", "slow"])
    for k in ("real_time_factor", "real_time_factor_cpu", "dropped_tactile_pct", "dropped_camera_pct"):
        assert k in sm and sm[k] is not None and np.isfinite(sm[k])
    slow = res["consumers"]["slow"]
    assert 0.4 < slow["real_time_factor"] < 0.9  # 30 Hz x 50 ms = 1.5 s of work per second
    assert slow["real_time_factor_cpu"] > 3.0  # sleeping costs no CPU
    assert res["consumers"]["fields"]["real_time_factor"] > 1.0
    assert sm["real_time_factor"] == slow["real_time_factor"]  # the busiest worker sets the pace
    assert 20.0 < sm["dropped_camera_pct"] < 80.0 and 0.0 <= sm["dropped_tactile_pct"] < 20.0
    cam = slow["streams"]["camera/cam0"]
    assert cam["busy_ms_mean"] == pytest.approx(50.0, abs=25.0) and cam["latency_ms_p95"] < 200
    with pytest.raises(InputError, match="no such field"):
        SessionReplaySource(live_session, streams=["camera/cam0"], fields={"camera/cam0": ["nope"]})


@pytest.mark.parametrize("mode", ["thread", "process"])
def test_track_consumer_runs_touch_as_the_images_arrive(tiny_session, mode):
    """The live tracker's touch stage turns each tactile image into a contact when it arrives (in a thread or
    a child process); the camera step then builds the same frame as from the images themselves."""
    pytest.importorskip("open3d")
    from vtrack.frames.touch import Contact
    from vtrack.live.consumers import TouchConsumer, TrackConsumer
    from vtrack.live.sources import FrameEvent

    tc = TrackConsumer(tiny_session, touch_worker=mode, frames_worker="inline")
    try:
        touch, track = tc.parts()
        assert isinstance(touch, TouchConsumer) and track is tc
        assert set(tc.fields()["camera/cam0"]) == {"depth", "rgb"}  # RGB for the colour term (SLAM)
        assert not tc.wants("tactile/digit_index") and touch.wants("tactile/digit_index")
        sf = tc.sf
        i = len(sf) // 2
        raw = sf.read(i)
        for s, img in raw["touch"]:
            touch.process(FrameEvent(f"tactile/{s}", float(sf.times[i]), i, {"image": img}))
        assert tc.touch_steps == len(raw["touch"]) and all(isinstance(c, Contact) for c in tc.images.values())
        want = sf.build(raw)
        got = sf.build({**raw, "touch": list(tc.images.items())})
        assert len(want.touch_points) > 0  # the frame has contacts
        np.testing.assert_allclose(got.touch_points, want.touch_points)
        np.testing.assert_allclose(got.free_points, want.free_points)
        if mode == "process":
            assert touch.offload_cpu_s > 0  # the child's CPU time is accounted to the worker
        js = sf.reader["joints"]
        j = int(js.index_at(sf.times[i])[0])
        tc.process(FrameEvent("joints", float(js.t[j]), j, {"q": js["q"][j]}))
        tc.process(FrameEvent("camera/cam0", float(sf.times[i]), i, {"depth": sf.cams[0].stream["depth"][i]}))
        assert len(tc.poses) == 1 and np.all(np.isfinite(tc.poses[0][1]))
    finally:
        for p in tc.parts():
            p.finish()


@pytest.mark.parametrize("fmode", ["process", "shared"])
def test_frames_stage_builds_in_the_child_process_what_the_tracker_would_build(tiny_session, fmode):
    """Default live tracking: touch and segmentation run in child processes (``shared``: one, which keeps the
    contacts it computed; ``process``: one each, the newest contacts go with the frame); the camera frame's
    tracking frame is forwarded to the tracker's mailbox as ``frames/<camera>``; it equals the frame built
    inline from the same depth, joints and contacts."""
    pytest.importorskip("open3d")
    from vtrack.live.consumers import FramesConsumer, TouchConsumer, TrackConsumer
    from vtrack.live.pipeline import DERIVED_PREFIX
    from vtrack.live.sources import FrameEvent

    tc = TrackConsumer(tiny_session, frames_worker=fmode)  # touch_worker: process (default)
    assert (tc.frames_helper is tc.touch_helper) == (fmode == "shared")
    out: list[FrameEvent] = []
    try:
        touch, frames, track = tc.parts()
        assert isinstance(touch, TouchConsumer) and isinstance(frames, FramesConsumer) and track is tc
        assert frames.wants("camera/cam0") and frames.wants("joints") and not tc.wants("camera/cam0")
        assert tc.wants(DERIVED_PREFIX + "camera/cam0") and not frames.wants("tactile/digit_index")
        frames.forward = out.append
        sf = tc.sf
        i = len(sf) // 2
        raw = sf.read(i)
        for s, img in raw["touch"]:
            touch.process(FrameEvent(f"tactile/{s}", float(sf.times[i]), i, {"image": img}))
        js = sf.reader["joints"]
        j = int(js.index_at(sf.times[i])[0])
        q_ev = FrameEvent("joints", float(js.t[j]), j, {"q": js["q"][j]})
        frames.process(q_ev)
        depth = sf.cams[0].stream["depth"][i]
        frames.process(FrameEvent("camera/cam0", float(sf.times[i]), i, {"depth": depth}, wall=123.0))
        assert len(out) == 1 and out[0].stream == DERIVED_PREFIX + "camera/cam0" and out[0].wall == 123.0
        got = out[0].data["frame"]
        k = sf.depth_stride
        want = sf.build(
            {"t": float(sf.times[i]), "q": tc._joints(q_ev), "cams": [(sf.cams[0], depth[::k, ::k], None)],
             "touch": raw["touch"]}
        ).tracking_frame()  # fmt: skip
        assert got.vision_points is not None and len(got.vision_points) > 50
        assert got.touch_points is not None and len(got.touch_points) > 0
        np.testing.assert_allclose(got.vision_points, want.vision_points)
        np.testing.assert_allclose(got.touch_points, want.touch_points)
        assert frames.offload_cpu_s > 0  # the child's CPU per frame is accounted to the stage
        tc.process(out[0])
        assert len(tc.poses) == 1 and np.all(np.isfinite(tc.poses[0][1]))
    finally:
        for p in tc.parts():
            p.finish()
    assert not tc.touch_helper.proc.is_alive() and not tc.frames_helper.proc.is_alive()
    assert touch.child_cpu_s > 0  # ended once, its CPU reported
    with pytest.raises(InputError, match="frames_worker"):
        TrackConsumer(tiny_session, frames_worker="gpu")


def test_summary_counts_a_chain_of_stages_against_the_source_schedule():
    """A camera frame lost at either stage of a chain (frames stage, then the tracker) is lost once each; the
    tracker's demand is the source's schedule; latency is the tracker's, from the camera frame; CPU per
    second of recording adds the child processes."""
    from vtrack.live.pipeline import live_summary

    def st(received, processed, dropped, busy, cpu, lat=None):
        return {"received": received, "processed": processed, "dropped": dropped, "busy_ms_mean": busy,
                "cpu_ms_mean": cpu, "latency_ms_mean": lat, "latency_ms_p95": lat}  # fmt: skip

    res = {
        "active_s": 1.0,
        "source": {"emitted": {"camera/c": 28, "tactile/a": 60}, "skipped_late": {"camera/c": 2}},
        "consumers": {
            "track.frames": {"streams": {"camera/c": st(28, 25, 3, 10.0, 1.0)}},
            "track": {"streams": {"frames/camera/c": st(25, 20, 5, 40.0, 20.0, 55.0)}, "result": {"steps": 20}},
            "track.touch": {"streams": {"tactile/a": st(60, 60, 0, 5.0, 2.0)}},
        },
        "cpu": {"total_s": 1.5, "session_s": 1.0},
    }
    sm = live_summary(res, ["track"])
    assert sm["dropped_camera_pct"] == pytest.approx(100 * (2 + 3 + 5) / 30, abs=0.01)
    assert sm["dropped_tactile_pct"] == 0.0
    # tracker: 40 ms x 30 scheduled camera frames = 1.2 s of work per second
    assert sm["real_time_factor"] == pytest.approx(1 / 1.2, abs=1e-3)
    assert sm["real_time_factor_cpu"] == pytest.approx(1 / 0.6, abs=1e-3)
    assert sm["latency_ms_mean"] == 55.0 and sm["poses_per_s"] == 20.0
    assert sm["cpu_s_per_session_s"] == 1.5


def test_offloaded_cpu_counts_once_for_the_frame_it_was_spent_on():
    """A stage that hands camera frames to a helper process reports that CPU (``offload_cpu_s``) for the
    camera frame; joint states it handles next cost it nothing and must not count it again."""
    from vtrack.live.sources import QueueSource

    class Offload(Consumer):
        name = "offload"

        def __init__(self) -> None:
            self.offload_cpu_s = 0.0

        def process(self, ev) -> None:
            if ev.stream == "camera/c":
                self.offload_cpu_s = 0.5  # s, as if a child process had worked 500 ms on it

    src = QueueSource()
    for i in range(5):
        src.push("camera/c", i / 30, {"depth": np.zeros((2, 2))})
        src.push("joints", i / 30 + 0.01, {"q": np.zeros(3)})
    src.close()
    res = LivePipeline(src, [Offload()]).run()
    st = res["consumers"]["offload"]["streams"]
    assert st["camera/c"]["processed"] >= 1 and st["joints"]["processed"] >= 1
    assert st["camera/c"]["cpu_ms_mean"] >= 500.0
    assert st["joints"]["cpu_ms_mean"] < 100.0
