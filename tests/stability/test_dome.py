"""Dome hard cases: no markers, a handful, collinear, wrong size, out-of-range pressure, NaN input."""

from __future__ import annotations

import numpy as np
import pytest

from vtrack.errors import InputError

pytestmark = pytest.mark.stability


@pytest.fixture(scope="module")
def rec():
    from vtrack.dome.reconstruct import DomeReconstructor

    return DomeReconstructor("gnn")


def _dots(points, size=160):
    import cv2

    img = np.full((size, size), 20, np.uint8)
    for x, y in points:
        cv2.circle(img, (int(x), int(y)), 2, 230, -1)
    return img


def _finite(res) -> None:
    assert np.isfinite(res.dense_mm).all() and np.isfinite(res.force_n).all()
    assert np.isfinite(res.contact_prob).all()


def test_no_markers(rec) -> None:
    from vtrack.dome.markers import build_graph, extract_markers

    black = np.zeros((160, 160), np.uint8)
    assert len(extract_markers(black)) == 0
    assert build_graph(extract_markers(black)).method == "empty"
    res = rec.reconstruct(black)
    _finite(res)
    assert res.n_markers == 0 and res.info["low_marker_count"]


def test_handful_of_markers(rec) -> None:
    res = rec.reconstruct(_dots([(60, 60), (100, 70), (80, 110)]))
    _finite(res)
    assert res.n_markers == 3 and res.graph_method == "delaunay"
    res2 = rec.reconstruct(_dots([(60, 60), (100, 70)]))
    _finite(res2)
    assert res2.graph_method == "knn"


def test_collinear_markers_fall_back_to_knn(rec) -> None:
    from vtrack.dome.markers import build_graph, extract_markers

    img = _dots([(30 + 15 * k, 80) for k in range(7)])
    ms = extract_markers(img)
    assert len(ms) == 7
    g = build_graph(ms)
    assert g.method == "knn" and g.edge_index.shape[1] > 0 and np.isfinite(g.edge_attr).all()
    _finite(rec.reconstruct(img))


def test_wrong_image_size(rec) -> None:
    from vtrack.dome.simulate import DomeSimulator

    with pytest.raises(InputError, match="wrong size"):
        rec.reconstruct(np.zeros((100, 120), np.uint8))
    import cv2

    big = cv2.resize(DomeSimulator().reference_image(), (320, 320), interpolation=cv2.INTER_LINEAR)
    res = rec.reconstruct(big, resize=True)
    _finite(res)
    assert res.n_markers > 300
    with pytest.raises(InputError):
        rec.reconstruct(np.zeros((4, 4), np.uint8))


@pytest.mark.parametrize("p", [-1.0, 10.5, float("nan"), float("inf")])
def test_out_of_range_pressure(rec, p) -> None:
    img = np.zeros((160, 160), np.uint8)
    with pytest.raises(InputError, match="pressure"):
        rec.reconstruct(img, pressure_kpa=p)


def test_nan_image_and_missing_file(rec, tmp_path) -> None:
    img = np.zeros((160, 160), np.float32)
    img[3, 3] = np.nan
    with pytest.raises(InputError, match="NaN"):
        rec.reconstruct(img)
    with pytest.raises(InputError, match="not found"):
        rec.reconstruct(tmp_path / "missing.png")


def test_merged_blob_in_simulated_image(rec) -> None:
    """Two markers pushed together by a press still give two detections (k-means split)."""
    import cv2

    from vtrack.dome.markers import extract_markers

    img = np.full((160, 160), 20, np.uint8)
    for k in range(8):
        cv2.circle(img, (20 + 15 * k, 30), 3, 230, -1)
    cv2.circle(img, (70, 100), 3, 230, -1)
    cv2.circle(img, (75, 100), 3, 230, -1)
    ms = extract_markers(img)
    assert len(ms) == 10 and ms.n_split == 1
    _finite(rec.reconstruct(img))
