"""Touch where vision fails: the weak-vision regime of the window tracker (``touch_weak_vision``).

In a frame that sees few segmented vision points the contacts carry the pose: they are pulled onto the surface from
both sides at ``sigma_touch_weak`` instead of SLAM's one-sided 5 mm (contacts may sit inside the map at no cost when
vision holds the pose, because they read shallow).
"""

import numpy as np
import pytest

from vtrack.errors import InputError
from vtrack.tracking.frame import TrackingFrame
from vtrack.tracking.slam import SLAM_TOUCH_WEAK_VISION, SLAMOptions
from vtrack.tracking.window import TrackerOptions, WindowTracker

R_SPHERE = 0.03


class _Sphere:
    """Exact SDF of a sphere of radius ``R_SPHERE`` at the object origin (m)."""

    def query(self, points, with_grad=True):
        n = np.linalg.norm(points, axis=1)
        g = points / np.maximum(n, 1e-12)[:, None]
        return n - R_SPHERE, (g if with_grad else None)


def _slam_tracker(**opts) -> WindowTracker:
    """A window tracker with SLAM's options and the heavy-occlusion preset (``opts`` override both)."""
    return WindowTracker(_Sphere(), np.eye(4), SLAMOptions.split({**SLAM_TOUCH_WEAK_VISION, **opts})[2])


def _contacts(offset: float, n: int = 40) -> TrackingFrame:
    """Contacts on a cap of the sphere, ``offset`` m off its surface (negative: inside), with outward normals."""
    rng = np.random.default_rng(0)
    d = rng.normal(size=(n, 3)) * [0.3, 0.3, 1.0] + [0, 0, 3.0]
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return TrackingFrame(t=0.0, touch_points=d * (R_SPHERE + offset), touch_normals=d)


def test_slam_preset_turns_the_regime_on_below_150_vision_points():
    assert SLAMOptions.split({})[2].touch_weak_vision == 0  # opt-in for SLAM (see SLAM_TOUCH_WEAK_VISION)
    o = SLAMOptions.split(dict(SLAM_TOUCH_WEAK_VISION))[2]
    assert o.touch_weak_vision == 150 and o.sigma_touch_weak == pytest.approx(0.0015)
    assert o.touch_blind_ratio == pytest.approx(0.1)
    # known shape and the plain tracker: off unless asked
    assert TrackerOptions().touch_weak_vision == 0 and TrackerOptions().touch_blind_ratio == 0
    assert SLAMOptions.split({"touch_weak_vision": 0})[2].touch_weak_vision == 0
    with pytest.raises(InputError, match="sigma_touch_weak"):
        TrackerOptions.from_dict({"touch_weak_vision": 10, "sigma_touch_weak": 0.0})


def test_contacts_inside_the_surface_pull_only_when_vision_is_weak():
    """A contact 2 mm inside the surface costs nothing in a well-seen frame (SLAM's one-sided contacts) but pulls the
    object back onto it in a frame seeing < 150 points; one 2 mm outside pulls harder there (1.5 mm vs 5 mm)."""
    tr = _slam_tracker()
    T = np.eye(4)
    inside, outside = _contacts(-0.002), _contacts(0.002)
    H_in_strong, b_in_strong, c_in_strong = tr._frame_terms(T, inside, n_vision=300)
    H_in_weak, b_in_weak, c_in_weak = tr._frame_terms(T, inside, n_vision=20)
    assert c_in_strong == pytest.approx(0.0) and np.abs(b_in_strong).max() == pytest.approx(0.0)
    assert c_in_weak == pytest.approx(40 * 0.5 * (2 / 1.5) ** 2)  # 40 contacts at 4/3 sigma (normals agree exactly)
    # the pull moves the object towards +z (contacts on the +z cap, inside): a Gauss-Newton step along -H^-1 b
    step = -np.linalg.lstsq(H_in_weak, b_in_weak, rcond=None)[0]
    assert step[2] < -0.001  # object origin moves down so the cap's surface comes to the contacts ... 2 mm
    H_out_strong, _, _ = tr._frame_terms(T, outside, n_vision=300)
    H_out_weak, _, _ = tr._frame_terms(T, outside, n_vision=20)
    # translation information along the cap's normal grows by (5 / 1.5)^2 in the weak regime
    assert H_out_weak[2, 2] / H_out_strong[2, 2] == pytest.approx((5 / 1.5) ** 2, rel=0.05)
    # the frame's own count is used when the slot's is unknown (-1); touch-only frames are weak
    assert tr._frame_terms(T, inside)[2] == pytest.approx(c_in_weak)


def test_hidden_object_is_tracked_by_touch(mustard_seq_heavy):
    """The heavy-occlusion mustard sequence cut to a 2 cm visible patch (~100 points a frame): SLAM with vision
    alone loses the object (ADD ~14 mm); with touch it stays within 7 mm (measured 4.4 mm; 5.0 without the regime)."""
    import copy

    from vtrack.eval.pose_metrics import sample_model_points, trajectory_errors
    from vtrack.geometry import se3
    from vtrack.tracking.slam import SLAMTracker

    seq = mustard_seq_heavy
    c0 = seq.frames[0].vision_points.mean(0)
    frames = []
    for f in seq.frames:
        g = copy.copy(f)
        if f.vision_points is not None and len(f.vision_points):
            V = f.vision_points
            g.vision_points = V[np.linalg.norm(V[:, :2] - c0[:2], axis=1) < 0.02]
        frames.append(g)
    pts = sample_model_points(seq.vertices, seq.faces, 300, seed=0)

    def run(touch: bool, **opts) -> tuple[float, SLAMTracker]:
        f0 = frames[0]
        T0 = np.eye(4)
        T0[:3, 3] = np.concatenate([f0.vision_points, f0.touch_points]).mean(0)
        tr = SLAMTracker(T0, **{**SLAM_TOUCH_WEAK_VISION, **opts})
        est = []
        for f in frames:
            t = f if touch else TrackingFrame(t=f.t, vision_points=f.vision_points)
            est.append(tr.step(t))
        est = np.stack(est)
        e = trajectory_errors(est @ se3.invert(est[0]) @ seq.gt[0], seq.gt, pts)
        return float(e["add"].mean() * 1e3), tr

    err_v, _ = run(False)
    err_vt, tr = run(True)
    assert np.median([h.n_vision for h in tr.history[1:]]) < 150  # the regime was on
    assert err_v > 10.0
    assert err_vt < 7.0 and err_vt < 0.5 * err_v


def test_contacts_do_not_pull_along_directions_their_normals_leave_free():
    """Fingers along a cylinder's side (normals radial, a 6 cm band) constrain neither its spin nor a slide along
    its axis: ``touch_blind_ratio`` removes exactly those two directions from the contacts' pull; a corner (three
    faces) constrains everything and nothing is removed."""
    tr = _slam_tracker(touch_blind_ratio=0.02)
    rng = np.random.default_rng(1)
    a = rng.uniform(0, 2 * np.pi, 60)
    n = np.stack([np.cos(a), np.sin(a), np.zeros_like(a)], 1)
    side = TrackingFrame(
        t=0.0, touch_points=n * 0.03 + [[0, 0, 1]] * rng.uniform(-0.03, 0.03, (60, 1)), touch_normals=n
    )
    P = tr._touch_projector(np.eye(4), side)
    assert P is not None
    spin, slide = np.array([0, 0, 0, 0, 0, 1.0]), np.array([0, 0, 1.0, 0, 0, 0])
    assert np.abs(P @ spin).max() < 1e-9 and np.abs(P @ slide).max() < 1e-9
    for k in (0, 1, 3, 4):  # radial translations and tilts are kept
        e = np.eye(6)[k]
        assert np.linalg.norm(P @ e - e) < 1e-6
    # the same contacts with the object moved: the projector follows the object frame (spin about its own axis)
    T = np.eye(4)
    T[:3, 3] = [0.1, -0.05, 0.2]
    moved = TrackingFrame(t=0.0, touch_points=side.touch_points + T[:3, 3], touch_normals=n)
    assert np.abs(tr._touch_projector(T, moved) @ spin).max() < 1e-9
    # a corner: three faces of a cube, each touched at several points
    pts, nrm = [], []
    for axis in range(3):
        for _ in range(10):
            p = rng.uniform(-0.02, 0.02, 3)
            p[axis] = 0.02
            pts.append(p)
            nrm.append(np.eye(3)[axis])
    assert (
        tr._touch_projector(np.eye(4), TrackingFrame(t=0.0, touch_points=np.array(pts), touch_normals=np.array(nrm)))
        is None
    )
    assert WindowTracker(_Sphere(), np.eye(4))._touch_projector(np.eye(4), side) is None  # off by default


def test_touch_only_frames_keep_every_direction_of_the_contacts():
    """The blind directions are removed only in frames that see some vision points or follow one within 1 s: in a
    touch-only run nothing else would hold them (touch-only SLAM, heavy sessions: 9.8 -> 33 mm with them removed)."""
    from vtrack.tracking.window import _Slot

    tr = _slam_tracker()
    fr = _contacts(0.001)
    for nv, projects in ((0, False), (20, True), (300, False)):
        s = _Slot(T=np.eye(4), t=0.0, frame=fr, T_prior=np.eye(4), n_vision=nv)
        tr._optimise([s], np.zeros(6))
        assert (s.proj_touch is not None) == projects, nv
    # a touch-only frame shortly after one with vision (the object hidden for a moment) still projects
    tr._t_vision = 0.0
    for t, projects in ((0.5, True), (2.0, False)):
        s = _Slot(T=np.eye(4), t=t, frame=fr, T_prior=np.eye(4), n_vision=0)
        tr._optimise([s], np.zeros(6))
        assert (s.proj_touch is not None) == projects, t


def test_known_shape_with_vision_and_touch_uses_the_regime(tmp_path):
    """Offline known shape with both modalities turns the regime on (touch alone keeps the tracker's defaults)."""
    pytest.importorskip("open3d")
    from vtrack.testing.sessions import write_sphere_session
    from vtrack.tracking.run import KNOWN_TOUCH_WEAK_VISION, track_session

    sess = write_sphere_session(tmp_path / "sphere", seconds=0.1)
    kept: dict = {}
    mesh = tmp_path / "sphere_sphere.ply"
    track_session(
        sess, "", shape="known_shape", mesh=mesh, init_pose=np.eye(4), write=False, keep_frames=kept, max_frames=1
    )
    o = kept["tracker"].opts
    assert (o.touch_weak_vision, o.sigma_touch_weak) == KNOWN_TOUCH_WEAK_VISION


def test_contacts_leave_alone_what_vision_already_holds():
    """``touch_vision_ratio``: directions where the frame's vision information exceeds the contacts' by the ratio are
    removed from the contacts' pull as well (generalised eigen-directions), so the contacts carry only what vision
    leaves weak; without vision information, or with the ratio at 0, the projector is the normals-only one."""
    tr = _slam_tracker(touch_blind_ratio=0.02, touch_vision_ratio=1.0)
    L = tr.opts.object_radius
    rng = np.random.default_rng(1)
    a = rng.uniform(0, 2 * np.pi, 60)
    n = np.stack([np.cos(a), np.sin(a), np.zeros_like(a)], 1)
    q = n * 0.03 + [[0, 0, 1]] * rng.uniform(-0.03, 0.03, (60, 1))
    side = TrackingFrame(t=0.0, touch_points=q, touch_normals=n)
    # the contacts' point-to-plane information (object-frame twist, unscaled) at sigma_touch_weak
    J = np.concatenate([-n, np.cross(n, q)], axis=1)
    Ht = J.T @ J / tr.opts.sigma_touch_weak**2
    # vision: a patch facing +x holds x translation 100x more than the contacts; blind in y; weak tilts
    Hv = np.diag([100 * Ht[0, 0], 1.0, 1.0, 1e-3 * Ht[3, 3], 1e-3 * Ht[4, 4], 1.0])

    def kept(P, k):  # fraction of the contacts' information along unit direction k left after projecting
        e = np.eye(6)[k]
        return float(e @ P.T @ Ht @ P @ e / (e @ Ht @ e))

    P = tr._touch_projector(np.eye(4), side, Hv)
    assert kept(P, 0) < 0.05  # x: vision holds it, the contacts hardly pull there any more
    assert kept(P, 1) > 0.9  # y: vision is blind, the contacts carry it
    assert kept(P, 3) > 0.9 and kept(P, 4) > 0.9  # tilts: vision is weak there
    spin, slide = np.eye(6)[5], np.eye(6)[2]
    assert np.abs(P @ spin).max() < 1e-9 and np.abs(P @ slide).max() < 1e-9  # the normals leave these free
    # the held basis: x (the direction vision dominates) when the contacts inform every direction
    S = np.diag([1.0, 1.0, 1.0, 1.0 / L, 1.0 / L, 1.0 / L])
    held = tr._vision_held(S @ Ht @ S + np.eye(6), S @ Hv @ S)
    assert np.abs(held[0]).max() > 0.95 and np.abs(held[1]).max() < 0.1
    assert tr._vision_held(np.eye(6) * 1e9, np.eye(6)).shape == (6, 0)  # vision uniformly weaker: nothing held
    # off (ratio 0) or no vision: the normals-only projector, which keeps x
    P0 = _slam_tracker(touch_blind_ratio=0.02)._touch_projector(np.eye(4), side, Hv)
    np.testing.assert_allclose(P0, tr._touch_projector(np.eye(4), side), atol=1e-12)
    assert kept(P0, 0) > 0.9
    for bad in (-1.0, float("nan")):
        with pytest.raises(InputError, match="touch_vision_ratio"):
            TrackerOptions.from_dict({"touch_vision_ratio": bad})
