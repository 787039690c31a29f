"""Hard cases for the foundation layers: geometry, cameras, clouds, sessions, scenes."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from vtrack.errors import InputError
from vtrack.geometry import se3
from vtrack.geometry.camera import PinholeCamera
from vtrack.geometry.pointcloud import estimate_normals, voxel_downsample
from vtrack.geometry.tactile_frame import height_to_points
from vtrack.io import streams
from vtrack.io.session import SessionWriter, open_session

pytestmark = pytest.mark.stability
CAM = PinholeCamera(32, 24, 30.0, 30.0, 15.5, 11.5)


def test_all_nan_depth_gives_empty_cloud() -> None:
    pts, pix = CAM.unproject(np.full((24, 32), np.nan, dtype=np.float32))
    assert pts.shape == (0, 3) and pix.shape == (0, 2)


def test_float32_extreme_depths_are_dropped_or_exact() -> None:
    d = np.full((24, 32), np.float32(1e-6))  # too near
    d[0, 0] = np.float32(3.4e38)  # float32 max: beyond range
    d[1, 1] = np.float32(9.99)  # far but valid
    pts, _ = CAM.unproject(d, max_depth=10.0)
    assert len(pts) == 1 and np.isclose(pts[0, 2], 9.99, rtol=1e-6)


def test_uint16_saturated_depth_is_far_not_garbage() -> None:
    d = np.full((24, 32), 65535, dtype=np.uint16)
    pts, _ = CAM.unproject(d, depth_scale=0.001, max_depth=10.0)
    assert len(pts) == 0


def test_empty_and_coincident_clouds() -> None:
    assert voxel_downsample(np.zeros((0, 3)), 0.01)[0].shape == (0, 3)
    same = np.ones((50, 3))
    q = voxel_downsample(same, 0.01)[0]
    assert q.shape == (1, 3) and np.allclose(q, 1.0)
    n = estimate_normals(same)
    assert np.all(np.isfinite(n)) and np.all(n == 0)


def test_far_from_origin_voxelisation_keeps_precision() -> None:
    rng = np.random.default_rng(0)
    local = rng.uniform(0, 0.01, (1000, 3))
    far = local + 10.0
    a = voxel_downsample(local, 0.002)[0]
    b = voxel_downsample(far, 0.002)[0]
    assert len(a) == len(b)
    assert np.allclose(np.sort(a, axis=0) + 10.0, np.sort(b, axis=0), atol=1e-9)


def test_nan_pose_inputs_rejected_or_contained() -> None:
    with pytest.raises(InputError):
        se3.quat_to_matrix(np.array([0.0, 0.0, 0.0, 0.0]))
    assert not se3.is_rigid(np.full((4, 4), np.nan))
    phi = se3.so3_log(np.eye(3))
    assert np.all(phi == 0)


def test_tactile_height_with_nan_and_empty_mask() -> None:
    h = np.zeros((20, 30))
    h[5, 5] = np.nan
    h[10, 10] = np.inf
    pts, n = height_to_points(h, 0.1)
    assert len(pts) == 20 * 30 - 2 and np.all(np.isfinite(pts)) and np.all(np.isfinite(n))
    pts, n = height_to_points(h, 0.1, mask=np.zeros_like(h, bool))
    assert pts.shape == (0, 3) and n.shape == (0, 3)
    pts, _ = height_to_points(np.ones((1, 1)), 0.1)  # single pixel
    assert pts.shape == (1, 3) and np.isclose(pts[0, 2], -0.001)


def test_duplicate_timestamps_rejected_at_write(tmp_path: Path) -> None:
    w = SessionWriter(tmp_path / "s", None)
    w.add_stream("joints", streams.joints_stream(["a"]))
    w.append("joints", 1.0, q=np.zeros(1))
    with pytest.raises(InputError, match="strictly increasing"):
        w.append("joints", 1.0, q=np.zeros(1))
    with pytest.raises(InputError, match="strictly increasing"):
        w.append("joints", 0.5, q=np.zeros(1))
    w.close()
    assert len(open_session(tmp_path / "s")["joints"]) == 1


def test_empty_stream_and_single_frame_sampling(tmp_path: Path) -> None:
    with SessionWriter(tmp_path / "s", None) as w:
        w.add_stream("joints", streams.joints_stream(["a"]))
        w.add_stream("gt/object_pose", streams.pose_stream())
        w.append("gt/object_pose", 0.0, T_world_object=np.eye(4))
    r = open_session(tmp_path / "s")
    assert len(r["joints"]) == 0
    with pytest.raises(InputError, match="no frames"):
        r["joints"].index_at(0.0)
    T = r["gt/object_pose"].sample("T_world_object", [-5.0, 0.0, 5.0], mode="linear")
    assert np.allclose(T, np.eye(4))
    with pytest.raises(InputError, match="finite"):
        r["gt/object_pose"].sample("T_world_object", [np.nan])


def test_depth_encoding_marks_out_of_range_as_missing() -> None:
    from vtrack.io.streams import encode_depth

    d = np.array([[0.0005, 0.0015, 1.2344, 65.535], [65.6, np.nan, -np.inf, -0.2]])
    out = encode_depth(d, 0.001)
    # Round to nearest mm; beyond the uint16 range and invalid values become 0 ("no measurement").
    assert out.dtype == np.uint16
    assert out.tolist() == [[0, 2, 1234, 65535], [0, 0, 0, 0]]
    raw = np.array([[1, 2]], np.uint16)
    assert encode_depth(raw) is raw
    with pytest.raises(InputError, match="depth"):
        encode_depth(np.array([["a"]]))
