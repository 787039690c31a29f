"""Scene files: schema (pydantic) and loader."""

from vtrack.scene.load import load_scene, scene_from_dict
from vtrack.scene.schema import (
    CameraSpec,
    HandSpec,
    ObjectSpec,
    PipelineSpec,
    Pose,
    Scene,
    SimSpec,
    TactileSpec,
)

__all__ = [
    "CameraSpec",
    "HandSpec",
    "ObjectSpec",
    "PipelineSpec",
    "Pose",
    "Scene",
    "SimSpec",
    "TactileSpec",
    "load_scene",
    "scene_from_dict",
]
