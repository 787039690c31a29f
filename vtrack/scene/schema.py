"""Scene description (validated with pydantic).

A scene declares only what it has: an object (mesh or unknown), optionally a hand (URDF +
which links carry which tactile sensors), optionally cameras, tactile sensors, the pipeline to
run and, for synthetic sessions, simulation parameters. Everything is in metres and radians
unless a field name says otherwise (``_mm``, ``_deg``, ``_hz``).

Paths in a scene file may use ``${assets}`` (data shipped inside the package, :func:`vtrack.paths.assets_dir`),
``${shared}`` (the ``shared/`` folder beside the repository) and ``${repo}`` (the repository root of a
checkout); other relative paths are relative to the scene file.
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator, model_serializer, model_validator


class _Model(BaseModel):
    # Unknown keys are errors: a typo in a scene file must not be silently ignored.
    # NaN/Inf in a scene number is always a mistake (it would leak into every later stage).
    model_config = ConfigDict(extra="forbid", frozen=False, arbitrary_types_allowed=True, allow_inf_nan=False)


Vec3 = tuple[float, float, float]


class Pose(_Model):
    """A rigid transform given as ``xyz`` (m) plus either ``rpy`` (rad, URDF order) or
    ``quat_xyzw`` (scalar last), or as a full row-major 4x4 ``matrix``."""

    xyz: Vec3 = (0.0, 0.0, 0.0)
    rpy: Vec3 | None = None
    quat_xyzw: tuple[float, float, float, float] | None = None
    matrix: list[list[float]] | None = None

    @model_validator(mode="after")
    def _one_rotation(self) -> Pose:
        given = [x is not None for x in (self.rpy, self.quat_xyzw, self.matrix)]
        if sum(given) > 1:
            raise ValueError("give only one of rpy, quat_xyzw or matrix")
        if self.quat_xyzw is not None and np.linalg.norm(self.quat_xyzw) < 1e-9:
            raise ValueError("quat_xyzw must be non-zero")
        if self.matrix is not None:
            from vtrack.geometry.se3 import is_rigid

            M = np.asarray(self.matrix, dtype=np.float64)
            if M.shape != (4, 4) or not is_rigid(M, tol=1e-5):
                raise ValueError("matrix must be a 4x4 rigid transform (orthonormal rotation, last row 0 0 0 1)")
        return self

    def as_matrix(self) -> np.ndarray:
        """4x4 float64 transform."""
        from vtrack.geometry import se3

        if self.matrix is not None:
            return np.asarray(self.matrix, dtype=np.float64)
        if self.quat_xyzw is not None:
            R = se3.quat_to_matrix(np.asarray(self.quat_xyzw))
        elif self.rpy is not None:
            R = se3.rpy_to_matrix(np.asarray(self.rpy))
        else:
            R = np.eye(3)
        return se3.make_transform(R, np.asarray(self.xyz))

    @classmethod
    def from_matrix(cls, T: np.ndarray) -> Pose:
        return cls(matrix=np.asarray(T, dtype=np.float64).tolist())


class LookAt(_Model):
    """Camera placement: camera centre ``eye`` looking at ``target`` (world frame, m)."""

    eye: Vec3
    target: Vec3 = (0.0, 0.0, 0.0)
    up: Vec3 = (0.0, 0.0, 1.0)

    @model_validator(mode="after")
    def _distinct(self) -> LookAt:
        d = np.subtract(self.target, self.eye)
        if float(np.linalg.norm(d)) < 1e-6:
            raise ValueError("look_at.eye and target must differ")
        if float(np.linalg.norm(np.cross(d, self.up))) < 1e-9 * float(np.linalg.norm(d)) or not np.any(self.up):
            raise ValueError("look_at.up must not be parallel to the viewing direction")
        return self


class ObjectSpec(_Model):
    """The manipulated object. ``mesh: null`` means the shape is unknown (to be reconstructed)."""

    name: str = "object"
    mesh: Path | None = None
    scale: float = Field(1.0, gt=0, description="mesh units -> metres")
    T_world_object: Pose | None = Field(None, description="initial object pose prior (None = unknown)")
    symmetric: bool = Field(False, description="rotationally symmetric (report ADD-S)")


class MountedSensor(_Model):
    """A tactile sensor rigidly mounted on a hand link."""

    sensor: str = Field(description="name of a sensor in `tactile`")
    link: str = Field(description="URDF link carrying the sensor")
    T_link_sensor: Pose = Field(default_factory=Pose, description="sensor frame in the link frame")


class HandSpec(_Model):
    """A robot hand from a URDF and the tactile sensors it carries."""

    urdf: Path
    T_world_base: Pose = Field(default_factory=Pose)
    sensors: list[MountedSensor] = Field(default_factory=list)
    joint_names: list[str] | None = Field(None, description="order of joint-state columns; default URDF order")


class CameraSpec(_Model):
    """An RGB-D camera: pinhole intrinsics (px), extrinsics and depth format."""

    name: str
    # Plausible ranges (hostile-input hardening, issue #22): values outside them are typos or unit mistakes.
    width: int = Field(640, gt=0, le=16384)
    height: int = Field(480, gt=0, le=16384)
    fx: float = Field(600.0, gt=0, le=1e5)
    fy: float = Field(600.0, gt=0, le=1e5)
    cx: float | None = None
    cy: float | None = None
    T_world_camera: Pose | None = None
    look_at: LookAt | None = None
    depth_scale: float = Field(0.001, ge=1e-6, le=0.1, description="metres per depth unit (uint16 depth)")
    depth_min: float = Field(0.1, ge=0, le=100.0, description="m")
    depth_max: float = Field(3.0, gt=0, le=100.0, description="m")
    rate_hz: float = Field(30.0, gt=0, le=10000.0)

    @model_validator(mode="after")
    def _placement(self) -> CameraSpec:
        if self.T_world_camera is not None and self.look_at is not None:
            raise ValueError("give either T_world_camera or look_at, not both")
        if self.depth_max <= self.depth_min:
            raise ValueError(f"depth_max ({self.depth_max}) must exceed depth_min ({self.depth_min})")
        # uint16 depth: depth_min..depth_max must map to distinct units, or every depth rounds to 0/saturates.
        if self.depth_max / self.depth_scale > 65535 or self.depth_min / self.depth_scale > 65535:
            raise ValueError(
                f"depth_max {self.depth_max} m is {self.depth_max / self.depth_scale:.4g} units at "
                f"depth_scale {self.depth_scale} m/unit: more than uint16 holds (65535)"
            )
        if (self.depth_max - self.depth_min) / self.depth_scale < 100:
            raise ValueError(
                f"depth_scale {self.depth_scale} m/unit leaves fewer than 100 depth steps between "
                f"depth_min and depth_max (expected about 0.0001..0.001 m/unit)"
            )
        for k, c, n in (("cx", self.cx, self.width), ("cy", self.cy, self.height)):
            if c is not None and not 0.0 <= c <= n:
                raise ValueError(f"{k} ({c} px) must lie inside the image (0..{n} px)")
        return self

    def intrinsics(self):
        """The :class:`~vtrack.geometry.camera.PinholeCamera` of this camera."""
        from vtrack.geometry.camera import PinholeCamera

        cx = (self.width - 1) / 2.0 if self.cx is None else self.cx
        cy = (self.height - 1) / 2.0 if self.cy is None else self.cy
        return PinholeCamera(self.width, self.height, self.fx, self.fy, cx, cy)

    def extrinsics(self) -> np.ndarray:
        """``T_world_camera`` (OpenCV camera frame)."""
        from vtrack.geometry.se3 import look_at

        if self.look_at is not None:
            return look_at(self.look_at.eye, self.look_at.target, self.look_at.up)
        return (self.T_world_camera or Pose()).as_matrix()


SensorType = Literal["gelsight", "gelsight_mini", "digit", "dome"]


class TactileSpec(_Model):
    """A vision-based tactile sensor (image size in px, scale in mm/px, gel in mm).

    For a known ``type`` (:data:`vtrack.tactile.sensors.SENSOR_PRESETS`) omitted ``width``/``height``,
    ``mm_per_px``, ``gel_thickness_mm`` and ``rate_hz`` come from the preset (the stored image size; the
    nominal pitch rescaled to the given size), so ``{name: index, type: digit}`` is a complete entry.
    """

    name: str
    type: SensorType
    width: int = Field(gt=0, le=8192)
    height: int = Field(gt=0, le=8192)
    mm_per_px: float = Field(gt=0, le=2.0)
    gel_thickness_mm: float = Field(3.0, gt=0, le=50.0)
    rate_hz: float = Field(60.0, gt=0, le=10000.0)

    @model_validator(mode="before")
    @classmethod
    def _preset_defaults(cls, data):
        from vtrack.tactile.sensors import SENSOR_PRESETS

        p = SENSOR_PRESETS.get(data.get("type")) if isinstance(data, dict) else None
        if p is None:
            return data
        out = dict(data)
        if "width" not in out and "height" not in out:
            out["width"], out["height"] = p.stored_size
        if "mm_per_px" not in out and isinstance(out.get("width"), int) and isinstance(out.get("height"), int):
            out["mm_per_px"] = p.pitch_at(out["width"], out["height"])
        out.setdefault("gel_thickness_mm", p.gel_thickness_mm)
        out.setdefault("rate_hz", p.fps)
        return out

    calibration: Path | None = Field(None, description="calibration file from `vtrack calibrate`")
    background: Path | None = Field(None, description="no-contact image")
    contact_threshold_mm: float = Field(0.05, gt=0, le=5.0)


class PipelineSpec(_Model):
    """What to run on the scene's data."""

    reconstruction: Literal["off", "tsdf", "neural_sdf"] = "off"
    tracking: Literal["off", "known_shape", "slam"] = "off"
    modalities: list[Literal["vision", "touch"]] = Field(default_factory=lambda: ["vision", "touch"])


class SimSpec(_Model):
    """Parameters of a synthetic session (see ``vtrack.sim``); times in s, angles in rad."""

    seconds: float = Field(5.0, gt=0, le=3600.0)
    seed: int = 0
    occlusion: Literal["none", "medium", "heavy"] = "none"
    rotation_axis: Vec3 = (0.0, 0.0, 1.0)
    rotation_speed: float = Field(0.5, ge=-20.0, le=20.0, description="rad/s")
    translation_amplitude: float = Field(0.005, ge=0, le=0.1, description="m")
    depth_noise: float = Field(1.0, ge=0, le=100.0, description="scale of the depth noise model (0 = none)")
    tactile_noise: float = Field(1.0, ge=0, le=100.0, description="scale of tactile image noise (0 = none)")
    joint_noise: float = Field(0.0, ge=0, le=0.5, description="encoder noise std, rad")
    penetration_mm: tuple[float, float] = (0.5, 2.0)
    finger_gaiting: bool = False
    joint_rate_hz: float = Field(60.0, gt=0, le=10000.0)
    #: ``slide``: each finger closes along its synergy and the object turns under it (contacts slide over the
    #: surface); ``stick``: fingers in contact follow the object (object-frame contact point fixed) and gait when
    #: their kinematics cannot follow (see :mod:`vtrack.sim.grasp`). Opt-in; absent from dumps when ``slide``.
    contact_mode: Literal["slide", "stick"] = "slide"

    @model_serializer(mode="wrap")
    def _dump(self, handler):  # noqa: ANN001
        # the default mode is left out of dumps, so scenes and sessions made before the option existed keep their
        # bytes and cache keys
        d = handler(self)
        if isinstance(d, dict) and d.get("contact_mode") == "slide":
            d.pop("contact_mode")
        return d

    @field_validator("penetration_mm")
    @classmethod
    def _penetration(cls, v: tuple[float, float]) -> tuple[float, float]:
        if not 0.0 <= v[0] <= v[1] <= 10.0:
            raise ValueError(f"penetration_mm must be [min, max] with 0 <= min <= max <= 10 mm, got {list(v)}")
        return v

    @field_validator("rotation_axis")
    @classmethod
    def _axis(cls, v: Vec3) -> Vec3:
        if float(np.linalg.norm(v)) < 1e-9:
            raise ValueError("rotation_axis must be non-zero")
        return v


class Scene(_Model):
    """A complete scene. ``source`` is set by the loader to the YAML file's path."""

    name: str
    version: Literal[1] = 1
    description: str = ""
    object: ObjectSpec = Field(default_factory=ObjectSpec)
    hand: HandSpec | None = None
    cameras: list[CameraSpec] = Field(default_factory=list)
    tactile: list[TactileSpec] = Field(default_factory=list)
    pipeline: PipelineSpec = Field(default_factory=PipelineSpec)
    sim: SimSpec | None = None
    source: Path | None = Field(None, exclude=True)

    @field_validator("cameras", "tactile")
    @classmethod
    def _unique_names(cls, items: list) -> list:
        names = [it.name for it in items]
        dup = {n for n in names if names.count(n) > 1}
        if dup:
            raise ValueError(f"duplicate names {sorted(dup)}")
        return items

    @model_validator(mode="after")
    def _cross_refs(self) -> Scene:
        names = {t.name for t in self.tactile}
        if self.hand is not None:
            for i, m in enumerate(self.hand.sensors):
                if m.sensor not in names:
                    raise ValueError(
                        f"hand.sensors[{i}].sensor '{m.sensor}' is not a tactile sensor of this scene "
                        f"(known: {sorted(names)})"
                    )
        if self.pipeline.tracking == "known_shape" and self.object.mesh is None:
            raise ValueError("pipeline.tracking 'known_shape' needs object.mesh")
        return self

    # Convenience accessors -------------------------------------------------------------
    def tactile_by_name(self, name: str) -> TactileSpec:
        for t in self.tactile:
            if t.name == name:
                return t
        raise KeyError(name)

    def camera_by_name(self, name: str) -> CameraSpec:
        for c in self.cameras:
            if c.name == name:
                return c
        raise KeyError(name)

    @property
    def effective_modalities(self) -> list[str]:
        """Modalities the pipeline asks for that the scene can actually provide."""
        out = []
        if "vision" in self.pipeline.modalities and self.cameras:
            out.append("vision")
        if "touch" in self.pipeline.modalities and self.tactile:
            out.append("touch")
        return out

    def to_dict(self) -> dict:
        """JSON-able dict for embedding in a session manifest: paths absolute, except files of the package's
        assets and of the shared folder, written ``${assets}/...`` / ``${shared}/...`` (portable across
        installs; :func:`vtrack.scene.load.scene_from_dict` expands them)."""
        from vtrack.scene.load import _PATH_FIELDS, _walk, abbreviate_path

        d = self.model_dump(mode="json")
        for f in _PATH_FIELDS:
            _walk(d, f.split("."), abbreviate_path)
        return d
