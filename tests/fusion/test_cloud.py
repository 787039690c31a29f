"""Unified cloud: RGB-D and tactile builders, frames, modality-balanced downsampling, PLY export."""

from __future__ import annotations

import numpy as np

from vtrack.fusion.cloud import TOUCH, VISION, UnifiedCloud, from_rgbd, from_tactile
from vtrack.geometry import se3
from vtrack.geometry.camera import PinholeCamera
from vtrack.io.export import read_ply_points


def _plane_depth(cam, z=0.5):
    return np.full((cam.height, cam.width), int(z * 1000), np.uint16)


def test_rgbd_plane_world_frame_and_normals():
    cam = PinholeCamera.from_fov(64, 48, np.deg2rad(50))
    T = se3.make_transform(np.eye(3), [0.1, -0.2, 0.3])
    mask = np.zeros((48, 64), np.uint8)
    mask[10:30, 20:50] = 1
    c = from_rgbd(_plane_depth(cam), cam, T, mask=mask, t=1.5, sensor_id=2)
    assert c.frame == "world" and len(c) == 20 * 30
    np.testing.assert_allclose(c.xyz[:, 2], 0.8, atol=1e-9)  # z = 0.5 in camera + 0.3 offset
    inner = np.linalg.norm(c.normal, axis=1) > 0
    assert inner.sum() > 0.7 * len(c)
    np.testing.assert_allclose(c.normal[inner], np.tile([0, 0, -1.0], (inner.sum(), 1)), atol=1e-9)
    assert np.all(c.modality == VISION) and np.all(c.sensor_id == 2) and np.all(c.t == 1.5)
    assert np.all((c.confidence > 0) & (c.confidence <= 1))


def test_rgbd_empty_and_nan_depth():
    cam = PinholeCamera.from_fov(32, 24, 1.0)
    assert len(from_rgbd(np.zeros((24, 32), np.uint16), cam, np.eye(4))) == 0
    d = np.full((24, 32), np.nan, np.float32)
    d[5, 5] = 0.4
    c = from_rgbd(d, cam, np.eye(4))
    assert len(c) == 1 and np.isfinite(c.xyz).all() and np.isfinite(c.normal).all()


def test_tactile_contact_points_in_world():
    h = np.zeros((40, 30))
    h[10:20, 5:15] = 1.0  # 1 mm flat indentation
    T_ws = se3.make_transform(np.eye(3), [0.0, 0.0, 0.1])
    c = from_tactile(h, None, 0.1, T_ws, t=0.2, sensor_id=1, stride=1)
    assert len(c) == 100 and np.all(c.modality == TOUCH)
    np.testing.assert_allclose(c.xyz[:, 2], 0.1 - 0.001)
    np.testing.assert_allclose(c.tactile_value, 1.0)
    # interior normals of the flat patch: object outward normal = -z of the sensor
    interior = np.abs(c.normal[:, 2]) > 0.999
    assert interior.sum() >= 36 and np.all(c.normal[interior, 2] < 0)
    none = from_tactile(np.zeros((40, 30)), None, 0.1, T_ws)
    assert len(none) == 0


def test_voxel_downsample_keeps_modalities_and_balance():
    rng = np.random.default_rng(0)
    v = rng.uniform(-0.05, 0.05, (20000, 3))
    t = rng.uniform(-0.005, 0.005, (500, 3))
    n = len(v) + len(t)
    c = UnifiedCloud(
        np.vstack([v, t]),
        np.tile([0, 0, 1.0], (n, 1)),
        [VISION] * len(v) + [TOUCH] * len(t),
        np.zeros(n),
        np.zeros(n),
        np.ones(n),
        np.zeros(n),
    )
    d = c.voxel_downsample(0.01, touch_voxel_size=0.002)
    cnt = d.counts()
    assert 900 < cnt["vision"] < 1100  # 10 x 10 x 10 voxels
    assert cnt["touch"] > 100  # fine touch voxels survive
    w = d.balance_weights()
    assert np.isclose(w[d.modality == VISION].sum(), w[d.modality == TOUCH].sum())
    np.testing.assert_allclose(np.linalg.norm(d.normal, axis=1), 1.0)


def test_ply_export_round_trip(tmp_path):
    n = 10
    c = UnifiedCloud(
        np.arange(30.0).reshape(10, 3) * 1e-3,
        np.tile([1, 0, 0.0], (n, 1)),
        [0] * 5 + [1] * 5,
        np.arange(n),
        np.linspace(0, 1, n),
        np.full(n, 0.5),
        np.arange(n) * 0.1,
    )
    d = read_ply_points(c.to_ply(tmp_path / "c.ply"))
    np.testing.assert_array_equal(d["modality"], [0] * 5 + [1] * 5)
    np.testing.assert_allclose(d["t"], np.linspace(0, 1, n), atol=1e-6)
    np.testing.assert_allclose(d["tactile_value"], np.arange(n) * 0.1, atol=1e-6)
    assert set(d) >= {"x", "y", "z", "nx", "sensor_id", "confidence"}


def test_transform_per_point_to_object_frame():
    c = from_tactile(np.ones((4, 4)), None, 0.1, np.eye(4), stride=1)
    T = np.stack([se3.make_transform(np.eye(3), [0, 0, 1.0])] * len(c))
    o = c.transform_per_point(T, "object")
    assert o.frame == "object"
    np.testing.assert_allclose(o.xyz[:, 2], c.xyz[:, 2] + 1.0)
