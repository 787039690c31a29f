"""Frames built in a child process ahead of the tracker (vtrack.frames.prefetch): the same poses as built in
process, errors from the child as one clear line, no child left behind, and the ``auto`` rule."""

import numpy as np
import pytest

from vtrack.errors import InputError


@pytest.mark.parametrize("shape", ["slam", "known_shape"])
def test_prefetched_frames_give_identical_poses(tiny_session, shape, tmp_path):
    import shutil

    from vtrack.tracking.run import track_session

    kw = dict(shape=shape, write=False, return_poses=True, max_frames=12)
    if shape == "known_shape":  # the shape a user gives (a copy of the object mesh, outside the session)
        kw["mesh"] = shutil.copy(tiny_session / "gt" / "object.ply", tmp_path / "object.ply")
    m_off, (t_off, T_off) = track_session(tiny_session, "", prefetch="off", **kw)
    m_on, (t_on, T_on) = track_session(tiny_session, "", prefetch="on", **kw)
    assert m_off["prefetch"] is False and m_on["prefetch"] is True
    # vision and touch: the tactile pipelines run in a process of their own, the frame builder takes their contacts
    assert m_off["prefetch_processes"] == 0 and m_on["prefetch_processes"] == 2
    if shape == "slam":  # the ablation: one child for both
        m_one, (_, T_one) = track_session(tiny_session, "", prefetch="single", **kw)
        assert m_one["prefetch_processes"] == 1
        np.testing.assert_allclose(T_one, T_off, rtol=0, atol=1e-12)
    assert m_on["frames"] == m_off["frames"] == 12
    assert np.array_equal(t_on, t_off)
    # the child's SessionFrames starts from frame 0 as a fresh one does (the known shape's initialisation built
    # and reset the parent's first frames): the same poses, up to the last bit of a BLAS sum (the child runs one
    # thread, this process may run more; measured <= 6e-16)
    np.testing.assert_allclose(T_on, T_off, rtol=0, atol=1e-12)
    assert m_on["prefetch_child_cpu_s"] > 0  # the build's CPU, spent in the child
    assert m_on["frames_wall_s"] > 0 and np.isfinite(m_on["poses_per_s"])


def test_child_error_is_one_clear_line(tiny_session):
    from vtrack.frames.prefetch import PrefetchedFrames

    pf = PrefetchedFrames(tiny_session, {"modalities": ("vision", "smell")})
    with pytest.raises(InputError, match="unknown modality"):
        next(pf.frames())
    assert not pf._proc.is_alive()


def test_frame_count_mismatch_is_reported(tiny_session):
    from vtrack.frames.prefetch import PrefetchedFrames

    pf = PrefetchedFrames(tiny_session, {"max_frames": 5})
    with pytest.raises(RuntimeError, match="5 frames, expected 7"):
        next(pf.frames(expected=7))
    assert not pf._proc.is_alive()


def test_leaving_early_ends_the_child(tiny_session):
    from vtrack.frames.prefetch import PrefetchedFrames

    pf = PrefetchedFrames(tiny_session, {"max_frames": 30}, queue_frames=2)
    it = pf.frames()
    i, fr, read_ms, build_ms = next(it)
    assert i == 0 and len(fr.vision_points) > 0 and read_ms >= 0 and build_ms > 0
    it.close()  # the consumer stops after one frame: the child (blocked on a full queue) is ended
    assert not pf._proc.is_alive()


def test_auto_rule(monkeypatch):
    import vtrack.frames.prefetch as pf
    import vtrack.threads as th

    monkeypatch.setattr(th, "available_cpus", lambda: 2)
    monkeypatch.setattr(th, "_LIMIT", None)
    assert pf.worth_prefetching("auto", pf.MIN_FRAMES) and pf.worth_prefetching("auto", None)
    assert not pf.worth_prefetching("auto", pf.MIN_FRAMES - 1)  # the child's start would cost more than it saves
    assert pf.worth_prefetching("on", 1) and not pf.worth_prefetching("off", 10**6)
    monkeypatch.setattr(th, "_LIMIT", 1)  # vtrack --threads 1: a single-core figure, no second process
    assert not pf.worth_prefetching("auto", 10**6)
    monkeypatch.setattr(th, "_LIMIT", None)
    monkeypatch.setattr(th, "available_cpus", lambda: 1)
    assert not pf.worth_prefetching("auto", 10**6)
    with pytest.raises(InputError, match="prefetch"):
        pf.worth_prefetching("sometimes", 100)


def test_corrupt_chunk_in_the_child_is_the_same_one_line_error(tiny_session, tmp_path):
    import shutil

    from vtrack.io.session import CorruptDataError

    s = tmp_path / "s"
    shutil.copytree(tiny_session, s)
    chunk = s / "data.zarr" / "camera" / "cam0" / "depth" / "c" / "3" / "0" / "0"
    chunk.write_bytes(b"\x28\xb5\x2f\xfd garbage" * 4)
    from vtrack.frames.prefetch import PrefetchedFrames

    got = []
    with pytest.raises(CorruptDataError, match=r"camera/cam0/depth.*frame") as e:
        for i, *_ in PrefetchedFrames(s, {"max_frames": 8}).frames(expected=8):
            got.append(i)
    assert "\n" not in str(e.value) and got == [0, 1, 2]  # the frames before the damaged one arrive


def test_touch_process_error_reaches_the_parent_as_one_line(tiny_session, tmp_path):
    """A damaged tactile chunk is met in the touch process: the frame builder hands its message on, the frames
    before it arrive, and both children end."""
    import shutil

    from vtrack.io.session import CorruptDataError

    s = tmp_path / "s"
    shutil.copytree(tiny_session, s)
    chunk = s / "data.zarr" / "tactile" / "digit_index" / "image" / "c" / "3" / "0" / "0" / "0"
    data = bytearray(chunk.read_bytes())
    data[len(data) // 2] ^= 0xFF
    chunk.write_bytes(bytes(data))
    from vtrack.frames.prefetch import PrefetchedFrames

    pf = PrefetchedFrames(s, {"max_frames": 12})
    assert pf.processes == 2
    got = []
    with pytest.raises(CorruptDataError, match=r"tactile/digit_index/image.*frame") as e:
        for i, *_ in pf.frames(expected=12):
            got.append(i)
    # tactile frames 12..15 are in chunk 3: camera frame 6 (60 Hz touch, 30 Hz camera) is the first to need it
    assert "\n" not in str(e.value) and got == list(range(6))
    assert not any(p.is_alive() for p in pf._procs)


def test_a_dead_touch_process_is_reported(tiny_session):
    from vtrack.frames.prefetch import PrefetchedFrames

    pf = PrefetchedFrames(tiny_session, {"max_frames": 30}, queue_frames=1)
    it = pf.frames(expected=30)
    next(it)
    touch = pf._procs[0]
    assert touch.name == "vtrack-touch"
    touch.kill()
    touch.join(5)
    with pytest.raises(RuntimeError, match="vtrack-touch|touch process"):
        for _ in it:
            pass
    assert not any(p.is_alive() for p in pf._procs)
