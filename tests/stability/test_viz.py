"""Viewer/screenshot hard cases: degenerate clouds, meshes, poses, single frames, NaN images."""

from __future__ import annotations

import json

import numpy as np
import pytest

from vtrack.errors import InputError
from vtrack.io.export import write_ply_points

pytestmark = pytest.mark.stability


def _rec(tmp_path, points, scalars=None, mesh=None, meta=None):
    d = tmp_path / "rec"
    d.mkdir(exist_ok=True)
    write_ply_points(d / "cloud.ply", np.asarray(points, np.float64).reshape(-1, 3), scalars=scalars)
    if mesh is not None:
        (d / "mesh.ply").write_bytes(mesh)
    (d / "result.json").write_text(json.dumps(meta or {"kind": "reconstruction"}))
    return d


def test_constant_time_nan_scalars_single_frame(tmp_path):
    from vtrack.viz.data import ViewData
    from vtrack.viz.screenshot import render_scene
    from vtrack.viz.viewer import Viewer

    n = 500
    rng = np.random.default_rng(0)
    d = _rec(
        tmp_path,
        rng.normal(size=(n, 3)) * 0.01,
        scalars={
            "modality": np.ones(n, np.int32),
            "t": np.full(n, 2.0),
            "tactile_value": np.full(n, np.nan, np.float32),
            "confidence": np.full(n, np.inf, np.float32),
        },
    )
    v = ViewData(d)
    assert v.n_frames == 1 and not v.cloud.has_time and v.recon_frame == "world"
    for mode, c in v.cloud.colors.items():
        assert c.shape == (n, 3) and c.dtype == np.uint8, mode
    assert np.all(v.cloud.colors["tactile value"] == (150, 150, 150))
    img = render_scene(v, size=(200, 150))
    assert img.shape[:2] == (150, 200) and (img < 200).any()
    viewer = Viewer(v, port=0, log=lambda m: None)
    try:
        assert viewer.slider.disabled and viewer.play_btn.disabled
        assert np.isfinite(viewer.update_frame(5))  # clamped to the only frame
        assert sum(viewer.bins.shown) == n
    finally:
        viewer.stop()


def test_empty_cloud_and_faceless_mesh_without_session(tmp_path):
    from vtrack.viz.data import ViewData

    header = b"ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\nproperty float y\nproperty float z\n"
    header += b"element face 0\nproperty list uchar int vertex_indices\nend_header\n"
    d = _rec(tmp_path, np.zeros((0, 3)), mesh=header)
    with pytest.raises(InputError, match="no points and no faces"):
        ViewData(d)


def test_all_nan_points_and_nan_mesh(tmp_path):
    from vtrack.viz.data import ViewData, load_mesh

    d = _rec(tmp_path, np.full((10, 3), np.nan))
    with pytest.raises(InputError, match="no points and no faces"):
        ViewData(d)
    import trimesh

    m = trimesh.creation.box()
    V = np.asarray(m.vertices).copy()
    V[0] = np.nan
    p = tmp_path / "bad.ply"
    trimesh.Trimesh(V, m.faces, process=False).export(p)
    with pytest.raises(InputError, match="non-finite"):
        load_mesh(p)
    (tmp_path / "junk.ply").write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 5\n")
    with pytest.raises(InputError, match="cannot read"):
        load_mesh(tmp_path / "junk.ply")


def test_truncated_cloud_ply(tmp_path):
    from vtrack.viz.data import ViewData

    d = _rec(tmp_path, np.random.default_rng(0).normal(size=(100, 3)))
    raw = (d / "cloud.ply").read_bytes()
    (d / "cloud.ply").write_bytes(raw[: len(raw) - 500])
    with pytest.raises(InputError, match="cloud"):
        ViewData(d)


def test_tracking_all_lost_and_zero_quaternions(tmp_path):
    from vtrack.viz.data import ViewData
    from vtrack.viz.screenshot import render_scene
    from vtrack.viz.viewer import Viewer

    d = tmp_path / "trk"
    d.mkdir()
    rows = ["t,x,y,z,qx,qy,qz,qw"] + [f"{0.1 * k},nan,nan,nan,0,0,0,0" for k in range(5)]
    rows.append("0.6,0.1,0,0,0,0,0,0")  # zero quaternion: invalid, not identity
    (d / "poses.csv").write_text("\n".join(rows) + "\n")
    (d / "result.json").write_text(json.dumps({"kind": "tracking"}))
    v = ViewData(d)
    assert v.n_frames == 6
    assert any("6 rows without a valid estimate" in n for n in v.notes)
    st = v.frame(3)
    assert st.T_world_object_est is None
    assert np.allclose(v.object_pose(st), np.eye(4))
    lo, hi = v.bounds()
    assert np.isfinite(lo).all() and np.isfinite(hi).all() and (hi > lo).all()
    assert render_scene(v, size=(160, 120)).shape == (120, 160, 3)
    viewer = Viewer(v, port=0, log=lambda m: None)
    try:
        assert viewer.traj.get("estimate") is None  # no valid segment to draw
        for i in range(6):
            assert np.isfinite(viewer.update_frame(i))
    finally:
        viewer.stop()


def test_height_colouring_nan_and_zero_range():
    from vtrack.viz.colors import colorize_height, scalar_colors

    h = np.array([[np.nan, 0.0], [1.0, np.inf]])
    img = colorize_height(h, 0.0)  # zero range must not divide by zero
    assert img.shape == (2, 2, 3) and np.all(img[0, 0] == 0) and np.all(img[1, 1] == 0)
    assert scalar_colors(np.zeros(0)).shape == (0, 3)


def test_decimation_budget_edge_cases():
    from vtrack.viz.data import decimate_indices

    assert len(decimate_indices(np.zeros(0, np.int64), 10)) == 0
    assert len(decimate_indices(np.ones(7, np.int64), 1)) == 1
    idx = decimate_indices(np.r_[np.ones(3, np.int64), np.zeros(1000, np.int64)], 10)
    assert len(idx) == 10 and set(range(3)) <= set(idx.tolist())
