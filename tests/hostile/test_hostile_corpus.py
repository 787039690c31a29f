"""Hostile-input corpus (issue #22): every command either succeeds with sane output or exits 2 with one
line naming the file/field; never a traceback, never exit 0 with garbage, never a file outside ``--out``.

Commands run in-process through the typer app (``run`` below reproduces ``vtrack_apps.cli.main``:
a ``VtrackError`` becomes ``error: <one line>`` and exit 2; any other exception fails the test as the
traceback a user would have seen).
"""

from __future__ import annotations

import json
import os
import pickle
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from vtrack.errors import VtrackError
from vtrack.paths import default_scene_path

SHARED = Path(__file__).resolve().parents[3] / "shared" / "data"
URDF = SHARED / "robots" / "allegro_digit" / "allegro_digit_left.urdf"
PRESSES = SHARED / "gelsight_ball_presses"
HYP = settings(
    max_examples=12,
    deadline=None,
    derandomize=True,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)


# ----------------------------------------------------------------------------------------- helpers
def run(args: list[str]) -> tuple[int, str, str]:
    """(exit code, stdout, error line) of ``vtrack ARGS`` run in-process."""
    from typer.testing import CliRunner
    from vtrack_apps.cli import app

    r = CliRunner().invoke(app, [str(a) for a in args])
    if isinstance(r.exception, VtrackError):
        return 2, r.stdout, f"error: {r.exception}"
    if r.exception is not None and not isinstance(r.exception, SystemExit):
        import traceback

        pytest.fail("traceback:\n" + "".join(traceback.format_exception(r.exception)))
    return r.exit_code, r.stdout, ""


def refused(args: list[str], *names: str) -> str:
    """Assert exit 2 with exactly one error line that names every string in ``names``."""
    code, out, err = run(args)
    assert code == 2, f"expected exit 2, got {code}: {out[-400:]}"
    assert "\n" not in err.strip() and "Traceback" not in err, err
    for n in names:
        assert n in err, f"{n!r} not named in: {err}"
    return err


def ok_or_refused(args: list[str], path: Path) -> tuple[int, str]:
    code, out, err = run(args)
    assert code in (0, 2), (code, out[-400:])
    if code == 2:
        assert "\n" not in err.strip() and (str(path) in err or "field" in err), err
    return code, out


def snapshot(root: Path) -> dict[str, tuple[int, int]]:
    return {str(p): (p.stat().st_size, p.stat().st_mtime_ns) for p in root.rglob("*") if p.is_file()}


def base_scene() -> dict:
    return yaml.safe_load(default_scene_path().read_text().replace("${shared}", str(SHARED.parent)))


def write_scene(tmp: Path, data: dict | str, name: str = "scene.yaml") -> Path:
    p = tmp / name
    p.write_text(data if isinstance(data, str) else yaml.safe_dump(data))
    return p


def tiny_session(path: Path, n: int = 6) -> Path:
    """A small hand-built session: one depth camera stream (+ joints), 8x10 px."""
    from vtrack.io.session import FieldSpec, SessionWriter, StreamSpec

    with SessionWriter(path, None) as w:
        w.add_stream("camera/cam0", StreamSpec(kind="camera", fields={"depth": FieldSpec((8, 10), "uint16", "mm", 1)}))
        w.add_stream("joints", StreamSpec(kind="joints", fields={"q": FieldSpec((3,), "float64", "rad", 16)}))
        for i in range(n):
            w.append("camera/cam0", 0.1 * i, depth=np.full((8, 10), 500 + i, np.uint16))
            w.append("joints", 0.1 * i, q=np.full(3, 0.01 * i))
    return path


# ----------------------------------------------------------------------------------------- scene
SCENE_MUTATIONS = [  # (path in the scene dict, bad value, field named in the error)
    (("cameras", 0, "depth_scale"), 1.0e9, "depth_scale"),  # issue #22: every depth became 0
    (("cameras", 0, "depth_scale"), 0.0, "depth_scale"),
    (("cameras", 0, "fx"), float("nan"), "fx"),
    (("cameras", 0, "width"), -640, "width"),
    (("cameras", 0, "depth_max"), 1.0e6, "depth_max"),
    (("tactile", 0, "mm_per_px"), 50.0, "mm_per_px"),
    (("tactile", 0, "rate_hz"), float("inf"), "rate_hz"),
    (("sim", "seconds"), 1.0e7, "seconds"),
    (("sim", "penetration_mm"), [3.0, 1.0], "penetration_mm"),
    (("sim", "rotation_axis"), [0.0, 0.0, 0.0], "rotation_axis"),
    (("sim", "joint_noise"), 5.0, "joint_noise"),
    (("cameras", 0, "no_such_key"), 1, "no_such_key"),
]


@pytest.mark.parametrize(
    "where,value,field", SCENE_MUTATIONS, ids=[m[2] + str(i) for i, m in enumerate(SCENE_MUTATIONS)]
)
def test_scene_out_of_range_refused(tmp_path, where, value, field) -> None:
    d = base_scene()
    d.setdefault("sim", {})
    node = d
    for k in where[:-1]:
        node = node[k]
    node[where[-1]] = value
    p = write_scene(tmp_path, d)
    refused(["scene", "check", p], str(p), field)


@pytest.mark.parametrize("text", ["", "- a\n- b\n", "name: [unclosed\n", "\x00\x01\x02binary", "name: 3\nobject: 7\n"])
def test_scene_malformed_files(tmp_path, text) -> None:
    p = write_scene(tmp_path, text)
    refused(["scene", "check", p], str(p))


def test_scene_check_opens_urdf_and_mesh(tmp_path) -> None:
    # issue #22: a URDF joint with an unknown parent link crashed generate with StopIteration,
    # a truncated URDF printed parser noise; scene check did not open either file.
    xml = URDF.read_text()
    bad = tmp_path / "bad_parent.urdf"
    bad.write_text(xml.replace('<parent link="link_1.0"', '<parent link="no_such_link"', 1))
    trunc = tmp_path / "trunc.urdf"
    trunc.write_text(xml[:3000])
    for urdf, names in ((bad, ["no_such_link", "joint_2.0"]), (trunc, ["not well-formed"])):
        d = base_scene()
        d["hand"]["urdf"] = str(urdf)
        refused(["scene", "check", write_scene(tmp_path, d)], str(urdf), *names)
    junk = tmp_path / "junk.ply"
    junk.write_bytes(os.urandom(300))
    d = base_scene()
    d["object"]["mesh"] = str(junk)
    refused(["scene", "check", write_scene(tmp_path, d)], str(junk))
    d["object"]["mesh"] = str(tmp_path / "missing.ply")
    refused(["scene", "check", write_scene(tmp_path, d)], "missing.ply")
    code, out, _ = run(["scene", "check", default_scene_path()])
    assert code == 0 and "16 joints" in out and "triangles" in out


def test_non_watertight_mesh_warns(tmp_path) -> None:
    import trimesh

    from vtrack.sim.objects import MeshNotWatertightWarning, load_object_mesh

    s = trimesh.creation.icosphere(2, 0.03)
    keep = np.ones(len(s.faces), bool)
    keep[np.argsort(s.triangles_center[:, 2])[-40:]] = False  # cut a cap off: not fillable
    trimesh.Trimesh(s.vertices, s.faces[keep]).export(tmp_path / "open.ply")
    with pytest.warns(MeshNotWatertightWarning, match="open edges"):
        load_object_mesh(tmp_path / "open.ply")
    box = trimesh.creation.box((0.05, 0.05, 0.05))
    trimesh.Trimesh(box.vertices, box.faces[:-1], process=False).export(tmp_path / "holey.ply")
    with pytest.warns(MeshNotWatertightWarning, match="holes were filled"):
        m = load_object_mesh(tmp_path / "holey.ply")
    assert trimesh.Trimesh(m.vertices, m.faces).is_watertight


_SCENE_NUMBERS = [
    ("cameras", 0, "fx"),
    ("cameras", 0, "depth_scale"),
    ("cameras", 0, "height"),
    ("tactile", 1, "gel_thickness_mm"),
    ("tactile", 2, "width"),
    ("object", "scale"),
]


@HYP
@given(
    which=st.sampled_from(_SCENE_NUMBERS),
    value=st.one_of(
        st.floats(allow_nan=True, allow_infinity=True), st.integers(-(10**12), 10**12), st.text(max_size=5), st.none()
    ),
)
def test_scene_number_mutations_hypothesis(tmp_path_factory, which, value) -> None:
    tmp = tmp_path_factory.mktemp("scene")
    d = base_scene()
    node = d
    for k in which[:-1]:
        node = node[k]
    node[which[-1]] = value
    p = write_scene(tmp, d)
    code, out = ok_or_refused(["scene", "check", p], p)
    if code == 0:  # accepted: the value must be a plausible one
        from vtrack.scene import load_scene

        v = float(value)
        assert np.isfinite(v) and v > 0 and load_scene(p) is not None


# ----------------------------------------------------------------------------------------- sessions
def test_session_verify_finds_corrupt_chunks(tmp_path) -> None:
    s = tiny_session(tmp_path / "s")
    code, out, _ = run(["session", "verify", s])
    assert code == 0 and "OK" in out
    chunk = s / "data.zarr" / "camera" / "cam0" / "depth" / "c" / "4" / "0" / "0"
    os.truncate(chunk, chunk.stat().st_size // 2)  # issue #22: truncate -s on one chunk
    code, out, _ = run(["session", "info", s])
    assert code == 0 and "session verify" in out  # info says what it does not check
    refused(["session", "verify", s], "camera/cam0/depth", "frames 4..4")


def test_corrupt_chunk_read_is_one_line_naming_array_and_frame(tmp_path) -> None:
    from vtrack.io.session import CorruptDataError, open_session

    s = tiny_session(tmp_path / "s")
    chunk = s / "data.zarr" / "camera" / "cam0" / "depth" / "c" / "2" / "0" / "0"
    chunk.write_bytes(b"\x28\xb5\x2f\xfd garbage" * 4)
    r = open_session(s)
    with pytest.raises(CorruptDataError, match=r"camera/cam0/depth.*frame 2") as e:
        r["camera/cam0"]["depth"][2]
    assert "\n" not in str(e.value)
    assert int(r["camera/cam0"]["depth"][1][0, 0]) == 501  # other frames still read
    skip = open_session(s, on_corrupt="skip")["camera/cam0"]
    assert skip.n == 5 and [int(skip["depth"][i][0, 0]) for i in range(5)] == [500, 501, 503, 504, 505]
    np.testing.assert_allclose(skip.t, [0.0, 0.1, 0.3, 0.4, 0.5])
    stop = open_session(s, on_corrupt="stop")["camera/cam0"]
    assert stop.n == 2


def test_missing_and_bitflipped_chunks(tmp_path) -> None:
    from vtrack.io.session import verify_session

    s = tiny_session(tmp_path / "s")
    (s / "data.zarr" / "camera" / "cam0" / "depth" / "c" / "1" / "0" / "0").unlink()
    c3 = s / "data.zarr" / "camera" / "cam0" / "depth" / "c" / "3" / "0" / "0"
    b = bytearray(c3.read_bytes())
    b[len(b) // 2] ^= 0x01  # one bit: only the checksum can see it
    c3.write_bytes(bytes(b))
    probs = verify_session(s)
    assert [(p.field, p.frames) for p in probs] == [("depth", (1, 2)), ("depth", (3, 4))]
    assert "missing" in probs[0].message and "checksum" in probs[1].message.lower()


@pytest.mark.parametrize(
    "manifest",
    [
        "{not json",
        "[]",
        json.dumps({"format": "other"}),
        json.dumps({"format": "vtrack-session", "version": 99, "streams": {}}),
        json.dumps({"format": "vtrack-session", "version": 1, "streams": 5}),
    ],
)
def test_bad_manifests(tmp_path, manifest) -> None:
    s = tiny_session(tmp_path / "s")
    (s / "manifest.json").write_text(manifest)
    refused(["session", "info", s], "manifest.json")


@HYP
@given(
    key=st.sampled_from(["n_committed", "t", "fields", "kind", "version", "streams"]),
    value=st.one_of(
        st.integers(-5, 10**9), st.floats(), st.text(max_size=4), st.none(), st.lists(st.integers(), max_size=3)
    ),
)
def test_manifest_mutations_hypothesis(tmp_path_factory, key, value) -> None:
    s = tiny_session(tmp_path_factory.mktemp("m") / "s")
    m = json.loads((s / "manifest.json").read_text())
    if key in ("version", "streams"):
        m[key] = value
    elif key == "n_committed":  # the commit counter lives in the zarr group attributes
        zj = s / "data.zarr" / "camera" / "cam0" / "zarr.json"
        z = json.loads(zj.read_text())
        z["attributes"]["n_committed"] = value
        zj.write_text(json.dumps(z))
    else:
        m["streams"]["camera/cam0"][key] = value
    (s / "manifest.json").write_text(json.dumps(m))
    code, out = ok_or_refused(["session", "verify", s], s)
    if code == 0:
        from vtrack.io.session import open_session

        r = open_session(s)
        assert all(0 <= st_.n <= 6 for st_ in r.streams.values())


def test_force_never_deletes_user_files(tmp_path) -> None:
    from vtrack.errors import InputError
    from vtrack.io.session import SessionWriter

    d = tmp_path / "d"
    d.mkdir()
    (d / "notes.txt").write_text("x")  # issue #22: generate --force deleted this
    with pytest.raises(InputError, match="not a vtrack session"):
        SessionWriter(d, None, overwrite=True)
    assert (d / "notes.txt").read_text() == "x"
    s = tiny_session(tmp_path / "s")
    (s / "mine.txt").write_text("keep")
    with pytest.raises(InputError, match="mine.txt"):
        SessionWriter(s, None, overwrite=True)
    (s / "mine.txt").unlink()
    SessionWriter(s, None, overwrite=True).close()  # a plain session is replaced
    assert json.loads((s / "manifest.json").read_text())["streams"] == {}
    f = tmp_path / "file"
    f.write_text("y")
    with pytest.raises(InputError, match="not a directory"):
        SessionWriter(f, None, overwrite=True)
    empty = tmp_path / "empty"
    empty.mkdir()
    SessionWriter(empty, None, overwrite=True).close()


def test_generate_force_on_user_folder_cli(tmp_path) -> None:
    d = tmp_path / "d"
    d.mkdir()
    (d / "notes.txt").write_text("x")
    before = snapshot(tmp_path)
    refused(
        ["generate", default_scene_path(), "--out", d, "--seconds", "0.2", "--force", "--quiet"],
        str(d),
        "not a vtrack session",
    )
    assert snapshot(tmp_path) == before


def test_on_corrupt_option(tmp_path) -> None:
    s = tiny_session(tmp_path / "s")
    (s / "data.zarr" / "camera" / "cam0" / "depth" / "c" / "0" / "0" / "0").write_bytes(b"xx")
    try:
        code, out, _ = run(["--on-corrupt", "skip", "session", "info", s])
        assert code == 0 and "1 damaged frame(s) hidden" in out
    finally:
        os.environ.pop("VTRACK_ON_CORRUPT", None)
    refused(["--on-corrupt", "maybe", "session", "info", s], "--on-corrupt")


# ----------------------------------------------------------------------------------------- import
class _Evil:
    def __reduce__(self):  # what an attacker puts in data.pkl
        return (os.system, ("touch PWNED_BY_PICKLE",))


def _feelsight(tmp: Path, data: object) -> Path:
    src = tmp / "obj" / "00"
    src.mkdir(parents=True)
    (src / "data.pkl").write_bytes(pickle.dumps(data))
    return src


def test_import_pickle_code_execution_refused(tmp_path, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    for payload in (_Evil(), {"time": np.arange(3.0), "x": _Evil()}):
        src = _feelsight(tmp_path / str(id(payload)), payload)
        refused(["import", "feelsight", src, "--out", tmp_path / "out"], "data.pkl", "os", "--trust-pickle")
        assert not (tmp_path / "PWNED_BY_PICKLE").exists() and not (tmp_path / "out").exists()


@pytest.mark.parametrize(
    "data,names",
    [
        ({"time": np.arange(5) / 30.0}, ["nothing to import"]),  # issue #22: wrote an empty session
        ({"nope": 1}, ["time"]),
        ([1, 2, 3], ["dict"]),
        ({"time": np.array([np.nan, 1.0])}, ["time"]),
        ({"time": np.arange(4.0), "allegro": {"joint_state": np.zeros((4, 15))}}, ["joint_state"]),
    ],
)
def test_import_bad_data_pkl(tmp_path, data, names) -> None:
    src = _feelsight(tmp_path, data)
    refused(["import", "feelsight", src, "--out", tmp_path / "out"], "data.pkl", *names)
    assert not (tmp_path / "out").exists()


def test_import_numpy_only_pickle_still_loads(tmp_path) -> None:
    from vtrack.io.importers.feelsight import load_data_pkl

    data = {"time": np.arange(3.0), "a": {"b": [np.float32(1.5), (1, 2)], "s": {1, 2}}, "o": np.zeros((2, 2), "f4")}
    for proto in (2, 4, 5):
        p = tmp_path / f"d{proto}.pkl"
        p.write_bytes(pickle.dumps(data, protocol=proto))
        got = load_data_pkl(p)
        assert got["a"]["b"][0] == 1.5 and got["a"]["s"] == {1, 2} and got["o"].shape == (2, 2)


# ----------------------------------------------------------------------------------------- tactile
def _press_set(tmp: Path, fill: int | None) -> Path:
    root = tmp / "gelsight_ball_presses"  # same folder name: the shipped preset gives its metadata
    shutil.copytree(PRESSES, root)
    if fill is not None:
        import cv2

        for p in root.glob("press_*.png"):
            img = cv2.imread(str(p))
            cv2.imwrite(str(p), np.full_like(img, fill))
    return root


@pytest.mark.parametrize("fill", [0, 255])
def test_calibrate_blank_presses_refused(tmp_path, fill) -> None:
    root = _press_set(tmp_path, fill)
    refused(["calibrate", root, "--out", tmp_path / "c.npz", "--method", "lut"], "press_", "blank")
    assert not (tmp_path / "c.npz").exists()


@pytest.mark.parametrize("fill", [0, 255, "background"])
def test_calibrate_unlabelled_junk_presses_refused(tmp_path, fill) -> None:
    """No labels.csv: black, white or no-contact presses -> every one dropped with its reason, exit 2."""
    import cv2

    root = _press_set(tmp_path, None if fill == "background" else fill)
    (root / "labels.csv").unlink()
    if fill == "background":
        bg = cv2.imread(str(root / "background.png"))
        for p in root.glob("press_*.png"):
            cv2.imwrite(str(p), bg)
    err = refused(["calibrate", root, "--out", tmp_path / "c.npz", "--method", "lut"], str(root), "usable presses")
    assert ("blank" in err) if fill != "background" else ("no contact" in err)
    assert not (tmp_path / "c.npz").exists() and not (tmp_path / "labels.auto.csv").exists()


def test_calibrate_with_wrong_labels_is_not_written(tmp_path) -> None:
    """Labels that do not match the images (mirrored, shuffled) give ~40 deg held-out normal error: the
    calibration is refused with the numbers instead of written (it used to be written with exit 0)."""
    import csv

    root = _press_set(tmp_path, None)
    rows = list(csv.reader(open(root / "labels.csv")))
    perm = np.random.default_rng(0).permutation(len(rows) - 1)
    with open(root / "labels.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(rows[0])
        for i, r in enumerate(rows[1:]):
            q = rows[1 + perm[i]]
            w.writerow([r[0], 640 - float(q[1]), 480 - float(q[2]), q[3]])
    err = refused(
        ["calibrate", root, "--out", tmp_path / "c.npz", "--method", "lut"],
        "c.npz",
        "not written",
        "held-out normal error",
    )
    assert float(err.split("normal error ")[1].split(" deg")[0]) > 15.0
    assert not (tmp_path / "c.npz").exists()


def test_calibrate_unlabelled_writes_auto_labels_and_review(tmp_path) -> None:
    root = _press_set(tmp_path, None)
    (root / "labels.csv").unlink()
    out = tmp_path / "out" / "c.npz"
    code, stdout, err = run(["calibrate", root, "--out", out, "--method", "lut", "--review", tmp_path / "s.png"])
    assert code == 0, err
    assert out.is_file() and (tmp_path / "s.png").is_file()
    lines = (out.parent / "labels.auto.csv").read_text().splitlines()
    assert len(lines) == 49 and "auto labels: 48 presses used, 0 dropped" in stdout
    from vtrack.tactile.calibration import Calibration

    assert Calibration.load(out).info["labels"] == "auto"


@pytest.mark.parametrize("kind", ["grey", "grey_as_colour", "not_an_image"])
def test_tactile_grey_or_junk_image_refused(tmp_path, kind) -> None:
    import cv2

    from vtrack.errors import InputError
    from vtrack.tactile.pressset import read_bgr

    img = cv2.imread(str(PRESSES / "press_00.png"))
    p = tmp_path / "t.png"
    if kind == "grey":
        cv2.imwrite(str(p), cv2.cvtColor(img, cv2.COLOR_BGR2GRAY))
    elif kind == "grey_as_colour":
        cv2.imwrite(str(p), cv2.cvtColor(cv2.cvtColor(img, cv2.COLOR_BGR2GRAY), cv2.COLOR_GRAY2BGR))
    else:
        p.write_text("hello")
    with pytest.raises(InputError, match="t.png") as e:
        read_bgr(p)
    assert "\n" not in str(e.value)
    assert read_bgr(PRESSES / "press_00.png").shape == img.shape  # a real colour frame still loads


# ----------------------------------------------------------------------------------------- dome
@pytest.fixture(scope="module")
def dome_images(tmp_path_factory) -> dict[str, Path]:
    import cv2

    from vtrack.dome.simulate import DomeSimulator

    d = tmp_path_factory.mktemp("dome")
    rng = np.random.default_rng(0)
    imgs = {
        "noise": rng.integers(0, 256, (160, 160)).astype(np.uint8),
        "black": np.zeros((160, 160), np.uint8),
        "white": np.full((160, 160), 255, np.uint8),
        "reference": DomeSimulator().reference_image(0.0),
    }
    out = {}
    for k, v in imgs.items():
        out[k] = d / f"{k}.png"
        cv2.imwrite(str(out[k]), v)
    (d / "text.png").write_text("not a png")
    out["text"] = d / "text.png"
    return out


@pytest.mark.parametrize("kind", ["noise", "black", "white", "text"])
def test_dome_garbage_refused(dome_images, kind) -> None:
    refused(["dome", "reconstruct", dome_images[kind]], str(dome_images[kind]))


def test_dome_real_fisheye_frame_refused_and_sim_frame_accepted(dome_images) -> None:
    real = SHARED / "dome_images" / "dome_markers_a.png"
    refused(["dome", "reconstruct", real, "--resize"], str(real), "not a frame of this dome sensor")
    code, out, _ = run(["dome", "reconstruct", dome_images["reference"]])
    res = json.loads(out[: out.rindex("}") + 1])
    assert code == 0 and res["n_markers"] > 300 and np.linalg.norm(res["force_n"]) < 1.0


@HYP
@given(seed=st.integers(0, 2**31 - 1), frac=st.floats(0.0, 1.0))
def test_dome_image_mutations_hypothesis(dome_images, tmp_path_factory, seed, frac) -> None:
    import cv2

    rng = np.random.default_rng(seed)
    img = cv2.imread(str(dome_images["reference"]), 0)
    mask = rng.random(img.shape) < frac  # replace a fraction of the pixels by noise
    img[mask] = rng.integers(0, 256, int(mask.sum()))
    p = tmp_path_factory.mktemp("dm") / "m.png"
    cv2.imwrite(str(p), img)
    code, out = ok_or_refused(["dome", "reconstruct", p], p)
    if code == 0:
        res = json.loads(out[: out.rindex("}") + 1])
        assert np.all(np.isfinite(res["force_n"])) and np.linalg.norm(res["force_n"]) < 50.0


# ----------------------------------------------------------------------------------------- batch / viewer
def test_batch_bad_inputs(tmp_path) -> None:
    (tmp_path / "notasession").mkdir()
    refused(["batch", "reconstruct", tmp_path / "notasession", "--out", tmp_path / "o"], "notasession")
    s = tiny_session(tmp_path / "s")
    refused(["batch", "reconstruct", s, "--out", tmp_path / "o", "--retries", "-1"], "retries")


def test_viewer_path_errors(tmp_path) -> None:
    refused(["view", tmp_path / "nope"], "nope")


@pytest.mark.parametrize(
    "host,origin,ok",
    [
        ("127.0.0.1:8080", "", True),  # non-browser client
        ("127.0.0.1:8080", "http://127.0.0.1:8080", True),  # the viewer's own page
        ("localhost:8080", "http://localhost:8080", True),
        ("127.0.0.1:8080", "http://evil.example", False),  # another site's page in the same browser
        ("evil.example:8080", "http://evil.example:8080", False),  # DNS rebinding
        ("127.0.0.1:8080", "null", False),  # sandboxed iframe / file:// page
    ],
)
def test_viewer_origin_check(host, origin, ok) -> None:
    from vtrack.viz.viewer import request_allowed

    headers = {"Host": host, **({"Origin": origin} if origin else {})}
    assert request_allowed(headers, "127.0.0.1")[0] is ok


def test_viewer_server_rejects_cross_origin_websocket() -> None:
    import http.client

    import viser

    from vtrack.viz.viewer import _origin_checked_serve

    with _origin_checked_serve("127.0.0.1"):
        srv = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    try:
        port = srv.get_port()

        def status(origin: str) -> int:
            c = http.client.HTTPConnection("127.0.0.1", port, timeout=10)
            c.putrequest("GET", "/", skip_host=True)
            for k, v in {
                "Host": f"127.0.0.1:{port}",
                "Origin": origin,
                "Upgrade": "websocket",
                "Connection": "Upgrade",
                "Sec-WebSocket-Key": "dGhlIHNhbXBsZSBub25jZQ==",
                "Sec-WebSocket-Version": "13",
            }.items():
                c.putheader(k, v)
            c.endheaders()
            return c.getresponse().status

        assert status("http://evil.example") == 403
        assert status(f"http://127.0.0.1:{port}") == 101
    finally:
        srv.stop()
