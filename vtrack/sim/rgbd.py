"""RGB-D rendering of the object and the hand by ray casting, with a structured-light/ToF-like
depth noise model.

Geometry: one ray per pixel through the pixel centre (OpenCV pinhole; ray direction has camera-z
component 1, so the hit parameter *is* the z-depth in metres). The object is cast in its own frame
(static BVH), the hand in the world frame (BVH rebuilt per frame from decimated link meshes); the
nearer hit wins, which gives hand occlusion and the object mask.

Noise model (``depth_noise`` scales all of it; 0 = exact depth, quantised to the depth unit):
- axial noise ``sigma(z) = 0.0012 + 0.0019 (z - 0.4)^2`` m (Nguyen et al. 2012, Kinect-class
  sensors; RealSense D4xx at 0.3-0.6 m is similar);
- dropouts at grazing angles: a pixel is lost with probability rising from 0 at
  ``cos(incidence) = 0.35`` to 1 at ``cos = 0.1``;
- dropouts on depth edges (> 1 cm jump to a 4-neighbour) with probability 0.5, plus 0.2 % speckle.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vtrack.geometry.raycast import Raycaster

#: Sensor-noise constants (m) of the axial model above.
AXIAL_A = 0.0012
AXIAL_B = 0.0019
AXIAL_Z0 = 0.4


@dataclass
class RenderedFrame:
    depth_m: np.ndarray  # (H, W) float64, 0 = no return (before noise)
    object_mask: np.ndarray  # (H, W) bool, object is the first surface
    object_unoccluded: np.ndarray  # (H, W) bool, object would be seen without the hand
    normal: np.ndarray  # (H, W, 3) world unit normals of the first surface
    cos_incidence: np.ndarray  # (H, W) |cos| between the ray and the normal
    kind: np.ndarray  # (H, W) int8: 0 none, 1 object, 2 hand
    points_obj: np.ndarray  # (H, W, 3) object-frame hit points (valid where object_mask)


def render_geometry(
    rays_cam: np.ndarray,
    T_world_camera: np.ndarray,
    obj_rc: Raycaster,
    T_world_object: np.ndarray,
    hand_rc: Raycaster | None,
    depth_max: float,
    window: tuple[int, int, int, int] | None = None,
) -> RenderedFrame:
    """Cast ``rays_cam`` (H, W, 3), z = 1 per ray, from the camera against the object and the hand.

    ``window`` = (r0, r1, c0, c1) casts only that pixel block (the rest is background), e.g. the
    projected bounding box of the object and the hand.
    """
    if window is not None:
        r0, r1, c0, c1 = window
        H, W, _ = rays_cam.shape
        sub = render_geometry(rays_cam[r0:r1, c0:c1], T_world_camera, obj_rc, T_world_object, hand_rc, depth_max)
        full = RenderedFrame(
            np.zeros((H, W)),
            np.zeros((H, W), bool),
            np.zeros((H, W), bool),
            np.zeros((H, W, 3)),
            np.zeros((H, W)),
            np.zeros((H, W), np.int8),
            np.zeros((H, W, 3)),
        )
        for f in ("depth_m", "object_mask", "object_unoccluded", "normal", "cos_incidence", "kind", "points_obj"):
            getattr(full, f)[r0:r1, c0:c1] = getattr(sub, f)
        return full
    H, W, _ = rays_cam.shape
    R_wc, t_wc = T_world_camera[:3, :3], T_world_camera[:3, 3]
    d_world = rays_cam @ R_wc.T
    T_ow = np.linalg.inv(T_world_object)
    o_obj = T_ow[:3, :3] @ t_wc + T_ow[:3, 3]
    d_obj = d_world @ T_ow[:3, :3].T
    ho = obj_rc.cast(np.broadcast_to(o_obj, d_obj.shape), d_obj)
    t_obj = np.where(ho["t"] <= depth_max, ho["t"], np.inf)
    if hand_rc is not None:
        hh = hand_rc.cast(np.broadcast_to(t_wc, d_world.shape), d_world)
        t_hand = np.where(hh["t"] <= depth_max, hh["t"], np.inf)
    else:
        hh = None
        t_hand = np.full((H, W), np.inf)
    obj_first = np.isfinite(t_obj) & (t_obj <= t_hand)
    hand_first = np.isfinite(t_hand) & ~obj_first
    depth = np.where(obj_first, t_obj, np.where(hand_first, t_hand, 0.0))
    n_obj_world = ho["normal"] @ T_world_object[:3, :3].T
    normal = np.zeros((H, W, 3))
    normal[obj_first] = n_obj_world[obj_first]
    if hh is not None:
        normal[hand_first] = hh["normal"][hand_first]
    du = d_world / np.linalg.norm(d_world, axis=-1, keepdims=True)
    cos_inc = np.abs(np.einsum("hwi,hwi->hw", du, normal))
    kind = np.zeros((H, W), np.int8)
    kind[obj_first] = 1
    kind[hand_first] = 2
    pts_obj = o_obj + d_obj * np.where(np.isfinite(t_obj), t_obj, 0.0)[..., None]
    return RenderedFrame(depth, obj_first, np.isfinite(t_obj), normal, cos_inc, kind, pts_obj)


def add_depth_noise(depth_m: np.ndarray, cos_inc: np.ndarray, rng: np.random.Generator, scale: float) -> np.ndarray:
    """Noisy depth (m, 0 = missing) from exact depth, following the module's noise model."""
    if scale <= 0:
        return depth_m.copy()
    valid = depth_m > 0
    sigma = (AXIAL_A + AXIAL_B * (depth_m - AXIAL_Z0) ** 2) * scale
    out = np.where(valid, depth_m + rng.normal(0.0, 1.0, depth_m.shape) * sigma, 0.0)
    p_graze = np.clip((0.35 - cos_inc) / 0.25, 0.0, 1.0) * min(scale, 1.0)
    edge = np.zeros_like(valid)
    dz = np.abs(np.diff(depth_m, axis=0)) > 0.01
    edge[:-1] |= dz
    edge[1:] |= dz
    dx = np.abs(np.diff(depth_m, axis=1)) > 0.01
    edge[:, :-1] |= dx
    edge[:, 1:] |= dx
    p_drop = np.maximum(p_graze, 0.5 * edge * min(scale, 1.0)) + 0.002 * min(scale, 1.0)
    drop = rng.random(depth_m.shape) < p_drop
    return np.where(valid & ~drop & (out > 0), out, 0.0)


def _albedo_object(points_obj: np.ndarray, base_rgb: np.ndarray) -> np.ndarray:
    """Object colour with a smooth procedural pattern fixed in the object frame (gives texture)."""
    p = points_obj * 60.0
    pattern = 0.75 + 0.25 * np.sin(p[..., 0] + 2 * np.sin(p[..., 1])) * np.cos(p[..., 2] * 1.3)
    return base_rgb * pattern[..., None]


def shade_rgb(fr: RenderedFrame, object_rgb: np.ndarray, rng: np.random.Generator, noise: float = 2.0) -> np.ndarray:
    """uint8 sRGB image: Lambertian + ambient lighting with a head light and a key light."""
    H, W = fr.kind.shape
    key = np.array([0.3, -0.4, 0.85])
    key /= np.linalg.norm(key)
    n = fr.normal
    lam = 0.55 * fr.cos_incidence + 0.35 * np.clip(np.abs(n @ key), 0.0, 1.0) + 0.15
    img = np.empty((H, W, 3))
    # Background: a dim vertical gradient (a wall/table far away, no depth return).
    g = np.linspace(70.0, 45.0, H)[:, None, None]
    img[:] = g * np.array([1.0, 1.0, 1.1])
    obj = fr.kind == 1
    hand = fr.kind == 2
    img[obj] = _albedo_object(fr.points_obj[obj], object_rgb) * lam[obj, None]
    img[hand] = np.array([48.0, 48.0, 52.0]) * lam[hand, None] * 1.6
    if noise > 0:
        img += rng.normal(0.0, noise, img.shape)
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)


def object_colour(name: str) -> np.ndarray:
    """A stable, name-dependent base colour (RGB, 0-255) for objects without texture."""
    import zlib

    h = zlib.crc32(name.encode())
    palette = np.array(
        [[200, 50, 40], [220, 190, 40], [60, 120, 200], [70, 160, 80], [200, 120, 60], [180, 180, 170], [140, 80, 160]],
        dtype=np.float64,
    )
    return palette[h % len(palette)]


def projected_window(
    K, T_world_camera: np.ndarray, points_world: np.ndarray, width: int, height: int, margin: int = 6
) -> tuple[int, int, int, int] | None:
    """Pixel block (r0, r1, c0, c1) covering the projection of ``points_world`` (None: nothing in view
    or a point behind the camera, i.e. no safe bound: cast the whole image)."""
    T_cw = np.linalg.inv(T_world_camera)
    pc = points_world @ T_cw[:3, :3].T + T_cw[:3, 3]
    if len(pc) == 0:
        return None
    if np.any(pc[:, 2] <= 1e-3):
        return (0, height, 0, width)
    u = K[0, 0] * pc[:, 0] / pc[:, 2] + K[0, 2]
    v = K[1, 1] * pc[:, 1] / pc[:, 2] + K[1, 2]
    c0 = int(np.clip(np.floor(u.min()) - margin, 0, width))
    c1 = int(np.clip(np.ceil(u.max()) + margin + 1, 0, width))
    r0 = int(np.clip(np.floor(v.min()) - margin, 0, height))
    r1 = int(np.clip(np.ceil(v.max()) + margin + 1, 0, height))
    if r1 <= r0 or c1 <= c0:
        return None
    return (r0, r1, c0, c1)
