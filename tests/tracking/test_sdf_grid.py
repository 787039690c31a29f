import numpy as np
import pytest

from vtrack.errors import InputError
from vtrack.tracking.sdf_grid import SDFGrid


def _sphere_grid(r=0.03, voxel=0.002, half=0.05):
    ax = np.arange(-half, half + 1e-9, voxel)
    X, Y, Z = np.meshgrid(ax, ax, ax, indexing="ij")
    return SDFGrid(np.sqrt(X**2 + Y**2 + Z**2) - r, np.full(3, -half), voxel)


def test_sphere_value_and_gradient():
    g = _sphere_grid()
    rng = np.random.default_rng(0)
    d = rng.normal(size=(500, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    P = d * rng.uniform(0.02, 0.04, (500, 1))
    sdf, grad = g.query(P)
    true = np.linalg.norm(P, axis=1) - 0.03
    assert np.abs(sdf - true).max() < 1e-4  # trilinear error well under 0.1 mm at 2 mm voxels
    cos = np.sum(grad / np.linalg.norm(grad, axis=1, keepdims=True) * d, axis=1)
    assert cos.min() > 0.99
    assert np.abs(np.linalg.norm(grad, axis=1) - 1).max() < 0.05


def test_outside_box_is_finite_and_attracting():
    g = _sphere_grid()
    P = np.array([[0.5, 0.0, 0.0], [0.0, -1.0, 0.3]])
    sdf, grad = g.query(P)
    assert np.all(np.isfinite(sdf)) and np.all(np.isfinite(grad))
    assert sdf[0] > 0.4 and sdf[1] > 0.9
    assert grad[0, 0] > 0.9  # moving the point towards the box decreases the distance


def test_gradient_matches_finite_differences():
    rng = np.random.default_rng(1)
    g = SDFGrid(rng.normal(size=(5, 6, 7)), np.array([0.1, -0.2, 0.3]), 0.01)
    # keep points away from cell faces, where the trilinear gradient is discontinuous
    cells = rng.integers(0, [4, 5, 6], (100, 3)) + rng.uniform(0.05, 0.95, (100, 3))
    P = np.array([0.1, -0.2, 0.3]) + cells * 0.01
    _, grad = g.query(P)
    e = 1e-6
    num = np.stack(
        [
            (g.query(P + e * np.eye(3)[k], False)[0] - g.query(P - e * np.eye(3)[k], False)[0]) / (2 * e)
            for k in range(3)
        ],
        1,
    )
    assert np.abs(num - grad).max() < 1e-3 * np.abs(grad).max()


def test_mesh_grid_sign_and_cache(tmp_path, mustard_mesh):
    from vtrack.io.mesh import load_mesh

    g = SDFGrid.from_mesh(mustard_mesh, voxel=0.004, padding=0.01)
    V, _ = load_mesh(mustard_mesh)
    c = 0.5 * (V.min(0) + V.max(0))
    inside, _ = g.query(c[None])
    assert inside[0] < -0.01  # the bottle centre is > 1 cm inside
    far, _ = g.query((V.max(0) + 0.005)[None])
    assert far[0] > 0.0
    g.save(tmp_path / "g.npz")
    g2 = SDFGrid.load(tmp_path / "g.npz")
    assert np.array_equal(g2.values, g.values) and g2.voxel == g.voxel
    g3 = SDFGrid.from_mesh(mustard_mesh, voxel=0.004, padding=0.01)  # from the cache
    assert np.array_equal(g3.values, g.values)


def test_bad_inputs():
    with pytest.raises(InputError):
        SDFGrid(np.zeros((1, 4, 4)), np.zeros(3), 0.01)
    with pytest.raises(InputError):
        SDFGrid(np.zeros((4, 4, 4)), np.zeros(3), 0.0)
    with pytest.raises(InputError):
        SDFGrid.from_mesh("/nonexistent/mesh.ply")
    with pytest.raises(InputError):
        SDFGrid.from_arrays(np.full((4, 3), np.nan), np.array([[0, 1, 2]] * 4))


def _query_einsum(grid: SDFGrid, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The row-major (N, 3) / np.einsum formulation of SDFGrid.query that the coordinate-major one replaced."""
    g = (P - grid.origin) / grid.voxel
    gc = np.minimum(np.maximum(g, 0.0), (grid._shape - 1).astype(np.float64) - 1e-9)
    outside = (g - gc) * grid.voxel
    i0 = np.minimum(gc.astype(np.int64), grid._shape - 2)
    f = gc - i0
    c = grid._flat[(i0 @ grid._strides)[:, None] + grid._corner_off[:, 0][None, :]]
    fx, fy, fz = f[:, 0:1], f[:, 1:2], f[:, 2:3]
    wy = np.concatenate([1.0 - fy, fy], 1)
    wz = np.concatenate([1.0 - fz, fz], 1)
    wyz = (wy[:, :, None] * wz[:, None, :]).reshape(-1, 4)
    c4 = c.reshape(-1, 2, 4)
    cx = c4[:, 1] - c4[:, 0]
    lerp_x = c4[:, 0] + cx * fx
    out_d = np.sqrt(np.einsum("ij,ij->i", outside, outside))
    sdf = np.einsum("ij,ij->i", lerp_x, wyz) + out_d
    lx = lerp_x.reshape(-1, 2, 2)
    dx = np.einsum("ij,ij->i", cx, wyz)
    dy = np.einsum("ij,ij->i", lx[:, 1] - lx[:, 0], wz)
    dz = np.einsum("ij,ij->i", lx[:, :, 1] - lx[:, :, 0], wy)
    grad = np.stack([dx, dy, dz], axis=1) * (1.0 / grid.voxel)
    far = out_d > 0
    grad[far] = outside[far] / out_d[far, None]
    return sdf, grad


def test_query_equals_the_einsum_formulation_bit_for_bit():
    """The tracker's results must not change with the query's layout: same values and gradients, to the last bit,
    inside the box, on its faces and outside it (float32 grid values, as every grid stores)."""
    rng = np.random.default_rng(3)
    g = SDFGrid(rng.normal(size=(9, 11, 13)) * 0.01, np.array([0.1, -0.2, 0.3]), 0.004)
    lo, hi = g.bounds
    P = np.concatenate(
        [
            rng.uniform(lo, hi, (20000, 3)),  # inside
            rng.uniform(lo - 0.05, hi + 0.05, (20000, 3)),  # about a third outside
            lo + 0.004 * rng.integers(0, 9, (2000, 3)),  # on grid samples
        ]
    )
    sdf, grad = g.query(P)
    ref_sdf, ref_grad = _query_einsum(g, P)
    assert np.array_equal(sdf, ref_sdf) and np.array_equal(grad, ref_grad)
    assert np.array_equal(g.query(P, with_grad=False)[0], ref_sdf)
