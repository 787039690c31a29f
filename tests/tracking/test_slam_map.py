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
    from vtrack.tracking.slam import SLAMTracker
    from vtrack.tracking.synth import run_sequence

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
    # measured: 99 % of the band identical, max 0.32 mm (surfels that moved < refresh_move = 0.3 mm keep
    # their band); with refresh_move = 3 mm the max is 18.5 mm (a voxel left at the truncation)
    assert np.percentile(diff, 99) < 1e-6
    assert diff.max() < 0.001
    assert np.all(np.isfinite(g_inc))
