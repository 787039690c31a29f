"""Data side of the tactile generator (numpy/OpenCV only): contact masks and poses, the rigid warp of a
reference contact, indenter height maps, and the simulated + real training pairs.

Frames and units: images are uint8 BGR ``(H, W, 3)`` as ``cv2.imread`` returns them; a colour change
("delta") is ``image - background`` in float32 grey levels. A contact pose ``(x, y, theta)`` is the
footprint's centroid in pixels (x = column, y = row) and its in-plane orientation in degrees (image
frame, measured from +x towards +y). Depths are indentations into the gel in mm.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from vtrack.errors import InputError

#: Side (px) of the network's square working crop: a window around the TARGET contact (half-size
#: :data:`CROP_K` times the footprint's largest radius) is resampled to it, so every contact reaches the
#: network at the same scale whatever the sensor resolution, and the net only spends time where the
#: image changes.
CROP_PX = 64
CROP_K = 2.2
#: Edge ramp of the reference's contact window (equivalent radii) for the generator's patch.
FEATHER = 0.5
#: The reference's colour change is smoothed (Gaussian, sigma = footprint radius / DENOISE_DIV px) before it
#: is moved: its camera/JPEG noise is not the target's, so copying it only adds error (on the real held-out
#: presses this alone lifts the shift's crop SSIM from 0.950 to 0.962; reported as its own row).
DENOISE_DIV = 35.0
#: Grey-level scale of the network's colour-change inputs/outputs.
DELTA_SCALE = 64.0
#: Below this peak colour change (grey levels, after a light blur) a reference shows no contact.
MIN_CONTACT_DELTA = 12.0
#: A reference contact footprint needs at least this fraction of the frame's pixels.
MIN_CONTACT_FRAC = 2e-4
#: Assumed effective modulus of the gel for the force proxy (MPa = N/mm^2): Hertz contact of a rigid
#: sphere on an elastomer with E ~ 0.25 MPa, Poisson 0.5 (E* = E / (1 - nu^2)). A stated assumption, not
#: a measured property: no press set here records force.
GEL_EFFECTIVE_MODULUS_MPA = 0.33


# ----------------------------------------------------------------------------------------------- force proxy
def hertz_force_n(depth_mm: float, radius_mm: float, e_star_mpa: float = GEL_EFFECTIVE_MODULUS_MPA) -> float:
    """Normal force (N) of a rigid sphere of ``radius_mm`` pressed ``depth_mm`` into the gel (Hertz:
    ``F = 4/3 E* sqrt(R) d^1.5``)."""
    return float(4.0 / 3.0 * e_star_mpa * math.sqrt(radius_mm) * max(depth_mm, 0.0) ** 1.5)


def hertz_depth_mm(force_n: float, radius_mm: float, e_star_mpa: float = GEL_EFFECTIVE_MODULUS_MPA) -> float:
    """Inverse of :func:`hertz_force_n`: indentation (mm) of a sphere under ``force_n`` N."""
    if not (np.isfinite(force_n) and force_n >= 0):
        raise InputError("force must be a finite non-negative number", field="force", expected=">= 0 N", got=force_n)
    return float((3.0 * force_n / (4.0 * e_star_mpa * math.sqrt(radius_mm))) ** (2.0 / 3.0))


# ----------------------------------------------------------------------------------------------- masks / poses
@dataclass(frozen=True)
class Pose:
    """In-plane contact pose: centroid (px, x = column, y = row) and orientation (deg)."""

    x: float
    y: float
    theta_deg: float = 0.0


def mask_pose(mask: np.ndarray) -> Pose:
    """Centroid and principal-axis orientation (deg, 0 for a near-isotropic footprint) of a binary mask."""
    m = np.asarray(mask) > 0
    ys, xs = np.nonzero(m)
    if xs.size == 0:
        raise InputError("contact mask is empty", field="mask", expected="a non-empty footprint")
    cx, cy = float(xs.mean()), float(ys.mean())
    dx, dy = xs - cx, ys - cy
    mu20, mu02, mu11 = float((dx * dx).mean()), float((dy * dy).mean()), float((dx * dy).mean())
    aniso = math.hypot(mu20 - mu02, 2 * mu11) / max(mu20 + mu02, 1e-9)
    theta = 0.5 * math.degrees(math.atan2(2 * mu11, mu20 - mu02)) if aniso > 0.1 else 0.0
    return Pose(cx, cy, theta)


def disc_mask(shape_hw: tuple[int, int], centre_xy: tuple[float, float], radius_px: float) -> np.ndarray:
    """uint8 {0, 1} disc of ``radius_px`` at ``centre_xy`` (px)."""
    H, W = shape_hw
    yy, xx = np.mgrid[0:H, 0:W]
    return (((xx - centre_xy[0]) ** 2 + (yy - centre_xy[1]) ** 2) <= radius_px**2).astype(np.uint8)


def detect_contact(image: np.ndarray, background: np.ndarray, path: object = None) -> np.ndarray:
    """Contact footprint (uint8 {0, 1}) of a tactile image against its no-contact background.

    Threshold of the blurred colour-change magnitude at half its peak, largest connected component, holes
    filled. Raises :class:`InputError` when the image shows no contact (peak change below
    :data:`MIN_CONTACT_DELTA` grey levels or a footprint below :data:`MIN_CONTACT_FRAC` of the frame).
    """
    import cv2

    img, bg = np.asarray(image), np.asarray(background)
    if img.shape != bg.shape or img.ndim != 3 or img.shape[2] != 3:
        raise InputError(
            "reference and background must be BGR images of the same size",
            path=path,
            field="background",
            expected=str(img.shape),
            got=bg.shape,
        )
    d = np.abs(img.astype(np.float32) - bg.astype(np.float32)).sum(2)
    sigma = max(1.0, 0.004 * max(img.shape[:2]))
    d = cv2.GaussianBlur(d, (0, 0), sigma)
    peak = float(d.max())
    if peak < MIN_CONTACT_DELTA:
        raise InputError(
            "reference image shows no contact (no colour change against the background)",
            path=path,
            field="reference",
            expected=f"a press with a colour change >= {MIN_CONTACT_DELTA:g} grey levels",
            got=f"peak change {peak:.1f}",
        )
    m = (d > 0.5 * peak).astype(np.uint8)
    n, lab, stats, _ = cv2.connectedComponentsWithStats(m, connectivity=8)
    k = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    m = (lab == k).astype(np.uint8)
    # fill holes (the centre of a flat press changes colour less than its rim)
    cnts, _ = cv2.findContours(m, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    m = cv2.drawContours(np.zeros_like(m), cnts, -1, 1, thickness=-1)
    if m.sum() < MIN_CONTACT_FRAC * m.size:
        raise InputError(
            "reference image shows no contact (footprint too small)",
            path=path,
            field="reference",
            expected=f">= {MIN_CONTACT_FRAC * m.size:.0f} px of contact",
            got=int(m.sum()),
        )
    return m


def check_mask(mask: np.ndarray, shape_hw: tuple[int, int], path: object = None) -> np.ndarray:
    """Validate a target contact mask: same size as the sensor image, non-empty, centroid inside the gel."""
    m = (np.asarray(mask) > 0).astype(np.uint8)
    if m.ndim == 3:
        m = m.max(2)
    if m.shape != tuple(shape_hw):
        raise InputError(
            "mask size differs from the reference", path=path, field="mask", expected=str(shape_hw), got=m.shape
        )
    if m.sum() == 0:
        raise InputError(
            "target mask is empty or outside the gel", path=path, field="mask", expected="a footprint on the gel"
        )
    return m


def relative_transform(ref: Pose, target: Pose) -> np.ndarray:
    """2x3 affine (px) that moves the reference contact to the target pose: rotate by the orientation
    difference about the reference centroid, then translate the centroid onto the target's."""
    a = math.radians(target.theta_deg - ref.theta_deg)
    c, s = math.cos(a), math.sin(a)
    R = np.array([[c, -s], [s, c]])
    t = np.array([target.x, target.y]) - R @ np.array([ref.x, ref.y])
    return np.hstack([R, t[:, None]]).astype(np.float32)


def check_pose_in_gel(pose: Pose, shape_hw: tuple[int, int], field: str = "position") -> None:
    H, W = shape_hw
    if not (np.isfinite([pose.x, pose.y, pose.theta_deg]).all() and 0 <= pose.x < W and 0 <= pose.y < H):
        raise InputError(
            "target contact position outside the gel",
            field=field,
            expected=f"x in [0, {W}), y in [0, {H})",
            got=(pose.x, pose.y),
        )


def contact_window(mask: np.ndarray, k: float = 1.0, feather: float = 0.0) -> np.ndarray:
    """float32 window in [0, 1]: the footprint dilated by ``k`` equivalent radii (the part of the reference's
    colour change that belongs to the contact; the rest is camera noise). ``feather`` > 0 ramps the edge
    linearly over that many equivalent radii (centred on the hard edge) so a moved patch leaves no seam."""
    import cv2

    m = (np.asarray(mask) > 0).astype(np.uint8)
    r_eq = math.sqrt(max(float(m.sum()), 1.0) / math.pi)
    dist = cv2.distanceTransform(1 - m, cv2.DIST_L2, 5)
    if feather <= 0:
        return (dist <= k * r_eq).astype(np.float32)
    f = feather * r_eq
    return np.clip((k * r_eq + f / 2 - dist) / f, 0.0, 1.0).astype(np.float32)


def warp(img: np.ndarray, M: np.ndarray, shape_hw: tuple[int, int] | None = None) -> np.ndarray:
    """``cv2.warpAffine`` with zero border (linear for float images, nearest for masks)."""
    import cv2

    H, W = shape_hw if shape_hw is not None else img.shape[:2]
    interp = cv2.INTER_NEAREST if img.dtype == np.uint8 else cv2.INTER_LINEAR
    return cv2.warpAffine(img, M, (W, H), flags=interp, borderMode=cv2.BORDER_CONSTANT, borderValue=0)


def scale_affine(M: np.ndarray, s: float) -> np.ndarray:
    """The same rigid motion expressed in an image scaled by ``s`` (pixel coordinates times s)."""
    out = M.copy()
    out[:, 2] *= s
    return out


def footprint_radius(mask: np.ndarray, pose: Pose) -> float:
    """Largest distance (px) of a footprint pixel from the pose centroid (>= 2 px)."""
    ys, xs = np.nonzero(np.asarray(mask) > 0)
    if xs.size == 0:
        return 2.0
    return float(max(2.0, np.sqrt(((xs - pose.x) ** 2 + (ys - pose.y) ** 2).max()) + 0.5))


def crop_affine(target: Pose, radius_px: float) -> np.ndarray:
    """2x3 affine from full-frame px to the :data:`CROP_PX` crop centred on the target contact."""
    hs = CROP_K * radius_px
    c = CROP_PX / (2.0 * hs)
    return np.array([[c, 0, CROP_PX / 2 - c * target.x], [0, c, CROP_PX / 2 - c * target.y]], np.float32)


def compose_affine(A: np.ndarray, M: np.ndarray) -> np.ndarray:
    """``A o M`` of two 2x3 affines."""
    A3 = np.vstack([A, [0, 0, 1]])
    M3 = np.vstack([M, [0, 0, 1]])
    return (A3 @ M3)[:2].astype(np.float32)


def crop_coords(A: np.ndarray, shape_hw: tuple[int, int]) -> np.ndarray:
    """(2, CROP_PX, CROP_PX) float32 full-frame coordinates of the crop pixels, normalised to [-1, 1]."""
    H, W = shape_hw
    Ainv = np.vstack([A, [0, 0, 1]])
    Ainv = np.linalg.inv(Ainv)
    u = np.arange(CROP_PX, dtype=np.float32)
    U, V = np.meshgrid(u, u)
    X = Ainv[0, 0] * U + Ainv[0, 1] * V + Ainv[0, 2]
    Y = Ainv[1, 0] * U + Ainv[1, 1] * V + Ainv[1, 2]
    return np.stack([2 * X / W - 1, 2 * Y / H - 1]).astype(np.float32)


def crop_inputs(
    ref_patch: np.ndarray,
    ref_mask: np.ndarray,
    ref_pose: Pose,
    target_pose: Pose,
    radius_px: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Network image input (6, CROP_PX, CROP_PX) float32, the crop affine A (full -> crop) and the rigid
    motion M (ref -> target, full-frame px).

    Channels: the reference patch (:func:`reference_patch`) moved onto the target pose
    (/ :data:`DELTA_SCALE`), the moved footprint (the target mask), and the crop pixels' full-frame
    coordinates in [-1, 1] (x, y).
    """
    import cv2

    M = relative_transform(ref_pose, target_pose)
    A = crop_affine(target_pose, radius_px)
    AM = compose_affine(A, M)
    size = (CROP_PX, CROP_PX)
    al = cv2.warpAffine(ref_patch, AM, size, flags=cv2.INTER_AREA if AM[0, 0] < 1 else cv2.INTER_LINEAR)
    mk = cv2.warpAffine(ref_mask.astype(np.float32), AM, size, flags=cv2.INTER_LINEAR)
    x = np.concatenate([al.transpose(2, 0, 1) / DELTA_SCALE, mk[None], crop_coords(A, ref_mask.shape[:2])])
    return x.astype(np.float32), A, M


def reference_patch(
    ref_delta: np.ndarray, ref_window: np.ndarray, radius_px: float, denoise: bool = True
) -> np.ndarray:
    """The reference's colour change inside its contact window (float32 (H, W, 3)), smoothed with
    sigma = ``radius_px`` / :data:`DENOISE_DIV` when ``denoise`` (only the window's bounding box is filtered)."""
    import cv2

    src = np.asarray(ref_delta, np.float32) * np.asarray(ref_window, np.float32)[..., None]
    if not denoise:
        return np.ascontiguousarray(src)
    ys, xs = np.nonzero(np.asarray(ref_window) > 0)
    if xs.size == 0:
        return np.ascontiguousarray(src)
    sig = radius_px / DENOISE_DIV
    pad = int(3 * sig) + 1
    r0, r1 = max(0, ys.min() - pad), ys.max() + pad + 1
    c0, c1 = max(0, xs.min() - pad), xs.max() + pad + 1
    src = np.ascontiguousarray(src)
    src[r0:r1, c0:c1] = cv2.GaussianBlur(src[r0:r1, c0:c1], (0, 0), sig)
    return src


def crop_taper() -> np.ndarray:
    """(CROP_PX, CROP_PX, 1) float32 taper of the correction: 1 inside 80 % of the crop's half-size, falling
    linearly to 0 at its border, so the correction field leaves no square seam in the frame."""
    u = np.abs(np.linspace(-1, 1, CROP_PX, dtype=np.float32))
    t = np.clip((1.0 - u) / 0.2, 0.0, 1.0)
    return (t[:, None] * t[None, :])[..., None]


def crop_target(target_delta: np.ndarray, A: np.ndarray) -> np.ndarray:
    """(3, CROP_PX, CROP_PX) float32 target colour change in the crop (/ :data:`DELTA_SCALE`)."""
    import cv2

    t = cv2.warpAffine(np.asarray(target_delta, np.float32), A, (CROP_PX, CROP_PX), flags=cv2.INTER_LINEAR)
    return (t.transpose(2, 0, 1) / DELTA_SCALE).astype(np.float32)


# ----------------------------------------------------------------------------------------------- indenters
#: Simulated indenters: name -> kind and size (mm). Spheres of several radii, a cylinder lying on the gel,
#: a cross and a T (flat-topped bars with rounded edges).
INDENTERS: dict[str, dict] = {
    "sphere_1.5": {"kind": "sphere", "r": 1.5},
    "sphere_2": {"kind": "sphere", "r": 2.0},
    "sphere_3": {"kind": "sphere", "r": 3.0},
    "sphere_4": {"kind": "sphere", "r": 4.0},
    "cylinder": {"kind": "cylinder", "r": 2.0, "length": 7.0},
    "cross": {"kind": "cross", "width": 1.4, "arm": 5.0},
    "tshape": {"kind": "tshape", "width": 1.4, "arm": 5.0},
}


def indenter_height(name: str, shape_hw: tuple[int, int], pose: Pose, depth_mm: float, mm_per_px: float) -> np.ndarray:
    """Indentation (mm, float32 (H, W)) of indenter ``name`` at ``pose`` pressed ``depth_mm`` into the gel."""
    import cv2

    spec = INDENTERS[name]
    H, W = shape_hw
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float32)
    a = math.radians(pose.theta_deg)
    u = ((xx - pose.x) * math.cos(a) + (yy - pose.y) * math.sin(a)) * mm_per_px  # along the indenter axis
    v = (-(xx - pose.x) * math.sin(a) + (yy - pose.y) * math.cos(a)) * mm_per_px  # across it
    kind = spec["kind"]
    if kind == "sphere":
        R = spec["r"]
        h = np.sqrt(np.clip(R**2 - u * u - v * v, 0, None)) - (R - depth_mm)
    elif kind == "cylinder":
        R, L = spec["r"], spec["length"]
        h = np.sqrt(np.clip(R**2 - v * v, 0, None)) - (R - depth_mm)
        h = np.where(np.abs(u) <= L / 2, h, 0.0)
    else:
        w, arm = spec["width"], spec["arm"]
        if kind == "cross":
            fp = ((np.abs(u) <= arm / 2) & (np.abs(v) <= w / 2)) | ((np.abs(v) <= arm / 2) & (np.abs(u) <= w / 2))
        else:  # T: a bar along u on top, a stem along v below its middle; centred on its bounding box
            fp = ((np.abs(u) <= arm / 2) & (np.abs(v + arm / 2 - w / 2) <= w / 2)) | (
                (np.abs(u) <= w / 2) & (v >= -arm / 2) & (v <= arm / 2)
            )
        # flat top with rounded edges: the gel wraps the indenter's edge over ~0.3 mm
        sm = cv2.GaussianBlur(fp.astype(np.float32), (0, 0), 0.3 / mm_per_px)
        h = depth_mm * np.clip(1.6 * sm - 0.3, 0, 1)
    return np.clip(h, 0, None).astype(np.float32)


#: Indentation (mm) above which a pixel belongs to an indenter's footprint (:func:`indenter_mask`).
FOOTPRINT_MIN_MM = 0.02


def indenter_mask(name: str, shape_hw: tuple[int, int], pose: Pose, depth_mm: float, mm_per_px: float) -> np.ndarray:
    """uint8 {0, 1} footprint of a known indenter at a labelled pose and depth: the mask the generator was
    trained with (indentation > :data:`FOOTPRINT_MIN_MM`). Use it with that label as ``ref_pose`` so the
    reference's mask and pose agree (a mask detected from the image can miss the contact's dim parts)."""
    return (indenter_height(name, shape_hw, pose, depth_mm, mm_per_px) > FOOTPRINT_MIN_MM).astype(np.uint8)


# ----------------------------------------------------------------------------------------------- data sets
@dataclass
class PressBank:
    """Presses at full resolution (lists: sim and real frames differ in size), grouped so that pairs share
    the indenter and the sensor unit.

    Attributes:
        delta: per press (H, W, 3) int16 colour change (grey levels).
        mask, window: per press (H, W) uint8 footprint and its feathered contact window (float16,
            :func:`contact_window`).
        pose: (N, 3) x, y (px), theta (deg).
        radius: (N,) footprint radius (px, :func:`footprint_radius`).
        depth: (N,) mm.
        group: (N,) int: presses of the same indenter on the same sensor unit (pairs are drawn within one).
        site: (N,) int: presses at the same pose of the same group share a site (stage-1 pairs).
        real: (N,) bool.
    """

    delta: list
    mask: list
    window: list
    pose: np.ndarray
    radius: np.ndarray
    depth: np.ndarray
    group: np.ndarray
    site: np.ndarray
    real: np.ndarray

    def __len__(self) -> int:
        return len(self.depth)

    @staticmethod
    def build(deltas, masks, poses, depths, groups, sites, real: bool) -> PressBank:
        poses = [Pose(*map(float, p)) for p in poses]
        return PressBank(
            [np.clip(np.rint(d), -32768, 32767).astype(np.int16) for d in deltas],
            [m.astype(np.uint8) for m in masks],
            [contact_window(m, feather=FEATHER).astype(np.float16) for m in masks],
            np.array([(p.x, p.y, p.theta_deg) for p in poses], np.float32),
            np.array([footprint_radius(m, p) for m, p in zip(masks, poses, strict=True)], np.float32),
            np.array(depths, np.float32),
            np.array(groups, int),
            np.array(sites, int),
            np.full(len(depths), real),
        )

    @staticmethod
    def concat(banks: list[PressBank]) -> PressBank:
        out, g_off, s_off = [], 0, 0
        for b in banks:
            out.append((b, g_off, s_off))
            g_off += int(b.group.max()) + 1 if len(b) else 0
            s_off += int(b.site.max()) + 1 if len(b) else 0
        return PressBank(
            [d for b in banks for d in b.delta],
            [m for b in banks for m in b.mask],
            [w for b in banks for w in b.window],
            np.concatenate([b.pose for b in banks]),
            np.concatenate([b.radius for b in banks]),
            np.concatenate([b.depth for b in banks]),
            np.concatenate([b.group + g for b, g, _ in out]),
            np.concatenate([b.site + s for b, _, s in out]),
            np.concatenate([b.real for b in banks]),
        )


def sim_bank(
    background: np.ndarray,
    mm_per_px: float,
    *,
    units: int = 2,
    poses: int = 10,
    depths: int = 4,
    seed: int = 0,
    indenters: tuple[str, ...] | None = None,
) -> PressBank:
    """Render simulated presses with the independent optical model (:mod:`vtrack.sim.tactile_optics`, GelSight
    preset jittered per unit) on a real no-contact ``background`` (BGR, pitch ``mm_per_px``).

    Per unit and indenter: ``poses`` random poses, each pressed at ``depths`` random depths (a site).
    """
    from vtrack.sim.tactile_optics import OpticalModel

    rng = np.random.default_rng(seed)
    H, W = background.shape[:2]
    names = indenters or tuple(INDENTERS)
    D, Mk, P, Dp, G, S = [], [], [], [], [], []
    g = site = 0
    bgf = background.astype(np.float32)
    for unit in range(units):
        model = OpticalModel.for_sensor("gelsight", seed=1000 + unit)
        for name in names:
            spec = INDENTERS[name]
            dmax = 0.8 * spec["r"] if spec["kind"] == "sphere" else 1.5
            for _ in range(poses):
                m = 0.2 * min(H, W)
                pose = Pose(float(rng.uniform(m, W - m)), float(rng.uniform(m, H - m)), float(rng.uniform(0, 180)))
                for d in np.sort(rng.uniform(0.15, dmax, depths)):
                    h = indenter_height(name, (H, W), pose, float(d), mm_per_px)
                    img = model.render(h, mm_per_px, background, rng, noise=1.0)
                    D.append(img.astype(np.float32) - bgf)
                    Mk.append((h > FOOTPRINT_MIN_MM).astype(np.uint8))
                    P.append((pose.x, pose.y, pose.theta_deg))
                    Dp.append(float(d))
                    G.append(g)
                    S.append(site)
                site += 1
            g += 1
    return PressBank.build(D, Mk, P, Dp, G, S, real=False)


def real_bank(ps, presses: list) -> PressBank:
    """Labelled real ball presses (one group; each press its own site). Depth from the labelled contact
    radius through the ball geometry; footprint = the labelled circle."""
    from vtrack.sim.presses import press_depth_mm

    bg = ps.background().astype(np.float32)
    H, W = bg.shape[:2]
    D, Mk, P, Dp = [], [], [], []
    for p in presses:
        D.append(ps.image(p).astype(np.float32) - bg)
        Mk.append(disc_mask((H, W), p.center_xy_px, p.contact_radius_px))
        P.append((p.center_xy_px[0], p.center_xy_px[1], 0.0))
        Dp.append(press_depth_mm(ps.ball_radius_mm, p.contact_radius_px * ps.mm_per_px))
    n = len(presses)
    return PressBank.build(D, Mk, P, Dp, [0] * n, list(range(n)), real=True)


def pair_arrays(bank: PressBank, pairs: np.ndarray) -> dict[str, np.ndarray]:
    """Network inputs/targets of ``pairs`` ((K, 2) indices: reference, target) drawn from ``bank``."""
    X, T, C, Q = [], [], [], []
    for i, j in pairs:
        pr, pt = Pose(*map(float, bank.pose[i])), Pose(*map(float, bank.pose[j]))
        patch = reference_patch(bank.delta[i], bank.window[i], float(bank.radius[i]))
        x, A, _ = crop_inputs(patch, bank.mask[i], pr, pt, float(bank.radius[i]))
        X.append(x)
        T.append(crop_target(bank.delta[j], A))
        C.append(cond_vector(float(bank.depth[i]), float(bank.depth[j])))
        Q.append(pose_vector(pr, pt, bank.mask[i].shape[:2]))
    return {"x": np.stack(X), "target": np.stack(T), "cond": np.stack(C), "pose": np.stack(Q)}


def cond_vector(ref_depth_mm: float, target_depth_mm: float) -> np.ndarray:
    """Force/depth condition: reference depth, target depth and their difference (mm; the paper conditions on
    the relative force, we also give the absolute levels)."""
    return np.array([ref_depth_mm, target_depth_mm, target_depth_mm - ref_depth_mm], np.float32)


def pose_vector(ref_pose: Pose, target_pose: Pose, shape_hw: tuple[int, int]) -> np.ndarray:
    """Position condition: target centroid in [-1, 1], displacement (fraction of the frame), rotation / 180."""
    H, W = shape_hw
    return np.array(
        [
            2 * target_pose.x / W - 1,
            2 * target_pose.y / H - 1,
            (target_pose.x - ref_pose.x) / W,
            (target_pose.y - ref_pose.y) / H,
            _wrap_deg(target_pose.theta_deg - ref_pose.theta_deg) / 180.0,
        ],
        np.float32,
    )


def _wrap_deg(d: float) -> float:
    return (d + 180.0) % 360.0 - 180.0
