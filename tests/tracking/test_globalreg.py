"""Global initialisation without a pose prior and re-localisation (vtrack.tracking.globalreg).

Synthetic single views of YCB meshes (hidden-point-removal view, 1 mm noise, 10 % "hand" blob
outliers, 4 contacts, 20 free gel points) at seeded random poses; ground truth only scores.
Rates measured with ``data_tools/globalreg_bench.py --seeds 10`` (OMP_NUM_THREADS=1): soup can
10/10 (ADD-S < 5 mm), mustard 8/10 (ADD < 5 mm), mug 6/10 (not tested:
slow); the bounds below keep a margin of ~1 failure.
"""

from __future__ import annotations

import time

import numpy as np
import pytest

from vtrack.errors import InputError
from vtrack.eval.pose_metrics import add, add_s, sample_model_points
from vtrack.geometry import se3
from vtrack.io.mesh import load_mesh
from vtrack.testing.views import synthetic_frame
from vtrack.tracking.globalreg import (
    GlobalRegOptions,
    PoseHypothesis,
    Relocaliser,
    global_register,
    random_pose,
)

CENTRE = np.array([0.0, 0.0, 0.1])


@pytest.fixture(scope="module")
def mustard(mustard_mesh):
    V, F = load_mesh(mustard_mesh)
    return V, F, sample_model_points(V, F, 1000)


@pytest.fixture(scope="module")
def can(can_mesh):
    V, F = load_mesh(can_mesh)
    return V, F, sample_model_points(V, F, 1000)


def _rate(obj, symmetric: bool, seeds) -> tuple[float, list[float], list[float]]:
    V, F, M = obj
    metric = add_s if symmetric else add
    errs, times = [], []
    for s in seeds:
        T_gt = random_pose(1000 + s, centre=CENTRE)
        fr = synthetic_frame(V, F, T_gt, seed=s)
        t0 = time.process_time()  # CPU time: wall time on a shared CI machine says little
        hyps = global_register(V, F, [fr], symmetric=symmetric)
        times.append(time.process_time() - t0)
        assert hyps and all(isinstance(h, PoseHypothesis) for h in hyps)
        assert all(np.all(np.isfinite(h.T_world_object)) and se3.is_rigid(h.T_world_object, 1e-6) for h in hyps)
        scores = [h.score for h in hyps]
        assert scores == sorted(scores, reverse=True) and 0.0 <= scores[-1] and scores[0] <= 1.0
        errs.append(float(metric(hyps[0].T_world_object[None], T_gt[None], M)[0]))
    return float(np.mean(np.array(errs) < 0.005)), errs, times


def test_soup_can_success_rate_and_time(can):
    rate, errs, times = _rate(can, True, range(6))
    assert rate >= 5 / 6, errs  # measured 10/10 over 10 seeds
    # target <= 1.5 s on one core; bound loose for slow CI machines
    assert np.median(times) < 4.0, times


def test_mustard_success_rate(mustard):
    rate, errs, _ = _rate(mustard, False, range(6))
    # measured 8/10 over seeds 0-9 (the misses: a front/back flip with ADD-S 3.3 mm, and a bottom view)
    assert rate >= 4 / 6, errs


def test_hypothesis_parts_are_consistent(can):
    V, F, M = can
    T_gt = random_pose(7, centre=CENTRE)
    fr = synthetic_frame(V, F, T_gt, seed=7)
    h = global_register(V, F, [fr], symmetric=True)[0]
    assert add_s(h.T_world_object[None], T_gt[None], M)[0] < 0.005
    # at the right pose: ~90 % of points are on the surface (10 % hand outliers), contacts lie on
    # it within their 0.2 mm noise, normals agree, free gel points are outside
    assert 0.8 < h.vision_fitness < 0.95 and h.vision_rmse < 0.0015
    assert h.contact_residual < 0.001 and h.normal_agreement > 0.95 and h.penetration < 1e-4
    assert h.n_vision > 100 and h.n_touch == 4 and h.n_free == 20


def test_symmetric_flag_merges_equivalent_poses(can):
    V, F, _ = can
    fr = synthetic_frame(V, F, random_pose(3, centre=CENTRE), seed=3)
    opts = GlobalRegOptions(top_k=10)
    plain = global_register(V, F, [fr], symmetric=False, options=opts)
    merged = global_register(V, F, [fr], symmetric=True, options=opts)
    # rotations about the can's axis are distinct under ADD but the same under ADD-S
    assert len(merged) < len(plain)
    assert merged[0].score == pytest.approx(plain[0].score)


def test_deterministic_with_seed(mustard):
    V, F, _ = mustard
    fr = synthetic_frame(V, F, random_pose(2, centre=CENTRE), seed=2)
    a = global_register(V, F, [fr], options=GlobalRegOptions(seed=5))
    b = global_register(V, F, [fr], options=GlobalRegOptions(seed=5))
    assert len(a) == len(b)
    for x, y in zip(a, b, strict=True):
        np.testing.assert_allclose(x.T_world_object, y.T_world_object, atol=1e-9)


def test_touch_only_with_spread_contacts(mustard):
    """No vision at all: 12 spread contacts pin the mustard bottle; 4 seldom do (documented limit)."""
    V, F, M = mustard
    ok = 0
    for s in range(3):
        T_gt = random_pose(1000 + s, centre=CENTRE)
        fr = synthetic_frame(V, F, T_gt, seed=s, n_contacts=12)
        fr.vision_points = None
        hyps = global_register(V, F, [fr])
        assert hyps[0].source == "touch" and np.isnan(hyps[0].vision_fitness)
        assert hyps[0].contact_residual < 0.001
        ok += add(hyps[0].T_world_object[None], T_gt[None], M)[0] < 0.005
    assert ok >= 2  # measured 4/4 (ADD 0.2-1.2 mm) over seeds 0-3


def test_relocaliser_near_last_pose(mustard):
    V, F, M = mustard
    reloc = Relocaliser(V, F, search_radius=0.05)
    T_last = random_pose(11, centre=CENTRE)
    # the object moved 2 cm and turned 20 deg while the tracker was lost
    T_now = se3.make_transform(se3.so3_exp(np.array([0.0, 0.35, 0.0])), np.array([0.02, 0.0, 0.0])) @ T_last
    fr = synthetic_frame(V, F, T_now, seed=11)
    h = reloc.relocalise([fr], T_last)
    assert h is not None and add_s(h.T_world_object[None], T_now[None], M)[0] < 0.005
    # a last good pose far from where the object is: nothing within the search radius
    T_far = T_last.copy()
    T_far[:3, 3] += np.array([0.3, 0.0, 0.0])
    assert reloc.relocalise([fr], T_far) is None
    # no data at all -> None, never an exception
    empty = synthetic_frame(V, F, T_now, seed=1, n_contacts=0, n_free=0)
    empty.vision_points = None
    assert reloc.relocalise([empty], T_last) is None


def test_bad_input_names_the_field(mustard):
    V, F, _ = mustard
    fr = synthetic_frame(V, F, random_pose(0, centre=CENTRE), seed=0)
    with pytest.raises(InputError, match="frames"):
        global_register(V, F, fr)  # type: ignore[arg-type]
    with pytest.raises(InputError, match="vertices"):
        global_register(V[:, :2], F, [fr])
    with pytest.raises(InputError, match="faces"):
        global_register(V, F + len(V), [fr])
    with pytest.raises(InputError, match="search_radius"):
        Relocaliser(V, F, search_radius=-1.0)
    with pytest.raises(InputError, match="bogus"):
        GlobalRegOptions.from_dict({"bogus": 1})


def test_batched_touch_scores_equal_the_one_by_one_score(mustard):
    # the touch-only path ranks its 3000 sampled rotations with the batched score: it must be _evaluate's
    from scipy.spatial.transform import Rotation

    from vtrack.tracking import globalreg as G

    V, F, _ = mustard
    T = random_pose(1, centre=CENTRE)
    fr = synthetic_frame(V, F, T, seed=1, n_contacts=5)
    fr.touch_normals[0] = np.nan  # a contact without a normal
    opts = GlobalRegOptions()
    model, obs = G._prepare_model(V, F, opts, None), G._gather([fr], opts)
    obs.vision = obs.vision[:20]
    R = Rotation.random(40, random_state=0).as_matrix()
    t = T[:3, 3] + np.random.default_rng(0).normal(0.0, 0.01, (40, 3))
    Ts = np.repeat(np.eye(4)[None], 40, 0)
    Ts[:, :3, :3], Ts[:, :3, 3] = R, t
    one = np.array([G._evaluate(X, model, obs, opts, "touch").score for X in Ts])
    np.testing.assert_allclose(G._batch_scores(R, t, model, obs, opts), one, atol=1e-12)
    assert one.std() > 0.01  # the poses differ in score: the comparison means something
