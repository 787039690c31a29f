"""Hand-grasp simulator for the FusionTouch hand-pose network (supplementary S24-S27).

A 12-joint articulated hand holds a dome of 70 mm radius (:data:`HAND_DOME`); the camera inside the dome sees

(a) a visible-light ("RGB") image of the hand through the translucent shell. Two image models
    (:data:`RGB_MODELS`, :func:`rgb_model`): ``opacity`` (the ``mixed`` / ``contact`` sets and their nets): every
    shell point takes the skin colour with an opacity that falls off with its distance to the nearest hand part
    (``exp(-gap / 5 mm)``), one flat skin colour; ``haze`` (the ``varied`` set, the default task): each camera ray
    is traced through the shell to the first hand surface it meets (depth ``d`` along the ray, surface normal),
    the skin is lit by the dome's inner light (Lambert shading per link, irradiance falling with ``d``), and the
    diffusing shell spreads the light from a surface ``d`` mm behind it over a disc that grows with ``d``
    (Gaussian, sigma = ``d`` x :data:`HAZE_TAN`): a fingertip on the shell is sharp, a phalanx 2 cm off it is a
    soft, darker smudge. Then vignetting, lens blur, gain and noise (same draws in both models);
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
from dataclasses import dataclass, replace
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
#: the hand-pose sensor of the ``varied`` set (the default task): the same dome with markers over the whole visible
#: cap the fingertips reach (74 deg polar, 11 rings = 397 pins at the same ~6.7 deg spacing), as a real FusionTouch
#: dome has markers over its whole surface. :data:`HAND_DOME` (markers to 68 deg) stays the sensor of the ``mixed``
#: and ``contact`` sets and of their nets (``weights/handpose.pt``). Only the hand-pose simulation uses either;
#: the force / reconstruction dome (:class:`DomeConfig` defaults, 20 mm) and its nets are untouched.
HAND_DOME_FULL = replace(HAND_DOME, marker_rings=11, marker_cap_deg=74.0)
#: visible-light image side (px); the same fisheye as the IR camera, scaled
RGB_SIZE = 64
#: opacity fall-off (mm) of a hand part seen through the diffusing shell (``opacity`` image model)
GAP_SCALE_MM = 5.0
#: visible-light image models (:meth:`HandDomeSimulator.render_rgb`): ``opacity`` (flat skin colour, opacity
#: ``exp(-gap / GAP_SCALE_MM)`` of the distance field) and ``haze`` (ray-traced depth and shading, blur growing
#: with the distance of each surface from the shell)
RGB_MODELS = ("opacity", "haze")
#: ``haze``: tan of the angular spread (1 sigma) of the light the shell passes on: a surface ``d`` mm behind the
#: shell is blurred on it with sigma ``d * HAZE_TAN`` mm (~19 deg; a hazy, not milky, shell: the paper's coating
#: keeps the visible transmittance "relatively high", Fig. S6, and the hand is observed through it, S-Text 1)
HAZE_TAN = 0.35
#: ``haze``: the inner light reaching the skin falls as ``1 / (1 + d / HAZE_LIGHT_MM)^2`` with its distance d (mm)
#: from the shell (the lit inner surface is an extended source of about this size)
HAZE_LIGHT_MM = 20.0
#: ``haze``: share of the skin's radiance that does not depend on its orientation (inter-reflections)
HAZE_AMBIENT = 0.25
#: ``haze``: depth layers (mm along the ray) rendered with one blur each
HAZE_DEPTH_EDGES_MM = (0.0, 0.5, 2.0, 4.0, 7.0, 11.0, 16.0, 22.0, 30.0, 42.0, 60.0, 1e9)
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
#: ``varied`` (:meth:`HandModel.sample_varied`): the hand placed at random over the dome, each fingertip drawn on the
#: visible shell (pressing or hovering a few mm over it), joints solved by inverse kinematics: every digit in
#: view of the inner camera with a realistic joint spread (the paper's task; the default of ``vtrack dome handpose``).
GRASP_SETS = ("mixed", "contact", "varied")
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
FINGERS = ("index", "middle", "ring", "little")

# ``varied`` grasp set (:meth:`HandModel.sample_varied`): the hand placed anywhere over the apex region, every
# fingertip on or a few mm above the visible shell, joints solved by inverse kinematics onto the tip targets
#: hand turn about the dome axis (deg, +-)
VARIED_YAW_DEG = 20.0
#: hand tilt about the x / y axes through the sphere centre (deg, +-): the palm slides off the apex
VARIED_TILT_DEG = (8.0, 12.0)
#: knuckle (and palm) height over the shell (mm): a flat hand rests on the dome, a claw holds it from above
VARIED_LIFT_MM = (1.0, 8.0)
#: finger spread per gap between neighbouring fingers (deg) and each finger's own abduction (+- deg)
VARIED_SPREAD_DEG = (-2.0, 5.0)
VARIED_FINGER_ABD_DEG = 3.0
#: thumb CMC abduction (+- deg, a regressed joint)
VARIED_THUMB_ABD_DEG = 20.0
#: thumb IP flexion = ratio x thumb MCP flexion (the thumb's redundant degree of freedom, drawn per grasp)
VARIED_THUMB_IP_RATIO = (0.5, 1.5)
#: fingertip target: great-circle arc (deg) from the digit's base along its (abducted) plane
VARIED_ARC_DEG = (20.0, 60.0)
#: share of fingertips pressing the shell; the others hover over it
VARIED_P_CONTACT = 0.75
#: fingertip press depth into the shell / hover gap over it (mm, of the tip's capsule end)
VARIED_PRESS_MM = (0.5, 2.5)
VARIED_HOVER_MM = (1.0, 5.0)
#: fingertips stay where the inner camera sees them (polar angle, deg; the shell cap is 75 deg)
VARIED_TIP_MAX_POLAR_DEG = 74.0
#: no phalanx may sink deeper than this into the shell (mm; the shell is 4 mm thick)
VARIED_MAX_PEN_MM = 4.0
#: joint limits (deg): proximal (finger MCP, thumb CMC) and distal (finger PIP, thumb MCP and IP)
PROX_LIMITS_DEG = (-30.0, 95.0)
DIST_LIMITS_DEG = (0.0, 110.0)


def rgb_model(grasp_set: str) -> str:
    """Visible-light image model of a grasp set (:data:`RGB_MODELS`): ``haze`` for ``varied`` (the default task),
    ``opacity`` for ``mixed`` / ``contact`` (their cached simulations and shipped nets keep the model they had)."""
    if grasp_set not in GRASP_SETS:
        raise ValueError(f"unknown grasp set {grasp_set!r} ({', '.join(GRASP_SETS)})")
    return "haze" if grasp_set == "varied" else "opacity"


def _ray_capsules(o: np.ndarray, v: np.ndarray, caps: list) -> tuple[np.ndarray, np.ndarray]:
    """First hit of rays ``o + t v`` (P, 3; unit ``v``) with the capsules ``caps`` (a, b, radius, name): distance
    ``t`` (P,) in mm (0 where the ray starts inside a capsule, inf where it hits nothing) and the outward surface
    normal at the hit (P, 3). Analytic ray-capsule intersection (cylinder body, then the end spheres)."""
    A = np.stack([c[0] for c in caps])[None]  # (1, C, 3)
    B = np.stack([c[1] for c in caps])[None]
    r = np.array([c[2] for c in caps])[None]  # (1, C)
    ba = B - A
    oa = o[:, None] - A  # (P, C, 3)
    vv = v[:, None]
    L2 = (ba * ba).sum(-1)
    bard = (ba * vv).sum(-1)
    baoa = (ba * oa).sum(-1)
    rdoa = (vv * oa).sum(-1)
    oaoa = (oa * oa).sum(-1)
    qa = np.maximum(L2 - bard * bard, 1e-9)
    qb = L2 * rdoa - baoa * bard
    qc = L2 * oaoa - baoa * baoa - r * r * L2
    h = qb * qb - qa * qc
    with np.errstate(invalid="ignore"):
        tb = (-qb - np.sqrt(h)) / qa
    yb = baoa + tb * bard
    t = np.where((h >= 0) & (yb > 0) & (yb < L2), tb, np.inf)
    for end in (A, B):  # the end spheres (where the body was missed or hit beyond its ends)
        oc = o[:, None] - end
        b2 = (vv * oc).sum(-1)
        h2 = b2 * b2 - ((oc * oc).sum(-1) - r * r)
        with np.errstate(invalid="ignore"):
            ts = -b2 - np.sqrt(h2)
        t = np.where((h2 >= 0) & np.isinf(t), ts, np.minimum(t, np.where(h2 >= 0, ts, np.inf)))
    # inside a capsule at the ray start (a pressing phalanx): depth 0
    tt = np.clip((oa * ba).sum(-1) / np.maximum(L2, 1e-12), 0.0, 1.0)
    inside = (np.linalg.norm(oa - tt[..., None] * ba, axis=-1) < r).any(1)
    t = np.where(t > 0, t, np.inf)
    k = np.argmin(t, 1)
    d = t[np.arange(len(o)), k]
    d = np.where(inside, 0.0, d)
    x = o + np.where(np.isfinite(d), d, 0.0)[:, None] * v
    a, ab = A[0, k], ba[0, k]
    s = np.clip(((x - a) * ab).sum(-1) / np.maximum((ab * ab).sum(-1), 1e-12), 0.0, 1.0)
    n = x - (a + s[:, None] * ab)
    n = n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-9)
    n = np.where(inside[:, None], -v, n)  # skin flattened on the shell faces the camera
    return d, n


def sensor_config(grasp_set: str) -> DomeConfig:
    """The hand-pose sensor a grasp set is simulated with: :data:`HAND_DOME_FULL` for ``varied``, else
    :data:`HAND_DOME` (the sets' cached simulations and shipped nets keep their marker layout)."""
    if grasp_set not in GRASP_SETS:
        raise ValueError(f"unknown grasp set {grasp_set!r} ({', '.join(GRASP_SETS)})")
    return HAND_DOME_FULL if grasp_set == "varied" else HAND_DOME


def _unit(polar_deg: float, az_deg: float) -> np.ndarray:
    t, a = np.deg2rad(polar_deg), np.deg2rad(az_deg)
    return np.array([np.sin(t) * np.cos(a), np.sin(t) * np.sin(a), np.cos(t)])


def _rot_z(deg: float) -> np.ndarray:
    c, s = np.cos(np.deg2rad(deg)), np.sin(np.deg2rad(deg))
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _rot_x(deg: float) -> np.ndarray:
    c, s = np.cos(np.deg2rad(deg)), np.sin(np.deg2rad(deg))
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _rot_y(deg: float) -> np.ndarray:
    c, s = np.cos(np.deg2rad(deg)), np.sin(np.deg2rad(deg))
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def _seg_point_dist(a: np.ndarray, b: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Distance (m,) from points p (m, 3) to the segment a-b; also works for a single point."""
    ab = b - a
    t = np.clip(((p - a) @ ab) / max(float(ab @ ab), 1e-12), 0.0, 1.0)
    return np.linalg.norm(p - (a + t[..., None] * ab), axis=-1)


@dataclass(frozen=True)
class HandPlace:
    """Placement of the hand on the dome (``varied`` set): a rotation about the sphere centre (yaw about the
    dome axis, tilts about x and y, deg), the knuckles' height over the shell (mm), and the abduction of the
    four fingers (deg, rotation of each finger's flexion plane about the shell normal at its base; nuisances,
    not regressed)."""

    yaw_deg: float = 0.0
    tilt_x_deg: float = 0.0
    tilt_y_deg: float = 0.0
    lift_mm: float = 2.0
    finger_abd_deg: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)

    def matrix(self) -> np.ndarray:
        return _rot_z(self.yaw_deg) @ _rot_y(self.tilt_y_deg) @ _rot_x(self.tilt_x_deg)

    def to_array(self) -> np.ndarray:
        return np.array([self.yaw_deg, self.tilt_x_deg, self.tilt_y_deg, self.lift_mm, *self.finger_abd_deg])

    @classmethod
    def from_array(cls, a: np.ndarray) -> HandPlace:
        a = [float(x) for x in np.asarray(a).ravel()]
        return cls(a[0], a[1], a[2], a[3], tuple(a[4:8]))


def _planar_ik(lengths: tuple[float, ...], couple: float, x: float, y: float) -> tuple[float, float] | None:
    """Two-angle inverse kinematics of a planar three-segment chain whose third joint is ``couple`` x the
    second (finger DIP = 2/3 PIP; thumb IP = ratio x MCP). Angles (deg) flex from +x towards +y; returns the
    (first, second) joint angles putting the chain end at (x, y), the second within :data:`DIST_LIMITS_DEG`,
    or None when out of reach. The reach |end| falls monotonically with the second angle over that range, so
    a grid bracket + bisection finds the unique solution."""
    l1, l2, l3 = lengths

    def end(t2: float) -> np.ndarray:
        return np.array(
            [l1 + l2 * np.cos(t2) + l3 * np.cos((1 + couple) * t2), l2 * np.sin(t2) + l3 * np.sin((1 + couple) * t2)]
        )

    d = float(np.hypot(x, y))
    lo, hi = np.deg2rad(DIST_LIMITS_DEG[0]), np.deg2rad(DIST_LIMITS_DEG[1])
    reach = lambda t: float(np.linalg.norm(end(t))) - d  # noqa: E731
    if reach(lo) < 0 or reach(hi) > 0:
        return None
    for _ in range(50):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if reach(mid) > 0 else (lo, mid)
    t2 = 0.5 * (lo + hi)
    v = end(t2)
    t1 = np.arctan2(y, x) - np.arctan2(v[1], v[0])
    t1 = (t1 + np.pi) % (2 * np.pi) - np.pi
    return float(np.rad2deg(t1)), float(np.rad2deg(t2))


class HandModel:
    """Forward kinematics of the 12-joint hand on a dome of radius ``radius_mm`` (mm, dome frame)."""

    def __init__(self, radius_mm: float = HAND_DOME.radius_mm) -> None:
        self.R = float(radius_mm)
        self._nominal: np.ndarray | None = None

    def _chain(self, d: Digit, q: np.ndarray, yaw_deg: float, place: HandPlace | None = None) -> list[np.ndarray]:
        """Joint positions (n_seg + 1) of digit ``d`` for the joint vector ``q`` (deg). ``place``: hand placement
        on the dome (:class:`HandPlace`; None = the fixed placement of the ``mixed`` / ``contact`` sets, turned by
        ``yaw_deg`` about the dome axis)."""
        n = _unit(d.polar_deg, d.azimuth_deg)
        lift = 2.0 if place is None else place.lift_mm
        base = n * (self.R + d.radius + lift)  # the knuckle hovers ``lift`` mm over the shell
        u = np.array([n[2] * n[0], n[2] * n[1], -(n[0] ** 2 + n[1] ** 2)])  # outward meridian tangent
        u /= np.linalg.norm(u)
        if d.name == "thumb":  # CMC abduction: rotate the thumb plane about the normal at its base
            abd = q[0]
        else:  # finger abduction: a nuisance of the varied set (not regressed; the 12 joints are flexions)
            abd = 0.0 if place is None else place.finger_abd_deg[FINGERS.index(d.name)]
        if abd:
            a = np.deg2rad(abd)
            u = np.cos(a) * u + np.sin(a) * np.cross(n, u)
        flex = [q[j] for j in d.joints]
        if d.name != "thumb":
            flex.append(flex[-1] * 2.0 / 3.0)  # DIP follows PIP
        pts, phi, p = [base], 0.0, base
        for length, f in zip(d.lengths, flex, strict=True):
            phi += np.deg2rad(f)
            p = p + length * (np.cos(phi) * u - np.sin(phi) * n)
            pts.append(p)
        rot = _rot_z(yaw_deg) if place is None else place.matrix()
        return [rot @ x for x in pts]

    def capsules(
        self, q: np.ndarray, yaw_deg: float = 0.0, place: HandPlace | None = None
    ) -> list[tuple[np.ndarray, np.ndarray, float, str]]:
        """Hand parts as capsules (a, b, radius mm, digit): 14 phalanges + the palm (segments between the
        digit bases and a centre over the apex). ``place`` as in :meth:`_chain` (``yaw_deg`` is then ignored)."""
        out = []
        bases = []
        for d in DIGITS:
            pts = self._chain(d, q, yaw_deg, place)
            bases.append(pts[0])
            out += [(pts[i], pts[i + 1], d.radius, d.name) for i in range(len(pts) - 1)]
        lift = 0.0 if place is None else place.lift_mm - 2.0  # the palm rises with the knuckles
        rot = _rot_z(yaw_deg) if place is None else place.matrix()
        centre = rot @ (_unit(6.0, 180.0) * (self.R + PALM_RADIUS + 5.0 + lift))
        for b in bases:
            # pull the palm end of the base up so the palm hovers (only digits press the shell)
            top = b / np.linalg.norm(b) * (self.R + PALM_RADIUS + 5.0 + lift)
            out.append((centre, top, PALM_RADIUS, "palm"))
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

    def tip_target(self, d: Digit, arc_deg: float, offset_mm: float, q: np.ndarray, place: HandPlace) -> np.ndarray:
        """Dome-frame point (mm) ``arc_deg`` along the great circle from digit ``d``'s base in its flexion plane
        (the plane holds the sphere centre, so the arc stays in it), at ``offset_mm`` over the radius where the
        tip's capsule touches the shell (``R + radius``; negative = pressed in)."""
        pts0 = self._chain(d, np.where(np.arange(len(q)) == 0, q, 0.0), 0.0, place)  # straight digit
        rot = place.matrix()
        n = rot @ _unit(d.polar_deg, d.azimuth_deg)
        u = pts0[1] - pts0[0]
        u = u - (u @ n) * n
        u /= np.linalg.norm(u)
        a = np.deg2rad(arc_deg)
        return (self.R + d.radius + offset_mm) * (np.cos(a) * n + np.sin(a) * u)

    def digit_ik(
        self, d: Digit, target: np.ndarray, q: np.ndarray, place: HandPlace, couple: float = 2.0 / 3.0
    ) -> np.ndarray | None:
        """Joint vector ``q`` with digit ``d``'s flexions solved so that its tip (end of the distal phalanx) sits
        at ``target`` (dome frame, mm; must lie in the digit's flexion plane, as :meth:`tip_target` gives):
        fingers solve MCP and PIP (DIP = 2/3 PIP), the thumb CMC and MCP with IP = ``couple`` x MCP (its
        abduction ``q[0]`` is given). None when out of reach or beyond :data:`PROX_LIMITS_DEG`."""
        pts0 = self._chain(d, np.where(np.arange(len(q)) == 0, q, 0.0), 0.0, place)
        base = pts0[0]
        u = pts0[1] - base
        u /= np.linalg.norm(u)
        n = base / np.linalg.norm(base)
        rel = np.asarray(target, np.float64) - base
        sol = _planar_ik(d.lengths, couple if d.name == "thumb" else 2.0 / 3.0, float(rel @ u), float(-(rel @ n)))
        if sol is None or not PROX_LIMITS_DEG[0] <= sol[0] <= PROX_LIMITS_DEG[1]:
            return None
        out = np.array(q, np.float64, copy=True)
        out[d.joints[0]], out[d.joints[1]] = sol
        if d.name == "thumb":
            out[d.joints[2]] = couple * sol[1]
        return out

    def digit_penetration_mm(self, d: Digit, q: np.ndarray, place: HandPlace | None = None) -> float:
        """Deepest reach (mm) of any phalanx of digit ``d`` into the shell (negative: the gap to it)."""
        pts = self._chain(d, q, 0.0, place)
        pen = -np.inf
        for a, b in zip(pts[:-1], pts[1:], strict=True):
            ab = b - a
            t = float(np.clip(-(a @ ab) / max(float(ab @ ab), 1e-12), 0.0, 1.0))
            pen = max(pen, self.R + d.radius - float(np.linalg.norm(a + t * ab)))
        return float(pen)

    def sample_varied(self, rng: np.random.Generator) -> tuple[np.ndarray, HandPlace, np.ndarray]:
        """A grasp of the ``varied`` set: joint vector (deg), placement, and which digits touch the shell (5,).

        The hand is placed at random (:data:`VARIED_YAW_DEG`, :data:`VARIED_TILT_DEG`, :data:`VARIED_LIFT_MM`,
        finger spread / abduction); then, digit by digit, a fingertip target is drawn on the sphere
        (:data:`VARIED_ARC_DEG` from the base along the digit's plane; pressed in by :data:`VARIED_PRESS_MM`
        with probability :data:`VARIED_P_CONTACT`, else hovering :data:`VARIED_HOVER_MM` over the shell) and the
        digit's flexions are solved by :meth:`digit_ik`. A target is redrawn when the solution breaks a joint
        limit, the tip leaves the visible cap (:data:`VARIED_TIP_MAX_POLAR_DEG`), a phalanx sinks more than
        :data:`VARIED_MAX_PEN_MM` into the shell, a hovering digit touches it, or the tip comes within a
        capsule radius of its neighbour's."""
        for _ in range(100):
            spread = rng.uniform(*VARIED_SPREAD_DEG)
            abd = tuple(
                float(spread * k + rng.uniform(-VARIED_FINGER_ABD_DEG, VARIED_FINGER_ABD_DEG))
                for k in (1.5, 0.5, -0.5, -1.5)
            )
            place = HandPlace(
                float(rng.uniform(-VARIED_YAW_DEG, VARIED_YAW_DEG)),
                float(rng.uniform(-VARIED_TILT_DEG[0], VARIED_TILT_DEG[0])),
                float(rng.uniform(-VARIED_TILT_DEG[1], VARIED_TILT_DEG[1])),
                float(rng.uniform(*VARIED_LIFT_MM)),
                abd,
            )
            q = np.zeros(len(JOINTS))
            q[0] = rng.uniform(-VARIED_THUMB_ABD_DEG, VARIED_THUMB_ABD_DEG)
            touch = np.zeros(len(DIGITS), bool)
            tips: list[np.ndarray] = []
            for i, d in enumerate(DIGITS):
                for _ in range(60):
                    contact = rng.random() < VARIED_P_CONTACT
                    off = -rng.uniform(*VARIED_PRESS_MM) if contact else rng.uniform(*VARIED_HOVER_MM)
                    target = self.tip_target(d, rng.uniform(*VARIED_ARC_DEG), off, q, place)
                    ratio = rng.uniform(*VARIED_THUMB_IP_RATIO)
                    qq = self.digit_ik(d, target, q, place, ratio)
                    if qq is None or any(not DIST_LIMITS_DEG[0] <= qq[j] <= DIST_LIMITS_DEG[1] for j in d.joints[1:]):
                        continue
                    if np.degrees(np.arccos(np.clip(target[2] / np.linalg.norm(target), -1, 1))) > (
                        VARIED_TIP_MAX_POLAR_DEG
                    ):
                        continue
                    pen = self.digit_penetration_mm(d, qq, place)
                    if pen > VARIED_MAX_PEN_MM or (not contact and pen > 0):
                        continue
                    tip = self._chain(d, qq, 0.0, place)[-1]
                    if i > 1 and np.linalg.norm(tip - tips[-1]) < d.radius + DIGITS[i - 1].radius:
                        continue
                    q, touch[i] = qq, pen > 0
                    tips.append(tip)
                    break
                else:
                    break  # this placement leaves a digit without a valid target: place the hand anew
            else:
                return q, place, touch
        raise RuntimeError("no valid varied grasp in 100 placements")  # not reached with the shipped ranges

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

    def __init__(
        self,
        cfg: DomeConfig | None = None,
        rgb_size: int = RGB_SIZE,
        grasp_set: str = "mixed",
        rgb_model_name: str | None = None,
    ) -> None:
        """``cfg``: the sensor (default :func:`sensor_config` of ``grasp_set``); ``rgb_model_name``: the
        visible-light image model (:data:`RGB_MODELS`, default :func:`rgb_model` of ``grasp_set``)."""
        from vtrack.dome.simulate import DomeSimulator

        cfg = sensor_config(grasp_set) if cfg is None else cfg
        self.rgb_model = rgb_model(grasp_set) if rgb_model_name is None else rgb_model_name
        if self.rgb_model not in RGB_MODELS:
            raise ValueError(f"unknown RGB model {self.rgb_model!r} ({', '.join(RGB_MODELS)})")
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
        # ``haze``: camera rays through the shell points (unit, dome frame) and the shell's size of one pixel (mm)
        ray = self._shell - geo.camera_center
        self._ray = ray / np.linalg.norm(ray, axis=1, keepdims=True)
        grid = self._shell.reshape(rgb_size, rgb_size, 3)
        ins = self._inside.reshape(rgb_size, rgb_size)
        step = np.linalg.norm(np.diff(grid, axis=1), axis=-1)[ins[:, 1:] & ins[:, :-1]]
        self._mm_per_px = float(np.median(step))

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
        """(S, S, 3) uint8 visible-light image of the hand through the translucent shell, by the simulator's
        image model (:data:`RGB_MODELS`). Both models draw the same random numbers (background and skin gains,
        pixel noise), so the IR frames drawn after them are the same whichever model renders the RGB image."""
        g_bg = rng.uniform(0.85, 1.1) if noise > 0 else 1.0
        g_skin = rng.uniform(0.85, 1.1) if noise > 0 else 1.0
        img = self.rgb_float(caps, g_bg, g_skin)
        if noise > 0:
            img = img + rng.normal(0.0, 0.015 * noise, img.shape)
        return np.clip(img * 255, 0, 255).astype(np.uint8)

    def rgb_float(self, caps: list, bg_gain: float = 1.0, skin_gain: float = 1.0) -> np.ndarray:
        """(S, S, 3) float32 noise-free visible-light image (full scale 1, before pixel noise and 8-bit
        quantisation) with the given room-light and skin gains (:meth:`render_rgb` draws them in 0.85-1.1)."""
        import cv2

        bg = np.array([0.70, 0.74, 0.78]) * bg_gain
        skin = np.array([0.78, 0.52, 0.42]) * skin_gain * 0.6
        S = self.rgb_size
        if self.rgb_model == "haze":
            img = self._haze_image(caps, bg, skin)
        else:
            p = self._shell
            clear = np.ones(len(p))
            for a, b, r, _ in caps:
                gap = np.clip(_seg_point_dist(a, b, p) - r, 0.0, None)
                clear *= 1.0 - 0.92 * np.exp(-gap / GAP_SCALE_MM)
            alpha = 1.0 - clear
            img = clear[:, None] * bg + alpha[:, None] * skin
        img = img * self._vign[:, None]
        img[~self._inside] = 0.02
        return cv2.GaussianBlur(img.reshape(S, S, 3).astype(np.float32), (0, 0), 0.8)

    def _haze_image(self, caps: list, bg: np.ndarray, skin: np.ndarray) -> np.ndarray:
        """(S * S, 3) radiance on the shell of the ``haze`` model (before vignetting, lens blur and noise).

        Each pixel's ray leaves the shell point and meets the first hand surface at depth ``d`` (mm; 0 where a
        phalanx presses the shell). That skin is lit by the dome's inner light: radiance ``skin * (HAZE_AMBIENT +
        (1 - HAZE_AMBIENT) cos) / (1 + d / HAZE_LIGHT_MM)^2`` with ``cos`` between its normal and the ray (per-link
        shading). The shell passes that light on through a cone of spread :data:`HAZE_TAN`: per depth layer
        (:data:`HAZE_DEPTH_EDGES_MM`) the layer's radiance and coverage are blurred with sigma ``d * HAZE_TAN``
        (mm on the shell, in px) and composited over the room light ``bg`` seen where no hand covers the view."""
        import cv2

        S = self.rgb_size
        inside = self._inside
        d = np.full(S * S, np.inf)
        cosang = np.zeros(S * S)
        dd, n = _ray_capsules(self._shell[inside], self._ray[inside], caps)
        d[inside] = dd
        cosang[inside] = np.clip(-(n * self._ray[inside]).sum(1), 0.0, 1.0)
        hit = np.isfinite(d)
        shade = np.where(
            hit, (HAZE_AMBIENT + (1 - HAZE_AMBIENT) * cosang) / (1 + np.where(hit, d, 0) / HAZE_LIGHT_MM) ** 2, 0
        )
        rad = (shade[:, None] * skin[None]).reshape(S, S, 3).astype(np.float32)
        acc = np.zeros((S, S, 3), np.float32)
        cover = np.zeros((S, S), np.float32)
        e = HAZE_DEPTH_EDGES_MM
        for lo, hi in zip(e[:-1], e[1:], strict=True):
            m = (hit & (d >= lo) & (d < hi)).reshape(S, S)
            if not m.any():
                continue
            sig = max(0.5 * (lo + min(hi, 2 * e[-2] - e[-3])) * HAZE_TAN / self._mm_per_px, 0.3)
            mf = m.astype(np.float32)
            acc += cv2.GaussianBlur(rad * mf[..., None], (0, 0), sig)
            cover += cv2.GaussianBlur(mf, (0, 0), sig)
        scale = 1.0 / np.maximum(cover, 1.0)  # layers overlapping after the blur: keep the light bounded
        cover = np.minimum(cover, 1.0)
        img = acc * scale[..., None] + (1.0 - cover)[..., None] * bg[None, None].astype(np.float32)
        return img.reshape(-1, 3).astype(np.float64)

    def render_ir(self, caps: list, rng: np.random.Generator, noise: float = 1.0) -> np.ndarray:
        """(S, S) uint8 infrared marker image with the contact deformations of all touching phalanges."""
        disp = np.zeros_like(self.sim.geo.marker_rest)
        for pr in self.presses(caps, rng):
            disp += self.sim.deform(pr)["disp_markers"]
        return self.sim.render(self.sim.geo.marker_rest + disp, rng, noise=noise)

    def sample(self, rng: np.random.Generator, noise: float = 1.0) -> dict:
        if self.grasp_set == "varied":  # the placement and the digits in contact are kept for the evaluation
            q, place, touch = self.hand.sample_varied(rng)
            caps = self.hand.capsules(q, place=place)
            return {
                "rgb": self.render_rgb(caps, rng, noise),
                "ir": self.render_ir(caps, rng, noise),
                "angles_deg": q.astype(np.float32),
                "yaw_deg": np.float32(place.yaw_deg),
                "grasp": "varied",
                "n_contacts": np.int32(len(self.presses(caps, np.random.default_rng(0)))),
                "place": place.to_array().astype(np.float32),
                "touch": touch,
            }
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

    key = {"n": n, "seed": seed, "cfg": sensor_config(grasp_set).to_dict(), "rgb": RGB_SIZE, "v": DATA_VERSION}
    if grasp_set != "mixed":  # the mixed set keeps its original cache key
        key["grasp_set"] = grasp_set
    if rgb_model(grasp_set) != "opacity":  # the sets simulated with the first image model keep their keys
        key["rgb_model"] = rgb_model(grasp_set)
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
