"""vtrack: 3D visuo-tactile reconstruction and in-hand object tracking.

Quick start (every name below is loaded on first use)::

    import vtrack
    scene = vtrack.load_scene(vtrack.default_scene_path())     # or your own scene YAML
    run = vtrack.calibrate("my_presses")                       # ball presses -> calibration (held-out checked)
    vtrack.reconstruct("session_dir", "out/recon")             # TSDF / neural SDF of the object
    vtrack.track("session_dir", "out/track", shape="slam")     # object pose in hand (known shape or SLAM)

Importing this package is cheap on purpose: heavy back-ends (torch, open3d, depthai, pyvista, viser) are
imported only by the components a scene or command actually uses (PEP 562 lazy attributes below).

Conventions used across the package:
- lengths in metres, angles in radians, unless a name says otherwise (``_mm``, ``_deg``, ``_px``);
- transforms are 4x4 homogeneous matrices named ``T_a_b``: they map points expressed in
  frame ``b`` into frame ``a`` (``p_a = T_a_b @ p_b``);
- timestamps are float64 seconds.
"""

from __future__ import annotations

import importlib
from importlib.metadata import PackageNotFoundError, version
from typing import Any

from vtrack.errors import InputError, VtrackError

try:
    __version__ = version("vtrack")
except PackageNotFoundError:  # running from a source tree that was never installed
    __version__ = "0+unknown"

#: public name -> (module, attribute): the front door, resolved lazily by ``__getattr__``.
_LAZY: dict[str, tuple[str, str]] = {
    "load_scene": ("vtrack.scene.load", "load_scene"),
    "Scene": ("vtrack.scene.schema", "Scene"),
    "default_scene_path": ("vtrack.paths", "default_scene_path"),
    "open_session": ("vtrack.io.session", "open_session"),
    "SessionWriter": ("vtrack.io.session", "SessionWriter"),
    "strip_gt": ("vtrack.io.strip", "strip_gt"),
    "load_mesh": ("vtrack.io.mesh", "load_mesh"),
    "load_press_set": ("vtrack.tactile.pressset", "load_press_set"),
    "calibrate": ("vtrack.tactile.calibrate_set", "calibrate_press_set"),
    "Calibration": ("vtrack.tactile.calibration", "Calibration"),
    "TactilePipeline": ("vtrack.tactile.pipeline", "TactilePipeline"),
    "SENSOR_PRESETS": ("vtrack.tactile.sensors", "SENSOR_PRESETS"),
    "reconstruct": ("vtrack.fusion.reconstruct", "reconstruct_session"),
    "track": ("vtrack.tracking.run", "track_session"),
    "KnownShapeTracker": ("vtrack.tracking.tracker", "KnownShapeTracker"),
    "SLAMTracker": ("vtrack.tracking.slam", "SLAMTracker"),
    "ICPTracker": ("vtrack.tracking.icp", "ICPTracker"),
    "Tracker": ("vtrack.protocols", "Tracker"),
    "Reconstructor": ("vtrack.protocols", "Reconstructor"),
}

__all__ = ["InputError", "VtrackError", "__version__", *_LAZY]


def __getattr__(name: str) -> Any:
    try:
        module, attr = _LAZY[name]
    except KeyError:
        raise AttributeError(f"module 'vtrack' has no attribute '{name}'") from None
    value = getattr(importlib.import_module(module), attr)
    globals()[name] = value  # cache: later lookups skip __getattr__
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))
