"""Scene files: validation, clear errors, path placeholders."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from vtrack.errors import InputError
from vtrack.paths import default_scene_path, scenes_dir
from vtrack.scene import load_scene, scene_from_dict


def test_all_shipped_scenes_validate(shared_data: Path) -> None:
    files = sorted(scenes_dir().glob("*.yaml")) + [default_scene_path()]
    assert len(files) >= 10 and default_scene_path().is_file()
    for f in files:
        s = load_scene(f)
        assert s.name and s.source == f.resolve()


def test_default_scene_contents(shared_data: Path) -> None:
    s = load_scene(default_scene_path())
    assert s.object.mesh is not None and s.object.mesh.exists()
    assert s.hand is not None and s.hand.urdf.exists() and len(s.hand.sensors) == 4
    assert {m.sensor for m in s.hand.sensors} == {t.name for t in s.tactile}
    T = s.cameras[0].extrinsics()
    assert np.allclose(T[:3, :3].T @ T[:3, :3], np.eye(3))
    assert s.effective_modalities == ["vision", "touch"]


def _write(tmp_path: Path, data: dict) -> Path:
    p = tmp_path / "scene.yaml"
    p.write_text(yaml.safe_dump(data))
    return p


BASE = {"name": "t", "tactile": [{"name": "g", "type": "gelsight", "width": 640, "height": 480, "mm_per_px": 0.03}]}


def test_bad_field_names_file_and_field(tmp_path: Path) -> None:
    bad = {**BASE, "cameras": [{"name": "c", "fx": -1}]}
    with pytest.raises(InputError) as e:
        load_scene(_write(tmp_path, bad))
    msg = str(e.value)
    assert "scene.yaml" in msg and "cameras.0.fx" in msg and "greater than 0" in msg


def test_unknown_key_is_an_error(tmp_path: Path) -> None:
    with pytest.raises(InputError, match=r"tactile\.0\.mm_per_pix.*Extra inputs"):
        load_scene(_write(tmp_path, {"name": "t", "tactile": [{**BASE["tactile"][0], "mm_per_pix": 1}]}))


def test_wrong_sensor_type_lists_choices(tmp_path: Path) -> None:
    bad = {"name": "t", "tactile": [{**BASE["tactile"][0], "type": "biotac"}]}
    with pytest.raises(InputError, match=r"tactile\.0\.type.*'gelsight'.*'dome'"):
        load_scene(_write(tmp_path, bad))


def test_cross_reference_and_missing_file(tmp_path: Path) -> None:
    urdf = tmp_path / "hand.urdf"
    urdf.write_text("<robot name='x'/>")
    bad = {**BASE, "hand": {"urdf": "hand.urdf", "sensors": [{"sensor": "nope", "link": "l"}]}}
    with pytest.raises(InputError, match=r"hand.sensors\[0\].sensor 'nope'"):
        load_scene(_write(tmp_path, bad))
    bad = {**BASE, "object": {"mesh": "missing.ply"}}
    with pytest.raises(InputError, match=r"object.mesh.*file does not exist"):
        load_scene(_write(tmp_path, bad))
    bad = {**BASE, "pipeline": {"tracking": "known_shape"}}
    with pytest.raises(InputError, match="needs object.mesh"):
        load_scene(_write(tmp_path, bad))


def test_relative_paths_resolve_against_the_scene_file(tmp_path: Path) -> None:
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "obj.ply").write_text("ply")
    s = load_scene(_write(tmp_path, {**BASE, "object": {"mesh": "sub/obj.ply"}}))
    assert s.object.mesh == (tmp_path / "sub" / "obj.ply").resolve()


def test_yaml_syntax_error_has_line(tmp_path: Path) -> None:
    p = tmp_path / "broken.yaml"
    p.write_text("name: a\ncameras: [\n  {name: c\n")
    with pytest.raises(InputError, match=r"broken.yaml.*line \d+"):
        load_scene(p)
    with pytest.raises(InputError, match="does not exist"):
        load_scene(tmp_path / "nope.yaml")
    p.write_text("- 1\n- 2\n")
    with pytest.raises(InputError, match="mapping"):
        load_scene(p)


def test_pose_forms() -> None:
    s = scene_from_dict({"name": "p", "object": {"T_world_object": {"xyz": [1, 2, 3], "quat_xyzw": [0, 0, 1, 1]}}})
    T = s.object.T_world_object.as_matrix()
    assert np.allclose(T[:3, 3], [1, 2, 3]) and np.allclose(T[:3, 0], [0, 1, 0], atol=1e-12)
    with pytest.raises(InputError, match="only one of"):
        scene_from_dict({"name": "p", "object": {"T_world_object": {"rpy": [0, 0, 0], "quat_xyzw": [0, 0, 0, 1]}}})
    with pytest.raises(InputError, match="rigid"):
        scene_from_dict(
            {
                "name": "p",
                "object": {"T_world_object": {"matrix": [[2, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]}},
            }
        )
