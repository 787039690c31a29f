"""SLAM under occlusion: which weak directions are left to the motion prior (``project_min_vision``)."""

import numpy as np

from vtrack.tracking.sdf_grid import SDFGrid
from vtrack.tracking.window import TrackerOptions, WindowTracker


def _tracker(**opts) -> WindowTracker:
    grid = SDFGrid(np.full((2, 2, 2), 0.01, np.float32), np.zeros(3), 1.0)
    return WindowTracker(grid, np.eye(4), {"degenerate_mode": "project", "project_ratio": 0.02, **opts})


def test_small_visible_patch_lifts_instead_of_projecting():
    """With ``project_min_vision`` a frame seeing 1..N-1 points lifts its weak directions (no projector); a frame
    with enough points still projects them, a frame without vision (touch only) unless ``project_without_vision``
    is off."""
    # data block (rotation scaled by the object radius 5 cm): two rotations 1e-4 of the rest (weak, below 2 %)
    H = np.diag([1e8, 1e8, 1e8, 1e4 * 0.05**2, 1e4 * 0.05**2, 1e8 * 0.05**2])
    tr = _tracker(project_min_vision=150)
    for n_vision, projects in ((0, True), (1, False), (149, False), (150, True), (300, True)):
        reg, dims, proj = tr._degeneracy(H, n_vision)
        assert dims == 2
        assert (proj is not None) == projects, n_vision
        assert np.abs(reg).max() > 0  # weak directions are lifted to the floor either way
    # touch-only frames lift too when asked (SLAM's default)
    tr = _tracker(project_min_vision=150, project_without_vision=False)
    assert tr._degeneracy(H, 0)[2] is None and tr._degeneracy(H, 150)[2] is not None
    # default 0: every frame projects (the known-shape and plain tracker behaviour is unchanged)
    assert _tracker()._degeneracy(H, 10)[2] is not None
    assert TrackerOptions().project_min_vision == 0
    from vtrack.tracking.slam import SLAMOptions

    assert SLAMOptions.split({})[2].project_min_vision == 150
    assert not SLAMOptions.split({})[2].project_without_vision and TrackerOptions().project_without_vision
    assert SLAMOptions.split({"project_min_vision": 0})[2].project_min_vision == 0
