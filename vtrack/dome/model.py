"""Dome sensor geometry: hemispherical shell, marker layouts, templates and the fisheye camera.

Frame ("dome frame", mm): origin at the centre of the dome sphere, +z through the apex (outwards).
The camera sits on the axis at ``z = -camera_offset_mm`` looking along +z; its image uses OpenCV
conventions (x = column, y = row). The lens is equidistant fisheye, ``r_px = f_px * theta``.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np


@dataclass(frozen=True)
class DomeConfig:
    """Geometry and imaging of the simulated dome (all lengths in mm, angles in degrees).

    The outer (contact) surface has radius ``radius_mm``; markers sit on the inner surface
    (``radius_mm - thickness_mm``). The cap spans polar angles ``<= cap_deg`` from the apex.

    Internal pressure ``P`` (kPa, ``0..pressure_max_kpa``) inflates the shell radially by
    ``inflation_mm_per_kpa * P`` (a sensor calibration: the no-contact shape at pressure P) and stiffens it.
    Default 0: the **confined-inflation** double shell of FusionTouch (S3: the outer fabric shell confines the
    inflation of the pressurised inner layer; the fabric's own stretch, ~0.0005 mm/kPa scaled to this dome, is a
    0.003 px marker shift at 10 kPa, 20x below the renderer's 1/16 px sub-pixel grid). Bundles trained before
    2026-11-26 used 0.03 mm/kPa (a single inflating shell) and keep it in their stored config.
    ``reference_at_pressure`` is the reference-frame protocol: True (default) = the no-contact reference
    frame is captured at the operating pressure, as a pneumatic sensor is re-zeroed after inflating, so the
    image shows only the contact deformation and the pressure must come from the pressure sensor; False =
    one reference at P = 0 for every pressure (inflation then shows in the image; the protocol of the
    bundles trained before 2026-11-23).
    """

    radius_mm: float = 20.0
    thickness_mm: float = 2.0
    cap_deg: float = 75.0
    marker_rings: int = 10  # TacTip-style hexagonal rings: 3 n (n + 1) + 1 markers (10 -> 331)
    marker_cap_deg: float = 68.0
    marker_radius_mm: float = 0.55
    camera_offset_mm: float = 6.0
    image_size: int = 160
    n_coarse: int = 256
    n_dense: int = 1024
    pressure_max_kpa: float = 10.0
    inflation_mm_per_kpa: float = 0.0
    reference_at_pressure: bool = True

    @property
    def inner_radius_mm(self) -> float:
        return self.radius_mm - self.thickness_mm

    @property
    def n_markers(self) -> int:
        n = self.marker_rings
        return 3 * n * (n + 1) + 1

    @property
    def focal_px(self) -> float:
        """Equidistant focal length so the cap rim lands 4 px inside the image border."""
        theta_rim = self.rim_view_angle()
        return (self.image_size / 2.0 - 4.0) / theta_rim

    def rim_view_angle(self) -> float:
        """View angle (rad from the optical axis) of the inner rim of the cap."""
        a = np.deg2rad(self.cap_deg)
        p = self.inner_radius_mm * np.array([np.sin(a), np.cos(a)])
        return float(np.arctan2(p[0], p[1] + self.camera_offset_mm))

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> DomeConfig:
        """Config stored in a bundle; keys added since then take the behaviour of that time."""
        legacy = {"reference_at_pressure": False}
        return cls(**{**legacy, **d})

    def reference_pressure(self, pressure_kpa: float) -> float:
        """Pressure (kPa) at which the reference frame of a frame taken at ``pressure_kpa`` was captured."""
        return float(pressure_kpa) if self.reference_at_pressure else 0.0


def fibonacci_cap(n: int, cap_deg: float) -> np.ndarray:
    """``n`` near-uniform unit directions on the spherical cap ``polar <= cap_deg`` (apex first), (n, 3)."""
    i = np.arange(n, dtype=np.float64) + 0.5
    cos_min = np.cos(np.deg2rad(cap_deg))
    z = 1.0 - i / n * (1.0 - cos_min)  # equal-area in z
    phi = i * np.pi * (3.0 - np.sqrt(5.0))
    s = np.sqrt(np.clip(1.0 - z * z, 0.0, None))
    return np.stack([s * np.cos(phi), s * np.sin(phi), z], axis=1)


def tactip_layout(rings: int, cap_deg: float) -> np.ndarray:
    """TacTip-style hexagonal ring layout: 1 centre pin + 6k pins on ring k, unit directions (n, 3).

    Ring k sits at polar angle ``k / rings * cap_deg`` (TacTip pins are spaced evenly along the dome).
    """
    dirs = [np.array([0.0, 0.0, 1.0])]
    for k in range(1, rings + 1):
        polar = np.deg2rad(cap_deg) * k / rings
        phi = np.arange(6 * k) * 2 * np.pi / (6 * k) + (0.5 if k % 2 else 0.0) * np.pi / (6 * k)
        dirs.append(
            np.stack(
                [np.sin(polar) * np.cos(phi), np.sin(polar) * np.sin(phi), np.full_like(phi, np.cos(polar))], axis=1
            )
        )
    return np.vstack([d.reshape(-1, 3) for d in dirs])


def knn_np(a: np.ndarray, b: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """k nearest rows of ``b`` for each row of ``a``: (indices (n, k), distances (n, k)), nearest first.

    Uses a k-d tree (scipy): ~40x faster than a dense distance matrix for the 331-marker graphs.
    """
    from scipy.spatial import cKDTree

    k = min(k, len(b))
    a = np.asarray(a, np.float64).reshape(len(a), -1)
    if len(a) == 0 or k == 0:
        return np.zeros((len(a), k), np.int64), np.zeros((len(a), k))
    dist, idx = cKDTree(np.asarray(b, np.float64)).query(a, k=k)
    return np.asarray(idx, np.int64).reshape(len(a), k), np.asarray(dist).reshape(len(a), k)


class DomeGeometry:
    """Templates, marker layout and camera model of one :class:`DomeConfig` (cached arrays)."""

    def __init__(self, cfg: DomeConfig | None = None) -> None:
        self.cfg = cfg or DomeConfig()
        c = self.cfg
        self.coarse_dirs = fibonacci_cap(c.n_coarse, c.cap_deg)
        self.dense_dirs = fibonacci_cap(c.n_dense, c.cap_deg)
        self.marker_dirs = tactip_layout(c.marker_rings, c.marker_cap_deg)
        #: rest positions (mm): templates on the outer surface, markers on the inner surface
        self.coarse_rest = self.coarse_dirs * c.radius_mm
        self.dense_rest = self.dense_dirs * c.radius_mm
        self.marker_rest = self.marker_dirs * c.inner_radius_mm
        self.camera_center = np.array([0.0, 0.0, -c.camera_offset_mm])
        self._faces: np.ndarray | None = None

    def reference_inflation_mm(self, pressure_kpa) -> np.ndarray:
        """Radial inflation (mm) of the reference (no-contact) state for frames at ``pressure_kpa`` (scalar or
        array): the offset from the rest templates that the nets do not have to read from the image."""
        p = np.asarray(pressure_kpa, np.float64)
        return self.cfg.inflation_mm_per_kpa * p if self.cfg.reference_at_pressure else np.zeros_like(p)

    @property
    def dense_faces(self) -> np.ndarray:
        """Triangles (m, 3) of the dense template (Delaunay of the cap seen from above; the cap is < 90 deg,
        so the projection onto the xy plane is one-to-one)."""
        if self._faces is None:
            from scipy.spatial import Delaunay

            f = Delaunay(self.dense_dirs[:, :2]).simplices
            # outward normals (+radial): orient every triangle counter-clockwise seen from outside
            a, b, c = (self.dense_dirs[f[:, i]] for i in range(3))
            flip = (np.cross(b - a, c - a) * (a + b + c)).sum(1) < 0
            f[flip] = f[flip][:, [0, 2, 1]]
            self._faces = f.astype(np.int64)
        return self._faces

    # ---- camera -------------------------------------------------------------------------------
    def project(self, p: np.ndarray) -> np.ndarray:
        """Dome-frame points (n, 3) mm -> pixels (n, 2) through the equidistant fisheye."""
        v = np.asarray(p, dtype=np.float64) - self.camera_center
        rho = np.hypot(v[:, 0], v[:, 1])
        theta = np.arctan2(rho, v[:, 2])
        r = self.cfg.focal_px * theta
        s = np.where(rho > 1e-12, r / np.maximum(rho, 1e-12), self.cfg.focal_px / np.maximum(v[:, 2], 1e-9))
        cx = cy = (self.cfg.image_size - 1) / 2.0
        return np.stack([cx + v[:, 0] * s, cy + v[:, 1] * s], axis=1)

    def backproject_to_dome(self, uv: np.ndarray, radius_mm: float | None = None) -> np.ndarray:
        """Pixels (n, 2) -> points (n, 3) mm where the view ray meets the rest sphere of ``radius_mm``."""
        radius = self.cfg.inner_radius_mm if radius_mm is None else radius_mm
        cx = cy = (self.cfg.image_size - 1) / 2.0
        du, dv = uv[:, 0] - cx, uv[:, 1] - cy
        r = np.hypot(du, dv)
        theta = r / self.cfg.focal_px
        phi = np.arctan2(dv, du)
        d = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], axis=1)
        c = self.camera_center
        # |c + t d|^2 = R^2 -> t^2 + 2 t (c.d) + |c|^2 - R^2 = 0 (camera inside the sphere: one root > 0)
        b = d @ c
        disc = np.maximum(b * b - (c @ c - radius**2), 0.0)
        t = -b + np.sqrt(disc)
        return c + t[:, None] * d
