"""A scene stored in a session does not point into one machine's checkout."""

from __future__ import annotations

import pytest

import vtrack
from vtrack.paths import assets_dir
from vtrack.scene import load_scene
from vtrack.scene.load import scene_from_dict


def test_package_assets_are_stored_as_placeholders_and_found_from_another_install() -> None:
    scene = load_scene(vtrack.default_scene_path())
    d = scene.to_dict()
    assert d["hand"]["urdf"] == "${assets}/robots/allegro_digit/allegro_digit_left.urdf"
    assert scene_from_dict(d).hand.urdf == scene.hand.urdf  # round trip
    # a session written by another install (older sessions stored the absolute path of its checkout)
    d["hand"]["urdf"] = "/somewhere/else/vtrack/assets/robots/allegro_digit/allegro_digit_left.urdf"
    assert scene_from_dict(d).hand.urdf == assets_dir() / "robots/allegro_digit/allegro_digit_left.urdf"
    # a path outside any assets folder stays as given (and a missing one is still reported)
    d["hand"]["urdf"] = "/somewhere/else/hand.urdf"
    with pytest.raises(vtrack.InputError, match="/somewhere/else/hand.urdf"):
        scene_from_dict(d)
