"""Pinhole camera model (OpenCV convention: x right, y down, z forward; metres).

Depth images are either uint16 in sensor units (``depth_scale`` metres per unit, 0.001 for mm)
or float32/float64 in metres. Invalid depth (0, NaN, Inf, negative, beyond ``max_depth``) is
dropped, never turned into points at the origin.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vtrack.errors import InputError


@dataclass(frozen=True)
class PinholeCamera:
    """Intrinsics of a pinhole camera; ``fx, fy, cx, cy`` in pixels, image ``width x height``."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float

    def __post_init__(self) -> None:
        if self.width <= 0 or self.height <= 0:
            raise InputError(
                "image size must be positive", field="width/height", expected="> 0", got=(self.width, self.height)
            )
        if not (np.isfinite(self.fx) and np.isfinite(self.fy) and self.fx > 0 and self.fy > 0):
            raise InputError(
                "focal lengths must be positive and finite", field="fx/fy", expected="> 0", got=(self.fx, self.fy)
            )

    @property
    def K(self) -> np.ndarray:
        """3x3 intrinsic matrix."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @classmethod
    def from_fov(cls, width: int, height: int, fov_y_rad: float) -> PinholeCamera:
        """Square-pixel camera with vertical field of view ``fov_y_rad`` and centred principal point."""
        f = 0.5 * height / np.tan(0.5 * fov_y_rad)
        return cls(width, height, f, f, (width - 1) / 2.0, (height - 1) / 2.0)

    def pixel_rays(self) -> np.ndarray:
        """(H, W, 3) ray directions with z = 1 in the camera frame (for ray casting)."""
        u, v = np.meshgrid(np.arange(self.width, dtype=np.float64), np.arange(self.height, dtype=np.float64))
        return np.stack([(u - self.cx) / self.fx, (v - self.cy) / self.fy, np.ones_like(u)], axis=-1)

    def depth_to_meters(self, depth: np.ndarray, depth_scale: float = 0.001) -> np.ndarray:
        """Convert a depth image to float64 metres (uint16 uses ``depth_scale``; floats are metres)."""
        d = np.asarray(depth)
        if d.shape != (self.height, self.width):
            raise InputError(
                "depth image size does not match the camera",
                field="depth",
                expected=f"({self.height}, {self.width})",
                got=d.shape,
            )
        if d.dtype.kind in "ui":
            return d.astype(np.float64) * depth_scale
        if d.dtype.kind == "f":
            return d.astype(np.float64)
        raise InputError("unsupported depth dtype", field="depth", expected="uint16 or float", got=str(d.dtype))

    def valid_depth(
        self,
        depth: np.ndarray,
        mask: np.ndarray | None,
        depth_scale: float,
        min_depth: float,
        max_depth: float,
    ) -> tuple[np.ndarray, np.ndarray]:
        """(z metres (H, W), valid (H, W) bool): finite depth inside ``(min_depth, max_depth)`` m and, when a
        ``mask`` is given, inside it (non-zero = keep).

        Raises:
            InputError: the mask's size differs from the depth image's.
        """
        z = self.depth_to_meters(depth, depth_scale)
        valid = np.isfinite(z) & (z > min_depth) & (z < max_depth)
        if mask is not None:
            m = np.asarray(mask)
            if m.shape != z.shape:
                raise InputError(
                    "mask size does not match the depth image", field="mask", expected=str(z.shape), got=m.shape
                )
            valid &= m.astype(bool)
        return z, valid

    def unproject(
        self,
        depth: np.ndarray,
        mask: np.ndarray | None = None,
        depth_scale: float = 0.001,
        min_depth: float = 1e-3,
        max_depth: float = 10.0,
        stride: int = 1,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Back-project valid depth pixels to 3D points in the camera frame.

        Args:
            depth: (H, W) depth image, uint16 in units of ``depth_scale`` m or float metres.
            mask: optional (H, W) boolean mask of pixels to keep (e.g. object segmentation).
            min_depth, max_depth: valid range in metres; others are dropped.
            stride: keep every ``stride``-th row and column (cheap downsampling).

        Returns:
            points (N, 3) float64 in metres (camera frame) and pixel indices (N, 2) as (row, col).
        """
        z, valid = self.valid_depth(depth, mask, depth_scale, min_depth, max_depth)
        if stride > 1:
            sub = np.zeros_like(valid)
            sub[::stride, ::stride] = True
            valid &= sub
        idx = np.flatnonzero(valid)  # (flat indices: numpy's 2-D nonzero and fancy indexing are several times slower)
        rows, cols = np.divmod(idx, valid.shape[1])
        zz = z.reshape(-1)[idx]
        pts = np.stack([(cols - self.cx) / self.fx * zz, (rows - self.cy) / self.fy * zz, zz], axis=-1)
        return pts, np.stack([rows, cols], axis=-1)

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Project (N, 3) camera-frame points to pixel coordinates (N, 2) as (u, v) = (col, row).

        Returns the pixels and a boolean ``in_front`` (z > 0) mask; pixels of points behind the
        camera are NaN so they cannot be used by accident.
        """
        P = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        z = P[:, 2]
        in_front = z > 1e-9
        zs = np.where(in_front, z, np.nan)
        uv = np.stack([self.fx * P[:, 0] / zs + self.cx, self.fy * P[:, 1] / zs + self.cy], axis=-1)
        return uv, in_front

    def in_image(self, uv: np.ndarray) -> np.ndarray:
        """Boolean mask of pixel coordinates that fall inside the image."""
        uv = np.asarray(uv)
        with np.errstate(invalid="ignore"):
            return (
                np.isfinite(uv).all(-1)
                & (uv[:, 0] >= -0.5)
                & (uv[:, 0] < self.width - 0.5)
                & (uv[:, 1] >= -0.5)
                & (uv[:, 1] < self.height - 0.5)
            )
