"""TSDF reconstruction (Open3D VoxelBlockGrid) on ray-cast observations; touch evidence; torch-free."""

from __future__ import annotations

import subprocess
import sys

import numpy as np

from vtrack.eval.reconstruction import mesh_metrics
from vtrack.fusion.cloud import TOUCH, VISION
from vtrack.fusion.tsdf import TSDFReconstructor


def _run(obs, mods):
    r = TSDFReconstructor()
    r.fit([o for o in obs if o.modality in mods])
    return r.extract_mesh()


def test_tsdf_vision_full_view_is_accurate(soup_obs):
    obs, V, F = soup_obs
    v, f = _run(obs, (VISION,))
    m = mesh_metrics(v, f, V, F)
    assert m["fscore"]["5mm"] > 0.9
    assert m["chamfer_mm"] < 3.0


def test_tsdf_touch_adds_unseen_surface(occluded_obs):
    obs, V, F = occluded_obs
    mv = mesh_metrics(*_run(obs, (VISION,)), V, F)
    mvt = mesh_metrics(*_run(obs, (VISION, TOUCH)), V, F)
    assert mvt["recall"]["5mm"] > mv["recall"]["5mm"] + 0.05
    assert mvt["precision"]["5mm"] > 0.8


def test_tsdf_touch_only_gives_patches(soup_obs):
    obs, V, F = soup_obs
    v, f = _run(obs, (TOUCH,))
    assert len(f) > 0
    m = mesh_metrics(v, f, V, F)
    assert m["precision"]["5mm"] > 0.8  # what is reconstructed is on the object


def test_tsdf_never_imports_torch():
    code = (
        "import sys, numpy as np\n"
        "from vtrack.fusion.tsdf import TSDFReconstructor\n"
        "r = TSDFReconstructor()\n"
        "K = np.array([[50., 0, 16], [0, 50., 12], [0, 0, 1]])\n"
        "d = np.full((24, 32), 0.3, np.float32)\n"
        "assert r.integrate_depth(d, K, np.eye(4))\n"
        "assert r.integrate_points(np.random.default_rng(0).normal(size=(50, 3)) * 0.003 + [0, 0, 0.25],"
        " np.tile([0, 0, -1.0], (50, 1)))\n"
        "v, f = r.extract_mesh()\n"
        "assert len(f) > 0\n"
        "assert 'torch' not in sys.modules, 'torch imported'\n"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]


def test_tsdf_plane_depth_mesh_position():
    r = TSDFReconstructor(voxel_size=0.004)
    K = np.array([[100.0, 0, 32], [0, 100.0, 24], [0, 0, 1]])
    for _ in range(2):
        assert r.integrate_depth(np.full((48, 64), 0.3, np.float32), K, np.eye(4))
    v, f = r.extract_mesh()
    assert len(f) > 10
    np.testing.assert_allclose(np.median(v[:, 2]), 0.3, atol=0.004)
