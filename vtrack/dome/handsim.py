"""Hand-grasp simulator for the FusionTouch hand-pose network (supplementary S24-S27).

A 12-joint articulated hand holds a dome of 70 mm radius (:data:`HAND_DOME`); the camera inside the dome sees

(a) a visible-light ("RGB") image of the hand through the translucent shell: every shell point takes the skin
    colour with an opacity that falls off with its distance to the nearest hand part (``exp(-gap / 5 mm)``: the
    diffusing shell blurs and attenuates what lies behind it; a finger 2 cm off the shell is all but invisible),
    then blur, vignetting, gain and noise;
(b) the infrared marker image: every hand part that touches the shell is a spherical press
    (:class:`vtrack.dome.simulate.Press`) with a tangential drag along the closing direction of the finger, the
    marker displacements of all presses are superposed and rendered by :class:`DomeSimulator` (same renderer
    as the force / reconstruction data).

Frame: the dome frame of :mod:`vtrack.dome.model` (mm, origin at the sphere centre, +z through the apex).
The palm rests over the apex; the four fingers wrap down the +x side, the thumb down the opposite side.

Joints (degrees, :data:`JOINTS`): thumb CMC abduction (a rotation of the thumb about the shell normal at its
base) and CMC, MCP, IP flexion; MCP and PIP flexion of the index, middle, ring and little fingers (DIP
coupled to PIP by 2/3, as in human fingers). Flexion 0 = the segment continues straight, tangent to the
shell at the finger base; positive = curling towards the shell.

Grasps (:data:`GRASPS`): per sample a grasp type sets which digits touch; the touching digits take the
nominal wrap (:func:`HandModel.nominal`, segment ends 1 mm into the shell) plus a uniform per-joint
variation, lifted digits are extended by 20-30 deg. A hand yaw about the dome axis (+-8 deg) is a nuisance
the networks must not confuse with the joints.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vtrack.dome.model import DomeConfig, DomeGeometry

#: the FusionTouch-sized dome: 70 mm radius, 4 mm shell, TacTip-style 331 pins, camera 35 mm below the centre
HAND_DOME = DomeConfig(
    radius_mm=70.0,
    thickness_mm=4.0,
    cap_deg=75.0,
    marker_rings=10,
    marker_cap_deg=68.0,
    marker_radius_mm=1.9,
    camera_offset_mm=35.0,
    image_size=128,
    n_coarse=64,
    n_dense=2048,
    pressure_max_kpa=10.0,
    inflation_mm_per_kpa=0.03,
)
#: visible-light image side (px); the same fisheye as the IR camera, scaled
RGB_SIZE = 64
#: opacity fall-off (mm) of a hand part seen through the diffusing shell
GAP_SCALE_MM = 5.0
#: regressed joint angles (degrees), in output order
JOINTS = (
    "thumb_cmc_abd",
    "thumb_cmc",
    "thumb_mcp",
    "thumb_ip",
    "index_mcp",
    "index_pip",
    "middle_mcp",
    "middle_pip",
    "ring_mcp",
    "ring_pip",
    "little_mcp",
    "little_pip",
)
#: grasp type -> digits in contact (the others are lifted)
GRASPS = {
    "power": ("thumb", "index", "middle", "ring", "little"),
    "tripod": ("thumb", "index", "middle"),
    "pinch": ("thumb", "index"),
    "hook": ("index", "middle", "ring", "little"),
}
#: grasp sets (:meth:`HandModel.sample`). ``mixed``: the grasp types of :data:`GRASPS`, lifted digits
#: included (their distal joints are invisible to both cameras; a harder task than the paper's). ``contact``:
#: every digit on the shell, every fingertip pressing (>= :data:`TIP_MIN_PRESS_MM`), as in FusionTouch's data:
#: the participants grasp and deform the dome (Fig. S21), and its IR-only net reaches 99.8 % @5 deg (Table S7),
#: which a marker image cannot give for a digit that does not touch.
GRASP_SETS = ("mixed", "contact")
#: ``contact`` set: the distal phalanx of every digit presses at least this far into the shell (mm)
TIP_MIN_PRESS_MM = 0.5
#: per-joint uniform variation (deg) of a touching digit around the nominal wrap
JOINT_VAR_DEG = 5.0
HAND_YAW_DEG = 8.0
DATA_VERSION = 1


@dataclass(frozen=True)
class Digit:
    """One digit: base direction (polar, azimuth deg), outward offset of its base (mm), segment lengths (mm),
    capsule radius (mm) and the indices of its joints in :data:`JOINTS` (one per driven segment)."""

    name: str
    polar_deg: float
    azimuth_deg: float
    lengths: tuple[float, ...]
    radius: float
    joints: tuple[int, ...]


DIGITS = (
    Digit("thumb", 24.0, 150.0, (38.0, 30.0, 26.0), 10.0, (1, 2, 3)),
    Digit("index", 28.0, 24.0, (40.0, 24.0, 18.0), 8.5, (4, 5)),
    Digit("middle", 28.0, 8.0, (44.0, 28.0, 19.0), 9.0, (6, 7)),
    Digit("ring", 28.0, -8.0, (41.0, 26.0, 18.0), 8.5, (8, 9)),
    Digit("little", 28.0, -24.0, (33.0, 19.0, 16.0), 7.5, (10, 11)),
)
PALM_RADIUS = 13.0


def _unit(polar_deg: float, az_deg: float) -> np.ndarray:
    t, a = np.deg2rad(polar_deg), np.deg2rad(az_deg)
    return np.array([np.sin(t) * np.cos(a), np.sin(t) * np.sin(a), np.cos(t)])


def _rot_z(deg: float) -> np.ndarray:
    c, s = np.cos(np.deg2rad(deg)), np.sin(np.deg2rad(deg))
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _seg_point_dist(a: np.ndarray, b: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Distance (m,) from points p (m, 3) to the segment a-b; also works for a single point."""
    ab = b - a
    t = np.clip(((p - a) @ ab) / max(float(ab @ ab), 1e-12), 0.0, 1.0)
    return np.linalg.norm(p - (a + t[..., None] * ab), axis=-1)


class HandModel:
    """Forward kinematics of the 12-joint hand on a dome of radius ``radius_mm`` (mm, dome frame)."""

    def __init__(self, radius_mm: float = HAND_DOME.radius_mm) -> None:
        self.R = float(radius_mm)
        self._nominal: np.ndarray | None = None

    def _chain(self, d: Digit, q: np.ndarray, yaw_deg: float) -> list[np.ndarray]:
        """Joint positions (n_seg + 1) of digit ``d`` for the joint vector ``q`` (deg)."""
        n = _unit(d.polar_deg, d.azimuth_deg)
        base = n * (self.R + d.radius + 2.0)  # the knuckle hovers 2 mm over the shell
        u = np.array([n[2] * n[0], n[2] * n[1], -(n[0] ** 2 + n[1] ** 2)])  # outward meridian tangent
        u /= np.linalg.norm(u)
        if d.name == "thumb":  # CMC abduction: rotate the thumb plane about the normal at its base
            a = np.deg2rad(q[0])
            u = np.cos(a) * u + np.sin(a) * np.cross(n, u)
        flex = [q[j] for j in d.joints]
        if d.name != "thumb":
            flex.append(flex[-1] * 2.0 / 3.0)  # DIP follows PIP
        pts, phi, p = [base], 0.0, base
        for length, f in zip(d.lengths, flex, strict=True):
            phi += np.deg2rad(f)
            p = p + length * (np.cos(phi) * u - np.sin(phi) * n)
            pts.append(p)
        rz = _rot_z(yaw_deg)
        return [rz @ x for x in pts]

    def capsules(self, q: np.ndarray, yaw_deg: float = 0.0) -> list[tuple[np.ndarray, np.ndarray, float, str]]:
        """Hand parts as capsules (a, b, radius mm, digit): 14 phalanges + the palm (segments between the
        digit bases and a centre over the apex)."""
        out = []
        bases = []
        for d in DIGITS:
            pts = self._chain(d, q, yaw_deg)
            bases.append(pts[0])
            out += [(pts[i], pts[i + 1], d.radius, d.name) for i in range(len(pts) - 1)]
        centre = _rot_z(yaw_deg) @ (_unit(6.0, 180.0) * (self.R + PALM_RADIUS + 5.0))
        for b in bases:
            # pull the palm end of the base up so the palm hovers (only digits press the shell)
            lift = b / np.linalg.norm(b) * (self.R + PALM_RADIUS + 5.0)
            out.append((centre, lift, PALM_RADIUS, "palm"))
        return out

    def nominal(self) -> np.ndarray:
        """Joint vector (deg) of the wrap grasp: every segment end 1 mm into the shell (found by bisection,
        joint by joint along each digit); thumb abduction 0."""
        if self._nominal is not None:
            return self._nominal
        q = np.zeros(len(JOINTS))
        for d in DIGITS:
            for k, j in enumerate(d.joints):
                last = k == len(d.joints) - 1

                def end_gap(f: float, d=d, j=j, k=k, last=last) -> float:
                    qq = q.copy()
                    qq[j] = f
                    pts = self._chain(d, qq, 0.0)
                    end = pts[-1] if last else pts[k + 1]
                    return float(np.linalg.norm(end)) - (self.R + d.radius - 1.0)

                lo, hi = -30.0, 120.0
                for _ in range(50):  # end_gap decreases with flexion over this bracket
                    mid = 0.5 * (lo + hi)
                    lo, hi = (mid, hi) if end_gap(mid) > 0 else (lo, mid)
                q[j] = 0.5 * (lo + hi)
        self._nominal = q
        return q

    def tip_press_mm(self, d: Digit, q: np.ndarray) -> float:
        """How far (mm) the distal phalanx of digit ``d`` reaches into the shell (negative: off the shell).
        Hand yaw is a rotation about the dome axis and does not change it."""
        pts = self._chain(d, q, 0.0)
        a, b = pts[-2], pts[-1]
        ab = b - a
        t = float(np.clip(-(a @ ab) / max(float(ab @ ab), 1e-12), 0.0, 1.0))
        return self.R + d.radius - float(np.linalg.norm(a + t * ab))

    def sample(self, rng: np.random.Generator, grasp_set: str = "mixed") -> tuple[np.ndarray, float, str]:
        """A random grasp of ``grasp_set`` (:data:`GRASP_SETS`): joint vector (deg), hand yaw (deg), grasp type.

        ``contact``: the power grasp with every fingertip on the shell: each digit's joints are drawn around the
        nominal wrap as for a touching digit (+- :data:`JOINT_VAR_DEG`), redrawn until its distal phalanx presses
        >= :data:`TIP_MIN_PRESS_MM` into the shell (rejection sampling per digit, so the variation stays uniform
        over the joint box that keeps the tip down)."""
        if grasp_set not in GRASP_SETS:
            raise ValueError(f"unknown grasp set {grasp_set!r} ({', '.join(GRASP_SETS)})")
        if grasp_set == "contact":
            q = self.nominal().copy()
            q[0] += rng.uniform(-JOINT_VAR_DEG, JOINT_VAR_DEG)  # thumb abduction
            for d in DIGITS:
                for _ in range(1000):
                    q[list(d.joints)] = self.nominal()[list(d.joints)] + rng.uniform(
                        -JOINT_VAR_DEG, JOINT_VAR_DEG, len(d.joints)
                    )
                    if self.tip_press_mm(d, q) >= TIP_MIN_PRESS_MM:
                        break
            return q, float(rng.uniform(-HAND_YAW_DEG, HAND_YAW_DEG)), "power"
        grasp = str(rng.choice(list(GRASPS)))
        q = self.nominal() + rng.uniform(-JOINT_VAR_DEG, JOINT_VAR_DEG, len(JOINTS))
        for d in DIGITS:
            if d.name not in GRASPS[grasp]:
                for j in d.joints:
                    q[j] -= rng.uniform(20.0, 30.0)
        return q, float(rng.uniform(-HAND_YAW_DEG, HAND_YAW_DEG)), grasp


class HandDomeSimulator:
    """Render (RGB, IR) image pairs of the hand holding the dome."""

    def __init__(self, cfg: DomeConfig = HAND_DOME, rgb_size: int = RGB_SIZE, grasp_set: str = "mixed") -> None:
        from vtrack.dome.simulate import DomeSimulator

        if grasp_set not in GRASP_SETS:
            raise ValueError(f"unknown grasp set {grasp_set!r} ({', '.join(GRASP_SETS)})")
        self.grasp_set = grasp_set
        self.cfg = cfg
        self.sim = DomeSimulator(cfg)
        self.hand = HandModel(cfg.radius_mm)
        # RGB camera: same fisheye scaled to rgb_size; shell points seen by every pixel (outer surface)
        rcfg = DomeConfig(**{**cfg.to_dict(), "image_size": rgb_size})
        geo = DomeGeometry(rcfg)
        yy, xx = np.mgrid[0:rgb_size, 0:rgb_size]
        uv = np.stack([xx.ravel(), yy.ravel()], 1).astype(np.float64)
        theta = np.hypot(uv[:, 0] - (rgb_size - 1) / 2, uv[:, 1] - (rgb_size - 1) / 2) / rcfg.focal_px
        self._shell = geo.backproject_to_dome(uv, cfg.radius_mm)
        polar = np.arccos(np.clip(self._shell[:, 2] / cfg.radius_mm, -1, 1))
        self._inside = (polar <= np.deg2rad(cfg.cap_deg)) & (theta < np.pi / 2)
        rr = np.hypot(xx - (rgb_size - 1) / 2, yy - (rgb_size - 1) / 2) / (rgb_size / 2)
        self._vign = (1.0 - 0.3 * rr**2).ravel()
        self.rgb_size = rgb_size

    def presses(self, caps: list, rng: np.random.Generator) -> list:
        """Spherical presses (depth mm) where phalanges meet the shell, with a drag along the closing
        direction of the digit (friction of the grip, 0.25 mm per mm of depth, +-noise)."""
        from vtrack.dome.simulate import Press, _tangent_basis

        R = self.cfg.radius_mm
        out = []
        for a, b, r, name in caps:
            if name == "palm":
                continue
            ab = b - a
            t = float(np.clip(-(a @ ab) / max(float(ab @ ab), 1e-12), 0.0, 1.0))
            c = a + t * ab
            pen = R + r - float(np.linalg.norm(c))
            if pen <= 0:
                continue
            n = c / np.linalg.norm(c)
            e1, e2 = _tangent_basis(n)
            drag = -(ab - (ab @ n) * n)  # the pad pulls the skin back towards the palm as the grip closes
            drag = drag / max(float(np.linalg.norm(drag)), 1e-9) * 0.25 * min(pen, 6.0)
            shear = np.array([drag @ e1, drag @ e2]) * rng.uniform(0.8, 1.2)
            out.append(Press("sphere", n, min(pen, 6.0), r, 0.0, shear, 0.0))
        return out

    def render_rgb(self, caps: list, rng: np.random.Generator, noise: float = 1.0) -> np.ndarray:
        """(S, S, 3) uint8 visible-light image: hand silhouette through the translucent shell."""
        import cv2

        p = self._shell
        clear = np.ones(len(p))
        for a, b, r, _ in caps:
            gap = np.clip(_seg_point_dist(a, b, p) - r, 0.0, None)
            clear *= 1.0 - 0.92 * np.exp(-gap / GAP_SCALE_MM)
        alpha = 1.0 - clear
        bg = np.array([0.70, 0.74, 0.78]) * (rng.uniform(0.85, 1.1) if noise > 0 else 1.0)
        skin = np.array([0.78, 0.52, 0.42]) * (rng.uniform(0.85, 1.1) if noise > 0 else 1.0) * 0.6
        img = (clear[:, None] * bg + alpha[:, None] * skin) * self._vign[:, None]
        img[~self._inside] = 0.02
        S = self.rgb_size
        img = cv2.GaussianBlur(img.reshape(S, S, 3).astype(np.float32), (0, 0), 0.8)
        if noise > 0:
            img = img + rng.normal(0.0, 0.015 * noise, img.shape)
        return np.clip(img * 255, 0, 255).astype(np.uint8)

    def render_ir(self, caps: list, rng: np.random.Generator, noise: float = 1.0) -> np.ndarray:
        """(S, S) uint8 infrared marker image with the contact deformations of all touching phalanges."""
        disp = np.zeros_like(self.sim.geo.marker_rest)
        for pr in self.presses(caps, rng):
            disp += self.sim.deform(pr)["disp_markers"]
        return self.sim.render(self.sim.geo.marker_rest + disp, rng, noise=noise)

    def sample(self, rng: np.random.Generator, noise: float = 1.0) -> dict:
        q, yaw, grasp = self.hand.sample(rng, self.grasp_set)
        caps = self.hand.capsules(q, yaw)
        return {
            "rgb": self.render_rgb(caps, rng, noise),
            "ir": self.render_ir(caps, rng, noise),
            "angles_deg": q.astype(np.float32),
            "yaw_deg": np.float32(yaw),
            "grasp": grasp,
            "n_contacts": np.int32(len(self.presses(caps, np.random.default_rng(0)))),
        }

    def ir_reference(self) -> np.ndarray:
        """No-contact, noise-free IR frame (the sensor's reference)."""
        return self.sim.reference_image(0.0)


def handpose_dataset_path(n: int, seed: int, grasp_set: str = "mixed") -> Path:
    from vtrack.paths import cache_dir

    key = {"n": n, "seed": seed, "cfg": HAND_DOME.to_dict(), "rgb": RGB_SIZE, "v": DATA_VERSION}
    if grasp_set != "mixed":  # the mixed set keeps its original cache key
        key["grasp_set"] = grasp_set
    h = hashlib.sha1(json.dumps(key, sort_keys=True).encode()).hexdigest()[:10]
    return cache_dir() / "dome" / f"handpose_{n}_{seed}_{h}.npz"


def make_handpose_dataset(
    n: int, seed: int, *, cache: bool = True, progress: bool = False, grasp_set: str = "mixed"
) -> dict[str, np.ndarray]:
    """``n`` simulated grasps stacked into arrays (cached .npz in ``vtrack.paths.cache_dir()``): ``rgb``
    (n, 64, 64, 3), ``ir`` (n, 128, 128) uint8, ``angles_deg`` (n, 12), ``yaw_deg``, ``grasp``, ``n_contacts``
    and ``ir_reference`` (128, 128). ``grasp_set``: :data:`GRASP_SETS`."""
    path = handpose_dataset_path(n, seed, grasp_set)
    if cache and path.exists():
        with np.load(path) as z:
            return {k: z[k] for k in z.files}
    sim = HandDomeSimulator(grasp_set=grasp_set)
    rng = np.random.default_rng(seed)
    out: dict[str, list] = {}
    for i in range(n):
        for k, v in sim.sample(rng).items():
            out.setdefault(k, []).append(v)
        if progress and (i + 1) % 500 == 0:
            print(f"[handpose simulate] {i + 1}/{n}", flush=True)
    arrs = {k: np.stack(v) if k != "grasp" else np.array(v) for k, v in out.items()}
    arrs["ir_reference"] = sim.ir_reference()
    if cache:
        from vtrack.io.jsonio import atomic_savez

        atomic_savez(path, **arrs)
    return arrs
