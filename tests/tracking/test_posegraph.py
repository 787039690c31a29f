"""SLAM back end (vtrack.tracking.posegraph): gtsam pose graph, loop closure, keyframe refinement."""

from __future__ import annotations

import numpy as np
import pytest

from vtrack.geometry import se3


def _circle(K: int) -> np.ndarray:
    """K poses turning once about z on a 5 cm circle (the last one comes back next to the first)."""
    out = []
    for k in range(K):
        a = 2 * np.pi * k / K
        out.append(se3.make_transform(se3.so3_exp(np.array([0.0, 0.0, a])), [0.05 * np.cos(a), 0.05 * np.sin(a), 0]))
    return np.stack(out)


def _odometry(G: np.ndarray, bias: np.ndarray) -> tuple[np.ndarray, list]:
    """Dead reckoning from relative motions corrupted by a constant twist bias ([rho, phi])."""
    from vtrack.tracking.posegraph import BackendOptions, odometry_edges
    from vtrack.tracking.window import _exp

    X = [G[0]]
    for k in range(len(G) - 1):
        X.append(X[-1] @ se3.invert(G[k]) @ G[k + 1] @ _exp(bias))
    X = np.stack(X)
    return X, odometry_edges(X, BackendOptions())


def test_pose_graph_closes_a_drifting_loop_and_a_robust_kernel_rejects_a_false_one():
    from vtrack.tracking.posegraph import Edge, optimise_pose_graph

    G = _circle(24)
    X, odo = _odometry(G, np.array([0.0006, -0.0003, 0.0, 0.006, 0.003, 0.01]))
    end = lambda P: float(np.linalg.norm(P[-1, :3, 3] - G[-1, :3, 3]))  # noqa: E731
    assert end(X) > 0.01  # dead reckoning drifted more than 1 cm by the end of the loop
    info = np.diag([1 / 0.0005**2] * 3 + [1 / 0.005**2] * 3)
    loop = Edge(len(G) - 1, 0, se3.invert(G[-1]) @ G[0], info, kind="loop", robust_k=3.0)
    P = optimise_pose_graph(X, [*odo, loop])
    assert end(P) < 0.15 * end(X)
    mean_err = np.linalg.norm(P[:, :3, 3] - G[:, :3, 3], axis=1).mean()
    assert mean_err < 0.6 * np.linalg.norm(X[:, :3, 3] - G[:, :3, 3], axis=1).mean()
    assert np.allclose(P[0], X[0], atol=1e-6)  # gauge: the first pose stays
    # a false loop (the last pose claimed to sit 90 deg turned and 4 cm away from the first): Gaussian, it
    # bends the trajectory; with the robust (Cauchy) kernel it barely moves it
    wrong = se3.invert(G[-1]) @ G[0] @ se3.make_transform(se3.so3_exp(np.array([0.0, 0.0, np.pi / 2])), [0.04, 0, 0])
    bent = optimise_pose_graph(X, [*odo, Edge(len(G) - 1, 0, wrong, info)])
    kept = optimise_pose_graph(X, [*odo, Edge(len(G) - 1, 0, wrong, info, kind="loop", robust_k=3.0)])
    move = lambda P: float(np.abs(P[:, :3, 3] - X[:, :3, 3]).max())  # noqa: E731
    assert move(bent) > 0.02
    assert move(kept) < 0.1 * move(bent)


def test_pose_graph_refuses_bad_input():
    from vtrack.errors import InputError
    from vtrack.tracking.posegraph import Edge, optimise_pose_graph

    G = _circle(4)
    with pytest.raises(InputError):
        optimise_pose_graph(G, [Edge(0, 7, np.eye(4), np.eye(6))])
    bad = G.copy()
    bad[1, 0, 3] = np.nan
    with pytest.raises(InputError):
        optimise_pose_graph(bad, [])


def test_interpolated_corrections_hit_keyframes_and_blend_between():
    from vtrack.tracking.posegraph import interpolate_corrections
    from vtrack.tracking.window import _exp

    G = _circle(3)
    E = [np.eye(4), _exp(np.array([0.002, 0, 0, 0, 0, 0])), _exp(np.array([0.004, 0, 0, 0, 0, 0]))]
    new = np.stack([g @ e for g, e in zip(G, E, strict=True)])
    times = np.array([0.0, 0.5, 1.0, 1.5, 2.0, 3.0])
    poses = np.repeat(np.eye(4)[None], len(times), 0)
    out = interpolate_corrections(np.array([0.0, 1.0, 2.0]), G, new, times, poses)
    assert np.allclose(out[:, 0, 3], [0.0, 0.001, 0.002, 0.003, 0.004, 0.004], atol=1e-9)


@pytest.fixture(scope="module")
def mustard_loop(mustard_mesh):
    """12 s of a mustard bottle turning 7 rad (the faces come back), every frame a keyframe."""
    from vtrack.tracking.synth import make_sequence

    ax = (0.2, 0.1, 1.0)
    return make_sequence(mustard_mesh, n_frames=36, fps=3.0, rot_speed=0.6, width=90, height=68, seed=1, axis=ax), ax


def test_loop_closure_removes_most_of_a_spin_drift(mustard_loop):
    """The front end's typical drift (the spin lags, 46 deg after 16 frames): the refinement without loops
    cannot see it; loop closure when the faces come back removes most of it."""
    from vtrack.tracking.posegraph import BackendOptions, refine_keyframes
    from vtrack.tracking.synth import drifting_keyframes

    seq, ax = mustard_loop
    kfs = drifting_keyframes(seq, ax, lag_per_frame=0.05, lag_frames=16, n_points=300)
    P = seq.vertices[::25]

    def add_mm(X):
        return 1e3 * np.mean(
            [
                np.linalg.norm(se3.transform_points(X[k], P) - se3.transform_points(seq.gt[k], P), axis=1).mean()
                for k in range(len(X))
            ]
        )

    front = add_mm(np.stack([k.T for k in kfs]))
    X_no, rep_no = refine_keyframes(kfs, BackendOptions(loop_closure=False, rounds=2))
    X_lc, rep_lc = refine_keyframes(kfs, BackendOptions(loop_closure=True, rounds=2))
    assert front > 15.0
    assert rep_lc["loop_edges"] > 5 and rep_no["loop_edges"] == 0
    assert add_mm(X_no) > 0.8 * front  # registration alone: the map is consistently drifted
    assert add_mm(X_lc) < 0.5 * front
    assert np.isfinite(X_lc).all()


def test_slam_options_are_typed_and_keyframes_feed_the_back_end(mustard_seq):
    from vtrack.errors import InputError
    from vtrack.tracking.slam import SLAMOptions, SLAMTracker
    from vtrack.tracking.synth import run_sequence

    with pytest.raises(InputError) as e:
        SLAMTracker(mustard_seq.gt[0], refresh_evry=3)
    assert "refresh_evry" in str(e.value.field)
    tr = SLAMTracker(mustard_seq.gt[0], trunc=0.01, kf_max_gap_s=0.2, refine=True)
    assert tr.slam_opts.trunc == 0.01 and tr.slam_opts.map_voxel == SLAMOptions().map_voxel
    assert tr.opts.gate == pytest.approx(0.008)  # SLAM's tracker default follows the band
    frames = mustard_seq.frames[:20]
    E, _ = run_sequence(tr, mustard_seq, frames=frames)
    assert len(tr.kf_graph) >= 3  # 0.67 s of turning: motion and time both promote keyframes
    times = np.array([f.t for f in frames])
    out = tr.refine_poses(times, E)
    assert tr.backend_report["refined"] and np.isfinite(out).all()
    assert np.allclose(out[0], E[0], atol=1e-6)  # the first keyframe is the gauge: SLAM's frame stays put
    assert np.abs(out[:, :3, 3] - E[:, :3, 3]).max() < 0.01  # a refinement, not a jump
    off = SLAMTracker(mustard_seq.gt[0], refine=False)
    run_sequence(off, mustard_seq, frames=frames[:6])
    assert off.kf_graph == [] and np.array_equal(off.refine_poses(times, E), E)


def test_missing_gtsam_names_the_extra(monkeypatch):
    import sys

    from vtrack.errors import VtrackError
    from vtrack.tracking.posegraph import _import_gtsam

    monkeypatch.setitem(sys.modules, "gtsam", None)  # import fails as if the extra were not installed
    with pytest.raises(VtrackError, match=r"vtrack\[slam\]"):
        _import_gtsam()


@pytest.mark.parametrize(
    "opt",
    [
        {"sigma_odom_trans": 0.0},
        {"sigma_point": float("nan")},
        {"robust_k": -1.0},
        {"kf_max": 1},
        {"loop_max_rot_rate": -0.1},
    ],
)
def test_back_end_options_are_checked_by_name(opt):
    from vtrack.errors import InputError
    from vtrack.tracking.posegraph import BackendOptions

    with pytest.raises(InputError) as e:
        BackendOptions.from_dict(opt)
    assert next(iter(opt)) in str(e.value.field)
    BackendOptions.from_dict({})  # the defaults pass
    from vtrack.tracking.slam import SLAM_BACKEND_SHORT, SLAMOptions

    assert SLAMOptions.split({"refine": True, **SLAM_BACKEND_SHORT})[1].loop_max_rot_rate == 0.05  # the preset's keys


def test_keyframes_stay_bounded_and_keep_covering_the_run(mustard_seq):
    from vtrack.tracking.slam import SLAMTracker
    from vtrack.tracking.synth import run_sequence

    tr = SLAMTracker(mustard_seq.gt[0], refine=True, kf_max=4, kf_max_gap_s=0.01)
    frames = mustard_seq.frames[:15]
    run_sequence(tr, mustard_seq, frames=frames)
    assert len(tr.kf_graph) <= 4 and tr.kf_thinned > 0
    # the gauge (first keyframe) stays and the newest frames still become keyframes
    assert tr.kf_graph[0].t == frames[0].t and tr.kf_graph[-1].t >= frames[-3].t


def test_loop_rotation_rate_bound_refuses_large_corrections_over_short_gaps(mustard_loop):
    """``loop_max_rot_rate``: a loop may correct the relative rotation by at most rate x its time gap. On keyframes
    whose spin lags by up to 46 deg the loops that would correct it are refused at 0.02 rad/s (and kept without
    the bound), and every loop that stays corrects its pair by less than the bound."""
    from vtrack.tracking.posegraph import BackendOptions, registration_edges
    from vtrack.tracking.synth import drifting_keyframes
    from vtrack.tracking.window import _log

    seq, ax = mustard_loop
    kfs = drifting_keyframes(seq, ax, lag_per_frame=0.05, lag_frames=16, n_points=300)
    X = np.stack([k.T for k in kfs])
    free, rep_free = registration_edges(kfs, X, BackendOptions(), loops=True)
    rate = 0.02
    held, rep_held = registration_edges(kfs, X, BackendOptions(loop_max_rot_rate=rate), loops=True)
    assert rep_free["loop"] > 5
    assert rep_held["loop"] < 0.5 * rep_free["loop"]
    assert rep_held["loop_rejected"] > rep_free["loop_rejected"]
    # registration edges (within loop_min_gap_s) are not affected by the bound
    assert rep_held["registration"] == rep_free["registration"]
    for e in held:
        if e.kind == "loop":  # the correction of the current relative pose the loop asks for
            turn = np.linalg.norm(_log(se3.invert(e.Z) @ se3.invert(X[e.i]) @ X[e.j])[3:])
            assert turn <= rate * abs(kfs[e.i].t - kfs[e.j].t) + 1e-6
