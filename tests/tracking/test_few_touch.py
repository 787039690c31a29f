"""The contact budget of frames that see little (``TrackerOptions.few_touch_points``; SLAM default ``SLAM_FEW_TOUCH``).

A sliding contact patch matched against a map the contacts built is off as a whole; its 120 pixels are not 120
measurements. With the budget a touch-only frame steers the pose only as far as a few measurements would.
"""

import numpy as np

from vtrack.tracking.frame import TrackingFrame
from vtrack.tracking.slam import SLAM_FEW_TOUCH, SLAMOptions, SLAMTracker
from vtrack.tracking.window import TrackerOptions, WindowTracker

R = 0.03  # m, sphere radius


class _Sphere:
    """Exact SDF of a sphere of radius ``R`` at the object origin (m)."""

    def query(self, points, with_grad=True):
        n = np.linalg.norm(points, axis=1)
        g = points / np.maximum(n, 1e-12)[:, None]
        return n - R, (g if with_grad else None)


def _touch_frame(t: float, shift: float, n: int = 160) -> TrackingFrame:
    """Touch only: contacts on two caps of the sphere (+-x, the fingers of a pinch), the whole set moved by
    ``shift`` m along +x (a patch that is off as a whole)."""
    rng = np.random.default_rng(1)
    caps = []
    for sx in (1.0, -1.0):
        d = rng.normal(size=(n // 2, 3)) * [1.0, 0.25, 0.25] + [3.0 * sx, 0, 0]
        caps.append(d / np.linalg.norm(d, axis=1, keepdims=True))
    d = np.concatenate(caps)
    return TrackingFrame(t=t, touch_points=d * R + [shift, 0, 0], touch_normals=d)


def _vision(n: int) -> np.ndarray:
    rng = np.random.default_rng(2)
    d = rng.normal(size=(n, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True) * R


def test_budget_applies_only_to_frames_that_see_little():
    o = SLAMOptions.split(dict(SLAM_FEW_TOUCH))[2]
    assert o.few_touch_points == 12 and o.few_touch_min_vision == 300
    # SLAM's default since 2026-11-28; the known-shape tracker keeps every contact (its shape is not built by them)
    assert SLAMOptions.split({})[2].few_touch_points == 12 and TrackerOptions().few_touch_points == 0
    tr = WindowTracker(_Sphere(), np.eye(4), o)
    fr = _touch_frame(0.0, 0.0)
    assert tr._touch_budget(fr) == 12  # touch only
    for nv, want in ((10, 12), (299, 12), (300, 120), (2000, 120)):
        fr.vision_points = _vision(nv)
        assert tr._touch_budget(fr) == want, nv
    fr.vision_points = np.full((500, 3), np.nan)  # 500 rows, none finite: the frame sees nothing
    assert tr._touch_budget(fr) == 12
    off = WindowTracker(_Sphere(), np.eye(4), SLAMOptions.split({"few_touch_points": 0})[2])
    assert off._touch_budget(_touch_frame(0.0, 0.0)) == 120


def test_a_shifted_patch_steers_a_touch_only_frame_less():
    """Object at rest, held by two fingers; then every contact reads 3 mm off along +x. With all 120 contacts the
    pose follows them almost fully; with the budget of 12 the motion prior holds a third of it."""
    res = {}
    for b in (0, 12):
        tr = WindowTracker(_Sphere(), np.eye(4), SLAMOptions.split({"few_touch_points": b})[2])
        for i in range(6):
            tr.step(_touch_frame(i / 30.0, 0.0))
        assert abs(tr.T[0, 3]) < 1e-4  # at rest while the contacts agree with the map
        tr.step(_touch_frame(6 / 30.0, 0.003))
        assert tr.last_info.n_touch == (120 if b == 0 else 12)
        res[b] = tr.T[0, 3]
        assert np.all(np.isfinite(tr.T))
    # measured: 2.90 mm with 120 contacts (the prior barely holds), 2.04 mm with 12
    assert res[0] > 0.0025
    assert 0.0 < res[12] < 0.8 * res[0]


def test_slam_keeps_the_full_budget_while_a_sphere_prior_holds():
    from vtrack.tracking.shape_prior import Sphere

    tr = SLAMTracker(np.eye(4), **SLAM_FEW_TOUCH)
    fr = _touch_frame(0.0, 0.0)
    assert tr._touch_budget(fr) == 12
    tr.shape_prior.sphere = Sphere(centre=np.zeros(3), radius=R, rms=0.0002, inlier=0.95)
    assert tr._touch_budget(fr) == 120
