"""The SLAM grid update's band and surfel SDF (vtrack.tracking.sdf_grid.band_voxels / surfel_band_sdf)
against brute force."""

from __future__ import annotations

import numpy as np

from vtrack.tracking.sdf_grid import band_voxels, surfel_band_sdf


def test_band_holds_every_voxel_within_the_radius_and_is_smaller_than_the_cube():
    rng = np.random.default_rng(0)
    shape = np.array([30, 25, 20])
    src = rng.integers(0, shape, size=(40, 3))
    radius = 3.0 + 0.5 * np.sqrt(3)  # the SLAM map: trunc = 3 voxels + half a voxel diagonal
    band = band_voxels(src, shape, radius)
    assert np.all((band >= 0) & (band < shape))
    got = np.zeros(tuple(shape), bool)
    got[tuple(band.T)] = True
    grid = np.stack(np.meshgrid(*[np.arange(s) for s in shape], indexing="ij"), -1).reshape(-1, 3)
    d = np.sqrt(((grid[:, None, :] - src[None]) ** 2).sum(-1)).min(1)
    need = d <= radius
    assert got.reshape(-1)[need].all()  # superset of the ball
    cube = np.abs(grid[:, None, :] - src[None]).max(-1).min(1) <= 3
    assert got.sum() < cube.sum()  # and cheaper than the half-size-3 cube it replaced
    full = np.zeros(tuple(shape), bool)
    full[tuple(band_voxels(src, shape, radius, ball=False).T)] = True
    assert np.array_equal(full.reshape(-1), cube)  # ball=False: exactly that cube (incremental updates)
    assert len(band_voxels(src[:0], shape, radius)) == 0


def test_surfel_band_sdf_matches_brute_force_weighted_plane_distance():
    rng = np.random.default_rng(1)
    # surfels on the plane z = 0 (normal +z), a few without normal
    S = np.concatenate([rng.uniform(-0.02, 0.02, (300, 2)), np.zeros((300, 1))], 1)
    N = np.tile([0.0, 0.0, 1.0], (300, 1))
    N[:20] = 0.0
    W = rng.uniform(0.5, 3.0, 300)
    X = rng.uniform(-0.02, 0.02, (200, 3))
    trunc, dmin = 0.012, 0.001
    val, wsum = surfel_band_sdf(X, S, N, W, trunc, dmin)
    d = np.linalg.norm(X[:, None] - S[None], axis=-1)
    ref = np.full(len(X), trunc)
    for i in range(len(X)):
        nn = np.argsort(d[i])[:4]
        nn = nn[d[i, nn] <= trunc]
        if not len(nn):
            continue
        w = W[nn] / np.maximum(d[i, nn], dmin)
        diff = X[i] - S[nn]
        sd = np.where(np.linalg.norm(N[nn], axis=1) > 0.5, (diff * N[nn]).sum(1), np.linalg.norm(diff, axis=1))
        ref[i] = np.clip((w * sd).sum() / w.sum(), -trunc, trunc)
    assert val.dtype == np.float32 and np.all(np.isfinite(val))
    np.testing.assert_allclose(val, ref, atol=1e-6)
    # mostly the plane distance z (a surfel without normal adds a little)
    near = wsum > 0
    assert near.sum() > 100 and np.median(np.abs(val[near] - X[near, 2])) < 1e-3
    v0, w0 = surfel_band_sdf(X[:0], S, N, W, trunc, dmin)
    assert v0.shape == (0,) and w0.shape == (0,)


def _dense_reference(X, S, N, W, trunc, dmin, k=4):
    """The previous implementation (every (point, neighbour) pair, out-of-reach ones weighted 0), kept as the
    bit-identity reference of the compacted one."""
    from scipy.spatial import cKDTree

    dist, idx = cKDTree(S, leafsize=32, balanced_tree=False, compact_nodes=False).query(
        X, k=k, distance_upper_bound=trunc
    )
    valid = np.isfinite(dist)
    idx_c = np.where(valid, idx, 0)
    wgt = np.where(valid, W[idx_c] / np.maximum(dist, dmin), 0.0)
    diff = X.astype(np.float32)[:, None, :] - S.astype(np.float32)[idx_c]
    has_n = (np.einsum("ij,ij->i", N, N) > 0.25)[idx_c]
    sd = np.where(
        has_n,
        np.einsum("ijk,ijk->ij", diff, N.astype(np.float32)[idx_c]),
        np.sqrt(np.einsum("ijk,ijk->ij", diff, diff)),
    )
    wsum = wgt.sum(1)
    val = np.where(wsum > 0, np.einsum("ij,ij->i", wgt, sd) / np.maximum(wsum, 1e-12), trunc)
    return np.clip(val, -trunc, trunc).astype(np.float32), wsum


def test_surfel_band_sdf_bit_identical_to_the_dense_formula():
    """Only the pairs within reach are evaluated (about half of a band's); the values are those of the dense
    formula bit for bit, on a curved map with mixed normals and many voxels out of reach."""
    rng = np.random.default_rng(3)
    d = rng.normal(size=(2000, 3))
    S = 0.04 * d / np.linalg.norm(d, axis=1, keepdims=True) + rng.normal(0, 3e-4, (2000, 3))
    N = S / np.linalg.norm(S, axis=1, keepdims=True)
    N[rng.random(2000) < 0.1] = 0.0
    W = rng.uniform(0.5, 5.0, 2000)
    X = np.stack(np.meshgrid(*[np.arange(-0.06, 0.06, 0.004)] * 3, indexing="ij"), -1).reshape(-1, 3)
    val, wsum = surfel_band_sdf(X, S, N, W, 0.012, 0.001)
    ref, rsum = _dense_reference(X, S, N, W, 0.012, 0.001)
    assert 0.1 < (rsum > 0).mean() < 0.9  # both cases present
    assert np.array_equal(val.view(np.uint32), ref.view(np.uint32))
    assert np.array_equal(wsum, rsum)
    far = X + 1.0  # nothing within reach: the truncation value, weight 0
    v, w = surfel_band_sdf(far[:5], S, N, W, 0.012, 0.001)
    assert np.all(v == np.float32(0.012)) and np.all(w == 0)


def _sphere_surfels(rng: np.random.Generator, n: int = 800) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    d = rng.normal(size=(n, 3))
    N = d / np.linalg.norm(d, axis=1, keepdims=True)
    S = 0.03 * N + rng.normal(scale=2e-4, size=(n, 3))
    N[:25] = 0.0  # a few surfels without normal
    return S, N, rng.uniform(0.5, 4.0, n)


def test_lazy_band_grid_values_are_the_eager_values_bit_for_bit():
    """A LazyBandGrid computes a pending voxel when a query reads it, from the surfels as they were when it was
    marked: the same float32 values as one eager surfel_band_sdf call over the whole band, whatever is read first,
    after the map's weights change in place, in a copy, and through ``values``."""
    from vtrack.tracking.sdf_grid import LazyBandGrid, SDFGrid, surfel_tree

    rng = np.random.default_rng(3)
    S, N, W = _sphere_surfels(rng)
    lo, v, trunc, dmin = np.full(3, -0.05), 0.004, 0.012, 0.001
    shape = (26, 26, 26)
    src = np.clip(np.round((S - lo) / v).astype(np.int64), 0, 25)
    bi = band_voxels(src, np.array(shape), trunc / v + 0.5 * np.sqrt(3))
    eager = np.full(shape, trunc, np.float32)
    eager[tuple(bi.T)], _ = surfel_band_sdf(lo + v * bi, S, N, W, trunc, dmin)
    lazy = LazyBandGrid(np.full(shape, trunc, np.float32), lo, v, trunc, dmin)
    flat = np.ravel_multi_index(tuple(bi.T), shape)
    lazy.mark(flat, 7, S, N, W, surfel_tree(S))
    assert lazy._n_pending == len(bi)
    W *= 3.0  # the map adds into its weights in place after the update: the marked values must not see it
    other = lazy.copy_lazy()
    Q = rng.uniform(-0.035, 0.035, (500, 3))
    ref = SDFGrid(eager.copy(), lo, v)
    for g in (lazy, other):
        d, grad = g.query(Q)
        d0, g0 = ref.query(Q)
        assert np.array_equal(d, d0) and np.array_equal(grad, g0)
        assert 0 < g._n_pending < len(bi)  # only what the queries read was computed
    assert np.array_equal(lazy.values, eager) and lazy._n_pending == 0
    assert np.array_equal(other.values, eager)
    lazy.mark(flat[:0], 8, S, N, W, None)
    assert lazy._snaps == {}  # nothing pending: the snapshot is released
    # values the caller computed itself (the neural mapper's) are stored at once and no longer pending
    again = LazyBandGrid(np.full(shape, trunc, np.float32), lo, v, trunc, dmin)
    again.mark(flat, 9, S, N, W, surfel_tree(S))
    again.put(flat[:10], np.full(10, -0.001, np.float32))
    assert again._n_pending == len(flat) - 10
    assert np.all(again.values.reshape(-1)[flat[:10]] == np.float32(-0.001))
