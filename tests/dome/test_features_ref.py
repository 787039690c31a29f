"""Reference-relative GNN node features: one-to-one matching of markers to the no-contact frame."""

from __future__ import annotations

import numpy as np

from vtrack.dome.features import (
    EDGE_REL_DIM,
    REL_DIM,
    edge_strain,
    gated_assignment,
    graph_arrays,
    match_reference,
    reference_markers,
)
from vtrack.dome.markers import EDGE_DIM, NODE_DIM, MarkerSet
from vtrack.dome.model import DomeConfig, DomeGeometry
from vtrack.dome.nets import NODE_IN


def _ms(centers, areas) -> MarkerSet:
    c = np.asarray(centers, np.float64)
    return MarkerSet(c, np.asarray(areas, np.float64), np.ones((len(c), 2)), np.zeros(len(c)), (160, 160))


def test_match_shift_area_and_unmatched() -> None:
    ref = _ms([[40, 40], [50, 40], [40, 50], [50, 50]], [8, 8, 8, 8])  # spacing 10 px
    # marker 0 moved 2 px right and doubled in area; marker 3 vanished; one spurious blob far away
    cur = _ms([[42, 40], [50, 40], [40, 50], [120, 120]], [16, 8, 8, 8])
    f = match_reference(cur, ref, 80.0)
    assert f.shape == (4, REL_DIM) and NODE_IN == NODE_DIM + REL_DIM
    assert np.allclose(f[0, :2], [0.2, 0.0])  # 2 px / 10 px spacing
    assert np.isclose(f[0, 2], 1.0) and np.isclose(f[0, 3], np.sqrt(2) - 1)
    assert np.allclose(f[1:3, :4], 0) and np.allclose(f[:3, 4], 1)
    assert f[3, 4] == 0 and np.allclose(f[3, 2:4], 0)  # unmatched: no size change, flag 0
    assert np.allclose(f[3, :2], [7.0, 7.0])  # dx, dy to its nearest rest marker (50, 50)


def test_match_degenerate_inputs() -> None:
    empty = _ms(np.zeros((0, 2)), np.zeros(0))
    one = _ms([[10, 10]], [5])
    assert match_reference(empty, one, 80.0).shape == (0, REL_DIM)
    assert np.allclose(match_reference(one, empty, 80.0), 0)
    f = match_reference(one, one, 80.0)
    assert np.allclose(f, [0, 0, 0, 0, 1])
    nan_area = _ms([[10, 10]], [np.nan])  # reference without usable areas: size changes are 0
    f2 = match_reference(_ms([[12, 10]], [9]), nan_area, 80.0)
    assert np.allclose(f2, [2 / 80, 0, 0, 0, 1])  # single rest marker: half-image units


def test_reference_frame_features_are_zero() -> None:
    from vtrack.dome.simulate import DomeSimulator

    cfg = DomeConfig()
    img = DomeSimulator(cfg).reference_image()
    a = graph_arrays(img, reference_markers(img), DomeGeometry(cfg))
    assert a["x"].shape[1] == NODE_IN and len(a["x"]) > 300
    assert np.allclose(a["x"][:, NODE_DIM : NODE_DIM + 4], 0) and np.all(a["x"][:, -1] == 1)
    assert a["edge_attr"].shape[1] == EDGE_DIM + EDGE_REL_DIM and np.allclose(a["edge_attr"][:, EDGE_DIM:], 0)
    b = graph_arrays(img, reference_markers(img).centers, DomeGeometry(cfg))  # bare centres accepted
    assert np.allclose(b["x"][:, NODE_DIM : NODE_DIM + 4], 0)


def test_edge_strain_measures_stretch_and_ignores_unmatched() -> None:
    ref = _ms([[40, 40], [50, 40], [40, 50], [50, 50]], [8, 8, 8, 8])  # spacing 10 px
    cur = _ms([[38, 40], [52, 40], [40, 50], [90, 90]], [8, 8, 8, 8])  # 0-1 stretched by 4 px, 3 gone
    e = np.array([[0, 1, 0, 2], [1, 0, 3, 0]])
    st = edge_strain(cur, ref, e, 80.0)
    assert st.shape == (4, EDGE_REL_DIM)
    assert np.allclose(st[0], [0.4, 0.0, 0.4]) and np.allclose(st[1], [-0.4, 0.0, 0.4])  # both directions
    assert np.allclose(st[2], 0)  # edge to an unmatched marker
    assert np.allclose(st[3], [-0.2, 0.0, (np.hypot(2, 10) - 10) / 10])  # edge 2->0: marker 0 moved 2 px left
    assert np.all(np.isfinite(edge_strain(cur, _ms(np.zeros((0, 2)), np.zeros(0)), e, 80.0)))


def test_gated_assignment_equals_dense_hungarian() -> None:
    """The component-wise solver must give the dense gated Hungarian optimum (count, then total distance)."""
    from scipy.optimize import linear_sum_assignment
    from scipy.spatial import cKDTree

    rng = np.random.default_rng(0)
    for _ in range(200):
        m, n = int(rng.integers(1, 40)), int(rng.integers(1, 40))
        b = rng.uniform(0, 60, (m, 2))
        k = min(n, m)
        a = np.concatenate([b[:k] + rng.normal(0, 2.5, (k, 2)), rng.uniform(0, 60, (max(0, n - m), 2))])
        gate = 4.0
        r, c = gated_assignment(a, b, cKDTree(b), gate)
        assert len(set(r.tolist())) == len(r) and len(set(c.tolist())) == len(c)  # one-to-one
        d = np.linalg.norm(a[r] - b[c], axis=1)
        assert np.all(d <= gate)
        D = np.linalg.norm(a[:, None] - b[None], axis=-1)
        rr, cc = linear_sum_assignment(np.where(D <= gate, D, 1e6))
        keep = D[rr, cc] <= gate
        assert len(r) == keep.sum()
        assert np.isclose(d.sum(), D[rr[keep], cc[keep]].sum())


def test_gated_assignment_with_crowded_gates_and_empty_sides() -> None:
    """More reference points inside one gate than the first k-nearest query returns (the query must widen),
    and empty inputs on either side."""
    from scipy.optimize import linear_sum_assignment
    from scipy.spatial import cKDTree

    rng = np.random.default_rng(5)
    b = np.concatenate([rng.normal(10, 0.8, (25, 2)), rng.uniform(20, 60, (10, 2))])  # a crowd of 25
    a = np.concatenate([rng.normal(10, 0.8, (20, 2)), b[25:] + 0.5])
    r, c = gated_assignment(a, b, cKDTree(b), 3.0)
    D = np.linalg.norm(a[:, None] - b[None], axis=-1)
    rr, cc = linear_sum_assignment(np.where(D <= 3.0, D, 1e6))
    keep = D[rr, cc] <= 3.0
    assert len(r) == keep.sum() == 30
    assert np.isclose(np.linalg.norm(a[r] - b[c], axis=1).sum(), D[rr[keep], cc[keep]].sum())
    for x, y in ((np.zeros((0, 2)), b), (a, np.zeros((0, 2)))):
        r, c = gated_assignment(x, y, cKDTree(y) if len(y) else None, 3.0)
        assert len(r) == len(c) == 0


def test_tactip_matcher_counts_every_pair_within_the_gate() -> None:
    """Out-of-gate pairs must not crowd out a pair within the gate: the earlier clipped-cost Hungarian
    (cost min(d, 10 gate)) paired 0->1 (3.8 px) and 1->0 (3.1 px), total 6.9 < 1.7 + 5.4, and so matched
    nothing although detection 0 lies 1.7 px from reference 0."""
    from vtrack.dome.tactip import match_to_reference

    ref = np.array([[1.2, 3.6], [0.9, 6.0]])
    cur = np.array([[2.6, 2.6], [2.9, 1.0]])
    assert match_to_reference(cur, ref, gate_px=3.0).tolist() == [0, -1]
    assert np.all(match_to_reference(np.zeros((0, 2)), ref, 3.0) == -1)
    assert match_to_reference(cur, np.zeros((0, 2)), 3.0).tolist() == [-1, -1]
