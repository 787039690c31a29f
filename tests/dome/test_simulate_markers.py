"""Dome simulator, camera model and marker extraction."""

from __future__ import annotations

import numpy as np
import pytest

from vtrack.dome.markers import build_graph, extract_markers, node_features
from vtrack.dome.model import DomeConfig, DomeGeometry, knn_np, tactip_layout
from vtrack.dome.simulate import DomeSimulator, Press

#: a single-layer shell that inflates (the default before 2026-11-26): the inflation tests need it
INFLATING = DomeConfig(inflation_mm_per_kpa=0.03)


@pytest.fixture(scope="module")
def sim() -> DomeSimulator:
    return DomeSimulator(INFLATING)


def test_default_dome_confines_the_inflation() -> None:
    """The default sensor is FusionTouch's double shell: the pressure does not move the markers (images and
    reference frames are the same at every P), it only stiffens the shell."""
    cfg = DomeConfig()
    assert cfg.inflation_mm_per_kpa == 0.0
    s = DomeSimulator(cfg)
    assert np.array_equal(s.reference_image(0.0), s.reference_image(10.0))
    press = lambda p: Press("sphere", np.array([0.0, 0.0, 1.0]), 1.0, 3.0, 0.0, np.zeros(2), p)  # noqa: E731
    a, b = s.deform(press(0.0)), s.deform(press(10.0))
    assert np.array_equal(a["disp_markers"], b["disp_markers"])
    assert b["force"][2] < 2.0 * a["force"][2] < 0  # k_n(10 kPa) = 5 k0, plus P on the contact patch


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


def test_uint8_statistics_path_equals_the_float_path(sim) -> None:
    """8-bit frames take their percentiles and median from the histogram; the same frame as float32 goes
    through np.partition. Both must find the same markers (as sets: split order is random) on a pressed frame,
    a bright-on-dark (inverted) frame and a low-contrast one."""
    from scipy.spatial import cKDTree

    from vtrack.dome.simulate import make_dataset

    rng = np.random.default_rng(3)
    pressed = make_dataset(3, 5, sim.cfg, cache=False)["image"]
    frames = [*pressed, 255 - sim.reference_image()]
    low = sim.reference_image().astype(np.float64) * 0.25 + 60 + rng.normal(0, 1.0, (sim.cfg.image_size,) * 2)
    frames.append(np.clip(low, 0, 255).astype(np.uint8))
    for f in frames:
        a, b = extract_markers(f), extract_markers(f.astype(np.float32))
        assert len(a) == len(b) > 100
        assert cKDTree(b.centers).query(a.centers)[0].max() < 1e-6


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


def test_reference_at_operating_pressure_cancels_inflation(sim) -> None:
    """A no-contact frame at P = 8 kPa matches its own reference (captured at 8 kPa) to noise level, while
    against a P = 0 reference the pins have moved outwards (away from the image centre)."""
    from vtrack.dome.features import _match, reference_markers

    P = 8.0
    frame = sim.sample(np.random.default_rng(1), _press(sim, 0.0, P, "none"))["image"]
    ms = extract_markers(frame)
    half = sim.cfg.image_size / 2
    c = (sim.cfg.image_size - 1) / 2
    shifts = {}
    for p_ref in (P, 0.0):
        ref = reference_markers(sim.reference_image(p_ref))
        partner, matched, _ = _match(ms, ref, half)
        d = ms.centers[matched] - ref.centers[partner[matched]]
        radial = ((ms.centers[matched] - c) * d).sum(1) / np.maximum(np.linalg.norm(ms.centers[matched] - c, axis=1), 1)
        shifts[p_ref] = (np.linalg.norm(d, axis=1).mean(), np.median(radial))
    # measured: 0.03 px mean shift, median radial 0.00 px at the right reference; 0.17 px, 0.11 px outwards
    # against the P = 0 reference (0.24 mm inflation is ~0.1 px through the fisheye)
    assert shifts[P][0] < 0.06 and abs(shifts[P][1]) < 0.02
    assert shifts[0.0][1] > 0.07 and shifts[0.0][0] > 3 * shifts[P][0]
    with pytest.raises(ValueError, match="reference pressure"):
        sim.reference_image(-1.0)


def test_dataset_references_follow_the_protocol() -> None:
    from dataclasses import replace

    from vtrack.dome.simulate import make_dataset

    cfg = INFLATING
    assert cfg.reference_at_pressure  # the default protocol
    d = make_dataset(3, 5, cfg, cache=False)
    assert d["reference_image"].shape == (3, cfg.image_size, cfg.image_size)
    sim = DomeSimulator(cfg)
    for i in range(3):
        assert np.array_equal(d["reference_image"][i], sim.reference_image(float(d["pressure_kpa"][i])))
    g = DomeGeometry(cfg)
    assert np.allclose(g.reference_inflation_mm(d["pressure_kpa"]), 0.03 * d["pressure_kpa"])
    legacy = replace(cfg, reference_at_pressure=False)
    d0 = make_dataset(3, 5, legacy, cache=False)
    assert d0["reference_image"].shape == (cfg.image_size, cfg.image_size)
    assert np.array_equal(d0["image"], d["image"])  # same presses; only the reference differs
    assert np.allclose(DomeGeometry(legacy).reference_inflation_mm(d0["pressure_kpa"]), 0.0)
    # bundles saved before the protocol existed load as the old (P = 0) protocol
    old = cfg.to_dict()
    old.pop("reference_at_pressure")
    assert DomeConfig.from_dict(old).reference_at_pressure is False
