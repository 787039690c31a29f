"""Hard cases of the pose trackers: missing modalities, contact loss, symmetry, jumps, bad
initial poses, degenerate geometry, NaN inputs. Synthetic ray-cast sequences (small images)."""

from __future__ import annotations

import copy

import numpy as np
import pytest

from vtrack.errors import InputError
from vtrack.geometry import se3
from vtrack.testing.sequences import make_sequence, run_sequence
from vtrack.tracking.frame import TrackingFrame
from vtrack.tracking.sdf_grid import SDFGrid
from vtrack.tracking.window import WindowTracker

pytestmark = pytest.mark.stability


@pytest.fixture(scope="module")
def mesh(shared_data):
    return shared_data / "objects" / "ycb" / "006_mustard_bottle.ply"


@pytest.fixture(scope="module")
def grid(mesh):
    return SDFGrid.from_mesh(mesh, voxel=0.002)


@pytest.fixture(scope="module")
def seq(mesh):
    # seed 3 (not the tracking tests' seed 1): docs/tracking.md quotes this sequence's bad-start outcome.
    return make_sequence(mesh, n_frames=40, width=120, height=90, seed=3)


def test_frames_without_vision(grid, seq):
    frames = [copy.copy(f) for f in seq.frames]
    for f in frames[10:30]:
        f.vision_points = None  # camera drop-out: touch only
    tr = WindowTracker(grid, seq.gt[0])
    est, err = run_sequence(tr, seq, frames=frames)
    assert np.all(np.isfinite(est))
    assert err.max() < 0.005 and err[30:].mean() < 0.001


def test_frames_without_contact_and_regrasp(mesh):
    # all fingers lift off for frames 12..27, then re-grasp
    s = make_sequence(mesh, n_frames=40, width=120, height=90, seed=4, contact_schedule=lambda i, k: not (12 <= i < 28))
    assert s.frames[15].touch_points is None and s.frames[15].free_points is not None
    grid = SDFGrid.from_mesh(mesh, voxel=0.002)
    tr = WindowTracker(grid, s.gt[0])
    est, err = run_sequence(tr, s)
    assert np.all(np.isfinite(est))
    assert err.max() < 0.003 and err[30:].mean() < 0.001
    # no data at all (no vision, no contact): prediction kept, flagged, finite
    frames = [copy.copy(f) for f in s.frames]
    for f in frames[12:20]:
        f.vision_points = f.free_points = None
    tr2 = WindowTracker(grid, s.gt[0])
    est2, err2 = run_sequence(tr2, s, frames=frames)
    assert [h.status for h in tr2.history[12:20]] == ["no_data"] * 8
    assert np.all(np.isfinite(est2)) and err2.max() < 0.02 and err2[-5:].mean() < 0.002


def test_symmetric_object_adds(shared_data):
    from vtrack.eval.pose_metrics import sample_model_points, summarize, trajectory_errors

    can = shared_data / "objects" / "ycb" / "005_tomato_soup_can.ply"
    # rotation about the can's own axis (object z) is unobservable from geometry
    s = make_sequence(can, n_frames=40, width=120, height=90, axis=(0.0, 0.0, 1.0), seed=5)
    tr = WindowTracker(SDFGrid.from_mesh(can, voxel=0.002), s.gt[0])
    est, err = run_sequence(tr, s)
    assert np.all(np.isfinite(est))
    assert any(h.degenerate_dims >= 1 for h in tr.history)  # the symmetry is detected
    m = summarize(trajectory_errors(est, s.gt, sample_model_points(s.vertices, s.faces, 800), symmetric=True))
    assert m["add_s_mm"] < 1.5 and m["drift_mm"] < 1.5 and m["rot_drift_deg"] < 2.0


def test_large_jump_recovers(grid, seq):
    # the object is knocked 2.5 cm sideways between frames 20 and 21
    J = se3.make_transform(np.eye(3), np.array([0.025, -0.01, 0.0]))
    frames, gt = [], seq.gt.copy()
    for i, f in enumerate(seq.frames):
        f = copy.copy(f)
        if i > 20:
            f.vision_points = se3.transform_points(J, f.vision_points)
            f.touch_points = se3.transform_points(J, f.touch_points)
            gt[i] = J @ gt[i]
        frames.append(f)
    s2 = copy.copy(seq)
    s2.gt = gt
    tr = WindowTracker(grid, seq.gt[0])
    est, err = run_sequence(tr, s2, frames=frames)
    assert np.all(np.isfinite(est))
    print("errors around the jump (mm):", np.round(err[19:26] * 1e3, 2))
    assert err[21] < 0.01  # the first frame after the jump already moved most of the way
    assert err[23:].max() < 0.002  # and the track is back to sub-2 mm within two frames


@pytest.mark.parametrize("trans,rot", [(0.01, 0.2), (0.08, 2.5)])
def test_bad_initial_pose_bounded_and_detected(grid, seq, trans, rot):
    from vtrack.tracking.run import perturb_pose

    T0 = perturb_pose(seq.gt[0], trans, rot, seed=1)
    tr = WindowTracker(grid, T0)
    est, err = run_sequence(tr, seq)
    assert np.all(np.isfinite(est))
    assert err.max() < trans + 0.1  # bounded: never runs away
    converged = err[-5:].mean() < 0.002
    # "lost" (recovery failed) and "recovered" (the frame was inconsistent and the tracker re-initialised)
    # both report the problem to the user; "ok" would be silent.
    flagged = any(h.status in ("lost", "recovered") for h in tr.history[:5])
    assert converged or flagged
    if trans > 0.05:
        assert flagged  # a grossly wrong start must be reported
        assert tr.history[0].status != "ok"  # ... from the very first frame


def test_planar_patch_is_degenerate_not_drifting():
    # SDF of the half-space z < 0 (a plane): only z, rot-x and rot-y are observable
    ax = np.arange(-0.05, 0.0501, 0.005)
    X, Y, Z = np.meshgrid(ax, ax, ax, indexing="ij")
    g = SDFGrid(Z, np.full(3, -0.05), 0.005)
    rng = np.random.default_rng(0)
    P = np.concatenate([rng.uniform(-0.02, 0.02, (200, 2)), np.zeros((200, 1))], 1)
    tr = WindowTracker(g, np.eye(4), {"object_radius": 0.03})
    for i in range(10):
        T = tr.step(TrackingFrame(t=i / 30, vision_points=P + rng.normal(0, 1e-4, P.shape)))
    assert tr.last_info.degenerate_dims >= 3
    assert np.linalg.norm(T[:3, 3]) < 1e-3 and se3.rotation_angle(T) < 0.01


def test_nan_inputs(grid, seq):
    frames = []
    rng = np.random.default_rng(0)
    for f in seq.frames:
        f = copy.copy(f)
        V = f.vision_points.copy()
        V[rng.random(len(V)) < 0.2] = np.nan
        P = f.touch_points.copy()
        P[::7] = np.inf
        N = f.touch_normals.copy()
        N[::5] = np.nan
        f.vision_points, f.touch_points, f.touch_normals = V, P, N
        frames.append(f)
    tr = WindowTracker(grid, seq.gt[0])
    est, err = run_sequence(tr, seq, frames=frames)
    assert np.all(np.isfinite(est)) and err.mean() < 0.001
    with pytest.raises(InputError):
        tr.step(TrackingFrame(t=float("nan")))
    with pytest.raises(InputError):
        tr.step(TrackingFrame(t=0.0))  # time going backwards
    with pytest.raises(InputError):
        tr.step(TrackingFrame(t=10.0, vision_points=np.zeros((5, 2))))
    with pytest.raises(InputError):
        WindowTracker(grid, np.full((4, 4), np.nan))
