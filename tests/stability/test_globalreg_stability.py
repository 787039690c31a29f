"""Hard cases of global initialisation: featureless sphere, no vision, NaN rows, one-face mesh."""

from __future__ import annotations

import numpy as np
import pytest

from vtrack.errors import InputError
from vtrack.eval.pose_metrics import add_s, sample_model_points
from vtrack.testing.views import synthetic_frame
from vtrack.tracking.globalreg import Relocaliser, global_register, random_pose

pytestmark = pytest.mark.stability

CENTRE = np.array([0.0, 0.0, 0.1])


@pytest.fixture(scope="module")
def sphere():
    import open3d as o3d

    m = o3d.geometry.TriangleMesh.create_sphere(radius=0.03, resolution=20)
    return np.asarray(m.vertices, np.float64), np.asarray(m.triangles, np.int64)


def test_featureless_sphere_translation_is_right(sphere):
    # FPFH cannot fix a sphere's rotation (all free), but the centre must be right: ADD-S scores that.
    V, F = sphere
    M = sample_model_points(V, F, 500)
    for s in range(3):
        T_gt = random_pose(s, centre=CENTRE)
        hyps = global_register(V, F, [synthetic_frame(V, F, T_gt, seed=s)], symmetric=True)
        assert hyps and np.all(np.isfinite(hyps[0].T_world_object))
        assert add_s(hyps[0].T_world_object[None], T_gt[None], M)[0] < 0.003
        assert np.linalg.norm(hyps[0].T_world_object[:3, 3] - T_gt[:3, 3]) < 0.003
        # every rotation of the sphere is one pose under ADD-S: the others kept are elsewhere
        for h in hyps[1:]:
            assert add_s(h.T_world_object[None], hyps[0].T_world_object[None], M)[0] > 0.1 * 0.06 * 3**0.5


def test_no_vision_and_no_data(sphere):
    V, F = sphere
    T_gt = random_pose(4, centre=CENTRE)
    fr = synthetic_frame(V, F, T_gt, seed=4, n_contacts=6)
    fr.vision_points = np.zeros((0, 3))
    hyps = global_register(V, F, [fr], symmetric=True)
    assert hyps[0].source == "touch"
    # six contacts on a sphere fix its centre
    assert np.linalg.norm(hyps[0].T_world_object[:3, 3] - T_gt[:3, 3]) < 0.003
    fr.touch_points = fr.touch_normals = fr.free_points = None
    assert global_register(V, F, [fr]) == []
    assert global_register(V, F, []) == []


def test_nan_rows_are_dropped(sphere):
    V, F = sphere
    M = sample_model_points(V, F, 500)
    T_gt = random_pose(5, centre=CENTRE)
    fr = synthetic_frame(V, F, T_gt, seed=5)
    fr.vision_points[::7] = np.nan
    fr.touch_points[0] = np.inf
    fr.touch_normals[1] = np.nan
    fr.free_points[::3] = np.nan
    hyps = global_register(V, F, [fr], symmetric=True)
    h = hyps[0]
    assert all(np.isfinite(v) for v in (h.score, h.vision_fitness, h.contact_residual, h.penetration))
    assert add_s(h.T_world_object[None], T_gt[None], M)[0] < 0.003
    reloc = Relocaliser(V, F, symmetric=True)
    r = reloc.relocalise([fr], T_gt)
    assert r is not None and np.all(np.isfinite(r.T_world_object))


def test_mesh_with_one_face_is_rejected():
    V = np.array([[0.0, 0, 0], [0.05, 0, 0], [0, 0.05, 0], [0, 0, 0.05]])
    F = np.array([[0, 1, 2]])
    with pytest.raises(InputError, match="faces"):
        global_register(V, F, [])
    with pytest.raises(InputError, match="faces"):
        Relocaliser(V, F)
