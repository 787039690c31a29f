"""Offline run selection of SLAM (``track_session(..., select_runs=True)``): the blind map-consistency score and the
replay of the same tracking frames with each alternative setting."""

import numpy as np
import pytest

from vtrack.errors import InputError
from vtrack.geometry import se3
from vtrack.tracking.frame import TrackingFrame
from vtrack.tracking.slam import SLAM_SELECT_ALTERNATIVES, map_consistency_mm, select_run, sphere_in_force

R = 0.03  # m, sphere radius


class _SphereMap:
    """A tracker whose final map is the exact SDF of a sphere of radius ``R`` at the object origin (m)."""

    class sdf:  # noqa: N801 - stands in for the tracker's ``sdf`` attribute
        @staticmethod
        def query(points, with_grad=True):
            return np.linalg.norm(points, axis=1) - R, None


def _frames(n_frames: int, n_points: int, poses: np.ndarray) -> list[TrackingFrame]:
    """Depth points on the sphere's surface seen at ``poses`` (T_world_object), world frame."""
    rng = np.random.default_rng(0)
    out = []
    for i in range(n_frames):
        d = rng.normal(size=(n_points, 3))
        p = d / np.linalg.norm(d, axis=1, keepdims=True) * R
        out.append(TrackingFrame(t=0.1 * i, vision_points=se3.transform_points(poses[i], p)))
    return out


def test_map_consistency_measures_how_far_frames_sit_off_the_map():
    n = 6
    true = np.stack([se3.make_transform(np.eye(3), [0.01 * i, 0.0, 0.2]) for i in range(n)])
    frames = _frames(n, 200, true)
    assert map_consistency_mm(_SphereMap(), frames, true) < 1e-9
    off = true.copy()
    off[:, 0, 3] += 0.003  # every pose 3 mm off along x: points sit 0-3 mm off the sphere (median |x| component)
    s = map_consistency_mm(_SphereMap(), frames, off)
    assert 1.0 < s < 3.0
    worse = true.copy()
    worse[:, 0, 3] += 0.006
    assert map_consistency_mm(_SphereMap(), frames, worse) > 1.8 * s  # grows with the error
    # frames with fewer than 30 finite points do not count; NaN rows are dropped; nothing left -> NaN
    few = _frames(n, 20, true)
    assert np.isnan(map_consistency_mm(_SphereMap(), few, off))
    nan_rows = _frames(n, 200, true)
    for f in nan_rows:
        f.vision_points[::2] = np.nan
    assert map_consistency_mm(_SphereMap(), nan_rows, true) < 1e-9
    mixed = [TrackingFrame(t=0.0)] + frames[1:]  # a frame without depth points is skipped
    assert np.isfinite(map_consistency_mm(_SphereMap(), mixed, off))


def test_select_run_compares_maps_of_one_kind_only():
    nan = float("nan")
    assert select_run([0.37, 0.36, 0.38], [False] * 3) == 1
    assert select_run([0.37, nan, 0.36], [False] * 3) == 2  # NaN: no frame with depth, never chosen
    assert select_run([nan, nan, nan], [False] * 3) == 0  # nothing to compare: the default
    # the default tracks a ball map (sphere prior): fused maps score lower but are not comparable with it
    assert select_run([0.57, 0.34, 0.35], [True, False, False]) == 0
    assert select_run([0.57, 0.55, 0.35], [True, True, False]) == 1
    assert select_run([0.37, 0.30, 0.36], [False, True, False]) == 2

    class _Prior:
        sphere = None

    class _Tracker:
        shape_prior = _Prior()

    t = _Tracker()
    assert not sphere_in_force(t) and not sphere_in_force(object())
    t.shape_prior.sphere = (np.zeros(3), 0.03)
    assert sphere_in_force(t)


def test_selected_run_is_the_lowest_score_and_replays_exactly(tiny_session):
    """Each alternative replays the same tracking frames: the chosen run's poses equal a run made directly with its
    setting, bit for bit; the metrics report every score and the choice."""
    from vtrack.tracking.run import track_session

    kept: dict = {}
    m, (_, T) = track_session(
        tiny_session, "", shape="slam", write=False, return_poses=True, select_runs=True, keep_frames=kept
    )
    scores = m["select_scores_mm"]
    assert len(scores) == 1 + len(SLAM_SELECT_ALTERNATIVES) and np.all(np.isfinite(scores))
    assert all(0.0 < s < 5.0 for s in scores)  # mm: depth points sit within a few mm of their own map
    best = m["selected_run"]
    assert best == select_run(scores, m["select_sphere_prior"])
    if not any(m["select_sphere_prior"]):  # the soup can: no ball map, so the plain lowest score
        assert best == int(np.argmin(scores))
    assert m["select_cpu_s"] > 0 and m["blind"]
    alt = {} if best == 0 else SLAM_SELECT_ALTERNATIVES[best - 1]
    m_direct, (_, T_direct) = track_session(tiny_session, "", shape="slam", write=False, return_poses=True, **alt)
    np.testing.assert_array_equal(T, T_direct)
    # the kept tracker is the one handed back (its map scores the kept poses as reported)
    frames = [fr.tracking_frame() for _, fr in kept["built"]]
    assert map_consistency_mm(kept["tracker"], frames, T) == pytest.approx(scores[best], rel=1e-9)
    assert m["motion_err_mm"] == m_direct["motion_err_mm"]
    # every alternative is really another run: their scores differ from the default's
    assert len(set(scores)) == len(scores)


def test_selection_is_for_slam_only(tiny_session):
    from vtrack.tracking.run import track_session

    with pytest.raises(InputError, match="select_runs"):
        track_session(tiny_session, "", shape="known_shape", write=False, select_runs=True)
