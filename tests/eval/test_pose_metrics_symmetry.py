"""Which shared YCB objects are rotationally symmetric (ADD-S) and which are not (ADD)."""

from __future__ import annotations

import pytest


@pytest.mark.parametrize(
    "name,expected",
    [
        ("005_tomato_soup_can", True),
        ("055_baseball", True),
        ("006_mustard_bottle", False),
        ("010_potted_meat_can", False),
        ("011_banana", False),
        ("025_mug", False),
    ],
)
def test_rotational_symmetry_of_the_ycb_objects(shared_data, name, expected):
    from vtrack.eval.pose_metrics import is_rotationally_symmetric
    from vtrack.io.mesh import load_mesh

    V, F = load_mesh(shared_data / "objects" / "ycb" / f"{name}.ply")
    # measured excess of rotated samples over the sampling spacing: <= 1.2 mm (can, ball), >= 6 mm (others)
    assert is_rotationally_symmetric(V, F) is expected


def test_a_box_is_not_symmetric_and_a_cylinder_is():
    import trimesh

    from vtrack.eval.pose_metrics import is_rotationally_symmetric

    box = trimesh.creation.box((0.04, 0.06, 0.1))
    cyl = trimesh.creation.cylinder(radius=0.03, height=0.1, sections=96)
    assert not is_rotationally_symmetric(box.vertices, box.faces)
    assert is_rotationally_symmetric(cyl.vertices, cyl.faces)
