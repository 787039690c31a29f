"""The colour term (KLT feature tracks, :mod:`vtrack.tracking.colour`): it observes a spin that depth cannot see
on a textured body of revolution, and it does nothing on a uniformly coloured one.

The fixture renders a cylinder spinning about its own axis (analytic ray casting, no session): depth sees the same
surface in every frame, colour sees its object-fixed texture move. Shading is light-fixed (Lambert), as in the
simulator, so a tracker that followed raw intensities would be pulled towards rest.
"""

from __future__ import annotations

import numpy as np
import pytest

from vtrack.geometry import se3
from vtrack.tracking.colour import FeatureTracks, backproject
from vtrack.tracking.frame import TrackingFrame
from vtrack.tracking.window import WindowTracker

W, H, F = 320, 240, 400.0  # image size (px) and focal length (px): ~1 mm per pixel at 0.4 m
K = np.array([[F, 0.0, (W - 1) / 2], [0.0, F, (H - 1) / 2], [0.0, 0.0, 1.0]])
CENTRE = np.array([0.0, 0.0, 0.4])  # cylinder centre, camera = world frame, m
RADIUS, HALF_H = 0.04, 0.05
SPIN = 1.2  # rad/s about the cylinder's axis (world / camera y)
FPS = 30.0


def _rot_y(a: float) -> np.ndarray:
    return se3.so3_exp(np.array([0.0, a, 0.0]))


def _pose(t: float) -> np.ndarray:
    """``T_world_object`` at time ``t`` (s): the spin about the world y axis through ``CENTRE``."""
    return se3.make_transform(_rot_y(SPIN * t), CENTRE)


def _render(t: float, textured: bool, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(grey uint8, depth m (0 = none), object mask) of the spinning cylinder at time t."""
    u, v = np.meshgrid(np.arange(W), np.arange(H))
    d = np.stack([(u - K[0, 2]) / F, (v - K[1, 2]) / F, np.ones_like(u, float)], -1)
    # ray t*d against x^2 + (z - zc)^2 = r^2 (axis along y)
    a = d[..., 0] ** 2 + 1.0
    b = -2.0 * CENTRE[2]
    c = CENTRE[2] ** 2 - RADIUS**2
    disc = b * b - 4 * a * c
    hit = disc > 0
    s = np.where(hit, (-b - np.sqrt(np.maximum(disc, 0))) / (2 * a), 0.0)
    P = d * s[..., None]
    hit &= np.abs(P[..., 1]) < HALF_H
    n = (P - CENTRE) * np.array([1.0, 0.0, 1.0]) / RADIUS
    q = (P - CENTRE) @ _rot_y(SPIN * t)  # object-frame points (R^T (P - c), row-wise)
    albedo = 200.0
    if textured:  # the simulator's object-fixed pattern (vtrack.sim.rgbd._albedo_object) at a 1.6 cm period
        p = q * 400.0
        albedo = 200.0 * (0.75 + 0.25 * np.sin(p[..., 0] + 2 * np.sin(p[..., 1])) * np.cos(p[..., 2] * 1.3))
    key = np.array([0.3, -0.4, 0.85]) / np.linalg.norm([0.3, -0.4, 0.85])
    view = -d / np.linalg.norm(d, axis=-1, keepdims=True)
    lam = 0.55 * np.clip(np.sum(n * view, -1), 0, 1) + 0.35 * np.abs(n @ key) + 0.15
    img = np.where(hit, albedo * lam, 60.0) + rng.normal(0.0, 2.0, (H, W))
    depth = np.where(hit, P[..., 2] + rng.normal(0.0, 0.0005, (H, W)), 0.0)
    return np.clip(np.rint(img), 0, 255).astype(np.uint8), depth, hit


class _CylinderSDF:
    """Signed distance to the (infinite) cylinder in its object frame (axis y), with gradient."""

    def query(self, points: np.ndarray, with_grad: bool = True):
        rho = np.hypot(points[:, 0], points[:, 2])
        g = np.stack([points[:, 0], np.zeros(len(points)), points[:, 2]], 1) / np.maximum(rho, 1e-9)[:, None]
        return rho - RADIUS, (g if with_grad else None)


def _frames(textured: bool, n: int = 40, colour: bool = True) -> list[TrackingFrame]:
    rng = np.random.default_rng(3)
    tracks = FeatureTracks()
    out = []
    for i in range(n):
        t = i / FPS
        grey, z, m = _render(t, textured, rng)
        k = 4
        zs, ms = z[::k, ::k], m[::k, ::k]
        vv, uu = np.nonzero(ms)
        zz = zs[vv, uu]
        V = np.stack([(uu * k - K[0, 2]) * zz / F, (vv * k - K[1, 2]) * zz / F, zz], 1)
        info: dict = {}
        if colour:
            ids, uv = tracks.update(grey, m)
            X, ok = backproject(uv, np.where(ms, zs, 0.0), k, K)
            info = {"colour_ids": ids[ok], "colour_points": X[ok], "colour_origins": np.zeros((int(ok.sum()), 3))}
        out.append(TrackingFrame(t=t, vision_points=V, info=info))
    return out


def _spin_of(T: np.ndarray) -> float:
    """Rotation angle about the world y axis of T_world_object (rad)."""
    R = T[:3, :3]
    return float(np.arctan2(R[0, 2], R[2, 2]))


def _track(frames: list[TrackingFrame], sigma_colour: float) -> np.ndarray:
    tr = WindowTracker(_CylinderSDF(), _pose(0.0), {"sigma_colour": sigma_colour, "object_radius": RADIUS})
    return np.array([tr.step(f) for f in frames])


def test_colour_recovers_a_spin_depth_cannot_see():
    frames = _frames(textured=True)
    truth = SPIN * frames[-1].t  # 1.56 rad
    n_tracks = [len(f.info["colour_ids"]) for f in frames]
    assert min(n_tracks) >= 20, n_tracks
    depth_only = _track(frames, 0.0)
    with_colour = _track(frames, 0.002)
    assert np.all(np.isfinite(with_colour))
    # depth sees the same cylinder every frame: the spin stays at the (zero) initial velocity
    assert abs(_spin_of(depth_only[-1])) < 0.05 * truth
    # colour follows the texture: most of the spin, and the position stays on the axis
    assert 0.8 * truth < _spin_of(with_colour[-1]) < 1.1 * truth, (_spin_of(with_colour[-1]), truth)
    assert np.linalg.norm(with_colour[-1][:3, 3] - CENTRE) < 0.003


def test_colour_term_does_nothing_on_a_uniform_object():
    frames = _frames(textured=False)
    # shading alone (divided out) gives no corner above the threshold but a stray noise one (1 track in 11 of 40
    # frames here): fewer tracks than the term's minimum in every frame, so no term and the very same poses
    from vtrack.tracking.window import TrackerOptions

    assert max(len(f.info["colour_ids"]) for f in frames) < TrackerOptions.colour_min_tracks
    assert sum(len(f.info["colour_ids"]) for f in frames) <= 20
    assert np.array_equal(_track(frames, 0.002), _track(_frames(textured=False, colour=False), 0.0))


def test_feature_tracks_are_nan_safe_on_empty_masks():
    rng = np.random.default_rng(0)
    grey, z, m = _render(0.0, True, rng)
    ft = FeatureTracks()
    ids, uv = ft.update(grey, m)
    assert len(ids) > 20 and np.all(np.isfinite(uv))
    for mask in (np.zeros_like(m), m):  # object gone (tracks end), then back (new ids only)
        ids2, uv2 = ft.update(grey, mask)
        assert np.all(np.isfinite(uv2))
    assert not set(ids.tolist()) & set(ids2.tolist())
    X, ok = backproject(np.zeros((0, 2)), z, 1, K)
    assert X.shape == (0, 3) and ok.shape == (0,)
    with pytest.raises(Exception, match="differ in size"):
        ft.update(grey, m[:-1])
    # NaN colour points reach the tracker: no term from them, finite poses
    tr = WindowTracker(_CylinderSDF(), _pose(0.0), {"sigma_colour": 0.002, "object_radius": RADIUS})
    frames = _frames(textured=True, n=6)
    for f in frames[3:]:
        f.info["colour_points"] = np.full_like(f.info["colour_points"], np.nan)
    assert np.all(np.isfinite(np.array([tr.step(f) for f in frames])))


def test_frames_layer_gives_colour_tracks_only_when_asked(tiny_session):
    from scipy.spatial import cKDTree

    from vtrack.frames.session import SessionFrames

    plain = SessionFrames(tiny_session, max_frames=4)
    assert "rgb" not in plain.read(0)  # the default path reads no RGB
    assert "colour_ids" not in plain.frame(0)[0].tracking_frame().info
    sf = SessionFrames(tiny_session, colour=True, max_frames=4)
    seen = []
    for i in range(len(sf)):
        fr, _ = sf.frame(i)
        seen.append(set(fr.colour_ids.tolist()))
        assert len(fr.colour_ids) == len(fr.colour_points) == len(fr.colour_origins)
        assert np.all(np.isfinite(fr.colour_points))
    assert len(seen[0]) >= 10 and len(seen[-1] & seen[0]) >= 5  # tracks continue from frame to frame
    # the tracks lie on the segmented object surface
    d, _ = cKDTree(fr.vision_points).query(fr.colour_points)
    assert np.median(d) < 0.004, np.median(d)
    info = fr.tracking_frame().info
    assert np.array_equal(info["colour_ids"], fr.colour_ids)


def test_slipped_tracks_are_reanchored_at_the_committed_pose():
    # camera at the origin looking down +z; object at CENTRE; three tracks anchored in frame 1
    P0 = CENTRE + np.array([[0.01, 0.0, -0.03], [-0.01, 0.0, -0.03], [0.0, 0.01, -0.03]])
    opts = {"sigma_colour": 0.001, "colour_reanchor": 0.002, "object_radius": RADIUS}
    tr = WindowTracker(_CylinderSDF(), _pose(0.0), opts)
    info = {"colour_ids": np.array([0, 1, 2]), "colour_points": P0, "camera_origin": np.zeros(3)}
    tr._colour_anchor(TrackingFrame(t=0.0, info=info), _pose(0.0), True)
    a0 = {k: v.copy() for k, v in tr._anchors.items()}
    # frame 2, object still: track 0 slipped 3 mm across its ray (re-anchored), track 1 0.5 mm (kept), track 2 moved
    # 5 mm ALONG its ray (depth noise: the ray residual does not see it, kept)
    P1 = P0.copy()
    P1[0, 1] += 0.003
    P1[1, 1] += 0.0005
    P1[2] *= 1.0 + 0.005 / np.linalg.norm(P1[2])
    info = {"colour_ids": np.array([0, 1, 2]), "colour_points": P1, "camera_origin": np.zeros(3)}
    tr._colour_anchor(TrackingFrame(t=1 / FPS, info=info), _pose(0.0), True)
    Ti = np.linalg.inv(_pose(0.0))
    assert np.allclose(tr._anchors[0], P1[0] @ Ti[:3, :3].T + Ti[:3, 3])
    assert np.array_equal(tr._anchors[1], a0[1]) and np.array_equal(tr._anchors[2], a0[2])
    # off (the default): nothing is re-anchored; an age limit of 1 frame re-anchors every track
    for extra, moved in (({}, set()), ({"colour_max_age": 1}, {0, 1, 2})):
        tr = WindowTracker(_CylinderSDF(), _pose(0.0), {**opts, "colour_reanchor": 0.0, **extra})
        tr._colour_anchor(TrackingFrame(t=0.0, info={**info, "colour_points": P0}), _pose(0.0), True)
        tr._frame_count += 1
        tr._colour_anchor(TrackingFrame(t=1 / FPS, info=info), _pose(0.0), True)
        assert {k for k in range(3) if not np.array_equal(tr._anchors[k], a0[k])} == moved
