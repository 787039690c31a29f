"""Known-shape / SLAM / ICP trackers on small synthetic sequences (ray-cast YCB mustard bottle)."""

import numpy as np
import pytest

from vtrack.errors import InputError
from vtrack.testing.sequences import run_sequence
from vtrack.tracking.window import TrackerOptions, WindowTracker


def test_visuotactile_known_shape_accurate(mustard_grid, mustard_seq):
    from vtrack.tracking.tracker import KnownShapeTracker

    tr = KnownShapeTracker(mustard_grid, mustard_seq.gt[0])
    est, err = run_sequence(tr, mustard_seq)
    assert np.all(np.isfinite(est))
    assert err.mean() < 0.001 and err.max() < 0.003  # sub-mm on clean synthetic data
    assert not any(h.status == "lost" for h in tr.history)


def test_small_step_accept_saves_window_evaluations_and_stays_accurate(mustard_seq):
    """``small_step="accept"`` (ablation) keeps an LM step below the convergence bounds without evaluating it: fewer
    window evaluations, and on clean synthetic data the same accuracy within 0.1 mm."""
    from vtrack.tracking.slam import SLAMTracker

    runs = {}
    for mode in ("iterate", "accept"):
        tr = SLAMTracker(mustard_seq.gt[0], small_step=mode)
        n = [0]
        total = tr._total

        def counted(*a, _total=total, _n=n, **k):
            _n[0] += 1
            return _total(*a, **k)

        tr._total = counted
        est, err = run_sequence(tr, mustard_seq)
        assert np.all(np.isfinite(est))
        runs[mode] = (n[0], float(err.mean()))
    assert runs["accept"][0] < 0.95 * runs["iterate"][0]
    assert abs(runs["accept"][1] - runs["iterate"][1]) < 1e-4
    assert runs["accept"][1] < 0.002


@pytest.mark.parametrize("drop", [("touch",), ("vision",)])
def test_single_modality_tracks(mustard_grid, mustard_seq, drop):
    tr = WindowTracker(mustard_grid, mustard_seq.gt[0])
    _, err = run_sequence(tr, mustard_seq, drop=drop)
    assert err.mean() < 0.003


def test_touch_helps_under_heavy_occlusion(mustard_grid, mustard_seq_heavy):
    seq = mustard_seq_heavy
    _, e_v = run_sequence(WindowTracker(mustard_grid, seq.gt[0]), seq, drop=("touch",))
    _, e_vt = run_sequence(WindowTracker(mustard_grid, seq.gt[0]), seq)
    assert e_vt.mean() < 0.6 * e_v.mean()


@pytest.mark.parametrize("window", [1, 2, 4])
def test_window_sizes(mustard_grid, mustard_seq, window):
    tr = WindowTracker(mustard_grid, mustard_seq.gt[0], {"window": window, "robust": "cauchy"})
    _, err = run_sequence(tr, mustard_seq)
    assert err.mean() < 0.0015
    assert len(tr.keyframes) <= max(window - 1, 0)


def test_icp_baseline(mustard_mesh, mustard_seq):
    from vtrack.tracking.icp import ICPTracker

    tr = ICPTracker(mustard_mesh, mustard_seq.gt[0])
    _, err = run_sequence(tr, mustard_seq)
    assert err.mean() < 0.003


def test_slam_tracks_without_the_mesh(mustard_seq):
    from vtrack.tracking.slam import SLAMTracker

    tr = SLAMTracker(mustard_seq.gt[0])
    est, err = run_sequence(tr, mustard_seq)
    assert np.all(np.isfinite(est))
    assert err.mean() < 0.003
    S, N = tr.surfel_cloud()
    assert len(S) > 500
    # the map lies on the true surface (object frame)
    from vtrack.tracking.sdf_grid import SDFGrid

    g = SDFGrid.from_arrays(mustard_seq.vertices, mustard_seq.faces, voxel=0.004, padding=0.01)
    d, _ = g.query(S, with_grad=False)
    assert np.median(np.abs(d)) < 0.002


def test_options_validation(mustard_grid):
    with pytest.raises(InputError):
        TrackerOptions.from_dict({"no_such_option": 1})
    with pytest.raises(InputError):
        TrackerOptions.from_dict({"window": 0})
    with pytest.raises(InputError):
        WindowTracker(mustard_grid, np.full((4, 4), np.nan))


@pytest.mark.parametrize(
    "field, bad",
    [
        ("window", 0),
        ("iterations", 0),
        ("colour_few_min_vision", -5),
        ("colour_max_age", -1),
        ("colour_reanchor", float("inf")),
        ("sigma_colour", float("nan")),
        ("stick_patch_move", 0.0),
        ("stick_min_step", -0.001),
        ("colour_drop_motion", 0.0),
        ("touch_vision_ratio", "many"),
        ("small_step", "skip"),
    ],
)
def test_an_option_out_of_range_is_named(field, bad):
    """Each range check names the option that is wrong (they were grouped: colour_few_min_vision=-5 was reported
    as field 'colour_few_tracks', colour_max_age as 'colour_reanchor')."""
    with pytest.raises(InputError) as e:
        TrackerOptions.from_dict({field: bad})
    assert e.value.field == field


def test_from_scene_and_registry():
    from vtrack import registry
    from vtrack.paths import default_scene_path
    from vtrack.scene.load import load_scene

    path = default_scene_path()
    try:
        scene = load_scene(path)
    except InputError as e:
        pytest.skip(f"default scene not loadable here: {e}")
    assert scene.object.T_world_object is None  # the default scene gives no pose: data or a user prior must
    with pytest.raises(InputError, match="initial pose"):
        registry.build("tracking.known_shape", scene, voxel=0.004)
    T0 = np.eye(4)
    T0[:3, 3] = [0.05, 0.0, 0.04]
    tr = registry.build("tracking.known_shape", scene, T_init=T0, voxel=0.004)
    assert np.allclose(tr.T, T0)
    with pytest.raises(InputError, match="object frame"):
        registry.build("tracking.slam", scene)
    slam = registry.build("tracking.slam", scene, T_init=T0)
    assert slam.mode == "slam"


def test_pose_metrics():
    from vtrack.eval.pose_metrics import add, add_s, summarize, symmetry_axis, trajectory_errors
    from vtrack.geometry import se3

    # a cylinder about z (its side, on a regular grid)
    a, z = np.meshgrid(np.linspace(0, 2 * np.pi, 60, endpoint=False), np.linspace(-0.05, 0.05, 30))
    P = np.stack([0.03 * np.cos(a.ravel()), 0.03 * np.sin(a.ravel()), z.ravel()], 1)
    assert abs(abs(symmetry_axis(P)[2]) - 1) < 1e-9
    T = np.stack([np.eye(4)] * 3)
    Tz = np.stack([se3.make_transform(se3.so3_exp([0, 0, 0.5]))] * 3)  # rotation about the axis
    assert np.allclose(add_s(T, T, P), 0)
    assert add_s(Tz, T, P).max() < 0.002 < add(Tz, T, P).min()  # ADD-S ignores the symmetry
    e = trajectory_errors(Tz, T, P, symmetric=True)
    s = summarize(e)
    assert s["drift_mm"] < 1e-6 and s["rot_drift_deg"] < 1e-3 and s["rot_drift_full_deg"] > 28
    with pytest.raises(InputError):
        add_s(T[:2], T, P)


def test_icp_holds_its_pose_through_frames_without_points(mustard_mesh, mustard_seq):
    """A hidden object (no depth points) must not send the baseline flying along its last velocity."""
    from vtrack.tracking.frame import TrackingFrame
    from vtrack.tracking.icp import ICPTracker

    tr = ICPTracker(mustard_mesh, mustard_seq.gt[0])
    run_sequence(tr, mustard_seq, frames=mustard_seq.frames[:10])
    T_last = tr.T.copy()
    t = mustard_seq.frames[9].t
    for k in range(1, 61):  # two seconds with nothing seen
        T = tr.step(TrackingFrame(t=t + k / 30.0, vision_points=np.zeros((0, 3))))
    assert np.linalg.norm(T[:3, 3] - T_last[:3, 3]) < 1e-9
    assert tr.history[-1].status == "no_data"


def test_shallow_contacts_do_not_push_with_one_sided_touch():
    """Contacts from tactile images lie too shallow (a lower bound on depth). Read two-sided they push the
    object away from the finger; one-sided (sigma_touch_inside = inf, the SLAM default) they cost nothing
    while inside the surface and still hold the object once it leaves them outside."""
    import trimesh

    from vtrack.tracking.frame import TrackingFrame
    from vtrack.tracking.sdf_grid import SDFGrid
    from vtrack.tracking.window import WindowTracker

    s = trimesh.creation.icosphere(subdivisions=4, radius=0.03)
    grid = SDFGrid.from_arrays(np.asarray(s.vertices), np.asarray(s.faces), voxel=0.002)
    rng = np.random.default_rng(0)
    # a patch of contacts on the +x side, 1.5 mm inside the sphere (as a too-shallow height map gives)
    d = rng.normal(size=(60, 3)) * 0.15 + np.array([1.0, 0.0, 0.0])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    inside = d * (0.03 - 0.0015)
    N = d.copy()

    def run(points, **opts):
        tr = WindowTracker(grid, np.eye(4), {"sigma_touch": 0.001, **opts})
        for k in range(5):
            T = tr.step(TrackingFrame(t=k / 30.0, touch_points=points, touch_normals=N))
        return T[:3, 3]

    two = run(inside)
    one = run(inside, sigma_touch_inside=float("inf"))
    assert two[0] < -0.0008  # measured: pushed 1.5 mm away from the finger
    assert np.linalg.norm(one) < 1e-4  # no pull from points already inside
    # points 1.5 mm OUTSIDE the surface still pull the object to them, one-sided or not
    out = run(d * (0.03 + 0.0015), sigma_touch_inside=float("inf"))
    assert out[0] > 0.0008


def test_hidden_spin_follows_the_motion_prior_not_world_fixed_data():
    """A mug spinning about its axis, seen from a fixed camera: once the handle is hidden, the body looks the same
    every frame, and an imperfect map (here 2 % elliptical) turns those world-fixed points into a pull that stops
    the spin (the 5 s mug sessions lost it this way). Projecting the data out of the weak directions leaves the
    spin to the constant-velocity prior (degenerate_mode="project", the default); only lifting them does not."""
    import trimesh

    from vtrack.geometry import se3
    from vtrack.tracking.frame import TrackingFrame
    from vtrack.tracking.sdf_grid import SDFGrid
    from vtrack.tracking.window import WindowTracker

    def mug(ellipticity: float) -> trimesh.Trimesh:
        body = trimesh.creation.cylinder(radius=0.03, height=0.08, sections=64)
        body.apply_scale([1.0, ellipticity, 1.0])
        handle = trimesh.creation.box(extents=[0.014, 0.012, 0.04])
        handle.apply_translation([0.036, 0.0, 0.0])
        return trimesh.util.concatenate([body, handle])

    the_map = mug(1.02)
    grid = SDFGrid.from_arrays(np.asarray(the_map.vertices), np.asarray(the_map.faces), voxel=0.003)
    true = mug(1.0)
    P, fi = trimesh.sample.sample_surface_even(true, 3000, seed=0)
    N = true.face_normals[fi]
    handle = P[:, 0] > 0.0295
    w, th0 = 1.0, -0.6  # rad/s about the mug's axis (object z = world z), start angle

    def final_spin_error_deg(mode: str) -> float:
        opts = {"degenerate_mode": mode, "project_ratio": 0.02}  # SLAM's setting
        tr = WindowTracker(grid, se3.make_transform(se3.so3_exp(np.array([0.0, 0.0, th0]))), opts)
        for k in range(75):
            t = k / 30.0
            T = se3.make_transform(se3.so3_exp(np.array([0.0, 0.0, th0 + w * t])))
            seen = (se3.rotate_vectors(T, N)[:, 0] > 0.2) & ~(handle & (k >= 30))  # camera at +x; handle hidden
            est = tr.step(TrackingFrame(t=t, vision_points=se3.transform_points(T, P[seen])))
        return float(np.degrees(abs(se3.so3_log(est[:3, :3] @ T[:3, :3].T)[2])))

    lifted, projected = final_spin_error_deg("lift"), final_spin_error_deg("project")
    assert lifted > 5.0  # measured 8.4 deg after 1.5 s hidden: the spin stalls
    assert projected < 0.25 * lifted and projected < 2.0  # measured 0.18 deg
    # SLAM (whose map is such an imperfect SDF) projects by default; known shape keeps lifting
    from vtrack.tracking.slam import SLAMOptions

    slam_opts = SLAMOptions.split({})[2]
    assert slam_opts.degenerate_mode == "project" and 0 < slam_opts.project_ratio < 0.1
    assert TrackerOptions().degenerate_mode == "lift"
    with pytest.raises(InputError):
        TrackerOptions.from_dict({"degenerate_mode": "freeze"})
