"""Lazy, scene-driven loading: `import vtrack` and the scene/registry layer import no heavy back-end."""

from __future__ import annotations

import subprocess
import sys
import textwrap

HEAVY = ("torch", "open3d", "depthai", "pyvista", "viser")


def _loaded_after(code: str) -> list[str]:
    probe = textwrap.dedent(code) + textwrap.dedent(
        f"""
        import sys
        print("LOADED:" + ",".join(m for m in {HEAVY!r} if m in sys.modules))
        """
    )
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    line = [ln for ln in out.stdout.splitlines() if ln.startswith("LOADED:")][-1]
    return [m for m in line.removeprefix("LOADED:").split(",") if m]


def test_import_vtrack_is_light() -> None:
    assert _loaded_after("import vtrack") == []


def test_scene_session_geometry_layers_are_light(shared_data) -> None:
    loaded = _loaded_after(
        """
        import vtrack, vtrack.geometry.se3, vtrack.geometry.camera, vtrack.geometry.pointcloud
        import vtrack.io.session, vtrack.io.streams, vtrack.registry
        from vtrack.scene import load_scene
        from vtrack.paths import default_scene_path
        s = load_scene(default_scene_path())
        vtrack.registry.required_components(s)
        """
    )
    assert loaded == []


def test_front_door_names_resolve_without_heavy_imports() -> None:
    """Every ``vtrack.<name>`` of the front door is the object its module owns, and resolving ALL of them
    (loading, sessions, calibration, pipeline, reconstruct/track entry points, trackers) still imports none of
    torch/open3d/depthai/pyvista/viser: those load when a component runs."""
    import importlib

    import vtrack

    for name, (module, attr) in vtrack._LAZY.items():
        assert getattr(vtrack, name) is getattr(importlib.import_module(module), attr), name
        assert name in vtrack.__all__ and name in dir(vtrack)
    import pytest

    with pytest.raises(AttributeError, match="no attribute 'tracker_of_doom'"):
        vtrack.tracker_of_doom  # noqa: B018
    assert vtrack.__version__ != "0+unknown"  # read from the installed package's metadata
    assert _loaded_after("import vtrack\nfor n in vtrack._LAZY: getattr(vtrack, n)") == []


def test_cli_help_is_light() -> None:
    assert _loaded_after("import vtrack_apps.cli") == []


_BUILD = """
import yaml
from vtrack import registry
from vtrack.paths import default_scene_path
from vtrack.scene import scene_from_dict
d = yaml.safe_load(open(default_scene_path()))
{edit}
s = scene_from_dict(d, base_dir=default_scene_path().parent)
built = registry.build_all(s)
print("BUILT:" + ",".join(sorted(built)))
"""


def test_touch_only_scene_never_imports_the_rgbd_stack(shared_data) -> None:
    edit = 'd.pop("cameras"); d["pipeline"] = {"reconstruction": "off", "tracking": "off", "modalities": ["touch"]}'
    loaded = _loaded_after(_BUILD.format(edit=edit))
    assert loaded == []  # no open3d (RGB-D), no torch, no viewer back-ends


def test_tsdf_scene_never_imports_torch(shared_data) -> None:
    edit = 'd["pipeline"] = {"reconstruction": "tsdf", "tracking": "off", "modalities": ["vision", "touch"]}'
    loaded = _loaded_after(_BUILD.format(edit=edit))
    assert "open3d" in loaded  # the TSDF really was built
    assert "torch" not in loaded and "viser" not in loaded and "depthai" not in loaded


def test_batch_paths_choose_their_classes_through_the_registry(monkeypatch):
    """``vtrack track`` / ``reconstruct`` build trackers and reconstructors via ``registry.load``, so the
    registry is the one table of components (a key swapped there is what the CLI runs)."""
    import numpy as np

    from vtrack import registry
    from vtrack.fusion.reconstruct import reconstruct_observations
    from vtrack.paths import assets_dir
    from vtrack.tracking.run import build_tracker

    seen: list[str] = []
    orig = registry.load

    def spy(key: str):
        seen.append(key)
        return orig(key)

    monkeypatch.setattr(registry, "load", spy)
    assert type(build_tracker("slam", None, np.eye(4))).__name__ == "SLAMTracker"
    can = assets_dir() / "objects" / "005_tomato_soup_can.ply"
    assert type(build_tracker("known_shape", can, np.eye(4))).__name__ == "KnownShapeTracker"
    assert type(build_tracker("slam", can, np.eye(4), method="icp")).__name__ == "ICPTracker"
    reconstruct_observations([], "tsdf")
    assert seen == ["tracking.slam", "tracking.known_shape", "tracking.icp", "reconstruction.tsdf"]
    # a swapped entry is what runs
    monkeypatch.setitem(registry.COMPONENTS, "tracking.slam", "builtins:list")
    assert type(build_tracker("slam", None, np.eye(4))) is list


def test_registered_trackers_and_reconstructors_satisfy_the_protocols():
    import inspect

    from vtrack import registry
    from vtrack.protocols import Reconstructor, Tracker

    def methods(proto) -> set[str]:
        return {n for n, v in vars(proto).items() if not n.startswith("_") and (callable(v) or isinstance(v, property))}

    for key in [k for k in registry.COMPONENTS if k.startswith(("tracking.", "reconstruction."))]:
        cls = registry.load(key)
        proto = Tracker if key.startswith("tracking.") else Reconstructor
        missing = [m for m in methods(proto) if not hasattr(cls, m)]
        assert not missing, (key, missing)
        if proto is Tracker:
            assert cls.mode == key.split(".", 1)[1], (key, cls.mode)  # result files name the mode as the registry
        for m in methods(proto) - {"last_info"}:
            assert inspect.isfunction(getattr(cls, m)), (key, m)
