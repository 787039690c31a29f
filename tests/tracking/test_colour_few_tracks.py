"""SLAM's minimum number of colour tracks in frames with plenty of depth (``SLAM_COLOUR_FEW_TRACKS`` where the frame
has >= ``SLAM_COLOUR_FEW_MIN_VISION`` depth points): with fewer anchored tracks the colour term is left out of such a
frame (a handful of slipping tracks steered the 5 s banana at medium occlusion off, docs/benchmarks/slam_5s_medium.md);
with sparse depth (heavy occlusion) the tracker's own minimum (6) applies.

A cylinder spinning about its axis (depth cannot see the spin) with exact colour tracks on its surface."""

from __future__ import annotations

import numpy as np
import pytest

from vtrack.geometry import se3
from vtrack.tracking.frame import TrackingFrame
from vtrack.tracking.slam import SLAM_COLOUR_FEW_MIN_VISION, SLAM_COLOUR_FEW_TRACKS, SLAMOptions
from vtrack.tracking.window import WindowTracker

CENTRE = np.array([0.0, 0.0, 0.4])  # camera = world frame, m
RADIUS = 0.04
SPIN = 1.2  # rad/s about the world y axis
FPS = 30.0


def _rot_y(a: float) -> np.ndarray:
    return se3.so3_exp(np.array([0.0, a, 0.0]))


def _pose(t: float) -> np.ndarray:
    """``T_world_object`` at time ``t`` (s): the spin about the world y axis through ``CENTRE``."""
    return se3.make_transform(_rot_y(SPIN * t), CENTRE)


class _CylinderSDF:
    def query(self, points: np.ndarray, with_grad: bool = True):
        rho = np.hypot(points[:, 0], points[:, 2])
        g = np.stack([points[:, 0], np.zeros(len(points)), points[:, 2]], 1) / np.maximum(rho, 1e-9)[:, None]
        return rho - RADIUS, (g if with_grad else None)


def _surface(n: int, rng: np.random.Generator) -> np.ndarray:
    """Object-frame points on the cylinder (axis y)."""
    a = rng.uniform(0, 2 * np.pi, n)
    return np.stack([RADIUS * np.sin(a), rng.uniform(-0.04, 0.04, n), RADIUS * np.cos(a)], 1)


def _frames(n_tracks: int, n: int = 30, n_vision: int = 300) -> list[TrackingFrame]:
    rng = np.random.default_rng(0)
    Q = _surface(4000, rng)
    anchors = _surface(400, rng)
    out = []
    for i in range(n):
        t = i / FPS
        T = _pose(t)
        P = Q @ T[:3, :3].T + T[:3, 3]
        N = (P - CENTRE) * np.array([1.0, 0.0, 1.0])
        V = P[np.sum(N * P, 1) < 0][:n_vision]  # the half facing the camera
        A = anchors @ T[:3, :3].T + T[:3, 3]
        vis = np.flatnonzero(np.sum((A - CENTRE) * np.array([1.0, 0.0, 1.0]) * A, 1) < -1e-5)[:n_tracks]
        info = {"colour_ids": vis, "colour_points": A[vis], "colour_origins": np.zeros((len(vis), 3))}
        out.append(TrackingFrame(t=t, vision_points=V, info=info))
    return out


def _spin(T: np.ndarray) -> float:
    return float(np.arctan2(T[0, 2], T[2, 2]))


def _run(frames: list[TrackingFrame], **over) -> np.ndarray:
    _, _, opts = SLAMOptions.split({"object_radius": RADIUS, **over})
    tr = WindowTracker(_CylinderSDF(), _pose(0.0), opts)
    return np.array([tr.step(f) for f in frames])


def test_slam_leaves_out_colour_with_few_tracks_where_depth_is_dense():
    o = SLAMOptions.split({})[2]
    assert (o.colour_few_tracks, o.colour_few_min_vision) == (SLAM_COLOUR_FEW_TRACKS, SLAM_COLOUR_FEW_MIN_VISION)
    assert o.colour_min_tracks < SLAM_COLOUR_FEW_TRACKS <= 300 and SLAM_COLOUR_FEW_MIN_VISION <= 300
    few = _frames(SLAM_COLOUR_FEW_TRACKS - 2)
    assert min(len(f.info["colour_ids"]) for f in few[1:]) == SLAM_COLOUR_FEW_TRACKS - 2
    assert min(f.n_vision for f in few) >= SLAM_COLOUR_FEW_MIN_VISION
    no_colour = _run(few, sigma_colour=0.0)
    assert np.array_equal(_run(few), no_colour)
    # the tracker's own minimum (6) would have used them: the colour term follows the spin
    truth = SPIN * few[-1].t
    assert abs(_spin(no_colour[-1])) < 0.1 * truth
    assert 0.8 * truth < _spin(_run(few, colour_few_tracks=0)[-1]) < 1.1 * truth


def test_slam_uses_few_tracks_where_depth_is_sparse():
    few = _frames(SLAM_COLOUR_FEW_TRACKS - 2, n_vision=SLAM_COLOUR_FEW_MIN_VISION // 2)
    truth = SPIN * few[-1].t
    assert 0.8 * truth < _spin(_run(few)[-1]) < 1.1 * truth


def test_slam_uses_colour_with_enough_tracks():
    many = _frames(SLAM_COLOUR_FEW_TRACKS + 8)
    truth = SPIN * many[-1].t
    assert 0.8 * truth < _spin(_run(many)[-1]) < 1.1 * truth


def test_few_track_options_are_checked():
    from vtrack.errors import InputError
    from vtrack.tracking.window import TrackerOptions

    for bad in ({"colour_few_tracks": -1}, {"colour_few_min_vision": -5}):
        with pytest.raises(InputError):
            TrackerOptions.from_dict(bad)
