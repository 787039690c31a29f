"""Box completion prior (:mod:`vtrack.fusion.boxprior`): a carton seen on three faces is completed by its
face-aligned box; curved clouds are refused."""

from __future__ import annotations

import numpy as np
import pytest

from vtrack.errors import InputError
from vtrack.fusion.boxprior import fit_box

HALF = np.array([0.05, 0.03, 0.04])  # a 10 x 6 x 8 cm carton


def _rot(rng: np.random.Generator) -> np.ndarray:
    Q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    return Q * np.sign(np.linalg.det(Q))


def _seen_box(rng: np.random.Generator, R: np.ndarray, n: int = 3000, noise: float = 0.0007):
    """Points and normals on the +x, +y, +z faces of the box (the other three never seen), rotated by R."""
    pts, nrm = [], []
    for ax in range(3):
        u = rng.uniform(-1, 1, (n // 3, 3)) * HALF
        u[:, ax] = HALF[ax]
        n_ = np.zeros((n // 3, 3))
        n_[:, ax] = 1.0
        pts.append(u)
        nrm.append(n_)
    P, N = np.concatenate(pts), np.concatenate(nrm)
    P = P + rng.normal(0, noise, P.shape)
    N = N + rng.normal(0, 0.05, N.shape)
    N /= np.linalg.norm(N, axis=1, keepdims=True)
    return P @ R.T + np.array([0.01, -0.02, 0.03]), N @ R.T


def test_three_seen_faces_give_the_whole_box():
    rng = np.random.default_rng(0)
    R = _rot(rng)
    P, N = _seen_box(rng, R)
    b = fit_box(P, N)
    assert b is not None
    assert b.aligned > 0.9 and b.on_face > 0.9
    # extents recovered within 2 mm (trimmed quantiles shave a little), in some order of the axes
    assert np.allclose(np.sort(2 * b.half), np.sort(2 * HALF), atol=0.002), b.half
    # the never-seen opposite corner is inside the box prior (the hull of the seen faces cuts it off)
    corner = (-HALF * 0.9) @ R.T + np.array([0.01, -0.02, 0.03])
    assert b.sdf(corner[None])[0] < -0.002
    # exact distance outside along a face normal
    out = (np.array([HALF[0] + 0.01, 0, 0])) @ R.T + np.array([0.01, -0.02, 0.03])
    assert abs(b.sdf(out[None])[0] - 0.01) < 0.002


def test_curved_clouds_and_bad_input_are_refused():
    rng = np.random.default_rng(1)
    # a cylinder side (can): normals spread round the axis
    t = rng.uniform(0, 1.5 * np.pi, 3000)
    z = rng.uniform(-0.05, 0.05, 3000)
    P = np.c_[0.033 * np.cos(t), 0.033 * np.sin(t), z]
    N = np.c_[np.cos(t), np.sin(t), np.zeros_like(t)]
    assert fit_box(P, N) is None
    # a ball
    N = rng.normal(size=(3000, 3))
    N /= np.linalg.norm(N, axis=1, keepdims=True)
    assert fit_box(0.03 * N, N) is None
    # one flat face only: no volume to complete
    P = np.c_[rng.uniform(-0.05, 0.05, (2000, 2)), np.zeros(2000)]
    assert fit_box(P, np.tile([0.0, 0.0, 1.0], (2000, 1))) is None
    # unknown normals, too few points, mismatched lengths
    assert fit_box(rng.normal(size=(500, 3)), np.zeros((500, 3))) is None
    assert fit_box(np.zeros((10, 3)), np.zeros((10, 3))) is None
    with pytest.raises(InputError):
        fit_box(np.zeros((100, 3)), np.zeros((99, 3)))
    b = fit_box(*_seen_box(rng, np.eye(3)))
    with pytest.raises(InputError):
        b.sdf(np.array([[np.nan, 0.0, 0.0]]))


def test_box_prior_keeps_the_unseen_corner_solid_in_the_neural_sdf():
    """Neural SDF prior of a carton seen on three faces: with the hull the far corner is cut away (outside the
    prior); with ``box=True`` it is inside."""
    pytest.importorskip("torch")
    from vtrack.fusion.neural_sdf import NeuralSDFReconstructor

    rng = np.random.default_rng(2)
    R = np.eye(3)
    P, N = _seen_box(rng, R)
    corner = (-HALF + 0.006) @ R.T + np.array([0.01, -0.02, 0.03])
    got = {}
    for box in (False, True):
        r = NeuralSDFReconstructor(seed=0, prior="symmetric", box=box)
        r.set_bounds(r.bounds_from_points(P))
        assert r.set_hull_prior(P, N)
        u = (corner[None] - r.lo) / r.size
        import torch

        got[box] = float(r._hull_t(torch.as_tensor(u, dtype=torch.float32))[0])
        assert (r.box is not None) == box
    assert got[True] < 0 < got[False], got
