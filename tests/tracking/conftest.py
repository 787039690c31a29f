"""Fixtures for tracking tests: small synthetic sequences (Open3D ray casting) and cached SDF grids."""

from __future__ import annotations

import pytest


@pytest.fixture(scope="session")
def mustard_mesh(shared_data):
    return shared_data / "objects" / "ycb" / "006_mustard_bottle.ply"


@pytest.fixture(scope="session")
def can_mesh(shared_data):
    return shared_data / "objects" / "ycb" / "005_tomato_soup_can.ply"


@pytest.fixture(scope="session")
def mustard_grid(mustard_mesh):
    from vtrack.tracking.sdf_grid import SDFGrid

    return SDFGrid.from_mesh(mustard_mesh, voxel=0.002)


@pytest.fixture(scope="session")
def mustard_seq(mustard_mesh):
    from vtrack.testing.sequences import make_sequence

    return make_sequence(mustard_mesh, n_frames=40, width=120, height=90, seed=1)


@pytest.fixture(scope="session")
def mustard_seq_heavy(mustard_mesh):
    from vtrack.testing.sequences import make_sequence

    return make_sequence(mustard_mesh, n_frames=40, width=120, height=90, occlusion="heavy", seed=2)
