"""Shared fusion test data: ray-cast observations of a YCB mesh (object frame), cached per session."""

from __future__ import annotations

import pytest


@pytest.fixture(scope="session")
def soup_obs(shared_data):
    from vtrack.testing.observations import make_observations

    mesh = shared_data / "objects" / "ycb" / "005_tomato_soup_can.ply"
    obs, V, F = make_observations(mesh, n_views=6, n_touch=20, touch_region="unseen", seed=0)
    return obs, V, F


@pytest.fixture(scope="session")
def occluded_obs(shared_data):
    """Heavy occlusion: two cameras on a 60 deg arc; touch on the unseen side."""
    from vtrack.testing.observations import make_observations

    mesh = shared_data / "objects" / "ycb" / "005_tomato_soup_can.ply"
    return make_observations(mesh, n_views=2, arc_deg=60.0, n_touch=40, touch_region="unseen", seed=1)
