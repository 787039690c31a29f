"""Reference-relative GNN node features: one-to-one matching of markers to the no-contact frame."""

from __future__ import annotations

import numpy as np

from vtrack.dome.features import REL_DIM, graph_arrays, match_reference, reference_markers
from vtrack.dome.markers import NODE_DIM, MarkerSet
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
    assert np.allclose(a["x"][:, NODE_DIM:NODE_DIM + 4], 0) and np.all(a["x"][:, -1] == 1)
    b = graph_arrays(img, reference_markers(img).centers, DomeGeometry(cfg))  # bare centres accepted
    assert np.allclose(b["x"][:, NODE_DIM:NODE_DIM + 4], 0)
