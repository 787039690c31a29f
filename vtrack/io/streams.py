"""Standard stream declarations, so that generators, recorders and importers write the same names.

Stream names:
- ``camera/<name>``: RGB-D frames (``rgb`` uint8 HxWx3, ``depth`` uint16 in ``depth_scale`` m units,
  optional ``mask`` uint8 object segmentation); attrs hold ``K``, ``depth_scale`` and the static
  ``T_world_camera``.
- ``tactile/<name>``: tactile images (``image`` uint8 HxWx3, BGR).
- ``joints``: hand joint positions ``q`` (rad), column order in attrs ``joint_names``.
- ``gt/object_pose``: ``T_world_object`` (4x4) ground truth.
- ``gt/tactile/<name>``: ground-truth ``height_mm`` (float32) and ``contact`` (uint8) per tactile frame.
- ``gt/camera/<name>``: ground-truth ``visible_fraction`` of the object per camera frame.
"""

from __future__ import annotations

import numpy as np

from vtrack.errors import InputError
from vtrack.io.session import FieldSpec, StreamSpec


def camera_stream(cam, with_mask: bool = True, T_world_camera: np.ndarray | None = None) -> StreamSpec:
    """Stream declaration for a :class:`~vtrack.scene.schema.CameraSpec`."""
    K = cam.intrinsics().K
    T = cam.extrinsics() if T_world_camera is None else np.asarray(T_world_camera)
    fields = {
        "rgb": FieldSpec((cam.height, cam.width, 3), "uint8", "sRGB"),
        "depth": FieldSpec((cam.height, cam.width), "uint16", f"{cam.depth_scale} m"),
    }
    if with_mask:
        fields["mask"] = FieldSpec((cam.height, cam.width), "uint8", "label")
    return StreamSpec(
        kind="rgbd",
        frame=f"camera/{cam.name}",
        rate_hz=cam.rate_hz,
        fields=fields,
        attrs={
            "K": K.tolist(),
            "width": cam.width,
            "height": cam.height,
            "depth_scale": cam.depth_scale,
            "T_world_camera": np.asarray(T).tolist(),
        },
    )


def camera_gt_stream(cam) -> StreamSpec:
    """Ground truth of a simulated camera (``gt/camera/<cam>``): the renderer's exact object mask and the
    visible fraction of the object. Scoring only: the pipeline segments the depth itself."""
    return StreamSpec(
        kind="visibility",
        frame=f"camera/{cam.name}",
        rate_hz=cam.rate_hz,
        fields={
            "visible_fraction": FieldSpec((), "float32", "fraction"),
            "mask": FieldSpec((cam.height, cam.width), "uint8", "label"),
        },
    )


def tactile_stream(spec) -> StreamSpec:
    """Stream declaration for a :class:`~vtrack.scene.schema.TactileSpec`."""
    return StreamSpec(
        kind="tactile",
        frame=f"sensor/{spec.name}",
        rate_hz=spec.rate_hz,
        fields={"image": FieldSpec((spec.height, spec.width, 3), "uint8", "BGR")},
        attrs={"type": spec.type, "mm_per_px": spec.mm_per_px, "width": spec.width, "height": spec.height},
    )


def tactile_gt_stream(spec) -> StreamSpec:
    """Ground-truth height map (mm, into the gel) and contact mask for a tactile sensor."""
    return StreamSpec(
        kind="tactile_gt",
        frame=f"sensor/{spec.name}",
        rate_hz=spec.rate_hz,
        fields={
            "height_mm": FieldSpec((spec.height, spec.width), "float32", "mm"),
            "contact": FieldSpec((spec.height, spec.width), "uint8", "bool"),
        },
        attrs={"sensor": spec.name, "mm_per_px": spec.mm_per_px},
    )


def joints_stream(joint_names: list[str], rate_hz: float | None = None) -> StreamSpec:
    """Joint positions (rad) in the given column order."""
    return StreamSpec(
        kind="joints",
        frame="hand",
        rate_hz=rate_hz,
        fields={"q": FieldSpec((len(joint_names),), "float64", "rad")},
        attrs={"joint_names": list(joint_names)},
    )


def pose_stream(field: str = "T_world_object", rate_hz: float | None = None, frame: str = "object") -> StreamSpec:
    """A 4x4 pose per frame."""
    return StreamSpec(kind="pose", frame=frame, rate_hz=rate_hz, fields={field: FieldSpec((4, 4), "float64", "m")})


def scalar_stream(field: str, units: str = "", kind: str = "scalar", rate_hz: float | None = None) -> StreamSpec:
    return StreamSpec(kind=kind, rate_hz=rate_hz, fields={field: FieldSpec((), "float32", units)})


def encode_depth(depth: np.ndarray, depth_scale: float = 0.001) -> np.ndarray:
    """Depth image -> uint16 in units of ``depth_scale`` metres (0.001 = mm), rounding to nearest.

    Float input is metres; uint16 input is passed through (already in sensor units). Invalid pixels
    (NaN, Inf, <= 0) and depths beyond the uint16 range become 0, the "no measurement" value: a
    saturated 65535 would look like a valid far reading.
    """
    d = np.asarray(depth)
    if d.dtype == np.uint16:
        return d
    if d.dtype.kind in "ui":
        d = d.astype(np.float64) * depth_scale
    if d.dtype.kind != "f":
        raise InputError(
            "depth must be float metres or uint16 sensor units",
            field="depth",
            expected="float32/float64 or uint16",
            got=str(d.dtype),
        )
    with np.errstate(invalid="ignore", over="ignore"):
        units = np.rint(d.astype(np.float64) / depth_scale)
        valid = np.isfinite(units) & (units > 0) & (units <= 65535)
    return np.where(valid, units, 0).astype(np.uint16)
