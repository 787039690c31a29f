"""Dome simulator, camera model and marker extraction."""

from __future__ import annotations

import numpy as np
import pytest

from vtrack.dome.markers import build_graph, extract_markers, node_features
from vtrack.dome.model import DomeConfig, DomeGeometry, knn_np, tactip_layout
from vtrack.dome.simulate import DomeSimulator, Press


@pytest.fixture(scope="module")
def sim() -> DomeSimulator:
    return DomeSimulator(DomeConfig())


def test_layout_and_camera_roundtrip() -> None:
    assert len(tactip_layout(10, 68.0)) == 331
    assert len(tactip_layout(6, 68.0)) == 127
    g = DomeGeometry()
    uv = g.project(g.marker_rest)
    assert uv.min() > 0 and uv.max() < g.cfg.image_size
    back = g.backproject_to_dome(uv)
    assert np.abs(back - g.marker_rest).max() < 1e-9
    f = g.dense_faces
    assert f.shape[1] == 3 and f.max() == g.cfg.n_dense - 1


def _press(sim, depth, pressure=0.0, shape="sphere"):
    return Press(shape, np.array([0.0, 0.0, 1.0]), depth, 4.0, 0.0, np.zeros(2), pressure)


def test_no_contact_only_inflates(sim) -> None:
    d = sim.deform(_press(sim, 0.0, 5.0, "none"))
    assert not d["contact_coarse"].any() and np.allclose(d["force"], 0)
    r = np.linalg.norm(sim.geo.dense_rest + d["disp_dense"], axis=1) - sim.cfg.radius_mm
    assert np.allclose(r, 0.03 * 5.0, atol=1e-9)  # uniform radial inflation


def test_sphere_press_physics(sim) -> None:
    d1 = sim.deform(_press(sim, 1.0))
    d2 = sim.deform(_press(sim, 2.0))
    d2p = sim.deform(_press(sim, 2.0, pressure=10.0))
    apex = int(np.argmax(sim.geo.dense_dirs[:, 2]))
    # the apex is pushed in by the press depth (rigid contact constraint), along -z
    assert d2["disp_dense"][apex, 2] == pytest.approx(-2.0, abs=0.05)
    assert d2["contact_dense"].sum() > d1["contact_dense"].sum() > 0
    assert d1["force"][2] < 0 and abs(d2["force"][2]) > abs(d1["force"][2])
    assert abs(d2p["force"][2]) > 1.5 * abs(d2["force"][2])  # inflated dome is stiffer
    # outside contact the shell is dragged along but less than in contact, and decays with distance
    far = np.linalg.norm(sim.geo.dense_rest - sim.geo.dense_rest[apex], axis=1) > 15
    assert np.abs(d2["disp_dense"][far]).max() < 0.3


def test_render_and_extract_reference(sim) -> None:
    img = sim.reference_image()
    ms = extract_markers(img)
    assert len(ms) == sim.cfg.n_markers
    gt = sim.geo.project(sim.geo.marker_rest)
    _, dist = knn_np(gt, ms.centers, 1)
    assert np.median(dist) < 0.3 and dist.max() < 1.0
    g = build_graph(ms)
    assert g.method == "delaunay" and g.x.shape == (331, 8) and np.isfinite(g.x).all()
    # undirected: every edge present in both directions
    e = set(map(tuple, g.edge_index.T))
    assert all((j, i) in e for i, j in e)
    assert 0 < g.x[:, 7].sum() < 331  # some but not all markers on the hull


def test_merged_blobs_are_split() -> None:
    import cv2

    img = np.zeros((120, 120), np.uint8)
    for k in range(6):  # isolated markers set the median area
        cv2.circle(img, (15 + 18 * k, 20), 4, 255, -1)
    cv2.circle(img, (50, 70), 4, 255, -1)
    cv2.circle(img, (57, 70), 4, 255, -1)  # overlapping pair -> one merged blob
    ms = extract_markers(img, mask_radius=2.0)
    assert len(ms) == 8 and ms.n_split == 1
    pair = ms.centers[ms.centers[:, 1] > 50]
    assert np.allclose(np.sort(pair[:, 0]), [50, 57], atol=1.0)


def test_descriptor_orientation() -> None:
    import cv2

    img = np.zeros((64, 64), np.uint8)
    for k in range(4):
        cv2.ellipse(img, (12 + 13 * k, 32), (5, 2), 0, 0, 360, 255, -1)  # horizontal ellipses
    ms = extract_markers(img, mask_radius=2.0, split=False)
    f = node_features(ms)
    assert len(ms) == 4
    assert np.allclose(f[:, 6], 1.0, atol=0.05)  # cos 2theta = 1 for a horizontal major axis
    assert np.all((f[:, 4] > 0.3) & (f[:, 4] < 0.6))  # eta = minor / major ~ 2/5


def test_tactip_init_frames_pin_counts(shared_data) -> None:
    import cv2

    from vtrack.dome.tactip import SETS

    for name, (expected, mask_r) in SETS.items():
        img = cv2.imread(str(shared_data / "tactip_frames" / name / "frames_bw" / "init_0.png"), 0)
        assert len(extract_markers(img, polarity="bright", mask_radius=mask_r)) == expected


def test_tactip_analysis_runs_end_to_end(shared_data) -> None:
    """`vtrack dome tactip` on the real 127-pin set: detection, matching and both pose regressors run and give
    finite, better-than-trivial numbers (a short GNN training budget keeps the test fast)."""
    pytest.importorskip("torch")
    from vtrack.dome.tactip import analyse_set, load_set

    r = analyse_set(load_set(shared_data / "tactip_frames", "tactip_127"), epochs=3, log=lambda *a: None)
    assert r["count_mean"] > 120 and r["track_continuity_mean"] > 0.9
    for k in ("gnn_depth_mae_mm", "gnn_roll_mae_deg", "ridge_depth_mae_mm", "ridge_roll_mae_deg"):
        assert np.isfinite(r[k]), k
    assert r["ridge_depth_mae_mm"] < r["label_std_depth_mm"]
