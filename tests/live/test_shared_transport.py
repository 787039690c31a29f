"""Live pipeline's shared-memory transport: frames decoded by the reader process into a ring in shared memory
reach the consumers (and the touch helper process) exactly, a reused slot is caught, and nothing is left in
/dev/shm after a run."""

from __future__ import annotations

import os

import numpy as np
import pytest

from vtrack.live.pipeline import Consumer, LivePipeline
from vtrack.live.shared import FrameOverwritten, FrameRing
from vtrack.live.sources import SessionReplaySource
from vtrack.testing.sessions import write_live_session


@pytest.fixture(scope="module")
def live_session(tmp_path_factory):
    # Real sizes: 640x480 RGB-D at 30 Hz, 4 DIGIT 240x320 at 60 Hz, joints at 60 Hz; 0.5 s.
    return write_live_session(tmp_path_factory.mktemp("live") / "s", seconds=0.5)


def test_ring_round_trips_frames_and_catches_a_reused_slot():
    ring = FrameRing.create({"tactile/a": {"image": ((4, 3, 3), np.uint8)}, "camera/c": {"depth": ((5, 6), "<u2")}}, 3)
    path = ring.layout.path
    try:
        frames = [np.full((4, 3, 3), i, np.uint8) for i in range(5)]
        seqs = []
        for i, f in enumerate(frames[:3]):
            seq, rest = ring.write("tactile/a", {"image": f, "small": np.arange(i)})
            seqs.append(seq)
            np.testing.assert_array_equal(rest["small"], np.arange(i))  # small fields are not in the ring
        d = np.arange(30, dtype=np.uint16).reshape(5, 6)
        sd, _ = ring.write("camera/c", {"depth": d})
        for seq, f in zip(seqs, frames[:3], strict=True):
            slot = ring.slots("tactile/a", seq)["image"]
            np.testing.assert_array_equal(slot.read(), f)
        np.testing.assert_array_equal(ring.slots("camera/c", sd)["depth"].read(), d)  # streams do not overlap
        old = ring.slots("tactile/a", 0)["image"]
        held = old.view()  # a consumer that holds the view while the reader goes round the ring
        ring.write("tactile/a", {"image": frames[3]})  # slot 0 again (3 slots)
        with pytest.raises(FrameOverwritten):
            old.read()
        np.testing.assert_array_equal(held, frames[3])  # the view now shows the newer frame: the check caught it
        np.testing.assert_array_equal(ring.slots("tactile/a", 3)["image"].read(), frames[3])
        np.testing.assert_array_equal(ring.slots("tactile/a", 1)["image"].read(), frames[1])  # untouched
    finally:
        ring.close()
    assert not os.path.exists(path)


def test_ring_memory_is_allocated_before_the_replay_starts(monkeypatch):
    """The ring's pages are allocated when it is created (not by the reader's first write into each slot during
    the replay), and a ring that does not fit fails there, with an OSError the replay turns into the pipe."""
    ring = FrameRing.create({"tactile/a": {"image": ((320, 240, 3), np.uint8)}}, 16)
    try:
        st = os.stat(ring.layout.path)
        assert st.st_size == ring.layout.nbytes and st.st_blocks * 512 >= ring.layout.nbytes  # not a sparse file
        seq, _ = ring.write("tactile/a", {"image": np.full((320, 240, 3), 7, np.uint8)})
        assert int(ring.slots("tactile/a", seq)["image"].read().sum()) == 7 * 320 * 240 * 3
    finally:
        ring.close()
    # no room after all (another process filled /dev/shm since the check): refused here, the file gone again
    before = set(os.listdir("/dev/shm"))

    def full(fd, off, n):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "posix_fallocate", full)
    with pytest.raises(OSError, match="No space"):
        FrameRing.create({"tactile/a": {"image": ((32, 24, 3), np.uint8)}}, 4)
    assert set(os.listdir("/dev/shm")) == before


class Collect(Consumer):
    """Keeps a checked copy of every frame's fields (as a consumer in the tracker's process would read them)."""

    name = "collect"

    def __init__(self) -> None:
        self.got: dict[tuple[str, int], dict[str, np.ndarray]] = {}
        self.shared = 0

    def process(self, ev) -> None:
        self.shared += bool(ev.shared)
        self.got[(ev.stream, ev.index)] = {f: ev.read(f) for f in ev.data}


def test_replay_through_the_ring_delivers_the_session_exactly(live_session):
    from vtrack.io.session import open_session

    fields = {"camera/cam0": ["depth"], **{f"tactile/digit_{s}": ["image"] for s in ("index", "thumb")}}
    fields["joints"] = ["q"]
    src = SessionReplaySource(live_session, streams=list(fields), fields=fields, reader="process", speed=0.5)
    c = Collect()
    res = LivePipeline(src, [c]).run()
    assert src.ring is None  # removed after the run
    assert not [f for f in os.listdir("/dev/shm") if f.startswith(f"vtrack-live-{os.getpid()}-")]
    r = open_session(live_session)
    n = sum(res["source"]["emitted"].values())
    assert n >= 0.8 * (15 + 30 + 30 + 30) and len(c.got) >= n - res["consumers"]["collect"]["dropped_total"]
    assert c.shared >= 0.8 * (15 + 30 + 30)  # camera and tactile frames came through the ring, joints not
    for (stream, i), data in c.got.items():
        for f, v in data.items():
            np.testing.assert_array_equal(v, r[stream][f][i])  # bit-exact, every frame


def test_touch_helper_reads_a_shared_slot_in_place(tiny_session):
    """The touch stage hands the helper process a slot of the ring, not the image: the contact is the one
    computed from the image itself, and a slot reused before the helper read it is a dropped frame."""
    pytest.importorskip("open3d")
    from vtrack.live.consumers import TrackConsumer
    from vtrack.live.sources import FrameEvent

    tc = TrackConsumer(tiny_session, touch_worker="process", frames_worker="inline")
    sf = tc.sf
    i = len(sf) // 2
    raw = sf.read(i)
    s, img = next((s, im) for s, im in raw["touch"] if len(sf.touch.contact(s, im).points))
    ring = FrameRing.create({f"tactile/{s}": {"image": (img.shape, img.dtype)}}, 2)
    try:
        touch = tc.parts()[0]
        seq, _ = ring.write(f"tactile/{s}", {"image": img})
        slots = ring.slots(f"tactile/{s}", seq)
        touch.process(FrameEvent(f"tactile/{s}", 0.0, i, {"image": slots["image"].view()}, shared=slots))
        want = sf.touch.contact(s, img)
        np.testing.assert_allclose(tc.images[s].points, want.points)
        ring.write(f"tactile/{s}", {"image": img})
        ring.write(f"tactile/{s}", {"image": img})  # the slot of `seq` reused
        with pytest.raises(FrameOverwritten):
            touch.process(FrameEvent(f"tactile/{s}", 0.0, i, {"image": slots["image"].view()}, shared=slots))
        # a batch (the stage's pending images): one round trip; the lost frame is reported, the others processed
        tc.images.clear()
        evs = [FrameEvent(f"tactile/{s}", 0.0, i, {"image": slots["image"].view()}, shared=slots)]
        evs += [FrameEvent(f"tactile/{o}", 0.0, i, {"image": im}) for o, im in raw["touch"]]
        assert touch.process_batch(evs) == [False] + [True] * len(raw["touch"])
        for o, im in raw["touch"]:
            np.testing.assert_array_equal(tc.images[o].points, sf.touch.contact(o, im).points)
    finally:
        for p in tc.parts():
            p.finish()
        ring.close()


def test_camera_stride_keeps_up_by_tracking_fewer_frames_only_while_behind():
    """Fixed stride: every k-th camera frame by time (robust to a dropped frame); adaptive: the stride follows
    the tracker's step time against the camera period (budget 0.9) up to its cap, and comes back when the steps
    are fast again."""
    from vtrack.errors import InputError
    from vtrack.live.consumers import CameraStride

    P = 1 / 30
    fixed = CameraStride(2, 1, 0.9, P)
    t = [i * P for i in range(10)] + [11 * P, 13 * P]  # frame 10 and 12 lost
    assert [fixed.take(x) for x in t] == [True, False] * 5 + [True, True]
    assert fixed.skipped == 5 and fixed.hist == {2: 7}

    ad = CameraStride(1, 3, 0.9, P)
    taken = []
    for i in range(60):
        if ad.take(i * P):
            taken.append(i)
            ad.done(2.2 * P if 10 <= i < 40 else 0.5 * P)  # the tracker falls behind between frames 10 and 40
    early, behind, late = (sum(a <= i < b for i in taken) for a, b in ((0, 10), (14, 40), (52, 60)))
    assert early == 10 and late == 8  # every frame while it keeps up (back within ~10 frames)
    assert 26 / 3 - 1 <= behind <= 26 / 2  # stride 3 (ceil(2.2 / 0.9)) while behind
    assert ad.hist.get(3, 0) >= 5 and ad.stride == 1
    with pytest.raises(InputError, match="camera_stride"):
        CameraStride(0, 1, 0.9, P)


def test_track_consumer_with_a_camera_stride_tracks_every_other_frame(tiny_session):
    pytest.importorskip("open3d")
    from vtrack.live.consumers import TrackConsumer
    from vtrack.live.sources import FrameEvent

    tc = TrackConsumer(tiny_session, touch_worker="off", frames_worker="inline", camera_stride=2)
    sf = tc.sf
    depth = sf.cams[0].stream["depth"]
    for i in range(12):
        tc.process(FrameEvent("camera/cam0", float(sf.times[i]), i, {"depth": depth[i]}))
    res = tc.finish()
    assert res["steps"] == 6 and res["camera_skipped"] == 6 and res["stride_hist"] == {"2": 6}
    assert [round(t / (sf.times[1] - sf.times[0])) for t, _ in tc.poses] == [0, 2, 4, 6, 8, 10]


def test_replay_emits_a_camera_frame_after_the_other_frames_of_its_time(live_session):
    """At equal times the camera frame comes last (sorted stream names would put it first): the tracker's step
    then has the joint state of the frame's own time, not the one a period older."""
    streams = sorted(["camera/cam0", "joints", "tactile/digit_index", "tactile/digit_thumb"])
    src = SessionReplaySource(live_session, streams=streams)
    names = [src.streams[int(k)] for _, k, _ in src.schedule]
    t = src.schedule[:, 0]
    cams = [j for j, n in enumerate(names) if n == "camera/cam0"]
    assert len(cams) >= 14
    for j in cams:
        same = np.flatnonzero(t == t[j])
        assert len(same) >= 3 and j == same.max()  # joints and tactile images of that time before it
    assert np.all(np.diff(t) >= 0)


def test_replay_without_room_for_the_ring_falls_back_to_the_pipe(live_session, monkeypatch):
    """A small /dev/shm (a container's 64 MB) must not crash the reader: the replay says so and pickles."""
    import vtrack.live.shared as shared

    assert shared.ring_dir(1 << 20) is not None  # the real check: this machine has room for 1 MB
    monkeypatch.setattr(shared, "ring_dir", lambda nbytes: None)
    src = SessionReplaySource(live_session, streams=["camera/cam0"], reader="process", speed=2.0)
    c = Collect()
    with pytest.warns(UserWarning, match="pipe transport"):
        res = LivePipeline(src, [c]).run()
    assert c.shared == 0 and len(c.got) >= 0.8 * 15 and res["consumers"]["collect"]["errors"] == 0
