"""RGB-D front end (registry key ``rgbd``): camera frames -> world-frame vision clouds."""

from __future__ import annotations

from typing import Any

import numpy as np

from vtrack.errors import InputError
from vtrack.fusion.cloud import UnifiedCloud, from_rgbd


class RGBDFrontend:
    """Masked unprojection of every camera of a scene, with its intrinsics and extrinsics.

    Args:
        cameras: scene ``CameraSpec`` list. stride: pixel stride. use_mask: apply the segmentation.
    """

    def __init__(self, cameras: list, stride: int = 4, use_mask: bool = True) -> None:
        self.cameras = {c.name: c for c in cameras}
        self.names = [c.name for c in cameras]
        self.stride = int(stride)
        self.use_mask = bool(use_mask)

    @classmethod
    def from_scene(cls, scene: Any, **opts: Any) -> RGBDFrontend:
        return cls(list(scene.cameras), **opts)

    def cloud(
        self,
        camera: str,
        depth: np.ndarray,
        mask: np.ndarray | None = None,
        t: float = 0.0,
        T_world_camera: np.ndarray | None = None,
    ) -> UnifiedCloud:
        """World-frame vision cloud of one frame of ``camera`` (depth in the camera's depth units)."""
        if camera not in self.cameras:
            raise InputError("unknown camera", field="camera", expected=str(self.names), got=camera)
        c = self.cameras[camera]
        T = c.extrinsics() if T_world_camera is None else np.asarray(T_world_camera, np.float64)
        return from_rgbd(
            depth,
            c.intrinsics(),
            T,
            mask=mask if self.use_mask else None,
            t=t,
            sensor_id=self.names.index(camera),
            depth_scale=c.depth_scale,
            stride=self.stride,
            min_depth=c.depth_min,
            max_depth=c.depth_max,
            sensor_names=self.names,
        )
