"""The colour term's fast paths give the values of the plain ones (issue #19, SLAM speed with colour on):

- the window's colour residuals computed in one vectorised pass (``WindowTracker._window_colour_terms``) equal one
  ``_colour_terms`` call per slot, whatever the mix of slots (ray and point residuals, projected, without tracks);
- the Huber weights and costs are the textbook ``where`` formulas bit for bit;
- ``FeatureTracks.update`` on the RGB image (grey conversion of the object's box only) gives the very tracks it
  gives on the whole frame's grey image.
"""

from __future__ import annotations

import numpy as np

from vtrack.tracking.colour import FeatureTracks, to_grey
from vtrack.tracking.frame import TrackingFrame
from vtrack.tracking.window import WindowTracker, _exp, _Slot


class _Plane:
    def query(self, points: np.ndarray, with_grad: bool = True):
        return points[:, 2], (np.tile([0.0, 0.0, 1.0], (len(points), 1)) if with_grad else None)


def _slot(rng: np.random.Generator, n: int, centres: bool = True) -> _Slot:
    T = _exp(np.concatenate([rng.normal(0, 0.05, 3), rng.normal(0, 0.4, 3)]))
    Q = rng.normal(0, 0.03, (n, 3))  # object-frame anchors, m
    # observations: the anchors at the pose, off by a few mm (some beyond the Huber knee), seen from ~0.4 m
    P = Q @ T[:3, :3].T + T[:3, 3] + rng.normal(0, 0.002, (n, 3))
    C = np.tile([0.05, -0.1, -0.4], (n, 1)) + rng.normal(0, 1e-3, (n, 3))
    return _Slot(T=T, t=0.0, frame=TrackingFrame(t=0.0), T_prior=T.copy(), colour=(P, Q, C if centres else None))


def test_window_colour_terms_equal_the_per_slot_terms():
    rng = np.random.default_rng(7)
    tr = WindowTracker(_Plane(), np.eye(4), {"sigma_colour": 0.001})
    slots = [_slot(rng, 37), _slot(rng, 6), _slot(rng, 80), _slot(rng, 12, centres=False), _slot(rng, 20)]
    slots.insert(2, _Slot(T=np.eye(4), t=0.0, frame=TrackingFrame(t=0.0), T_prior=np.eye(4)))  # no colour
    # a slot with a colour projector (the colour_ratio option) takes the per-slot path, with its linearisation pose
    slots[4].proj_colour = np.diag([1.0, 1.0, 1.0, 0.0, 0.0, 1.0])
    slots[4].T_lin = slots[4].T @ _exp(np.full(6, 0.01))
    batched = tr._window_colour_terms(slots)
    assert sorted(batched) == [0, 1, 3, 4, 5]
    for i, (H, b, c) in batched.items():
        H1, b1, c1 = tr._colour_terms(slots[i])
        assert np.abs(H1).max() > 0 and c1 > 0
        np.testing.assert_allclose(H, H1, rtol=1e-12, atol=1e-9 * np.abs(H1).max())
        np.testing.assert_allclose(b, b1, rtol=1e-12, atol=1e-9 * np.abs(b1).max())
        assert abs(c - c1) <= 1e-12 * c1
    # the point residual (option colour_residual) is per slot too, and the same
    tr.opts.colour_residual = "point"
    for i, (H, b, c) in tr._window_colour_terms(slots).items():
        H1, b1, c1 = tr._colour_terms(slots[i])
        assert np.array_equal(H, H1) and np.array_equal(b, b1) and c == c1


def test_tracks_on_rgb_equal_tracks_on_the_whole_grey_frame():
    rng = np.random.default_rng(1)
    h, w = 120, 160
    yy, xx = np.mgrid[0:h, 0:w]
    mask = (xx - 80) ** 2 + (yy - 60) ** 2 < 45**2
    a, b = FeatureTracks(), FeatureTracks()
    first = np.zeros(0, np.int64)
    for i in range(8):
        # a coloured texture sliding right 1.5 px per frame, with sensor noise
        x = xx - 1.5 * i
        rgb = np.stack([120 + 60 * np.sin(x / 3.0) * np.cos(yy / 4.0), 100 + 50 * np.cos(x / 5.0), 90 + 0 * x], -1)
        rgb = np.clip(rgb + rng.normal(0, 2.0, rgb.shape), 0, 255).astype(np.uint8)
        ids_a, uv_a = a.update(rgb, mask)
        ids_b, uv_b = b.update(to_grey(rgb), mask)
        assert np.array_equal(ids_a, ids_b) and np.array_equal(uv_a, uv_b)
        if i == 0:
            first = ids_a
    assert len(first) >= 5 and len(np.intersect1d(first, ids_a)) >= 5 and len(ids_a) >= 10  # continued, refilled


def test_huber_weights_are_the_where_formulas_bit_for_bit():
    from vtrack.tracking.window import _robust_weights

    rng = np.random.default_rng(0)
    special = [0.0, -0.0, np.inf, -np.inf, np.nan, 1e-300, 5e-324]
    for k in (0.5, 1.5, 2.0, 1e9):
        r = np.concatenate([rng.normal(0, 3, 20000), rng.normal(0, 1e-160, 200), special, [k, -k]])
        a = np.abs(r)
        w, rho = _robust_weights(r, "huber", k)
        assert np.array_equal(w, np.where(a <= k, 1.0, k / np.maximum(a, 1e-12)), equal_nan=True)
        assert np.array_equal(rho, np.where(a <= k, 0.5 * a * a, k * (a - 0.5 * k)), equal_nan=True)
