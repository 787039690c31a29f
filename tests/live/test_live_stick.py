"""Sticking contacts in live tracking (``vtrack live S --consumer track --contacts stick``): the live frames carry the
same contact ids and world gel points (``stick_ids`` / ``stick_points``) as the offline run's, built in the process
that builds the frames; a real-time replay of a session whose fingers drive the object tracks it far better with the
preset than without. The sessions are the simulator's (``sim.contact_mode: stick``); ground truth only scores."""

from __future__ import annotations

import numpy as np
import pytest

from vtrack.errors import InputError
from vtrack.live.sources import FrameEvent


@pytest.fixture(scope="module")
def stick_session(shared_data):
    """1 s of the potted meat can driven by sticking fingers under heavy occlusion (generated once per cache, ~20 s;
    the same session as tests/tracking/test_stick.py's)."""
    from vtrack.testing.sim import ycb_session

    return ycb_session("010_potted_meat_can", "heavy", 1.0, contact_mode="stick")


def _ids(frame) -> tuple[np.ndarray, np.ndarray]:
    return frame.info.get("stick_ids", np.zeros(0, np.int64)), frame.info.get("stick_points", np.zeros((0, 3)))


def test_live_frames_carry_the_offline_sticking_contacts(stick_session):
    pytest.importorskip("open3d")
    from vtrack.frames.session import SessionFrames
    from vtrack.live.consumers import TrackConsumer
    from vtrack.tracking.slam import SLAM_STICKING_CONTACTS
    from vtrack.tracking.stick import sticking_contacts_for

    n = 12
    tc = TrackConsumer(
        stick_session, touch_worker="off", frames_worker="inline", colour=False, **SLAM_STICKING_CONTACTS
    )
    plain = TrackConsumer(stick_session, touch_worker="off", frames_worker="inline", colour=False)
    assert tc.sticker is not None and plain.sticker is None
    c = tc.config
    ref = SessionFrames(stick_session, touch_stride=c.touch_stride, touch_downsample=c.touch_downsample, max_frames=n)
    ref_sticker = sticking_contacts_for(SLAM_STICKING_CONTACTS, ref.modalities)
    js = ref.reader["joints"]
    got: dict[str, list] = {"stick": [], "plain": []}
    for name, cons in (("stick", tc), ("plain", plain)):
        cons._step = lambda ev, fr, name=name: got[name].append(fr)  # the frames the tracker would step on
    want = []
    for i in range(n):
        t = float(ref.times[i])
        j = int(js.index_at(t)[0])
        raw = ref.read(i)
        evs = [FrameEvent("joints", float(js.t[j]), j, {"q": js["q"][j]})]
        evs += [FrameEvent(f"tactile/{s}", t, i, {"image": img}) for s, img in raw["touch"]]
        evs.append(FrameEvent("camera/cam0", t, i, {"depth": ref.cams[0].stream["depth"][i]}))
        for ev in evs:
            for cons in (tc, plain):
                cons.process(ev)
        fr = ref.build({**{k: v for k, v in raw.items() if k != "i"}, "t": t, "q": tc.q})
        want.append(ref_sticker.annotate(fr, fr.tracking_frame()))
    assert len(got["stick"]) == len(got["plain"]) == n
    ids = [_ids(f)[0] for f in want]
    assert sum(len(x) for x in ids) >= n  # the fingers are in contact ...
    assert len(set(ids[0].tolist()) & set(ids[-1].tolist())) >= 1  # ... and some contact sticks all along
    for w, live, p in zip(want, got["stick"], got["plain"], strict=True):
        np.testing.assert_array_equal(_ids(live)[0], _ids(w)[0])
        np.testing.assert_allclose(_ids(live)[1], _ids(w)[1], atol=1e-9)
        assert np.all(np.isfinite(_ids(live)[1]))
        assert "stick_ids" not in p.info  # the default (slide) builds none


def test_live_sticking_contacts_need_touch_and_slam(stick_session, tmp_path):
    pytest.importorskip("open3d")
    from vtrack_apps.commands.track import contacts_opts

    from vtrack.live.consumers import TrackConsumer

    with pytest.raises(InputError, match="--contacts"):  # the CLI's check: known shape
        contacts_opts("stick", ("vision", "touch"), False, "no --mesh (SLAM)")
    mesh = tmp_path / "box.ply"
    import trimesh

    trimesh.creation.box((0.05, 0.05, 0.05)).export(mesh)
    with pytest.raises(InputError, match="sticking-contact term needs touch and SLAM"):
        TrackConsumer(stick_session, mesh=mesh, init_pose=np.eye(4), touch_worker="off", sigma_stick=0.00025)


@pytest.mark.slow
def test_live_replay_with_sticking_contacts_tracks_the_driven_object(stick_session):
    """Real-time replay slowed to a fifth (a loaded CI machine drops few frames), SLAM with the default settings and
    with the sticking-contact preset (frames and contact ids built in the helper process, the live default). Offline
    the preset gives 0.60 mm against 1.69 on this session (tests/tracking/test_stick.py). Live, the default run takes
    each sensor's newest contact when its frame is built, so it depends on timing: 1.558 mm alone (three runs, the
    preset 0.866 in each: ratio 0.556), 1.446 / 1.474 beside a busy process (0.568 / 0.588), 1.361 in a CI run beside
    the other test worker (0.636). Hence the bound of 0.7 (still a 30 % gain) and an absolute one on the preset."""
    pytest.importorskip("open3d")
    from vtrack.live.consumers import make_consumer, replay_fields, replay_streams
    from vtrack.live.pipeline import LivePipeline
    from vtrack.live.sources import SessionReplaySource
    from vtrack.tracking.slam import SLAM_STICKING_CONTACTS

    out = {}
    for name, opts in (("slide", {}), ("stick", SLAM_STICKING_CONTACTS)):
        tc = make_consumer("track", stick_session, **opts)
        seen: list[int] = []
        step = tc._step
        tc._step = lambda ev, fr, step=step, seen=seen: (seen.append(len(_ids(fr)[0])), step(ev, fr))
        src = SessionReplaySource(
            stick_session,
            streams=replay_streams(stick_session, [tc]),
            fields=replay_fields([tc]),
            reader="process",
            speed=0.2,
        )
        r = LivePipeline(src, [tc]).run()["consumers"]["track"]
        assert r["errors"] == 0, r.get("first_error")
        res = r["result"]
        assert res["steps"] >= 20 and res["frames_worker"] == "process"
        assert res["sticking_contacts"] == (name == "stick")
        assert (sum(seen) >= res["steps"]) if name == "stick" else max(seen) == 0
        out[name] = res["motion_err_mm"]
    assert np.isfinite(out["stick"]) and out["stick"] < 0.7 * out["slide"] and out["stick"] < 1.2, out
