"""Build the scene (as a validated dict) that an importer or recorder embeds in a session."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from vtrack.errors import InputError


def camera_entry(
    name: str,
    K: np.ndarray,
    width: int,
    height: int,
    T_world_camera: np.ndarray | None = None,
    depth_scale: float = 0.001,
    rate_hz: float = 30.0,
) -> dict[str, Any]:
    """A scene ``cameras`` entry from a 3x3 intrinsic matrix (px) and extrinsics (m)."""
    K = np.asarray(K, dtype=np.float64)
    if K.shape != (3, 3) or not np.all(np.isfinite(K)) or K[0, 0] <= 0 or K[1, 1] <= 0:
        raise InputError(
            "invalid camera intrinsics",
            field=f"cameras.{name}.K",
            expected="3x3 matrix with positive focal lengths",
            got=K.tolist(),
        )
    entry: dict[str, Any] = {
        "name": name,
        "width": int(width),
        "height": int(height),
        "fx": float(K[0, 0]),
        "fy": float(K[1, 1]),
        "cx": float(K[0, 2]),
        "cy": float(K[1, 2]),
        "depth_scale": float(depth_scale),
        "rate_hz": float(rate_hz),
    }
    if T_world_camera is not None:
        entry["T_world_camera"] = {"matrix": _rigid(T_world_camera, f"cameras.{name}.T_world_camera").tolist()}
    return entry


def tactile_entry(
    name: str, sensor_type: str, width: int, height: int, rate_hz: float, mm_per_px: float | None = None
) -> dict[str, Any]:
    """A scene ``tactile`` entry; scale and gel thickness default to the sensor type's preset."""
    from vtrack.tactile.sensors import SENSOR_PRESETS

    p = SENSOR_PRESETS.get(sensor_type, SENSOR_PRESETS["digit"])
    return {
        "name": name,
        "type": sensor_type,
        "width": int(width),
        "height": int(height),
        "mm_per_px": float(mm_per_px or p.mm_per_px),
        "gel_thickness_mm": p.gel_thickness_mm,
        "rate_hz": float(rate_hz),
    }


def _rigid(T: Any, what: str) -> np.ndarray:
    from vtrack.geometry.se3 import is_rigid, orthonormalize

    M = np.asarray(T, dtype=np.float64)
    if M.shape != (4, 4) or not np.all(np.isfinite(M)):
        raise InputError("not a finite 4x4 transform", field=what, got=getattr(M, "shape", None))
    if not is_rigid(M, tol=1e-5):
        if not is_rigid(M, tol=1e-2):
            raise InputError("not a rigid transform", field=what, expected="orthonormal rotation, last row 0 0 0 1")
        # Float32 round trips in other tools leave ~1e-4 errors: re-orthonormalise.
        M = M.copy()
        M[:3, :3] = orthonormalize(M[:3, :3])
        M[3] = [0, 0, 0, 1]
    return M


def finalize_scene(scene: dict[str, Any], source: Path | None = None) -> dict[str, Any]:
    """Validate a scene dict (no file checks) and return it as the JSON-able dict to embed."""
    from vtrack.scene.load import scene_from_dict

    sc = scene_from_dict(scene, source=source, check_files=False)
    return sc.to_dict()


def write_scene_yaml(writer: Any, scene: dict[str, Any]) -> None:
    """Store the scene as ``assets/scene.yaml`` too (so ``vtrack`` commands can take it as --scene)."""
    import yaml

    dst = writer.path / "assets" / "scene.yaml"
    dst.write_text(yaml.safe_dump(scene, sort_keys=False))
    writer.manifest["assets"]["scene.yaml"] = {"role": "scene", "source": "importer"}
    writer._write_manifest()
