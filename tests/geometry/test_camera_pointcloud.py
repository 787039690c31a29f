"""Pinhole unprojection/projection and point-cloud helpers."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vtrack.errors import InputError
from vtrack.geometry.camera import PinholeCamera
from vtrack.geometry.pointcloud import estimate_normals, remove_outliers, row_norms, voxel_downsample
from vtrack.geometry.tactile_frame import gradient_at, height_to_points

CAM = PinholeCamera(64, 48, 60.0, 62.0, 31.5, 23.5)


@settings(max_examples=50, deadline=None)
@given(st.floats(0.2, 5.0), st.integers(0, 47), st.integers(0, 63))
def test_unproject_project_round_trip(z: float, row: int, col: int) -> None:
    depth = np.zeros((48, 64), dtype=np.float32)
    depth[row, col] = z
    pts, pix = CAM.unproject(depth)
    assert pts.shape == (1, 3) and tuple(pix[0]) == (row, col)
    uv, front = CAM.project(pts)
    assert front[0]
    assert np.allclose(uv[0], [col, row], atol=1e-4)


def test_unproject_drops_invalid_depth_and_respects_mask() -> None:
    depth = np.full((48, 64), 1000, dtype=np.uint16)  # 1 m in mm
    depth[0, :] = 0
    f = depth.astype(np.float32) / 1000
    f[1, :] = np.nan
    f[2, :] = np.inf
    f[3, :] = -1
    pts, _ = CAM.unproject(f)
    assert len(pts) == 44 * 64 and np.all(np.isfinite(pts))
    mask = np.zeros((48, 64), bool)
    mask[10:20, 10:20] = True
    pts, pix = CAM.unproject(depth, mask=mask)
    assert len(pts) == 100 and np.allclose(pts[:, 2], 1.0)
    assert pix[:, 0].min() == 10 and pix[:, 1].max() == 19
    pts, _ = CAM.unproject(depth, stride=4)
    assert len(pts) == 11 * 16  # rows 4, 8, ..., 44 (row 0 has no depth) x 16 columns


def test_unproject_plane_geometry() -> None:
    depth = np.full((48, 64), 2.0)
    pts, _ = CAM.unproject(depth)
    # Corner pixel (0, 0) -> x = (0 - cx)/fx * z.
    assert np.isclose(pts[:, 0].min(), -31.5 / 60.0 * 2.0)
    assert np.isclose(pts[:, 1].max(), (47 - 23.5) / 62.0 * 2.0)


def test_camera_bad_input() -> None:
    with pytest.raises(InputError, match="depth"):
        CAM.unproject(np.zeros((10, 10)))
    with pytest.raises(InputError, match="mask"):
        CAM.unproject(np.ones((48, 64)), mask=np.ones((2, 2), bool))
    with pytest.raises(InputError, match="fx"):
        PinholeCamera(10, 10, 0.0, 1.0, 5, 5)
    uv, front = CAM.project(np.array([[0, 0, -1.0]]))
    assert not front[0] and np.all(np.isnan(uv))


def test_voxel_downsample_means_and_groups() -> None:
    P = np.array([[0.001, 0, 0], [0.002, 0, 0], [0.5, 0, 0], [np.nan, 0, 0]])
    val = np.array([1.0, 3.0, 5.0, 7.0])
    lab = np.array([0, 1, 0, 0])
    Q, v = voxel_downsample(P, 0.01, val)
    assert len(Q) == 2 and np.allclose(sorted(v), [2.0, 5.0])
    Q, v, labs = voxel_downsample(P, 0.01, val, lab, group=lab)
    assert len(Q) == 3  # the two near points stay apart: different groups
    empty = voxel_downsample(np.zeros((0, 3)), 0.01)
    assert empty[0].shape == (0, 3)
    with pytest.raises(InputError, match="voxel_size"):
        voxel_downsample(P, 0.0)


def test_normals_of_a_plane_and_degenerate_input() -> None:
    rng = np.random.default_rng(0)
    P = np.c_[rng.uniform(-1, 1, (500, 2)), np.zeros(500)]
    n = estimate_normals(P, k=12, viewpoint=[0, 0, 5])
    assert np.allclose(n[:, 2], 1.0, atol=1e-9)
    line = np.c_[np.linspace(0, 1, 20), np.zeros(20), np.zeros(20)]
    assert np.all(estimate_normals(line) == 0)  # collinear: flagged with zero normals, no NaN
    assert estimate_normals(np.zeros((2, 3))).shape == (2, 3)


def test_outlier_removal_finds_far_points() -> None:
    rng = np.random.default_rng(1)
    P = np.r_[rng.normal(size=(300, 3)) * 0.01, [[5.0, 5.0, 5.0], [-4.0, 3.0, 1.0]]]
    keep = remove_outliers(P)
    assert not keep[-1] and not keep[-2] and keep[:300].mean() > 0.95


def test_norms_equal_numpy_norms() -> None:
    # the per-frame paths' vector lengths: np.linalg.norm's floats, bit for bit, at any scale
    rng = np.random.default_rng(4)
    for n in (0, 1, 7, 3000):
        v = rng.normal(size=(n, 3)) * 10.0 ** rng.uniform(-6, 3, size=(n, 1))
        np.testing.assert_array_equal(row_norms(v), np.linalg.norm(v, axis=1))


def test_gradient_at_pixels_equals_numpy_gradient() -> None:
    # height_to_points differentiates only at the lifted pixels: the same floats as np.gradient, borders included
    rng = np.random.default_rng(5)
    for H, W, s in ((2, 2, 0.25), (3, 17, 0.1), (31, 28, 0.0625), (9, 2, 1)):
        f = rng.normal(size=(H, W)) * 3.0
        rows, cols = (a.ravel() for a in np.mgrid[0:H, 0:W])
        gy, gx = np.gradient(f, s)
        np.testing.assert_array_equal(gradient_at(f, rows, cols, 0, s), gy.ravel())
        np.testing.assert_array_equal(gradient_at(f, rows, cols, 1, s), gx.ravel())


def test_tactile_height_to_points_sphere() -> None:
    # A 2 mm-radius ball pressed 0.5 mm into a flat gel: lifted points lie on the sphere.
    s = 0.05
    H, W = 81, 101
    r, c = np.mgrid[0:H, 0:W]
    x = (c - (W - 1) / 2) * s
    y = (r - (H - 1) / 2) * s
    R, d = 2.0, 0.5
    h = np.clip(np.sqrt(np.clip(R**2 - x**2 - y**2, 0, None)) - (R - d), 0, None)
    pts, nrm = height_to_points(h, s, mask=h > 0)
    # The deformed surface is z = -h; the ball lies outside the gel (+z), its centre at z = R - d.
    centre = np.array([0.0, 0.0, (R - d) / 1000.0])
    dist = np.linalg.norm(pts - centre, axis=1) * 1000.0
    assert np.abs(dist - R).max() < 0.02
    # Normals point out of the gel (towards the ball centre) at the contact.
    to_centre = centre - pts
    cosang = np.einsum("ij,ij->i", nrm, to_centre / np.linalg.norm(to_centre, axis=1, keepdims=True))
    assert np.median(cosang) > 0.99
