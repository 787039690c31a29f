"""Per-track lag rejection of the colour term (``TrackerOptions.colour_drop_lag``): a track whose residual at the
committed pose grows with its anchor's motion (it follows the light or the hand, not the object) is dropped for the
rest of its life, the object-fixed ones keep the spin (docs/benchmarks/slam_5s_lag.md).

A cylinder spinning about its axis (depth cannot see the spin) with exact object-fixed colour tracks and a share of
world-fixed ones (light-fixed shading: the track stays put in the image while the surface turns under it)."""

from __future__ import annotations

import numpy as np
import pytest

from vtrack.errors import InputError
from vtrack.geometry import se3
from vtrack.tracking.frame import TrackingFrame
from vtrack.tracking.slam import SLAM_COLOUR_DROP_KEEP, SLAM_COLOUR_DROP_LAG, SLAM_COLOUR_DROP_MOTION, SLAMOptions
from vtrack.tracking.window import TrackerOptions, WindowTracker

CENTRE = np.array([0.0, 0.0, 0.4])  # camera = world frame, m
RADIUS = 0.04
SPIN = 1.2  # rad/s about the world y axis
FPS = 30.0
N_FRAMES = 30
LIGHT_LIFE = 8  #: frames a light-fixed track lives


def _pose(t: float) -> np.ndarray:
    """``T_world_object`` at time ``t`` (s): the spin about the world y axis through ``CENTRE``."""
    return se3.make_transform(se3.so3_exp(np.array([0.0, SPIN * t, 0.0])), CENTRE)


class _CylinderSDF:
    def query(self, points: np.ndarray, with_grad: bool = True):
        rho = np.hypot(points[:, 0], points[:, 2])
        g = np.stack([points[:, 0], np.zeros(len(points)), points[:, 2]], 1) / np.maximum(rho, 1e-9)[:, None]
        return rho - RADIUS, (g if with_grad else None)


def _surface(n: int, rng: np.random.Generator, half_angle: float = np.pi) -> np.ndarray:
    """Object-frame points on the cylinder (axis y), within ``half_angle`` of the side facing the camera (-z)."""
    a = np.pi + rng.uniform(-half_angle, half_angle, n)
    return np.stack([RADIUS * np.sin(a), rng.uniform(-0.04, 0.04, n), RADIUS * np.cos(a)], 1)


def _frames(n_fixed: int, n_light: int, noise: float = 0.0) -> list[TrackingFrame]:
    """Depth of the visible half, ``n_fixed`` object-fixed tracks (ids 0..) and ``n_light`` world-fixed ones (ids
    1000..: the same world points in every frame, a new id every ``LIGHT_LIFE`` frames) with ``noise`` (m) of
    lateral noise."""
    rng = np.random.default_rng(0)
    Q = _surface(4000, rng)
    anchors = _surface(n_fixed, rng, 0.5)
    light = _surface(n_light, rng, 0.5) + CENTRE  # world points on the surface at t = 0, fixed in the world
    out = []
    for i in range(N_FRAMES):
        t = i / FPS
        T = _pose(t)
        P = Q @ T[:3, :3].T + T[:3, 3]
        V = P[np.sum((P - CENTRE) * np.array([1.0, 0.0, 1.0]) * P, 1) < 0][:300]  # the half facing the camera
        A = np.vstack([anchors @ T[:3, :3].T + T[:3, 3], light])
        A = A + noise * rng.standard_normal(A.shape) * np.array([1.0, 1.0, 0.0])
        # the light-fixed tracks end and are found again (new ids) every LIGHT_LIFE frames, as LK corners do
        ids = np.r_[np.arange(n_fixed), 1000 + np.arange(n_light) + 100 * (i // LIGHT_LIFE)]
        info = {"colour_ids": ids, "colour_points": A, "colour_origins": np.zeros((len(ids), 3))}
        out.append(TrackingFrame(t=t, vision_points=V, info=info))
    return out


def _spin(T: np.ndarray) -> float:
    return float(np.arctan2(T[0, 2], T[2, 2]))


def _run(frames: list[TrackingFrame], **over) -> tuple[np.ndarray, WindowTracker]:
    """SLAM's tracker options with the lag test off unless ``over`` turns it on (its own thresholds here: this scene's
    32 tracks are fewer than SLAM's ``colour_drop_keep``)."""
    _, _, opts = SLAMOptions.split({"object_radius": RADIUS, "colour_drop_lag": 0.0, "colour_drop_keep": 0, **over})
    tr = WindowTracker(_CylinderSDF(), _pose(0.0), opts)
    return np.array([tr.step(f) for f in frames]), tr


def test_world_fixed_tracks_are_dropped_and_the_spin_is_kept():
    frames = _frames(24, 8, noise=2e-4)
    truth = SPIN * frames[-1].t
    plain, _ = _run(frames)
    kept, tr = _run(frames, colour_drop_lag=0.5, colour_drop_motion=0.003)
    err_plain = abs(_spin(plain[-1]) - truth)
    err_kept = abs(_spin(kept[-1]) - truth)
    # the light-fixed third pulls the plain tracker back by a measurable share of the rotation; the rule drops them
    assert err_plain > 0.03 * truth
    assert err_kept < 0.02 * truth and err_kept < 0.5 * err_plain
    # the live light-fixed tracks (their last rebirth) are all dropped, no object-fixed one
    assert tr._colour_dropped == set(1000 + 100 * ((N_FRAMES - 1) // LIGHT_LIFE) + np.arange(8))
    assert all(a < 1000 for a in tr._anchors)


def test_object_fixed_tracks_are_all_kept():
    frames = _frames(24, 0, noise=2e-4)
    poses, tr = _run(frames, colour_drop_lag=0.5, colour_drop_motion=0.003)
    assert not tr._colour_dropped and len(tr._anchors) == 24
    assert np.array_equal(poses, _run(frames)[0])  # nothing dropped: the same poses as without the rule


def test_degenerate_tracks_give_finite_poses():
    frames = _frames(12, 4)
    for k, f in enumerate(frames):
        P = f.info["colour_points"].copy()
        if k % 3 == 1:
            P[0] = np.nan  # a track without depth
        if k % 5 == 2:
            P[1] = 0.0  # on the camera centre: no viewing ray
        f.info["colour_points"] = P
    frames[20].info = {"colour_ids": np.zeros(0, int), "colour_points": np.zeros((0, 3))}
    frames[21].info = {}
    poses, _ = _run(frames, colour_drop_lag=0.3, colour_drop_motion=1e-4)
    assert np.isfinite(poses).all()


@pytest.mark.parametrize(
    "bad",
    [
        {"colour_drop_lag": -0.1},
        {"colour_drop_lag": float("nan")},
        {"colour_drop_motion": 0.0},
        {"colour_drop_motion": float("inf")},
        {"robust_colour": "tukey"},
        {"colour_drop_keep": -1},
    ],
)
def test_bad_lag_options_are_input_errors(bad):
    with pytest.raises(InputError):
        TrackerOptions.from_dict(bad)


def test_slam_defaults_leave_the_lag_test_off_and_the_preset_turns_it_on():
    from vtrack.tracking.slam import SLAM_COLOUR_DROP

    o = SLAMOptions.split({})[2]
    assert (o.colour_drop_lag, o.colour_drop_motion, o.colour_drop_keep) == (
        SLAM_COLOUR_DROP_LAG,
        SLAM_COLOUR_DROP_MOTION,
        SLAM_COLOUR_DROP_KEEP,
    )
    assert SLAM_COLOUR_DROP_LAG == 0.0 and TrackerOptions().colour_drop_lag == 0.0  # off (see slam.py: why)
    on = SLAMOptions.split(dict(SLAM_COLOUR_DROP))[2]
    assert (on.colour_drop_lag, on.colour_drop_motion, on.colour_drop_keep) == (0.3, 0.003, 24)


def test_keep_bounds_the_drops():
    frames = _frames(24, 8, noise=2e-4)
    _, tr = _run(frames, colour_drop_lag=0.5, colour_drop_motion=0.003, colour_drop_keep=30)
    # 32 tracks, at most 2 may go per frame: some of the live light-fixed ones stay anchored
    assert 0 < len(tr._colour_dropped) <= 2
    assert any(a >= 1000 for a in tr._anchors)
