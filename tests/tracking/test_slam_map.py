"""The SLAM map's numerics: surfel fusion and the incremental tracking-grid update."""

from __future__ import annotations

import numpy as np


def _naive_surfels(batches, voxel):
    """Reference: per-voxel weighted sums by a Python dict (slow, obviously right)."""
    acc: dict[tuple, list] = {}
    for P, N, w in batches:
        for p, n in zip(P, N, strict=True):
            k = tuple(np.floor(p / voxel).astype(int))
            a = acc.setdefault(k, [np.zeros(3), np.zeros(3), 0.0])
            a[0] += w * p
            a[1] += w * n
            a[2] += w
    keys = sorted(acc)
    return (np.array([acc[k][0] / acc[k][2] for k in keys]), np.array([acc[k][2] for k in keys]))


def test_surfel_integrate_matches_naive_sums():
    from vtrack.tracking.slam import SurfelMap

    rng = np.random.default_rng(0)
    m = SurfelMap(0.004)
    batches = []
    for i in range(6):
        P = rng.normal(0, 0.02, (300, 3))
        if i % 2:
            P[:100] = batches[0][0][:100] + 1e-4  # revisits existing voxels
        N = rng.normal(size=(300, 3))
        w = 3.0 if i == 4 else 1.0
        batches.append((P, N, w))
        m.integrate(P, N, w)
    S_ref, W_ref = _naive_surfels(batches, 0.004)
    S, _, W = m.surfels()
    assert len(S) == len(S_ref)
    # keys sort as (x, y, z) voxel indices, the same order as the sorted tuples
    assert np.allclose(S, S_ref, atol=1e-12)
    assert np.allclose(W, W_ref)
    assert np.all(np.diff(m.keys) > 0)


def _grid_of(tr):
    return tr.sdf.values.copy()


def test_incremental_refresh_matches_a_full_rebuild(mustard_seq):
    """The incremental band update equals a rebuild from scratch up to the moved-surfel tolerance."""
    from vtrack.testing.sequences import run_sequence
    from vtrack.tracking.slam import SLAMTracker

    inc = SLAMTracker(mustard_seq.gt[0], refresh_every=2, full_refresh_every=1000)
    run_sequence(inc, mustard_seq)
    assert inc._n_refresh % inc.full_refresh_every != 0
    inc._refresh()  # incremental: the surfels changed since the last update (a grown map or not)
    g_inc = _grid_of(inc)
    inc._n_refresh = 0  # next update is a full one, on the same map
    inc._refresh()
    g_full = _grid_of(inc)
    assert g_inc.shape == g_full.shape
    band = (np.abs(g_full) < inc.trunc) | (np.abs(g_inc) < inc.trunc)
    assert band.sum() > 1000
    diff = np.abs(g_inc - g_full)[band]
    # measured: 99 % of the band identical, max 0.32 mm before the observed-surface gate and 1.15 mm (one voxel of
    # 12604) with it: another trajectory, another map (surfels that moved < refresh_move = 0.3 mm keep their band,
    # and with full_refresh_every = 1000 their weight changes are never re-read); with refresh_move = 3 mm the max
    # is 18.5 mm (a voxel left at the truncation)
    assert np.percentile(diff, 99) < 1e-6
    assert diff.max() < 0.0015
    assert np.all(np.isfinite(g_inc))


def test_map_box_holds_a_long_object_and_a_repeated_frame_stays_put(mustard_seq):
    """The same frame fed again must not move the pose. The map cube once was a fixed 10 cm around the first
    points: the far end of a 19 cm bottle read the clamped boundary of the grid and the pose crept 1.2 mm per
    frame along the bottle (measured on the mustard session; 4.1 mm after 5 repeats)."""
    import copy

    from vtrack.tracking.slam import SLAMTracker

    f0 = mustard_seq.frames[0]
    T0 = mustard_seq.gt[0]
    tr = SLAMTracker(T0)
    tr.step(f0)
    lo, hi = tr._box
    P = mustard_seq.frames[0].vision_points
    q = (P - T0[:3, 3]) @ T0[:3, :3]
    assert np.all(q > lo + tr.trunc) and np.all(q < hi - tr.trunc)
    for k in range(6):
        f = copy.deepcopy(f0)
        f.t = f0.t + (k + 1) / 30.0
        T = tr.step(f)
    # measured: 0.2 mm after 6 repeats (was 4.1 mm)
    assert np.linalg.norm(T[:3, 3] - T0[:3, 3]) < 0.0007


def test_map_box_grows_with_points_outside_it():
    from vtrack.tracking.slam import SLAMTracker

    tr = SLAMTracker(np.eye(4), extent=0.05)
    rng = np.random.default_rng(0)
    P = rng.normal(0, 0.003, (500, 3))
    tr._ensure_box(P)
    lo, hi = (b.copy() for b in tr._box)
    assert np.allclose(hi - lo, 0.1)  # the minimum extent holds this small cloud (radius + margin < 5 cm)
    big = rng.normal(0, 0.03, (500, 3))
    tr2 = SLAMTracker(np.eye(4), extent=0.05)
    tr2._ensure_box(big)
    r = np.percentile(np.linalg.norm(big - 0.5 * (np.percentile(big, 1, 0) + np.percentile(big, 99, 0)), axis=1), 99.5)
    assert np.allclose(tr2._box[1] - tr2._box[0], 2 * (r + tr2.box_margin))  # turned any way, it fits
    far = P + np.array([0.12, 0.0, 0.0])
    tr._ensure_box(far)
    lo2, hi2 = tr._box
    assert tr._box_grew and np.all(lo2 <= lo) and hi2[0] >= far[:, 0].max() + tr.trunc
    # growth is whole grid voxels: old samples stay on the lattice
    assert np.allclose(((hi2 - hi) / tr.grid_voxel) % 1.0, 0.0, atol=1e-6) or np.allclose(
        ((hi2 - hi) / tr.grid_voxel) % 1.0, 1.0, atol=1e-6
    )


def test_slam_keyframe_thresholds_reach_the_graph_and_the_window_separately():
    """kf_trans / kf_rot exist in the pose graph and in the window tracker; the flat names go to the graph and the
    window's are reached by window_kf_*; an unknown window_ key is still refused."""
    import pytest

    from vtrack.errors import InputError
    from vtrack.tracking.slam import SLAMOptions

    _, bo, to = SLAMOptions.split({"kf_rot": 0.2, "window_kf_rot": 0.05, "window_kf_trans": 0.003})
    assert bo.kf_rot == 0.2
    assert to.kf_rot == 0.05 and to.kf_trans == 0.003
    _, bo, to = SLAMOptions.split({})
    assert (to.kf_rot, to.kf_trans) == (0.01, 0.001) and bo.kf_rot == 0.07
    with pytest.raises(InputError):
        SLAMOptions.split({"window_kf_spin": 1.0})


def test_merged_insertion_equals_np_insert():
    """The surfel map inserts its new voxels with positions computed once for its four arrays: the same arrays as
    ``np.insert`` at the (sorted, possibly repeated) insertion points, for 1-D and (K, 3) arrays."""
    from vtrack.tracking.slam import _merge_order, _merged

    rng = np.random.default_rng(2)
    for k, m in ((0, 5), (7, 1), (50, 20), (400, 130)):
        pos = np.sort(rng.integers(0, k + 1, m))  # where each new row goes in the old array, in order
        order = _merge_order(k, pos)
        for shape in ((k,), (k, 3)):
            a = rng.normal(size=shape)
            v = rng.normal(size=(m, *shape[1:]))
            assert np.array_equal(_merged(a, v, order), np.insert(a, pos, v, axis=0))
        keys = np.sort(rng.integers(0, 1 << 40, k))
        new = rng.integers(0, 1 << 40, m)
        assert np.array_equal(_merged(keys, new, order), np.insert(keys, pos, new))


def test_add_rows_equals_fancy_index_add():
    """The surfel map's flat-index row addition: bit for bit ``a[rows] += b`` on (K, 3) arrays."""
    from vtrack.tracking.slam import _add_rows

    rng = np.random.default_rng(3)
    for k, m in ((1, 1), (10, 0), (50, 20), (400, 399)):
        a = rng.normal(size=(k, 3))
        rows = np.sort(rng.choice(k, min(m, k), replace=False))
        b = rng.normal(size=(len(rows), 3))
        ref = a.copy()
        ref[rows] += b
        _add_rows(a, rows, b)
        assert np.array_equal(a, ref)
