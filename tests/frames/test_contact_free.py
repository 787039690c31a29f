"""Gel points beside a contact patch as free space, in frames where vision sees (almost) nothing."""

import numpy as np
import pytest


@pytest.fixture(scope="module")
def touch_frames(tiny_session):
    from vtrack.frames.session import SessionFrames

    on = SessionFrames(tiny_session, ("touch",))
    off = SessionFrames(tiny_session, ("touch",), contact_free_max_vision=0)
    both = SessionFrames(tiny_session, ("vision", "touch"))
    idx = [0, 10, 20]
    return [(on.frame(i)[0], off.frame(i)[0], both.frame(i)[0]) for i in idx], on


def test_gel_beside_the_patch_is_free_and_outside_the_object(touch_frames, tiny_session):
    from vtrack.eval.session_gt import SessionGroundTruth
    from vtrack.geometry import se3
    from vtrack.tracking.sdf_grid import SDFGrid

    frames, sf = touch_frames
    gt = SessionGroundTruth.load(tiny_session)
    V, F = gt.model()
    sdf = SDFGrid.from_arrays(np.asarray(V), np.asarray(F), voxel=0.002)
    n_added = 0
    for on, off, _ in frames:
        assert len(on.touch_points) > 0  # the sensors touch the can
        extra = len(on.free_points) - len(off.free_points)
        assert extra > 0  # without vision, the in-contact gels add free points
        n_added += extra
        # the added points keep the margin from every contact point (sensor xy, 2 mm; in the world >= that minus
        # the patch's depth, 3 mm at most)
        added = on.free_points[len(off.free_points) :] if extra else np.zeros((0, 3))
        d = np.linalg.norm(added[:, None, :] - on.touch_points[None, :, :], axis=2).min(1)
        assert d.min() > 0.0015
        # ... and lie outside the true object (scored against ground truth): the object is not there. Measured 94 %
        # beyond -0.5 mm; the rest is up to 1.3 mm inside, where the detected patch is smaller than the true contact
        T = gt.poses_at(np.array([on.t]))[0]
        phi, _ = sdf.query(se3.transform_points(se3.invert(T), added), with_grad=False)
        assert np.mean(phi > -0.0005) > 0.9 and phi.min() > -0.003, np.sort(phi)[:5]
    assert n_added > 50


def test_no_contact_free_points_when_vision_sees_the_object(touch_frames):
    frames, _ = touch_frames
    for _, off, both in frames:
        assert len(both.vision_points) >= 30
        assert len(both.free_points) == len(off.free_points)  # only the gels of sensors without contact


def test_contact_free_margin_is_checked(tiny_session):
    from vtrack.errors import InputError
    from vtrack.frames.session import SessionFrames

    with pytest.raises(InputError):
        SessionFrames(tiny_session, ("touch",), contact_free_margin_m=-0.001)
