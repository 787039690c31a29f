"""Session format: round trip, lazy time-synchronised access, crash recovery, clear errors."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

from vtrack.errors import InputError
from vtrack.geometry import se3
from vtrack.io import streams
from vtrack.io.session import FieldSpec, SessionWriter, StreamSpec, open_session
from vtrack.scene import load_scene
from vtrack.scene.schema import CameraSpec, TactileSpec

CAM = CameraSpec(name="cam0", width=32, height=24, fx=30.0, fy=30.0, look_at={"eye": [0.5, 0, 0.2]})
TAC = TactileSpec(name="digit_0", type="digit", width=12, height=16, mm_per_px=0.1)


def _write(path: Path, n_cam: int = 6, n_j: int = 12) -> dict:
    rng = np.random.default_rng(0)
    data = {
        "rgb": rng.integers(0, 255, (n_cam, 24, 32, 3), dtype=np.uint8),
        "depth": rng.integers(0, 3000, (n_cam, 24, 32), dtype=np.uint16),
        "mask": (rng.random((n_cam, 24, 32)) > 0.5).astype(np.uint8),
        "q": rng.normal(size=(n_j, 16)),
        "tac": rng.integers(0, 255, (n_j, 16, 12, 3), dtype=np.uint8),
        "T": se3.se3_exp(rng.normal(size=(n_j, 6)) * 0.3),
    }
    with SessionWriter(path, {"name": "unit"}, info={"generator": "test"}) as w:
        w.add_stream("camera/cam0", streams.camera_stream(CAM))
        w.add_stream("tactile/digit_0", streams.tactile_stream(TAC))
        w.add_stream("joints", streams.joints_stream([f"joint_{i}.0" for i in range(16)], rate_hz=60))
        w.add_stream("gt/object_pose", streams.pose_stream())
        for i in range(n_cam):
            w.append("camera/cam0", i / 30, rgb=data["rgb"][i], depth=data["depth"][i], mask=data["mask"][i])
        for i in range(n_j):
            t = i / 60
            w.append("joints", t, q=data["q"][i])
            w.append("tactile/digit_0", t, image=data["tac"][i])
            w.append("gt/object_pose", t, T_world_object=data["T"][i])
    return data


def test_round_trip_exact(tmp_path: Path) -> None:
    data = _write(tmp_path / "s")
    r = open_session(tmp_path / "s")
    assert r.complete
    cam = r["camera/cam0"]
    assert len(cam) == 6 and cam.kind == "rgbd"
    assert np.array_equal(cam["rgb"][:], data["rgb"])
    assert np.array_equal(cam["depth"][2], data["depth"][2])
    assert np.array_equal(cam["mask"][[0, 5]], data["mask"][[0, 5]])
    assert np.allclose(np.asarray(cam.attrs["K"]), CAM.intrinsics().K)
    assert np.array_equal(r["joints"]["q"][:], data["q"])
    assert r["joints"].attrs["joint_names"][3] == "joint_3.0"
    assert np.array_equal(r["gt/object_pose"]["T_world_object"][-1], data["T"][-1])
    summ = r.summary()
    assert summ["joints"]["frames"] == 12
    assert summ["joints"]["rate_hz_measured"] == pytest.approx(60.0)
    assert r.manifest["created"]["generator"] == "test"


def test_one_frame_reads_in_any_order_match_the_data(tmp_path: Path) -> None:
    """One-frame reads share a decoded chunk: forward, backward and random order give the stored frames, and a
    returned frame is the caller's own copy (writing into it changes nothing read later)."""
    data = _write(tmp_path / "s", n_j=23)
    tac = open_session(tmp_path / "s")["tactile/digit_0"]["image"]
    assert tac._chunk > 1  # small images: several frames per chunk, the case the chunk cache serves
    order = list(range(23)) + list(range(22, -1, -1)) + list(np.random.default_rng(1).permutation(23))
    for i in order:
        assert np.array_equal(tac[int(i)], data["tac"][i]), i
    a = tac[5]
    a[:] = 0
    assert np.array_equal(tac[5], data["tac"][5])
    assert np.array_equal(tac[-1], data["tac"][22])


def test_time_synchronised_access(tmp_path: Path) -> None:
    data = _write(tmp_path / "s")
    r = open_session(tmp_path / "s")
    j = r["joints"]
    # Nearest: the tactile timestamps coincide with joint timestamps.
    assert np.array_equal(j.sample("q", r["tactile/digit_0"].t[4])[0], data["q"][4])
    # Linear: halfway between frames 2 and 3.
    q = j.sample("q", (2.5) / 60, mode="linear")[0]
    assert np.allclose(q, 0.5 * (data["q"][2] + data["q"][3]))
    # Poses interpolate on SE(3): result stays rigid and hits the endpoints.
    T = r["gt/object_pose"].sample("T_world_object", np.array([1.5 / 60, 0.0]), mode="linear")
    assert se3.is_rigid(T) and np.allclose(T[1], data["T"][0])
    # Camera frame nearest to a tactile time; clamping outside the range.
    assert r["camera/cam0"].index_at([0.049, 10.0, -1.0]).tolist() == [1, 5, 0]


def test_writer_rejects_bad_frames(tmp_path: Path) -> None:
    w = SessionWriter(tmp_path / "s", None)
    w.add_stream("joints", streams.joints_stream(["a", "b"]))
    w.append("joints", 0.0, q=np.zeros(2))
    with pytest.raises(InputError, match="strictly increasing"):
        w.append("joints", 0.0, q=np.zeros(2))
    with pytest.raises(InputError, match=r"joints/q.*shape"):
        w.append("joints", 1.0, q=np.zeros(3))
    with pytest.raises(InputError, match="unknown stream"):
        w.append("nope", 1.0, q=np.zeros(2))
    with pytest.raises(InputError, match="missing"):
        w.append("joints", 1.0)
    with pytest.raises(InputError, match="not finite"):
        w.append("joints", float("nan"), q=np.zeros(2))
    w.add_stream("img", StreamSpec("x", {"im": FieldSpec((2, 2), "uint8")}))
    with pytest.raises(InputError, match="float data for an integer field"):
        w.append("img", 0.0, im=np.zeros((2, 2)))
    w.close()
    with pytest.raises(InputError, match="exists"):
        SessionWriter(tmp_path / "s", None)


_KILLED_WRITER = textwrap.dedent(
    """
    import sys, time, numpy as np
    from vtrack.io.session import SessionWriter
    from vtrack.io import streams
    from vtrack.scene.schema import CameraSpec
    cam = CameraSpec(name="c", width=64, height=48)
    w = SessionWriter(sys.argv[1], None, flush_every=int(sys.argv[2]))
    w.add_stream("camera/c", streams.camera_stream(cam))
    w.add_stream("joints", streams.joints_stream(["a", "b", "c"]))
    i = 0
    while True:
        v = i % 250
        w.append("camera/c", i * 0.01, rgb=np.full((48, 64, 3), v, np.uint8),
                 depth=np.full((48, 64), i, np.uint16), mask=np.zeros((48, 64), np.uint8))
        w.append("joints", i * 0.01, q=np.full(3, float(i)))
        if i % int(sys.argv[2]) == int(sys.argv[2]) - 1:
            print(i, flush=True)   # frames 0..i are committed
        i += 1
    """
)


@pytest.mark.parametrize("flush_every", [1, 7])
def test_killed_writer_keeps_every_flushed_frame(tmp_path: Path, flush_every: int) -> None:
    path = tmp_path / "rec"
    proc = subprocess.Popen(
        [sys.executable, "-c", _KILLED_WRITER, str(path), str(flush_every)], stdout=subprocess.PIPE, text=True
    )
    last = -1
    t0 = time.time()
    while time.time() - t0 < 60:
        line = proc.stdout.readline()
        if line:
            last = int(line)
        if last >= 60:
            break
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    assert last >= 60, "writer did not make progress"
    r = open_session(path)
    assert not r.complete
    cam, j = r["camera/c"], r["joints"]
    # Every frame reported flushed before the kill is there, intact; nothing half-written is exposed.
    assert len(cam) >= last + 1 and len(j) >= last + 1
    n = len(cam)
    assert np.array_equal(cam["depth"][:][:, 0, 0], np.arange(n))
    assert np.array_equal(j["q"][:][:, 0], np.arange(len(j), dtype=float))
    assert np.allclose(cam.t, np.arange(n) * 0.01)
    assert (cam["rgb"][n - 1] == (n - 1) % 250).all()


def test_corrupt_and_mismatched_sessions_give_clear_errors(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="does not exist"):
        open_session(tmp_path / "missing")
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputError, match="no manifest.json"):
        open_session(tmp_path / "empty")

    _write(tmp_path / "s")
    m = tmp_path / "s" / "manifest.json"
    good = m.read_text()
    m.write_text(good[:100])
    with pytest.raises(InputError, match=r"manifest.json.*corrupt"):
        open_session(tmp_path / "s")
    bad = json.loads(good)
    bad["version"] = 99
    m.write_text(json.dumps(bad))
    with pytest.raises(InputError, match="version"):
        open_session(tmp_path / "s")
    bad = json.loads(good)
    bad["streams"]["joints"]["fields"]["q"]["shape"] = [15]
    m.write_text(json.dumps(bad))
    with pytest.raises(InputError, match=r"joints/q.*shape differs"):
        open_session(tmp_path / "s")
    bad = json.loads(good)
    bad["streams"]["camera/extra"] = bad["streams"]["joints"]
    m.write_text(json.dumps(bad))
    with pytest.raises(InputError, match="camera/extra"):
        open_session(tmp_path / "s")
    m.write_text(good)
    r = open_session(tmp_path / "s")
    with pytest.raises(InputError, match="no such stream"):
        r["camera/nope"]
    with pytest.raises(InputError, match="no such field"):
        r["joints"]["nope"]
    with pytest.raises(IndexError, match="out of range"):
        r["joints"]["q"][12]


def test_out_of_order_timestamps_on_disk_are_detected(tmp_path: Path) -> None:
    import zarr

    _write(tmp_path / "s")
    t = zarr.open_array(str(tmp_path / "s" / "data.zarr" / "joints" / "t"), mode="r+")
    t[5] = t[3]
    with pytest.raises(InputError, match="not strictly increasing at frame 5"):
        open_session(tmp_path / "s")


def test_scene_embedded_in_session(tmp_path: Path, shared_data: Path) -> None:
    from vtrack.paths import default_scene_path

    scene = load_scene(default_scene_path())
    with SessionWriter(tmp_path / "s", scene) as w:
        w.add_stream("joints", streams.joints_stream(["a"]))
        w.append("joints", 0.0, q=np.zeros(1))
    back = open_session(tmp_path / "s").scene()
    assert back.name == scene.name
    assert [t.name for t in back.tactile] == [t.name for t in scene.tactile]
    assert np.allclose(back.cameras[0].extrinsics(), scene.cameras[0].extrinsics())


def test_sequential_reads_prefetch_blocks_and_return_the_same_frames(tmp_path: Path) -> None:
    """A sequential pass of one-frame reads decodes several chunks per call (one image per chunk: depth) and
    returns exactly the frames that one-frame reads in random order return."""
    frames = np.random.default_rng(3).integers(0, 3000, (60, 240, 320), dtype=np.uint16)
    with SessionWriter(tmp_path / "s", {"name": "unit"}) as w:  # one frame per chunk, as a full-size depth image
        w.add_stream("cam", StreamSpec("rgbd", {"depth": FieldSpec((240, 320), "uint16", chunk_frames=1)}))
        for i, f in enumerate(frames):
            w.append("cam", i / 30, depth=f)

    def counted():
        f = open_session(tmp_path / "s")["cam"]["depth"]
        calls: list[str] = []
        read = f._read
        f._read = lambda sel, fr: (calls.append(fr), read(sel, fr))[1]
        return f, calls

    depth, calls = counted()
    assert depth._chunk == 1 and 1 < depth._block_chunks < 60
    assert all(np.array_equal(depth[i], frames[i]) for i in range(60))
    assert len(calls) <= 1 + -(-59 // depth._block_chunks)  # frame 0, then blocks: not 60 calls
    depth, calls = counted()
    for i in np.random.default_rng(2).permutation(60):
        assert np.array_equal(depth[int(i)], frames[i]), i
    assert len(calls) >= 40  # random access reads one frame at a time (no wasted blocks)
