"""Rotational-symmetry shape prior (vtrack.fusion.symmetry): a half-observed ball / can completes, a box and a
tri-axial ellipsoid are not taken for surfaces of revolution."""

from __future__ import annotations

import numpy as np
import pytest

from vtrack.fusion.symmetry import fit_revolution


def _noisy(P, N, rng, sigma=0.0005):
    return P + rng.normal(0, sigma, P.shape), N


def _sphere(n, R, rng, visible):
    """n points on a sphere of radius R (m) at the origin where visible(unit normal) holds, normals."""
    N = rng.normal(size=(4 * n, 3))
    N /= np.linalg.norm(N, axis=1, keepdims=True)
    N = N[visible(N)][:n]
    return R * N, N


def _cylinder(n, R, H, rng, max_angle):
    """Side points of a cylinder (axis z, radius R, height 2H) at angles within +-max_angle of +x, plus its top."""
    a = rng.uniform(-max_angle, max_angle, n)
    z = rng.uniform(-H, H, n)
    N = np.column_stack([np.cos(a), np.sin(a), np.zeros(n)])
    P = np.column_stack([R * np.cos(a), R * np.sin(a), z])
    m = n // 3
    r, t = R * np.sqrt(rng.random(m)), rng.uniform(-max_angle, max_angle, m)
    top = np.column_stack([r * np.cos(t), r * np.sin(t), np.full(m, H)])
    return np.concatenate([P, top]), np.concatenate([N, np.tile([0.0, 0.0, 1.0], (m, 1))])


def test_half_observed_sphere_completes():
    """A 37 mm ball seen only on the half facing +x: the revolved profile puts its unseen back within 1.5 mm."""
    rng = np.random.default_rng(0)
    P, N = _noisy(*_sphere(3000, 0.037, rng, lambda n: n[:, 0] > -0.1), rng)
    rev = fit_revolution(P, N)
    assert rev is not None and rev.inlier > 0.9
    back, _ = _sphere(500, 0.037, rng, lambda n: n[:, 0] < -0.5)  # never observed
    assert np.percentile(np.abs(rev.sdf(back)), 90) < 0.0015
    assert rev.sdf(np.zeros((1, 3)))[0] == pytest.approx(-0.037, abs=0.002)  # inside, by the radius
    assert rev.sdf(np.array([[0.08, 0.0, 0.0]]))[0] == pytest.approx(0.043, abs=0.002)  # outside
    far = rev.sdf(np.array([[0.0, 0.0, 0.5]]))[0]  # beyond the raster: still the distance, roughly
    assert 0.4 < far < 0.5
    from vtrack.errors import InputError

    with pytest.raises(InputError, match="non-finite"):
        rev.sdf(np.array([[np.nan, 0.0, 0.0]]))


def test_partly_observed_cylinder_completes():
    """A can (r 33 mm, 100 mm tall) seen over 200 deg of its side and its top: the back of the side and the
    bottom edge come out within 1.5 mm, the axis within 2 deg."""
    rng = np.random.default_rng(1)
    P, N = _noisy(*_cylinder(4000, 0.033, 0.05, rng, np.radians(100)), rng)
    rev = fit_revolution(P, N)
    assert rev is not None
    assert abs(rev.axis[2]) > np.cos(np.radians(2))
    a = rng.uniform(np.radians(120), np.radians(240), 500)  # the unseen back
    z = rng.uniform(-0.045, 0.045, 500)
    back = np.column_stack([0.033 * np.cos(a), 0.033 * np.sin(a), z])
    assert np.percentile(np.abs(rev.sdf(back)), 90) < 0.0015


def test_box_and_ellipsoid_are_not_surfaces_of_revolution():
    rng = np.random.default_rng(2)
    # three visible faces of a 10 x 6 x 4 cm box
    pts, nrm = [], []
    half = np.array([0.05, 0.03, 0.02])
    for ax in range(3):
        P = rng.uniform(-1, 1, (1500, 3)) * half
        P[:, ax] = half[ax]
        n = np.zeros((1500, 3))
        n[:, ax] = 1.0
        pts.append(P)
        nrm.append(n)
    assert fit_revolution(*_noisy(np.concatenate(pts), np.concatenate(nrm), rng)) is None
    # a tri-axial ellipsoid (50 x 30 x 20 mm half-axes; a bent tube along a circular arc would be a torus piece,
    # which is a surface of revolution), seen from +x
    semi = np.array([0.05, 0.03, 0.02])
    u = rng.normal(size=(8000, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    P = u * semi
    N = P / semi**2
    N /= np.linalg.norm(N, axis=1, keepdims=True)
    vis = N[:, 0] > -0.2
    assert fit_revolution(*_noisy(P[vis], N[vis], rng)) is None


def test_degenerate_inputs_give_no_prior():
    assert fit_revolution(np.zeros((0, 3)), np.zeros((0, 3))) is None
    assert fit_revolution(np.full((100, 3), np.nan), np.zeros((100, 3))) is None
    rng = np.random.default_rng(3)
    line = np.column_stack([rng.uniform(-0.05, 0.05, 200), np.zeros(200), np.zeros(200)])
    assert fit_revolution(line, np.zeros((200, 3))) is None  # no surface at all


def test_symmetric_prior_completes_the_back_of_a_ball_in_the_neural_sdf():
    """Neural SDF on a ball seen from one side (60 % of its surface): with the hull prior the unseen back is cut
    flat (points 5 mm inside the true back come out outside); the symmetric prior keeps them inside."""
    torch = pytest.importorskip("torch")
    from vtrack.fusion.neural_sdf import NeuralSDFReconstructor
    from vtrack.fusion.observations import Observation

    torch.set_num_threads(1)
    rng = np.random.default_rng(4)
    P, N = _noisy(*_sphere(2500, 0.037, rng, lambda n: n[:, 0] > -0.2), rng)
    obs = [Observation(0.0, 1, 0, "touch", P, N, np.ones(len(P)), np.zeros(len(P)), np.eye(4))]
    back, _ = _sphere(400, 0.032, rng, lambda n: n[:, 0] < -0.7)  # 5 mm inside the unseen back
    inside = {}
    for prior in ("hull", "symmetric"):
        r = NeuralSDFReconstructor(seed=0, prior=prior)
        r.fit(obs, n_iters=30)
        s, _ = r.query(back, with_grad=False)
        inside[prior] = float(np.mean(s < 0))
        if prior == "symmetric":
            assert r.revolution is not None
    assert inside["symmetric"] > 0.95, inside
    assert inside["hull"] < 0.5, inside  # the flat cut the symmetric prior fixes is really there
