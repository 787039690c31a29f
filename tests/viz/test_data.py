"""Loading sessions / result folders for display: resolution, readers, decimation, colours, frames."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from vtrack.errors import InputError
from vtrack.io.poses import read_pose_table
from vtrack.viz import colors as C
from vtrack.viz.data import ViewData, decimate_indices, load_cloud, resolve_sources


def test_resolve_demo_folder_finds_both_results_and_session(view_fixture):
    src = resolve_sources(view_fixture["demo"])
    assert src.reconstruction == view_fixture["reconstruction"].resolve()
    assert src.tracking == view_fixture["tracking"].resolve()
    assert src.session == view_fixture["session"]
    assert resolve_sources(view_fixture["session"]).session == view_fixture["session"].resolve()
    # A file inside a result folder resolves to the folder.
    assert resolve_sources(view_fixture["tracking"] / "poses.csv").tracking == view_fixture["tracking"].resolve()


def test_view_data_contents(view_fixture):
    d = ViewData(view_fixture["demo"])
    assert d.n_frames == 12
    assert d.recon_frame == "object"
    assert len(d.cloud) == 6000 and d.cloud.has_time
    assert np.all(np.diff(d.cloud.t) >= 0)
    assert d.mesh is not None and len(d.mesh[1]) == 12
    assert d.gt_mesh is not None
    assert set(d.tactile) == {"digit_index", "digit_thumb"}
    assert [c.name for c in d.cameras] == ["cam0"]
    st = d.frame(5)
    assert st.t == pytest.approx(5 / 30.0)
    # Estimate is GT + a drift along x of 0.002 * k / 12 m.
    assert st.T_world_object_est[0, 3] - st.T_world_object_gt[0, 3] == pytest.approx(0.002 * 5 / 12, abs=1e-7)
    # Panel strip = tactile image | height | contact, each 32 px high.
    for img in st.panels.values():
        assert img.dtype == np.uint8 and img.shape[0] == 32 and img.shape[1] == 3 * 24 + 2 * 3
    assert st.camera_images["cam0"].shape == (48, 64, 3)
    # Cloud prefix grows with time and reaches all points at the end.
    counts = [d.cloud.count_until(t) for t in d.times]
    assert counts == sorted(counts) and counts[-1] == len(d.cloud)
    if view_fixture["hand"]:
        assert set(st.sensor_poses) == {"digit_index", "digit_thumb"}
        assert len(st.link_poses) > 10
        T = st.sensor_poses["digit_index"]
        assert np.allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-9)


def test_recon_only_and_tracking_only(view_fixture, tmp_path):
    rec = tmp_path / "rec"
    shutil.copytree(view_fixture["reconstruction"], rec)
    (rec / "result.json").write_text(json.dumps({"kind": "reconstruction", "session": str(tmp_path / "gone")}))
    d = ViewData(rec)
    assert d.session is None and d.cloud is not None
    assert any("was not found" in n for n in d.notes)
    assert d.recon_frame == "world"  # no "frame" key and no object poses to place it with
    d2 = ViewData(view_fixture["tracking"])
    assert d2.est is not None and d2.gt_T is not None and d2.n_frames == 12


def test_pose_table_reader(view_fixture, tmp_path):
    p = read_pose_table(view_fixture["tracking"] / "poses.csv")
    assert p["T_est"].shape == (12, 4, 4) and p["T_gt"].shape == (12, 4, 4)
    R = p["T_gt"][3, :3, :3]
    assert np.allclose(R @ R.T, np.eye(3), atol=1e-6)
    bad = tmp_path / "poses.csv"
    bad.write_text("t,x,y,z,qx,qy,qw\n0,0,0,0,0,0,1\n")
    with pytest.raises(InputError, match="lacks required columns") as e:
        read_pose_table(bad)
    assert "qz" in str(e.value)
    bad.write_text("t,x,y,z,qx,qy,qz,qw\n")
    with pytest.raises(InputError, match="no rows"):
        read_pose_table(bad)
    # Extra text columns (the tracker writes `status`) are ignored; a NaN row is a lost estimate.
    bad.write_text("t,x,y,z,qx,qy,qz,qw,status,ms\n0.1,nan,0,0,0,0,0,0,lost,3.1\n0,1,2,3,0,0,0,1,ok,2.0\n")
    p = read_pose_table(bad)
    assert np.allclose(p["t"], [0.0, 0.1])  # sorted by time
    assert np.allclose(p["T_est"][0, :3, 3], [1, 2, 3]) and np.isnan(p["T_est"][1]).all()
    bad.write_text("t,x,y,z,qx,qy,qz,qw\n0,1,2,abc,0,0,0,1\n")
    with pytest.raises(InputError, match="non-numeric") as e:
        read_pose_table(bad)
    assert "'z'" in str(e.value) and "abc" in str(e.value)
    bad.write_text("t,x,y,z,qx,qy,qz,qw\n0,1,2\n")
    with pytest.raises(InputError, match="row 2 has 3 fields"):
        read_pose_table(bad)


@pytest.mark.parametrize(
    "case, match",
    [
        ("missing", "path does not exist"),
        ("empty", "not a vtrack session or result folder"),
        ("corrupt_json", "corrupt result.json"),
        ("bad_kind", "unknown result kind"),
        ("no_ply", "neither mesh.ply nor cloud.ply"),
        ("no_poses", "poses.csv is missing"),
        ("bad_file", "expected a folder"),
    ],
)
def test_bad_paths_give_clear_errors(tmp_path, case, match):
    d = tmp_path / "x"
    if case != "missing":
        d.mkdir()
    if case == "corrupt_json":
        (d / "result.json").write_text("{kind: ")
    elif case == "bad_kind":
        (d / "result.json").write_text(json.dumps({"kind": "movie"}))
    elif case == "no_ply":
        (d / "result.json").write_text(json.dumps({"kind": "reconstruction"}))
    elif case == "no_poses":
        (d / "result.json").write_text(json.dumps({"kind": "tracking"}))
    elif case == "bad_file":
        d = d / "notes.txt"
        d.write_text("hi")
    with pytest.raises(InputError, match=match) as e:
        ViewData(d)
    assert str(d.name) in str(e.value)


def test_decimation_keeps_touch_and_budget():
    mod = np.zeros(100_000, np.int64)
    mod[:500] = 1
    idx = decimate_indices(mod, 10_000)
    assert len(idx) == 10_000 and np.all(np.diff(idx) > 0)
    assert (mod[idx] == 1).sum() == 500  # every touch point survives
    mod[:] = 1
    idx = decimate_indices(mod, 10_000)
    assert len(idx) == 10_000  # all-touch cloud: half budget of touch + nothing else -> fills with rest
    assert len(decimate_indices(mod[:50], 10_000)) == 50


def test_load_cloud_decimates_and_colours(tmp_path):
    from vtrack.io.export import write_ply_points

    rng = np.random.default_rng(1)
    n = 30_000
    P = rng.normal(size=(n, 3))
    P[:10] = np.nan
    mod = (rng.random(n) < 0.1).astype(np.int32)
    write_ply_points(
        tmp_path / "cloud.ply",
        P,
        scalars={"modality": mod, "t": rng.uniform(0, 2, n), "tactile_value": rng.uniform(0, 2, n)},
    )
    notes: list[str] = []
    c = load_cloud(tmp_path / "cloud.ply", max_points=5000, notes=notes)
    assert len(c) == 5000 and c.n_total == n
    assert any("non-finite" in m for m in notes) and any("decimated" in m for m in notes)
    assert np.isfinite(c.points).all()
    assert np.all(c.colors["modality"][c.modality == 0] == C.VISION_RGB)
    assert np.all(c.colors["tactile value"][c.modality == 0] == C.NEUTRAL_RGB)
    assert "rgb" not in c.colors


def test_scalar_colors_constant_and_nonfinite():
    out = C.scalar_colors(np.array([1.0, 1.0, np.nan, np.inf]))
    assert out.dtype == np.uint8
    assert np.all(out[0] == out[1]) and np.all(out[2] == C.NEUTRAL_RGB) and np.all(out[3] == C.NEUTRAL_RGB)
    ramp = C.scalar_colors(np.linspace(0, 1, 5))
    assert len({tuple(r) for r in ramp}) == 5


def test_hand_mesh_cache_roundtrip_and_corruption(view_fixture):
    import pytest as _pytest

    from vtrack.viz.data import _hand_cache_path

    if not view_fixture["hand"]:
        _pytest.skip("shared Allegro URDF not available")
    d1 = ViewData(view_fixture["session"])
    p = _hand_cache_path(d1.hand.urdf_path)
    assert p is not None and p.exists()
    d2 = ViewData(view_fixture["session"])  # from the cache
    assert list(d1.link_meshes) == list(d2.link_meshes)
    for link in d1.link_meshes:
        for (V1, F1), (V2, F2) in zip(d1.link_meshes[link], d2.link_meshes[link], strict=True):
            assert np.array_equal(V1, V2) and np.array_equal(F1, F2)
    p.write_bytes(b"garbage")
    d3 = ViewData(view_fixture["session"])  # corrupt cache: rebuilt, same meshes
    assert sum(len(v) for v in d3.link_meshes.values()) == sum(len(v) for v in d1.link_meshes.values())


def test_cloud_times_outside_session_span(view_fixture, tmp_path):
    import shutil

    from vtrack.io.export import read_ply_points, write_ply_points
    from vtrack.viz.data import ViewData

    rec = tmp_path / "rec2"
    shutil.copytree(view_fixture["reconstruction"], rec)
    d = read_ply_points(rec / "cloud.ply")
    P = np.stack([d.pop("x"), d.pop("y"), d.pop("z")], axis=1)
    d["t"] = d["t"] + 1000.0  # another time base than the session (which starts at 0 s)
    write_ply_points(rec / "cloud.ply", P, scalars=d)
    v = ViewData(rec)
    assert not v.cloud.has_time and any("outside the session" in n for n in v.notes)
