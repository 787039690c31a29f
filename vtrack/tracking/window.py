"""Robust sliding-window Levenberg-Marquardt pose tracker on SE(3) against a signed-distance field.

State: the poses ``T_world_object`` of a short window of keyframes plus the current frame,
optimised jointly (fixed-lag smoothing). Perturbations are right-multiplied,
``T <- T @ exp(delta)``, with ``delta = [rho, phi]`` in the **object** frame (m, rad), so an
object-frame point ``q = T^-1 p`` moves as ``dq/d delta = [-I, hat(q)]``.

Residuals of each frame in the window (all from the SDF ``phi(q)`` and its gradient ``g``):

- vision: ``phi(q)`` of segmented depth points (robust Huber/Cauchy, sigma ``sigma_vision``);
- touch: ``phi(q)`` of contact points (sigma ``sigma_touch``) and normal agreement
  ``R^T n - g/|g|`` (sigma ``sigma_normal``);
- non-penetration: ``min(0, phi(q) - margin)`` of gel points of sensors not in contact;
- constant velocity: ``log(T_{i-1}^-1 T_i) - (dt_i/dt_{i-1}) log(T_{i-2}^-1 T_{i-1})``
  (the first slot uses the velocity estimated before it), sigmas per nominal frame;
- anchor: the oldest keyframe stays near its previous estimate (marginalisation stand-in).

Degeneracy: per slot, the eigen-spectrum of the data normal equations (rotation scaled by the
object radius so both blocks are in metres) is inspected; eigen-directions weaker than
``degeneracy_ratio * max`` (rotation about a symmetry axis, sliding on a plane, no data at all)
are lifted to that floor, i.e. held at the prediction instead of wandering. The number of such
directions is reported per frame. With ``degenerate_mode="project"`` (SLAM's default) the data terms are
also projected out of them: the data sees and pulls only the well-constrained part of the motion, and
the weak directions follow the constant-velocity prior alone.

Safety: each LM step is clamped (``max_step_trans``, ``max_step_rot``); the per-frame correction
away from the prediction is bounded (``max_correction_*``); when the fit is poor (inlier fraction
of vision/touch points below ``lost_inlier_frac``) a recovery from a few hypotheses is tried and
the frame is flagged ``lost`` if it fails, never producing NaN.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from vtrack.errors import InputError, require_range
from vtrack.geometry import se3
from vtrack.geometry.pointcloud import row_norms
from vtrack.tracking.frame import TrackingFrame, sanitize


class SDF(Protocol):
    def query(self, points: np.ndarray, with_grad: bool = True) -> tuple[np.ndarray, np.ndarray | None]: ...


@dataclass
class TrackerOptions:
    """Tuning of the window tracker (metres, radians, seconds)."""

    window: int = 3  #: frames optimised jointly (keyframes + current), >= 1
    iterations: int = 5  #: max LM iterations per frame
    converge_trans: float = 2e-5  #: stop when every slot's step is below this (m) ...
    converge_rot: float = 2e-4  #: ... and this (rad)
    #: an LM step below both convergence bounds: ``iterate`` evaluates it, keeps it and stops if the cost did not rise,
    #: else undoes it and tries again with a larger damping (up to ``iterations``); ``accept`` (ablation) keeps it and
    #: stops without evaluating: 13 % fewer window evaluations, but a third of those steps raise the cost and over 5 s
    #: sessions the error grows by 5 % (docs/benchmarks/lm_small_step.md)
    small_step: str = "iterate"
    robust: str = "huber"  #: huber | cauchy
    sigma_vision: float = 0.002  #: depth point-to-surface noise, m
    #: m, > 0: the depth points' sigma in a frame that sees fewer than ``few_vision_points`` segmented depth points
    #: (0: ``sigma_vision`` everywhere). Under heavy occlusion the few points seen between the fingers tilt the pose
    #: against a map they half built; with sticking contacts (``sigma_stick``) the contacts hold it better
    sigma_vision_few: float = 0.0
    few_vision_points: int = 150  #: see ``sigma_vision_few``
    sigma_touch: float = 0.001  #: contact point-to-surface noise, m (patch edges are ~0.3 mm off)
    sigma_normal: float = 1.0  #: contact normal disagreement (unit vectors); weak on purpose
    sigma_free: float = 0.001  #: non-penetration, m
    sigma_touch_inside: float = 0.0  #: sigma of contact points INSIDE the surface, m (0: sigma_touch; inf: one-sided)
    free_margin: float = 0.0  #: free gel points must stay this far outside, m
    free_gate: float = 0.003  #: ignore free gel points predicted deeper than this inside, m
    kernel_vision: float = 1.5  #: robust kernel width in sigmas
    kernel_touch: float = 2.0
    sigma_motion_trans: float = 0.0015  #: constant-velocity deviation per nominal frame, m
    sigma_motion_rot: float = 0.015  #: rad per nominal frame
    sigma_anchor_trans: float = 0.0005  #: oldest keyframe prior, m
    sigma_anchor_rot: float = 0.005  #: rad
    #: the oldest keyframe's anchor (``T_prior``) follows its latest estimate: True re-anchors every keyframe at its
    #: value after the window it was last refined in; False keeps, for the keyframe that becomes the oldest, its value
    #: from one window earlier. Then each window is pinned to the state two frames back, so even and odd frames form
    #: two chains, and along a direction the data leaves free they drift apart (the 5 s banana at medium occlusion
    #: flipped 4-7 deg between consecutive frames). SLAM's default: True (docs/benchmarks/anchor_refresh.md)
    anchor_refresh: bool = False
    nominal_dt: float = 1.0 / 30.0  #: s, frame period the motion sigmas refer to
    gate: float = 0.02  #: drop vision points farther than this from the predicted surface, m
    max_vision_points: int = 300
    max_touch_points: int = 120
    #: > 0: in a frame that sees fewer than ``few_touch_min_vision`` segmented vision points (touch-only frames
    #: included), the contacts are subsampled to at most this many instead of ``max_touch_points``. The pixels of one
    #: contact patch do not carry independent errors: matched against a map the sliding contacts built themselves, a
    #: patch is off as a whole, yet 120 rows outweigh the motion prior as if each were a measurement of its own.
    #: SLAM's opt-in heavy-occlusion setting (``SLAM_FEW_TOUCH``, docs/benchmarks/few_touch.md); 0: off
    few_touch_points: int = 0
    few_touch_min_vision: int = 300  #: see ``few_touch_points`` (300: every frame that is not fully seen)
    max_free_points: int = 48
    degeneracy_ratio: float = 1e-5  #: relative floor of the spectrum (absolute floor: one vision point)
    #: what the data may do along weak eigen-directions: ``lift`` (default) lifts them to the floor and keeps the
    #: data's pull there (with a known, exact shape a weak direction still carries real information: touch-only
    #: known-shape tracking of the mustard bottle is 1.0 mm with it, 6.0 mm without); ``project`` removes the
    #: data's pull there so the motion prior alone carries them (solution remapping, Zhang et al., ICRA 2016) -
    #: SLAM's default, where the map is built from the same views and its errors are world-fixed: a spinning mug's
    #: body looks the same every frame from a fixed camera and would hold the spin back
    degenerate_mode: str = "lift"
    #: ``project`` only the weak directions below this fraction of the strongest one (0: every weak one); the
    #: others are lifted: a frame with few points is weak everywhere, and there the data still informs
    project_ratio: float = 0.0
    #: ``project`` only in frames with no segmented vision point or at least this many (0: in every frame); a frame
    #: that sees a small patch of the object (heavy occlusion) is weak in several directions because the patch is
    #: small, not because the object looks the same under that motion: the data still informs there and is lifted
    project_min_vision: int = 0
    #: ``project`` also in frames without any segmented vision point (touch only)
    project_without_vision: bool = True
    #: weak-vision regime (heavy occlusion): in a frame with fewer segmented vision points than this (0: off; touch
    #: only frames included) contacts are weighted as what carries the pose: ``sigma_touch_weak`` on both sides of
    #: the surface and normals at ``sigma_normal_weak``, instead of ``sigma_touch`` / ``sigma_touch_inside`` /
    #: ``sigma_normal`` (which, in SLAM, let contacts sit inside the surface at no cost because they read shallow)
    touch_weak_vision: int = 0
    sigma_touch_weak: float = 0.0015  #: m, contact point-to-surface sigma in weak-vision frames (both sides)
    sigma_normal_weak: float = 0.0  #: contact normal sigma in weak-vision frames (0: ``sigma_normal``)
    #: in weak-vision frames the contacts pull only along the directions their patches constrain by their MEASURED
    #: normals (a patch fixes position along its normal; several fingers fix rotations): directions whose information
    #: ``sum [n, q x n]^T [n, q x n]`` is below this fraction of the strongest (0: off) are removed from the contacts'
    #: pull, e.g. a mug's spin under fingers on its body, which the map's small errors would otherwise hold at rest;
    #: only in frames that see some vision points or follow one within ``touch_blind_vision_s`` (in a touch-only run
    #: nothing else would hold those directions)
    touch_blind_ratio: float = 0.0
    touch_blind_vision_s: float = 1.0  #: s
    #: > 0 (with ``touch_blind_ratio``): in weak-vision frames that see some vision points the contacts also leave
    #: alone the directions where the frame's vision already holds this many times more information than the
    #: contacts' measured normals give (generalised eigen-directions of the two 6x6 information matrices, touch at
    #: ``sigma_touch_weak``, vision at ``sigma_vision``, rotation scaled by ``object_radius``): there the contacts,
    #: matched against a map they built themselves, add bias rather than information; they carry only what vision
    #: leaves weak (0: off)
    touch_vision_ratio: float = 0.0
    object_radius: float = 0.05  #: m, scales rotation for the spectrum test
    lm_lambda: float = 1e-4
    max_step_trans: float = 0.01
    max_step_rot: float = 0.15
    max_correction_trans: float = 0.05  #: per-frame bound on |estimate - prediction|, m
    max_correction_rot: float = 0.6  #: rad
    inlier_dist: float = 0.005  #: |sdf| below this counts as inlier, m
    lost_inlier_frac: float = 0.5
    recover: bool = True
    kf_trans: float = 0.001  #: promote a frame to keyframe after this motion, m
    kf_rot: float = 0.01  #: rad
    kf_dt: float = 0.1  #: or after this much time, s
    kf_vision_points: int = 100  #: points a keyframe keeps (older frames matter less; saves time)
    kf_touch_points: int = 60
    velocity_decay_dt: float = 0.5  #: a gap longer than this resets the velocity, s
    seed: int = 0
    #: colour term (0: off): colour feature tracks (``frame.info["colour_ids"]`` / ``["colour_points"]``, world, from
    #: :mod:`vtrack.tracking.colour`) are anchored in the object frame when first seen; later observations must land
    #: on their anchors, point-to-point with this sigma (m), robust (``kernel_colour``). Added AFTER the degeneracy
    #: projection: it is what observes a spin about a symmetry axis that depth and touch leave to the motion prior
    sigma_colour: float = 0.0
    #: robust kernel width of the colour term, in sigmas. 0.5 (Huber: quadratic to 0.5 mm at 1 mm sigma, then a
    #: constant pull per track): the tracks slip ~8 % behind the true motion and a wide kernel let their summed
    #: pull beat well-conditioned geometry (5 s unoccluded mustard 1.5 sigmas: 4.81 mm, 0.5: 3.36; mug kept:
    #: docs/benchmarks/slam_colour.md, "Tighter kernel")
    kernel_colour: float = 0.5
    colour_gate: float = 0.01  #: drop tracks farther than this from their anchor at the prediction, m
    colour_min_tracks: int = 6  #: fewer anchored tracks in a frame: no colour term there
    #: > 0: in a frame with at least ``colour_few_min_vision`` depth points (after ``max_vision_points`` and the gate),
    #: the colour term needs at least this many anchored tracks instead. Each track past the kernel pulls with the
    #: same force, so a handful of slipping ones steers the pose about axes the depth holds only weakly (the 5 s
    #: banana at medium occlusion); where depth is sparse (heavy occlusion) a few tracks are still what sees a spin
    colour_few_tracks: int = 0
    colour_few_min_vision: int = 0
    #: > 0: the colour term acts only along the eigen-directions of the frame's depth / touch data weaker than this
    #: fraction of the strongest (rotation scaled by ``object_radius``, as in the degeneracy test): colour observes
    #: what the geometry leaves free and does not fight it where the geometry is good (LK on shaded texture is
    #: biased towards rest); 0: in every direction
    colour_ratio: float = 0.0
    #: ``ray``: an anchor must lie on its track's viewing ray (the observation's depth, the noisiest part, is not
    #: used); ``point``: on the observed 3D point (see ``_colour_terms``)
    colour_residual: str = "ray"
    #: > 0: after each tracked frame, a track whose anchor lies farther than this from its observation at the
    #: committed pose (the term's residual, m) is re-anchored there: LK tracks slip on the surface (they recover
    #: ~92 % of the motion), and an anchor that keeps an old slip pulls the pose back for the track's whole life
    colour_reanchor: float = 0.0
    #: > 0: tracks anchored this many frames ago are re-anchored at the committed pose (bounds the slip a track
    #: accumulates against its anchor; the term then observes the motion over at most this many frames)
    colour_max_age: int = 0
    #: sticking-contact term (0: off), m: a contact that sticks to the object keeps its object-frame point. Each
    #: sensor's contact point (``frame.info["stick_ids"]`` / ``["stick_points"]``, world, from
    #: :class:`vtrack.tracking.stick.StickingContacts`: one id per unbroken contact whose patch stays put on the gel;
    #: the point is the gel point under the id's first patch centre, carried by the sensor pose)
    #: is anchored in the object frame when first seen; later observations must land on the anchor, point-to-point
    #: with this sigma, robust (``kernel_stick``). Blind slip test, besides the patch staying put on the gel: a
    #: contact is used only while its finger carries it ALONG the surface (tangential step since the last frame of at
    #: least ``stick_min_step`` per nominal frame: a finger closing on an object that turns under it moves along the
    #: normal, or not at all) and while that step follows the predicted object motion within ``stick_step_gate``
    #: and the contact lies within ``stick_gate`` of its anchor at the prediction; otherwise it is re-anchored.
    #: Added after the degeneracy projection, like the colour term (see docs/benchmarks/heavy_occlusion3.md)
    sigma_stick: float = 0.0
    kernel_stick: float = 1.5  #: robust kernel width of the sticking-contact term, in sigmas
    stick_step_gate: float = 0.001  #: m per frame (see ``sigma_stick``)
    stick_min_step: float = 0.00015  #: m per nominal frame (see ``sigma_stick``)
    stick_gate: float = 0.004  #: m (see ``sigma_stick``)
    #: m: a patch centre that moves more than this on the gel between frames starts a new contact (the gel slips)
    stick_patch_move: float = 0.0008
    #: with the sticking term on, drop the contacts' point-to-map residuals in every frame that has vision points
    #: (they are matched against the strip of map they laid down themselves; the sticking term carries what they
    #: know). The map still integrates them. Frames without vision keep them: nothing else holds the map there (the
    #: baseball hidden at medium occlusion)
    stick_drop_touch: bool = False
    #: what the slip test compares a contact's motion with: ``prediction`` (the constant-velocity prediction) or
    #: ``data`` (the frame solved first WITHOUT the sticking term: the motion the other senses see; one more solve per
    #: frame). With ``prediction`` the accepted contacts bend the prediction itself, so sliding contacts that hold the
    #: object still pass
    stick_reference: str = "prediction"
    #: > 0: per-track lag rejection of the colour term. After each tracked frame, a track whose anchor has moved
    #: (at the committed pose, laterally to its viewing ray) by more than ``colour_drop_motion`` since it was
    #: anchored and whose residual (anchor against its observation) exceeds this fraction of that motion is dropped
    #: for the rest of its life: it does not follow the object (an object-fixed track's residual
    #: stays at the noise, a world-fixed one's grows with the motion: lag 1). On the 5 s medium potted meat / mug
    #: 4-14 % of the tracks lag 0.9-1.0 of the motion (docs/benchmarks/slam_5s_lag.md)
    colour_drop_lag: float = 0.0
    colour_drop_motion: float = 0.002  #: m of anchor motion before the lag test of ``colour_drop_lag`` applies
    #: the lag test never leaves fewer than this many anchored tracks (the most lagging go first): with few tracks
    #: a drop flips the few-track guard on and off (the 5 s banana at medium occlusion)
    colour_drop_keep: int = 0
    #: robust kernel of the colour term (``huber`` | ``cauchy`` | ``none``; empty: ``robust``, the other terms')
    robust_colour: str = ""

    @classmethod
    def from_dict(cls, opts: dict) -> TrackerOptions:
        from vtrack.config import checked_fields

        o = cls(**checked_fields(cls, opts, "tracker"))
        # a bad value is an InputError naming its own field (require_range: lo 0, hi inf inclusive unless given;
        # hi_inclusive=False = finite)
        R = require_range
        R("window", o.window, "window must be >= 1", "an integer >= 1 (frames)", 1)
        R("iterations", o.iterations, "iterations must be >= 1", "an integer >= 1", 1)
        if o.degenerate_mode not in ("project", "lift"):
            raise InputError(
                "unknown degenerate mode", field="degenerate_mode", expected="project|lift", got=o.degenerate_mode
            )
        if o.touch_weak_vision > 0:
            R(
                "sigma_touch_weak",
                o.sigma_touch_weak,
                "sigma_touch_weak must be > 0 when the weak-vision regime is on",
                "> 0 m",
                lo_inclusive=False,
                hi_inclusive=False,
            )
        R(
            "touch_vision_ratio",
            o.touch_vision_ratio,
            "touch_vision_ratio must be >= 0",
            ">= 0 (0: off)",
            hi_inclusive=False,
        )
        if o.colour_residual not in ("ray", "point"):
            raise InputError(
                "unknown colour residual", field="colour_residual", expected="ray|point", got=o.colour_residual
            )
        R("sigma_colour", o.sigma_colour, "sigma_colour must be >= 0", ">= 0 m (0: off)", hi_inclusive=False)
        R("colour_few_tracks", o.colour_few_tracks, "colour few-track count must be >= 0", ">= 0 (0: off)")
        R("colour_few_min_vision", o.colour_few_min_vision, "colour few-track vision count must be >= 0", ">= 0")
        R(
            "colour_reanchor",
            o.colour_reanchor,
            "colour re-anchoring must be >= 0",
            ">= 0 m (0: off)",
            hi_inclusive=False,
        )
        R("colour_max_age", o.colour_max_age, "colour track age must be >= 0", ">= 0 frames (0: no limit)")
        R("sigma_stick", o.sigma_stick, "sigma_stick must be >= 0", ">= 0 m (0: off)", hi_inclusive=False)
        R("sigma_vision_few", o.sigma_vision_few, "sigma_vision_few must be >= 0", ">= 0 m", hi_inclusive=False)
        R("few_vision_points", o.few_vision_points, "few_vision_points must be >= 0", ">= 0 points")
        for name in ("stick_step_gate", "stick_gate", "kernel_stick", "stick_patch_move"):
            R(name, getattr(o, name), f"{name} must be > 0", "> 0 m", lo_inclusive=False, hi_inclusive=False)
        R("stick_min_step", o.stick_min_step, "stick_min_step must be >= 0", ">= 0 m", hi_inclusive=False)
        if o.stick_reference not in ("prediction", "data"):
            raise InputError(
                "unknown stick reference", field="stick_reference", expected="prediction|data", got=o.stick_reference
            )
        if o.robust not in ("huber", "cauchy", "none"):
            raise InputError("unknown robust kernel", field="robust", expected="huber|cauchy|none", got=o.robust)
        if o.small_step not in ("iterate", "accept"):
            raise InputError("unknown small-step rule", field="small_step", expected="iterate|accept", got=o.small_step)
        if o.robust_colour not in ("", "huber", "cauchy", "none"):
            raise InputError(
                "unknown robust kernel", field="robust_colour", expected="huber|cauchy|none|''", got=o.robust_colour
            )
        R("colour_drop_lag", o.colour_drop_lag, "colour_drop_lag must be >= 0", ">= 0 (0: off)", hi_inclusive=False)
        R(
            "colour_drop_motion",
            o.colour_drop_motion,
            "colour_drop_motion must be > 0",
            "> 0 m",
            lo_inclusive=False,
            hi_inclusive=False,
        )
        R("colour_drop_keep", o.colour_drop_keep, "colour_drop_keep must be >= 0", ">= 0")
        return o


@dataclass
class StepInfo:
    """Diagnostics of one ``step``."""

    t: float
    status: str = "ok"  #: ok | no_data | degenerate | lost | recovered
    iterations: int = 0
    cost: float = 0.0
    inlier_frac: float = float("nan")
    degenerate_dims: int = 0
    n_vision: int = 0
    n_touch: int = 0
    n_free: int = 0
    ms: float = 0.0


@dataclass
class _Slot:
    T: np.ndarray
    t: float
    frame: TrackingFrame
    T_prior: np.ndarray
    v: np.ndarray = field(default_factory=lambda: np.zeros(6))  #: body velocity (1/s) when committed
    reg: np.ndarray = field(default_factory=lambda: np.zeros((6, 6)))
    #: projector of a twist onto the well-constrained directions of this slot's data (None: all of them), and the
    #: pose it was computed at: the data terms see only the projected part of the motion away from it
    proj: np.ndarray | None = None
    T_lin: np.ndarray | None = None
    _lin_inv: tuple[np.ndarray, np.ndarray] | None = None  #: (T_lin, its inverse), see :meth:`lin_inv`
    #: projector of a twist onto the directions the slot's contacts constrain by their measured normals (None: all)
    proj_touch: np.ndarray | None = None
    n_vision: int = -1  #: segmented vision points of the frame when it was current (-1: count the slot's frame)
    #: colour correspondences: world points (N, 3) of anchored tracks, their object-frame anchors (N, 3) and the world
    #: centres of the cameras that saw them (N, 3)
    colour: tuple[np.ndarray, ...] | None = None
    #: projector of a twist onto the directions the colour term acts along (None: all of them; see colour_ratio)
    proj_colour: np.ndarray | None = None
    #: sticking contacts (see ``TrackerOptions.sigma_stick``): world points (K, 3) and their object-frame anchors
    stick: tuple[np.ndarray, np.ndarray] | None = None

    def lin_inv(self) -> np.ndarray:
        """Inverse of ``T_lin`` (4x4), computed once per linearisation pose (``T_lin`` is replaced, never edited in
        place): every cost evaluation of a projected slot needs it."""
        c = self._lin_inv
        if c is None or c[0] is not self.T_lin:
            c = self._lin_inv = (self.T_lin, _inv(self.T_lin))  # type: ignore[arg-type]
        return c[1]


#: read-only identities (np.eye allocates and fills one per call: ~4 us, a dozen times per cost evaluation)
_EYE3 = np.eye(3)
_EYE4 = np.eye(4)
_EYE6 = np.eye(6)
for _e in (_EYE3, _EYE4, _EYE6):
    _e.flags.writeable = False


def _hat3(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def _inv(T: np.ndarray) -> np.ndarray:
    """Inverse of one rigid 4x4 (cheap scalar path; se3.invert is batched and slower for one)."""
    out = _EYE4.copy()
    Rt = T[:3, :3].T
    out[:3, :3] = Rt
    out[:3, 3] = -Rt @ T[:3, 3]
    return out


def _exp(xi: np.ndarray) -> np.ndarray:
    """se3 exp of one twist [rho, phi] (written out on Python floats: one small array instead of a dozen 3x3
    products; equal to ``I + A K + B K^2`` / ``(I + B K + C K^2) rho`` with ``K = hat(phi)`` to rounding)."""
    r0, r1, r2, p0, p1, p2 = (float(v) for v in xi)
    th2 = p0 * p0 + p1 * p1 + p2 * p2
    if th2 < 1e-10:
        A, B, C = 1.0 - th2 / 6.0, 0.5 - th2 / 24.0, 1.0 / 6.0 - th2 / 120.0
    else:
        th = math.sqrt(th2)
        s, c = math.sin(th), math.cos(th)
        A, B, C = s / th, (1.0 - c) / th2, (th - s) / (th2 * th)
    # K^2 = phi phi^T - |phi|^2 I
    q00, q11, q22 = p0 * p0 - th2, p1 * p1 - th2, p2 * p2 - th2
    q01, q02, q12 = p0 * p1, p0 * p2, p1 * p2
    v00, v01, v02 = 1.0 + C * q00, -B * p2 + C * q01, B * p1 + C * q02
    v10, v11, v12 = B * p2 + C * q01, 1.0 + C * q11, -B * p0 + C * q12
    v20, v21, v22 = -B * p1 + C * q02, B * p0 + C * q12, 1.0 + C * q22
    return np.array(
        [
            [1.0 + B * q00, -A * p2 + B * q01, A * p1 + B * q02, v00 * r0 + v01 * r1 + v02 * r2],
            [A * p2 + B * q01, 1.0 + B * q11, -A * p0 + B * q12, v10 * r0 + v11 * r1 + v12 * r2],
            [-A * p1 + B * q02, A * p0 + B * q12, 1.0 + B * q22, v20 * r0 + v21 * r1 + v22 * r2],
            [0.0, 0.0, 0.0, 1.0],
        ]
    )


def _log(T: np.ndarray) -> np.ndarray:
    """se3 log of one rigid transform (falls back to the batched routine near pi); written out on Python floats
    like :func:`_exp`."""
    (R00, R01, R02, t0), (R10, R11, R12, t1), (R20, R21, R22, t2) = T[:3].tolist()
    c = (R00 + R11 + R22 - 1.0) / 2.0
    if c < -0.99:
        return se3.se3_log(T)
    c = min(1.0, c)
    th = math.acos(c)
    w0, w1, w2 = 0.5 * (R21 - R12), 0.5 * (R02 - R20), 0.5 * (R10 - R01)
    if th < 1e-5:
        f = 1.0 + th * th / 6.0
        D = 1.0 / 12.0
    else:
        f = th / math.sin(th)
        D = 1.0 / (th * th) - math.cos(th / 2.0) / (2.0 * th * math.sin(th / 2.0))
    p0, p1, p2 = w0 * f, w1 * f, w2 * f
    n2 = p0 * p0 + p1 * p1 + p2 * p2
    # (I - K / 2 + D K^2) t with K = hat(phi), K^2 = phi phi^T - |phi|^2 I
    q00, q11, q22 = p0 * p0 - n2, p1 * p1 - n2, p2 * p2 - n2
    q01, q02, q12 = p0 * p1, p0 * p2, p1 * p2
    return np.array(
        [
            (1.0 + D * q00) * t0 + (0.5 * p2 + D * q01) * t1 + (-0.5 * p1 + D * q02) * t2,
            (-0.5 * p2 + D * q01) * t0 + (1.0 + D * q11) * t1 + (0.5 * p0 + D * q12) * t2,
            (0.5 * p1 + D * q02) * t0 + (-0.5 * p0 + D * q12) * t1 + (1.0 + D * q22) * t2,
            p0,
            p1,
            p2,
        ]
    )


def _adjoint(T: np.ndarray) -> np.ndarray:
    """Adjoint of T for twists ordered [rho, phi]."""
    R, t = T[:3, :3], T[:3, 3]
    A = np.zeros((6, 6))
    A[:3, :3] = R
    A[:3, 3:] = _hat3(t) @ R
    A[3:, 3:] = R
    return A


def _ray_directions(P: np.ndarray, C: np.ndarray) -> np.ndarray:
    """Unit viewing rays ``d = (p - c)/|p - c|`` (N, 3) of observed points ``P`` from camera centres ``C`` (world)."""
    d = P - C
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return d


def _ray_residuals(
    R: np.ndarray, t: np.ndarray, P: np.ndarray, Q: np.ndarray, C: np.ndarray, d: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Point-to-ray residuals of colour-track anchors and their Jacobians, one row per correspondence.

    ``R`` (N, 3, 3) / ``t`` (N, 3): the rotation and translation of ``T_world_object`` each row is scored at;
    ``Q`` (N, 3) anchors in the object frame (m); ``P`` (N, 3) observed points and ``C`` (N, 3) camera centres in
    the world frame (m). ``r = (I - d d^T)(R q + t - c)`` with ``d = (p - c)/|p - c|`` (N, 3) and
    ``dr/d delta = (I - d d^T) R [I, -hat(q)] = (I - d d^T) [R, -hat(R q) R]`` (N, 3, 6). ``d``: the rays
    (:func:`_ray_directions`) when the caller has them (they do not depend on the pose).

    The 3-term sums are written out in the order of the numpy reductions they replace (``np.einsum("nij,nj->ni")``:
    ``(p0 + p2) + p1``; ``np.einsum("nk,nkj->nj")`` and ``np.sum(axis=1)``: ``(p0 + p1) + p2``), so the values are
    the same bit for bit (tests/tracking/test_speed_paths.py) at a third of the time."""
    Rq = (R[:, :, 0] * Q[:, 0:1] + R[:, :, 2] * Q[:, 2:3]) + R[:, :, 1] * Q[:, 1:2]
    if d is None:
        d = _ray_directions(P, C)
    e = Rq + t - C
    de = d * e
    r = e - d * ((de[:, 0] + de[:, 1]) + de[:, 2])[:, None]
    J = np.empty((len(Q), 3, 6))
    J[:, :, :3] = R
    hx = np.zeros((len(Q), 3, 3))
    hx[:, 0, 1], hx[:, 0, 2] = -Rq[:, 2], Rq[:, 1]
    hx[:, 1, 0], hx[:, 1, 2] = Rq[:, 2], -Rq[:, 0]
    hx[:, 2, 0], hx[:, 2, 1] = -Rq[:, 1], Rq[:, 0]
    J[:, :, 3:] = -hx @ R
    dJ = (d[:, 0:1] * J[:, 0] + d[:, 1:2] * J[:, 1]) + d[:, 2:3] * J[:, 2]  # d^T J (N, 6)
    J -= d[:, :, None] * dJ[:, None, :]
    return r, J


def _sdf_jacobian(q: np.ndarray, g: np.ndarray) -> np.ndarray:
    """(N, 6) Jacobians ``d phi(T^-1 p) / d delta = g^T [-I, hat(q)] = [-g, g x q]`` of SDF residuals at object-frame
    points ``q`` (N, 3) with SDF gradients ``g`` (N, 3), for the right perturbation ``T exp(delta)``."""
    J = np.empty((len(q), 6))
    J[:, :3] = -g
    # g x q written out (np.cross computes the same products; its wrapper costs more than they do)
    J[:, 3] = g[:, 1] * q[:, 2] - g[:, 2] * q[:, 1]
    J[:, 4] = g[:, 2] * q[:, 0] - g[:, 0] * q[:, 2]
    J[:, 5] = g[:, 0] * q[:, 1] - g[:, 1] * q[:, 0]
    return J


def _normal_rows(n_obj: np.ndarray, ghat: np.ndarray, sig, sig2, robust: str) -> tuple:
    """Per-row algebra of the contact-normal term: measured normals ``n_obj = R^T n`` (m, 3, object frame) against
    the unit SDF gradients ``ghat`` (m, 3), residual ``rn = n_obj - ghat`` with sigma ``sig`` (``sig2`` = its square;
    scalars or one per row). Returns ``n_obj``, the weights ``wn`` (m,) and costs (m,) (robust on ``|rn|``, kernel
    2), ``wnn = wn n_obj`` (m, 3), ``wnn * n_obj`` (m, 3) and the three components of ``rn x n_obj`` (m,) each."""
    rn = n_obj - ghat
    wn, rhon = _robust_weights(row_norms(rn) / sig, robust, 2.0)
    wn = wn / sig2
    wnn = n_obj * wn[:, None]
    cross = (
        rn[:, 1] * n_obj[:, 2] - rn[:, 2] * n_obj[:, 1],
        rn[:, 2] * n_obj[:, 0] - rn[:, 0] * n_obj[:, 2],
        rn[:, 0] * n_obj[:, 1] - rn[:, 1] * n_obj[:, 0],
    )
    return n_obj, wn, rhon, wnn, wnn * n_obj, cross


def _robust_weights(r_scaled: np.ndarray, kind: str, k: float) -> tuple[np.ndarray, np.ndarray]:
    """IRLS weights and robust cost for residuals already divided by their sigma."""
    a = np.abs(r_scaled)
    if kind == "huber":
        # = where(a <= k, 1, k / a) and where(a <= k, a^2 / 2, k (a - k / 2)), bit for bit (NaN and inf included:
        # a - a / 2 is exact), in fewer passes over the array: this runs for every group of every slot per evaluation
        w = np.minimum(k / np.maximum(a, 1e-12), 1.0)
        m = np.minimum(a, k)
        rho = m * (a - 0.5 * m)
    elif kind == "cauchy":
        u = (a / k) ** 2
        w = 1.0 / (1.0 + u)
        rho = 0.5 * k * k * np.log1p(u)
    else:
        w = np.ones_like(a)
        rho = 0.5 * a * a
    return w, rho


class WindowTracker:
    """Sliding-window robust LM tracker of ``T_world_object`` against an object-frame SDF.

    Args:
        sdf: object with ``query(points_obj) -> (sdf (N,), grad (N, 3))`` in metres.
        T_init: initial ``T_world_object`` (4x4).
        options: :class:`TrackerOptions` or a dict of overrides.
    """

    def __init__(self, sdf: SDF, T_init: np.ndarray, options: TrackerOptions | dict | None = None) -> None:
        if isinstance(options, dict) or options is None:
            options = TrackerOptions.from_dict(options or {})
        self.opts = options
        self.sdf = sdf
        T0 = np.asarray(T_init, dtype=np.float64)
        if T0.shape != (4, 4) or not se3.is_rigid(T0, tol=1e-4):
            raise InputError(
                "initial pose must be a finite 4x4 rigid transform",
                field="T_init",
                expected="T_world_object (4, 4)",
                got=T0.shape,
            )
        T0 = T0.copy()
        T0[:3, :3] = se3.orthonormalize(T0[:3, :3])
        self.T = T0
        self.velocity = np.zeros(6)  # body twist per second, [rho, phi]
        self.t_last: float | None = None
        self.keyframes: list[_Slot] = []
        self.history: list[StepInfo] = []
        self._frame_count = 0
        self._t_vision: float | None = None  # time of the last frame with segmented vision points
        self._anchors: dict[int, np.ndarray] = {}  # colour track id -> object-frame anchor (m)
        self._anchor_frame: dict[int, int] = {}  # colour track id -> frame count when anchored
        self._anchor_world: dict[int, np.ndarray] = {}  # colour track id -> its world point when anchored (m)
        self._colour_dropped: set[int] = set()  # colour track ids rejected by the lag test (colour_drop_lag)
        self._stick_anchors: dict[int, np.ndarray] = {}  # sticking-contact id -> object-frame anchor (m)
        self._stick_last: dict[int, np.ndarray] = {}  # sticking-contact id -> its world point in the last frame
        self._stick_reanchor: set[int] = set()  # ids that failed the slip test this frame
        #: the window's stacked colour correspondences (slots' ``colour`` tuples, P, Q, C, counts, rays), reused
        #: while the slots keep the same tuples (:meth:`_window_colour_terms`)
        self._colour_batch: tuple | None = None

    # -- public API ---------------------------------------------------------------------------
    def reset(self, T_world_object: np.ndarray) -> None:
        """Re-initialise (e.g. after a detected loss, from an external detector)."""
        self.T = np.asarray(T_world_object, dtype=np.float64).copy()
        self.velocity[:] = 0.0
        self.keyframes.clear()
        self.t_last = None
        self._anchors.clear()
        self._anchor_frame.clear()
        self._anchor_world.clear()
        self._colour_dropped.clear()
        self._stick_anchors.clear()
        self._stick_last.clear()

    @property
    def last_info(self) -> StepInfo | None:
        return self.history[-1] if self.history else None

    def step(self, frame: TrackingFrame) -> np.ndarray:
        """Consume one frame and return the estimated ``T_world_object`` (4x4) at ``frame.t``."""
        t_start = time.perf_counter()
        o = self.opts
        self._frame_count += 1
        fr = sanitize(
            frame, o.max_vision_points, self._touch_budget(frame), o.max_free_points, seed=o.seed + self._frame_count
        )
        dt = o.nominal_dt if self.t_last is None else fr.t - self.t_last
        if self.t_last is not None and dt <= 0:
            raise InputError("frame timestamps must increase", field="frame.t", expected=f"> {self.t_last}", got=fr.t)
        if dt > o.velocity_decay_dt:
            self.velocity[:] = 0.0
        T_pred = self.T @ _exp(self.velocity * dt) if self.t_last is not None else self.T.copy()
        fr = self._gate(fr, T_pred)
        if fr.n_vision:
            self._t_vision = fr.t
        info = StepInfo(
            t=fr.t,
            n_vision=fr.n_vision,
            n_touch=fr.n_touch,
            n_free=0 if fr.free_points is None else len(fr.free_points),
        )
        cur = _Slot(T=T_pred.copy(), t=fr.t, frame=fr, T_prior=T_pred.copy(), n_vision=fr.n_vision)
        cur.colour = self._colour_pairs(fr, T_pred)
        slots = [*self.keyframes[-(o.window - 1) :], cur] if o.window > 1 else [cur]
        v_before = self.velocity.copy()
        T_ref = T_pred
        if o.sigma_stick > 0 and o.stick_reference == "data" and len(fr.info.get("stick_ids", ())):
            T_ref = self._solve_without_stick(slots, v_before)
        cur.stick = self._stick_pairs(fr, T_ref)
        if o.stick_drop_touch and o.sigma_stick > 0 and fr.n_vision > 0:
            fr.touch_points = fr.touch_normals = None
        if info.n_vision + info.n_touch + info.n_free == 0:
            info.status = "no_data"
        else:
            cost, iters, dims = self._optimise(slots, v_before)
            info.cost, info.iterations, info.degenerate_dims = cost, iters, dims
            info.inlier_frac = self._inlier_frac(cur.T, fr)
            if dims:
                info.status = "degenerate"
            if np.isfinite(info.inlier_frac) and info.inlier_frac < o.lost_inlier_frac:
                info.status = "lost"
                if o.recover:
                    if self._recover(cur, slots, v_before, T_pred, info):
                        info.status = "recovered"
        self._bound(cur, T_pred)
        self._commit(slots, cur, dt)
        self._colour_anchor(fr, self.T, info.status not in ("lost", "no_data"))
        self._stick_anchor(fr, self.T)
        info.ms = (time.perf_counter() - t_start) * 1e3
        self.history.append(info)
        return self.T.copy()

    # -- internals ----------------------------------------------------------------------------
    def _colour_pairs(self, fr: TrackingFrame, T_pred: np.ndarray) -> tuple[np.ndarray, ...] | None:
        """The frame's colour tracks that have an anchor and lie within ``colour_gate`` of it at the prediction:
        (world points, object-frame anchors, world camera centres or None when the frame names none: the point
        residual); None when the term is off or fewer than ``colour_min_tracks``."""
        o = self.opts
        if o.sigma_colour <= 0 or not self._anchors:
            return None
        ids = fr.info.get("colour_ids")
        P = fr.info.get("colour_points")
        if ids is None or P is None or len(ids) == 0:
            return None
        sel = [(k, a) for k, a in enumerate(np.asarray(ids).tolist()) if a in self._anchors]
        n_min = o.colour_min_tracks
        if o.colour_few_tracks > 0 and fr.n_vision >= o.colour_few_min_vision:
            n_min = max(n_min, o.colour_few_tracks)
        if len(sel) < n_min:
            return None
        rows = [k for k, _ in sel]
        P = np.asarray(P, np.float64)
        C = self._colour_centres(fr, P)  # None: no camera centre known, the point residual
        P = P[rows]
        C = None if C is None else C[rows]
        Q = np.array([self._anchors[a] for _, a in sel])
        Ti = _inv(T_pred)
        ok = np.isfinite(P).all(1) & (np.linalg.norm(P @ Ti[:3, :3].T + Ti[:3, 3] - Q, axis=1) < o.colour_gate)
        if o.colour_residual == "ray" and C is not None:
            ok &= np.isfinite(C).all(1) & (np.linalg.norm(P - C, axis=1) > 1e-6)
        if ok.sum() < n_min:
            return None
        return P[ok], Q[ok], (None if C is None else np.array(C[ok]))

    def _colour_anchor(self, fr: TrackingFrame, T: np.ndarray, ok: bool) -> None:
        """Anchor the frame's new colour tracks in the object frame at pose ``T`` (only if the frame was tracked:
        ``ok``); forget the anchors of tracks that ended; re-anchor at ``T`` those that slipped past
        ``colour_reanchor`` or are older than ``colour_max_age`` frames."""
        o = self.opts
        if o.sigma_colour <= 0:
            return
        ids = fr.info.get("colour_ids")
        P = fr.info.get("colour_points")
        if ids is None or P is None:
            self._anchors.clear()
            self._anchor_frame.clear()
            self._anchor_world.clear()
            self._colour_dropped.clear()
            return
        ids = np.asarray(ids).tolist()
        # a rejected track stays rejected while it lives (ids are not reused; forget the ended ones)
        self._colour_dropped &= set(ids)
        keep = {a: self._anchors[a] for a in ids if a in self._anchors}
        if ok and np.all(np.isfinite(T)):
            P = np.asarray(P, np.float64)
            Ti = _inv(T)
            Q = P @ Ti[:3, :3].T + Ti[:3, 3]
            if o.colour_drop_lag > 0 and keep:
                self._colour_drop(fr, ids, P, T, keep)
            renew = np.zeros(len(ids), bool)
            if o.colour_max_age > 0:
                renew |= np.array(
                    [a in keep and self._frame_count - self._anchor_frame.get(a, 0) >= o.colour_max_age for a in ids],
                    bool,
                )
            if o.colour_reanchor > 0 and keep:
                has = np.array([a in keep for a in ids], bool)
                Qa = np.array([keep[a] if a in keep else np.zeros(3) for a in ids])
                e = Qa @ T[:3, :3].T + T[:3, 3] - P  # anchor minus observation, world
                C = self._colour_centres(fr, P)
                if o.colour_residual == "ray" and C is not None:
                    d = P - C
                    d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)
                    e = e - d * np.sum(d * e, axis=1, keepdims=True)
                renew |= has & (np.linalg.norm(e, axis=1) > o.colour_reanchor)
            finite = np.isfinite(Q).all(1).tolist()  # once for all rows, not one np.all per track
            for k, (a, q) in enumerate(zip(ids, Q, strict=True)):
                if a in self._colour_dropped:
                    continue
                if (a not in keep or renew[k]) and finite[k]:
                    keep[a] = q
                    self._anchor_frame[a] = self._frame_count
                    self._anchor_world[a] = P[k].copy()
        self._anchors = keep
        self._anchor_frame = {a: self._anchor_frame.get(a, self._frame_count) for a in keep}
        self._anchor_world = {a: self._anchor_world[a] for a in keep if a in self._anchor_world}

    def _colour_drop(self, fr: TrackingFrame, ids: list[int], P: np.ndarray, T: np.ndarray, keep: dict) -> None:
        """Per-track lag test (``colour_drop_lag``): remove from ``keep`` (and remember) the anchored tracks whose
        residual at the committed pose ``T`` exceeds ``colour_drop_lag`` times their anchor's motion since it was
        anchored, once that motion exceeds ``colour_drop_motion``; both lateral to the track's viewing ray (m).

        The residual of a track that slips behind the object grows with the motion in proportion to its lag (0:
        object-fixed, 1: world-fixed); the pose ``T`` is the one the tracks helped set, so a lag that all tracks
        share stays unseen, but the tracks that follow the light or the hand (lag ~1) stand out of the rest."""
        o = self.opts
        rows = [k for k, a in enumerate(ids) if a in keep and a in self._anchor_world]
        if not rows:
            return
        Pk = P[rows]
        Qa = np.array([keep[ids[k]] for k in rows])
        P0 = np.array([self._anchor_world[ids[k]] for k in rows])
        A = Qa @ T[:3, :3].T + T[:3, 3]  # anchors in the world now
        e = A - Pk  # residual
        m = A - P0  # the anchor's motion since it was anchored
        C = self._colour_centres(fr, P)
        if C is not None:
            d = Pk - C[rows]
            d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)
            e = e - d * np.sum(d * e, axis=1, keepdims=True)
            m = m - d * np.sum(d * m, axis=1, keepdims=True)
        ne, nm = np.linalg.norm(e, axis=1), np.linalg.norm(m, axis=1)
        bad = np.isfinite(ne) & np.isfinite(nm) & (nm > o.colour_drop_motion) & (ne > o.colour_drop_lag * nm)
        idx = np.flatnonzero(bad)
        idx = idx[np.argsort(-ne[idx] / nm[idx], kind="stable")][: max(len(keep) - o.colour_drop_keep, 0)]
        for k in idx:
            a = ids[rows[k]]
            keep.pop(a, None)
            self._colour_dropped.add(a)

    @staticmethod
    def _colour_centres(fr: TrackingFrame, P: np.ndarray) -> np.ndarray | None:
        """World camera centres (N, 3) of a frame's colour tracks (None when the frame names none)."""
        C = fr.info.get("colour_origins")
        if C is not None and len(C) == len(P):
            return np.asarray(C, np.float64)
        if fr.info.get("camera_origin") is not None:
            return np.broadcast_to(np.asarray(fr.info["camera_origin"], np.float64), P.shape)
        return None

    def _colour_projector(self, H: np.ndarray) -> np.ndarray | None:
        """Projector of a twist onto the eigen-directions of the data block ``H`` weaker than ``colour_ratio`` of
        the strongest (None: ``colour_ratio`` is 0, i.e. every direction); a zero matrix when none is weak."""
        o = self.opts
        if o.colour_ratio <= 0:
            return None
        L = o.object_radius
        S = np.diag([1.0, 1.0, 1.0, 1.0 / L, 1.0 / L, 1.0 / L])
        Hs = S @ H @ S
        lam, U = np.linalg.eigh(0.5 * (Hs + Hs.T))
        Uw = U[:, lam < o.colour_ratio * max(float(lam[-1]), 0.0)]
        return S @ Uw @ Uw.T @ np.diag([1.0, 1.0, 1.0, L, L, L])

    def _colour_terms(self, s: _Slot) -> tuple[np.ndarray, np.ndarray, float]:
        """6x6 normal matrix, gradient and robust cost of a slot's colour correspondences at its pose, robust on the
        residual's norm. ``colour_residual``:

        - ``ray``: the anchor ``T q`` (world) against the track's viewing ray from the camera centre ``c`` through
          the observed point ``p``: ``r = (I - d d^T)(T q - c)``, ``d = (p - c)/|p - c|``; the depth of the
          observation (noisy: ~1.3 mm on the simulated sensor against ~0.2 mm laterally) does not enter;
          ``dr/d delta = (I - d d^T) R [I, -hat(q)]``;
        - ``point``: ``r = T^-1 p - q`` (object frame), ``dr/d delta = [-I, hat(T^-1 p)]``.

        With a projector ``proj_colour`` the term sees only the projected part of the motion since ``T_lin``."""
        o = self.opts
        P, Q, C = s.colour  # type: ignore[misc]
        Pc = s.proj_colour
        if Pc is not None and not Pc.any():
            return np.zeros((6, 6)), np.zeros(6), 0.0
        T = s.T if Pc is None or s.T_lin is None else s.T_lin @ _exp(Pc @ _log(s.lin_inv() @ s.T))
        if o.colour_residual == "ray" and C is not None:
            n = len(Q)
            r, J = _ray_residuals(np.broadcast_to(T[:3, :3], (n, 3, 3)), np.broadcast_to(T[:3, 3], (n, 3)), P, Q, C)
        else:
            J = np.zeros((len(Q), 3, 6))
            Ti = _inv(T)
            q = P @ Ti[:3, :3].T + Ti[:3, 3]
            r = q - Q
            J[:, 0, 0] = J[:, 1, 1] = J[:, 2, 2] = -1.0
            J[:, 0, 4], J[:, 0, 5] = -q[:, 2], q[:, 1]  # hat(q)
            J[:, 1, 3], J[:, 1, 5] = q[:, 2], -q[:, 0]
            J[:, 2, 3], J[:, 2, 4] = -q[:, 1], q[:, 0]
        w, rho = _robust_weights(
            np.linalg.norm(r, axis=1) / o.sigma_colour, o.robust_colour or o.robust, o.kernel_colour
        )
        w = w / o.sigma_colour**2
        H = np.einsum("n,nki,nkj->ij", w, J, J)
        b = np.einsum("n,nki,nk->i", w, J, r)
        if Pc is not None:
            H, b = Pc.T @ H @ Pc, Pc.T @ b
        return H, b, float(rho.sum())

    def _window_colour_terms(self, slots: list[_Slot]) -> dict[int, tuple[np.ndarray, np.ndarray, float]]:
        """:meth:`_colour_terms` of every slot with colour correspondences, by slot index. The ray residuals of
        slots without a colour projector are computed in ONE vectorised pass over the window's correspondences
        (the same values as one :meth:`_colour_terms` call per slot, to rounding: the per-call overhead, ~12 calls
        per frame on a few dozen tracks each, was most of the term's CPU)."""
        o = self.opts
        out: dict[int, tuple[np.ndarray, np.ndarray, float]] = {}
        batch = []
        for i, s in enumerate(slots):
            if s.colour is None:
                continue
            if s.proj_colour is not None or o.colour_residual != "ray" or s.colour[2] is None or not len(s.colour[1]):
                out[i] = self._colour_terms(s)
            else:
                batch.append(i)
        if not batch:
            return out
        # the window's correspondences do not change between cost evaluations: stacked once per window
        key = [slots[i].colour for i in batch]
        cb = self._colour_batch
        if cb is None or len(cb[0]) != len(key) or any(a is not b for a, b in zip(cb[0], key, strict=False)):
            P = np.concatenate([c[0] for c in key])  # type: ignore[index]
            Q = np.concatenate([c[1] for c in key])  # type: ignore[index]
            C = np.concatenate([c[2] for c in key])  # type: ignore[index]
            counts = [len(c[1]) for c in key]  # type: ignore[index]
            cb = self._colour_batch = (key, P, Q, C, counts, _ray_directions(P, C))
        _, P, Q, C, counts, d = cb
        R = np.repeat(np.stack([slots[i].T[:3, :3] for i in batch]), counts, axis=0)  # (N, 3, 3) each row's slot's
        t = np.repeat(np.stack([slots[i].T[:3, 3] for i in batch]), counts, axis=0)
        r, J = _ray_residuals(R, t, P, Q, C, d)  # the per-slot algebra of _colour_terms, row by row
        w, rho = _robust_weights(row_norms(r) / o.sigma_colour, o.robust_colour or o.robust, o.kernel_colour)
        w = w / o.sigma_colour**2
        # per slot, the normal equations as two BLAS products on its (3 n, 6) Jacobian (a third of the einsum's time)
        Jw = (J * w[:, None, None]).reshape(-1, 6)
        J = J.reshape(-1, 6)
        r = r.reshape(-1)
        a = 0
        for i, n in zip(batch, counts, strict=True):
            sl = slice(3 * a, 3 * (a + n))
            out[i] = (Jw[sl].T @ J[sl], Jw[sl].T @ r[sl], float(rho[a : a + n].sum()))
            a += n
        return out

    def _stick_pairs(self, fr: TrackingFrame, T_pred: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """The frame's sticking contacts that pass the blind slip test at the prediction: (world points (K, 3),
        object-frame anchors (K, 3)); None when the term is off or none passes. The ones that fail are re-anchored
        after the frame (:meth:`_stick_anchor`)."""
        o = self.opts
        self._stick_reanchor = set()
        if o.sigma_stick <= 0:
            return None
        ids = fr.info.get("stick_ids")
        P = fr.info.get("stick_points")
        if ids is None or P is None or not len(ids):
            return None
        P = np.asarray(P, np.float64)
        Nrm = fr.info.get("stick_normals")
        Nrm = np.full(P.shape, np.nan) if Nrm is None or len(Nrm) != len(P) else np.asarray(Nrm, np.float64)
        dt = o.nominal_dt if self.t_last is None else max(fr.t - self.t_last, 1e-6)
        min_step = o.stick_min_step * dt / o.nominal_dt
        Tp_inv = _inv(T_pred)
        M = T_pred @ _inv(self.T)  # predicted motion of object-fixed world points since the last frame
        keep, anchors = [], []
        for k, i in enumerate(np.asarray(ids).tolist()):
            a = self._stick_anchors.get(i)
            last = self._stick_last.get(i)
            if a is None or last is None or not np.all(np.isfinite(P[k])):
                continue
            step = P[k] - last
            n = Nrm[k] if np.all(np.isfinite(Nrm[k])) else np.zeros(3)
            tangential = np.linalg.norm(step - (step @ n) * n)
            step_err = np.linalg.norm(P[k] - (M[:3, :3] @ last + M[:3, 3]))
            anchor_err = np.linalg.norm(Tp_inv[:3, :3] @ P[k] + Tp_inv[:3, 3] - a)
            if tangential < min_step or step_err > o.stick_step_gate or anchor_err > o.stick_gate:
                self._stick_reanchor.add(i)  # slipping (or a bad prediction): start over from this frame
                continue
            keep.append(k)
            anchors.append(a)
        if not keep:
            return None
        return P[keep], np.array(anchors)

    def _solve_without_stick(self, slots: list[_Slot], v_before: np.ndarray) -> np.ndarray:
        """The current (last) slot's pose solved from the window WITHOUT the sticking term (the slots are left as they
        were): the reference of the slip test with ``stick_reference="data"``."""
        saved = [(s.T.copy(), s.stick) for s in slots]
        for s in slots:
            s.stick = None
        try:
            if self.t_last is not None:
                self._optimise(slots, v_before)
            T = slots[-1].T.copy()
        finally:
            for s, (T0, st) in zip(slots, saved, strict=True):
                s.T, s.stick = T0, st
        return T

    def _stick_anchor(self, fr: TrackingFrame, T: np.ndarray) -> None:
        """After a frame: anchor its new (or re-anchored) sticking contacts in the object frame of the committed pose
        ``T``; forget the contacts that ended."""
        if self.opts.sigma_stick <= 0:
            return
        ids = fr.info.get("stick_ids")
        P = fr.info.get("stick_points")
        ids = [] if ids is None or P is None else np.asarray(ids).tolist()
        Tinv = _inv(T)
        present = set(ids)
        for i in [i for i in self._stick_anchors if i not in present]:
            del self._stick_anchors[i]
            self._stick_last.pop(i, None)
        for k, i in enumerate(ids):
            p = np.asarray(P[k], np.float64)
            if not np.all(np.isfinite(p)):
                continue
            if i not in self._stick_anchors or i in self._stick_reanchor:
                self._stick_anchors[i] = Tinv[:3, :3] @ p + Tinv[:3, 3]
            self._stick_last[i] = p
        self._stick_reanchor = set()

    def _window_stick_terms(self, slots: list[_Slot]) -> dict[int, tuple[np.ndarray, np.ndarray, float]]:
        """Per slot with sticking contacts: normal matrix, gradient and robust cost of ``T^-1 p - anchor`` (object
        frame; Jacobian ``[-I, hat(q)]`` for the right perturbation ``T exp(xi)``, ``q = T^-1 p``)."""
        o = self.opts
        out = {}
        sig = o.sigma_stick
        for i, s in enumerate(slots):
            if s.stick is None:
                continue
            P, A = s.stick
            Ti = _inv(s.T)
            q = P @ Ti[:3, :3].T + Ti[:3, 3]
            r = q - A
            w, rho = _robust_weights(np.linalg.norm(r, axis=1) / sig, o.robust, o.kernel_stick)
            w = w / (sig * sig)
            J = np.zeros((len(q), 3, 6))
            J[:, :, :3] = -_EYE3
            J[:, :, 3:] = np.stack([_hat3(x) for x in q])
            H = np.einsum("k,kai,kaj->ij", w, J, J)
            b = np.einsum("k,kai,ka->i", w, J, r)
            out[i] = (H, b, float(rho.sum()))
        return out

    def _gate(self, fr: TrackingFrame, T_pred: np.ndarray) -> TrackingFrame:
        """Drop vision points far from the predicted surface (hand, background, flying pixels) and
        gel points of "free" sensors that would be deep inside the object (such a sensor is not free:
        its contact was missed, e.g. beyond the gel's range; pushing the object out would be wrong)."""
        F = fr.free_points
        if F is not None and len(F):
            d, _ = self.sdf.query(se3.transform_points(_inv(T_pred), F), with_grad=False)
            fr.free_points = F[d > -self.opts.free_gate]
        V = fr.vision_points
        if V is None or len(V) == 0 or self.opts.gate <= 0:
            return fr
        q = se3.transform_points(_inv(T_pred), V)
        d, _ = self.sdf.query(q, with_grad=False)
        keep = np.abs(d) < self.opts.gate
        # If the gate removes almost everything the prediction is probably off: keep all (recovery decides).
        if keep.sum() < max(10, 0.2 * len(V)):
            return fr
        fr.vision_points = V[keep]
        return fr

    def _inlier_frac(self, T: np.ndarray, fr: TrackingFrame) -> float:
        pts = [p for p in (fr.vision_points, fr.touch_points) if p is not None and len(p)]
        if not pts:
            return float("nan")
        P = np.concatenate(pts)
        d, _ = self.sdf.query(se3.transform_points(_inv(T), P), with_grad=False)
        return float(np.mean(np.abs(d) < self.opts.inlier_dist))

    @staticmethod
    def _groups(fr: TrackingFrame) -> list[tuple[str, np.ndarray]]:
        """The frame's point groups in residual order: vision ``v``, touch ``t``, free gel ``f`` (non-empty ones)."""
        groups = []
        if fr.vision_points is not None and len(fr.vision_points):
            groups.append(("v", fr.vision_points))
        if fr.touch_points is not None and len(fr.touch_points):
            groups.append(("t", fr.touch_points))
        if fr.free_points is not None and len(fr.free_points):
            groups.append(("f", fr.free_points))
        return groups

    @classmethod
    def _object_points(cls, T: np.ndarray, fr: TrackingFrame) -> np.ndarray:
        """The frame's points (:meth:`_groups` order) in the object frame of pose ``T`` (N, 3)."""
        groups = cls._groups(fr)
        if not groups:
            return np.zeros((0, 3))
        Tinv = _inv(T)
        return np.concatenate([g[1] for g in groups]) @ Tinv[:3, :3].T + Tinv[:3, 3]

    def _touch_budget(self, frame: TrackingFrame) -> int:
        """How many contact points a frame keeps (``max_touch_points``, or ``few_touch_points`` when it sees little)."""
        o = self.opts
        if o.few_touch_points <= 0:
            return o.max_touch_points
        try:
            V = frame.vision_points
            nv = 0 if V is None else int(np.isfinite(np.asarray(V, float)).all(-1).sum())
        except (TypeError, ValueError):
            nv = 0  # sanitize() names the bad array
        return o.max_touch_points if nv >= o.few_touch_min_vision else min(o.max_touch_points, o.few_touch_points)

    def _weak_vision(self, fr: TrackingFrame, n_vision: int) -> bool:
        """Whether a frame is in the weak-vision regime (``touch_weak_vision``; ``n_vision``: its segmented vision
        points when it was current, -1: count ``fr``'s)."""
        o = self.opts
        nv = fr.n_vision if n_vision < 0 else n_vision
        return o.touch_weak_vision > 0 and nv < o.touch_weak_vision

    def _normal_sigma(self, weak: bool) -> float:
        """Sigma of the contact-normal residuals (unit vectors) in a frame (``weak``: the weak-vision regime)."""
        o = self.opts
        return o.sigma_normal_weak if (weak and o.sigma_normal_weak > 0) else o.sigma_normal

    def _group_weighting(self, kind: str, weak: bool, r: np.ndarray, n_vision: int) -> tuple[float | np.ndarray, float]:
        """Sigma (m; a scalar or one per row) and robust kernel width (sigmas) of a point group's SDF residuals ``r``
        (m): ``kind`` v(ision) / t(ouch) / f(ree gel), ``weak``: the frame is in the weak-vision regime, ``n_vision``:
        its segmented depth points (``sigma_vision_few``)."""
        o = self.opts
        if kind == "v":
            few = o.sigma_vision_few > 0 and n_vision < o.few_vision_points
            return (o.sigma_vision_few if few else o.sigma_vision), o.kernel_vision
        if kind == "t" and weak:
            # vision sees too little to hold the pose: the contacts carry it, pulled onto the surface from both
            # sides (their shallow bias, ~0.3 mm median on the YCB sessions, is below this sigma)
            return o.sigma_touch_weak, o.kernel_touch
        if kind == "t":
            if o.sigma_touch_inside > 0:
                # contacts read from tactile images lie too shallow (their depth is a lower bound): a point
                # inside the surface is weak evidence, one outside it strong
                return np.where(r < 0, o.sigma_touch_inside, o.sigma_touch), o.kernel_touch
            return o.sigma_touch, o.kernel_touch
        return o.sigma_free, 1e9  # free gel points: one-sided, not robust

    def _frame_terms(
        self, T: np.ndarray, fr: TrackingFrame, n_vision: int = -1, qdg: tuple | None = None
    ) -> tuple[np.ndarray, np.ndarray, float]:
        """6x6 normal matrix, 6-vector gradient and robust cost of one frame's data at pose T (``n_vision``: the
        frame's segmented vision points when it was current, -1: count ``fr``'s; selects the weak-vision regime).
        ``qdg``: the frame's object-frame points (:meth:`_object_points`) with their SDF values, gradients and
        Jacobians (:func:`_sdf_jacobian`), and the depth / contact rows' robust weights, costs, weighted Jacobians and
        weighted residuals, when the caller computed them already (once for the whole window)."""
        o = self.opts
        nv = fr.n_vision if n_vision < 0 else n_vision
        weak = self._weak_vision(fr, nv)
        sig_normal = self._normal_sigma(weak)
        R = T[:3, :3]
        H = np.zeros((6, 6))
        b = np.zeros(6)
        cost = 0.0
        groups = self._groups(fr)
        if not groups:
            return H, b, 0.0
        rw = None
        if qdg is None:
            q = self._object_points(T, fr)
            d, g = self.sdf.query(q)
            J = _sdf_jacobian(q, g)
        else:
            q, d, g, J, rw = qdg
        s = 0
        for kind, P in groups:
            n = len(P)
            sl = slice(s, s + n)
            s += n
            r = d[sl]
            Jk = J[sl]
            if rw is not None and kind != "f":
                w, rho, Jw, wr = (x[sl] for x in rw[:4])
            else:
                sig, kern = self._group_weighting(kind, weak, r, nv)
                if kind == "f":
                    r = np.minimum(r - o.free_margin, 0.0)
                    Jk = Jk * (r < 0)[:, None]
                w, rho = _robust_weights(r / sig, o.robust if kind != "f" else "none", kern)
                w = w / (sig * sig)
                Jw, wr = Jk * w[:, None], w * r
            cost += float(rho.sum())
            H += Jw.T @ Jk
            b += Jk.T @ wr
            if kind == "t" and fr.touch_normals is not None and len(fr.touch_normals):
                if rw is not None:
                    rows = rw[4]  # the window's pass (None: no usable normal)
                else:
                    rows = None
                    ok, gnorm = self._normal_ok(fr, g[sl])
                    if ok.any():
                        n_obj = fr.touch_normals[ok] @ R  # R^T n for each row
                        rows = _normal_rows(n_obj, g[sl][ok] / gnorm[ok, None], sig_normal, sig_normal**2, o.robust)
                if rows is not None:
                    # d(R^T n)/d phi = hat(R^T n); the gradient's own change with q is neglected. In closed form
                    # (the same sums as with the (m, 3, 3) hat matrices, in another order): hat(n)^T hat(n) =
                    # |n|^2 I - n n^T and hat(n)^T r = r x n
                    n_obj, wn, rhon, wnn, nn, (c0, c1, c2) = rows
                    cost += float(rhon.sum())
                    H[3:, 3:] += _EYE3 * float(nn.sum()) - wnn.T @ n_obj
                    b[3:] += np.array([wn @ c0, wn @ c1, wn @ c2])
        return H, b, cost

    @staticmethod
    def _normal_ok(fr: TrackingFrame, g: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The contacts whose measured normal is finite and whose SDF gradient ``g`` (m, 3) is not degenerate (norm
        above 0.5: off the map's band edges), and the gradient norms (m,)."""
        gnorm = row_norms(g)
        return np.isfinite(fr.touch_normals).all(1) & (gnorm > 0.5), gnorm

    def _motion_terms(
        self, slots: list[_Slot], v_before: np.ndarray, dt_first: float
    ) -> tuple[list[tuple[list[int], list[np.ndarray], np.ndarray, np.ndarray]], float]:
        """Linearised constant-velocity and anchor residuals: (slot ids, Jacobian blocks, r, sqrt-info)."""
        o = self.opts
        terms = []
        cost = 0.0
        sig = np.array([o.sigma_motion_trans] * 3 + [o.sigma_motion_rot] * 3)
        # anchor on the oldest slot if it is a keyframe
        if len(slots) > 1:
            s0 = slots[0]
            r = _log(_inv(s0.T_prior) @ s0.T)
            sa = 1.0 / np.array([o.sigma_anchor_trans] * 3 + [o.sigma_anchor_rot] * 3)
            terms.append(([0], [_EYE6], r, sa))
            cost += 0.5 * float(((r * sa) ** 2).sum())
        prev_log = None
        prev_dt = None
        prev_ad = None  # Ad(D^-1) of the previous pair: the derivative of its log wrt its older slot, negated
        for i in range(1, len(slots)):
            D = _inv(slots[i - 1].T) @ slots[i].T
            lg = _log(D)
            dt_i = max(slots[i].t - slots[i - 1].t, 1e-6)
            scale = max(dt_i / o.nominal_dt, 1e-3)
            sq = 1.0 / (sig * scale)
            Jb = _EYE6
            ad = _adjoint(_inv(D))
            Ja = -ad
            if prev_log is None:
                v0 = slots[0].v  # velocity estimated when the oldest slot was current
                r = lg - v0 * dt_i
                terms.append(([i - 1, i], [Ja, Jb], r, sq))
            else:
                ratio = dt_i / prev_dt
                r = lg - ratio * prev_log
                # -ratio * log(Dp), Dp = T_{i-2}^-1 T_{i-1} (the previous pair's D): derivative wrt slot i-1 is
                # -ratio*I, wrt slot i-2 is +ratio*Ad(Dp^-1)
                Jc = ratio * prev_ad
                terms.append(([i - 2, i - 1, i], [Jc, Ja - ratio * _EYE6, Jb], r, sq))
            cost += 0.5 * float(((r * sq) ** 2).sum())
            prev_log, prev_dt, prev_ad = lg, dt_i, ad
        if len(slots) == 1 and self.t_last is not None:
            # single-slot window: prior towards the constant-velocity prediction
            s0 = slots[0]
            r = _log(_inv(s0.T_prior) @ s0.T)
            sq = 1.0 / (sig * max(dt_first / o.nominal_dt, 1e-3))
            terms.append(([0], [_EYE6], r, sq))
            cost += 0.5 * float(((r * sq) ** 2).sum())
        return terms, cost

    def _degeneracy(self, H: np.ndarray, n_vision: int = 0) -> tuple[np.ndarray, int, np.ndarray | None]:
        """Regulariser lifting weak eigen-directions of a 6x6 data block; their count; and the projector of a
        twist onto the strong directions (None when none is weak, ``degenerate_mode`` is ``lift`` or the frame's
        ``n_vision`` segmented points are fewer than ``project_min_vision`` but not none)."""
        o = self.opts
        L = o.object_radius
        S = np.diag([1.0, 1.0, 1.0, 1.0 / L, 1.0 / L, 1.0 / L])
        Hs = S @ H @ S
        lam, U = np.linalg.eigh(0.5 * (Hs + Hs.T))
        lam_max = max(float(lam[-1]), 0.0)
        floor = max(o.degeneracy_ratio * lam_max, 1.0 / o.sigma_vision**2)  # at least one point's worth
        weak = lam < floor
        if not weak.any():
            return np.zeros((6, 6)), 0, None
        lift = np.where(weak, floor - np.maximum(lam, 0.0), 0.0)
        Rs = (U * lift) @ U.T
        Sinv = np.linalg.inv(S)
        n_weak = int(weak.sum()) if lam_max > 0 else 6
        proj = None
        pw = weak & (lam < o.project_ratio * lam_max) if o.project_ratio > 0 else weak
        few = (0 < n_vision < o.project_min_vision) or (n_vision == 0 and not o.project_without_vision)
        if o.degenerate_mode == "project" and pw.any() and not few:
            Uw = U[:, pw]
            # twist delta = S delta_s; its strong part is S (I - Uw Uw^T) S^-1 delta
            proj = S @ (np.eye(6) - Uw @ Uw.T) @ Sinv
        return Sinv @ Rs @ Sinv, n_weak, proj

    def _touch_projector(
        self, T: np.ndarray, fr: TrackingFrame, H_vision: np.ndarray | None = None
    ) -> np.ndarray | None:
        """Projector of a twist onto the directions the frame's contacts constrain by their measured normals
        (point-to-plane information ``[-n, q x n]`` per contact, object frame, rotation scaled by the object
        radius); None when every direction is constrained, ``touch_blind_ratio`` is 0 or there are no normals.
        ``H_vision``: the frame's vision information (6x6, object-frame twist); with ``touch_vision_ratio`` > 0 the
        directions where it exceeds the contacts' by that factor are removed too."""
        o = self.opts
        if o.touch_blind_ratio <= 0 or fr.touch_points is None or fr.touch_normals is None or not fr.n_touch:
            return None
        ok = np.isfinite(fr.touch_normals).all(1) & np.isfinite(fr.touch_points).all(1)
        if not ok.any():
            return None
        Tinv = _inv(T)
        q = fr.touch_points[ok] @ Tinv[:3, :3].T + Tinv[:3, 3]
        n = fr.touch_normals[ok] @ T[:3, :3]  # R^T n
        L = o.object_radius
        J = np.concatenate([-n, np.cross(n, q) / L], axis=1)  # scaled like _degeneracy's spectrum
        Ht = J.T @ J
        lam, U = np.linalg.eigh(Ht)
        weak = lam < o.touch_blind_ratio * max(float(lam[-1]), 1e-12)
        S = np.diag([1.0, 1.0, 1.0, 1.0 / L, 1.0 / L, 1.0 / L])
        Uw = U[:, weak]
        if o.touch_vision_ratio > 0 and H_vision is not None:
            Uv = self._vision_held(Ht / o.sigma_touch_weak**2, S @ H_vision @ S)
            if Uv.shape[1]:
                # union of the two removed subspaces, orthonormal (scaled twist space)
                Q, sv, _ = np.linalg.svd(np.concatenate([Uw, Uv], axis=1), full_matrices=False)
                Uw = Q[:, sv > 1e-6]
        if not Uw.shape[1]:
            return None
        return S @ (np.eye(6) - Uw @ Uw.T) @ np.diag([1.0, 1.0, 1.0, L, L, L])

    def _vision_held(self, Ht: np.ndarray, Hv: np.ndarray) -> np.ndarray:
        """Orthonormal basis (6, k) of the directions where vision information ``Hv`` exceeds touch information
        ``Ht`` by ``touch_vision_ratio`` (both 6x6 in the same scaled twist space): generalised eigenvectors of
        ``Ht u = mu Hv u`` with ``1 / mu`` above the ratio, found by whitening with ``Hv`` floored at one vision
        point's information."""
        o = self.opts
        floor = 1.0 / o.sigma_vision**2
        lv, Uv = np.linalg.eigh(0.5 * (Hv + Hv.T))
        W = Uv / np.sqrt(np.maximum(lv, floor))  # Hv^(-1/2) in the eigenbasis: W^T Hv W ~ I
        mu, Vm = np.linalg.eigh(0.5 * (W.T @ Ht @ W + (W.T @ Ht @ W).T))
        held = mu * o.touch_vision_ratio < 1.0  # vision / touch > ratio along u = W v
        if not held.any():
            return np.zeros((6, 0))
        Q, _ = np.linalg.qr(W @ Vm[:, held])
        return Q

    def _slot_parts(self, s: _Slot, T: np.ndarray) -> list[tuple[np.ndarray, TrackingFrame, int]]:
        """The data-term evaluations ``(pose, frame, n_vision)`` of one slot at pose T: the whole frame, or, when the
        slot has a touch projector, the frame without its contacts and the contacts alone at the projected pose (the
        contacts see only their constrained part of the motion since ``T_lin``; consistent cost)."""
        if s.proj_touch is None or s.T_lin is None:
            return [(T, s.frame, s.n_vision)]
        fr = s.frame
        rest = TrackingFrame(t=fr.t, vision_points=fr.vision_points, free_points=fr.free_points, info=fr.info)
        touch = TrackingFrame(t=fr.t, touch_points=fr.touch_points, touch_normals=fr.touch_normals)
        nv = s.n_vision if s.n_vision >= 0 else fr.n_vision
        P = s.proj_touch
        return [(T, rest, nv), (s.T_lin @ _exp(P @ _log(s.lin_inv() @ T)), touch, nv)]

    def _slot_combine(self, s: _Slot, terms: list[tuple[np.ndarray, np.ndarray, float]]):
        """One slot's data terms from the terms of its :meth:`_slot_parts`."""
        if len(terms) == 1:
            return terms[0]
        (H, b, c), (Ht, bt, ct) = terms
        P = s.proj_touch
        return H + P.T @ Ht @ P, b + P.T @ bt, c + ct

    def _slot_terms(self, s: _Slot, T: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
        """One slot's data terms at pose T (see :meth:`_slot_parts`)."""
        return self._slot_combine(s, [self._frame_terms(Tp, fr, nv) for Tp, fr, nv in self._slot_parts(s, T)])

    def _window_terms(self, slots: list[_Slot]) -> list[tuple[np.ndarray, np.ndarray, float]]:
        """Every slot's data terms (:meth:`_slot_terms`, at the projected pose for a slot with a projector ``proj``),
        with ONE SDF query for the points of the whole window (the query is per point: same values as one query
        per slot, at a third of the call overhead)."""
        o = self.opts
        evals = []
        for s in slots:
            # the data says nothing reliable along a slot's weak directions: it sees (and pulls) only the strong
            # part of the motion since T_lin; the motion prior alone carries the rest
            T = s.T if s.proj is None else s.T_lin @ _exp(s.proj @ _log(s.lin_inv() @ s.T))
            evals.append(self._slot_parts(s, T))
        qs = [self._object_points(T, fr) for parts in evals for T, fr, _ in parts]
        q_all = np.concatenate(qs)
        d_all, g_all = self.sdf.query(q_all) if len(q_all) else (np.zeros(0), np.zeros((0, 3)))
        J_all = _sdf_jacobian(q_all, g_all)  # row-wise: the same rows as one per frame, in one pass
        # the robust weights of the depth and contact residuals, row-wise too: each row with its group's sigma and
        # kernel (:meth:`_group_weighting`; free gel points keep their own path in _frame_terms)
        sig_rows, kern_rows = np.ones(len(q_all)), np.ones(len(q_all))
        # ... and the contact-normal term's rows (:func:`_normal_rows`): per part, (rows of q_all, n_obj, sigma)
        nrm: list[tuple[np.ndarray, np.ndarray, float] | None] = []
        a = 0
        for T, fr, nv in (p for parts in evals for p in parts):
            nv = fr.n_vision if nv < 0 else nv
            weak = self._weak_vision(fr, nv)
            nrm.append(None)
            for kind, P in self._groups(fr):
                sl = slice(a, a + len(P))
                a += len(P)
                if kind != "f":
                    sig_rows[sl], kern_rows[sl] = self._group_weighting(kind, weak, d_all[sl], nv)
                if kind == "t" and fr.touch_normals is not None and len(fr.touch_normals):
                    ok, _ = self._normal_ok(fr, g_all[sl])
                    if ok.any():
                        nrm[-1] = (
                            sl.start + np.flatnonzero(ok),
                            fr.touch_normals[ok] @ T[:3, :3],
                            self._normal_sigma(weak),
                        )
        w_all, rho_all = _robust_weights(d_all / sig_rows, self.opts.robust, kern_rows)
        w_all = w_all / (sig_rows * sig_rows)
        Jw_all, wr_all = J_all * w_all[:, None], w_all * d_all
        used = [x for x in nrm if x is not None]
        if used:
            idx = np.concatenate([x[0] for x in used])
            counts = [len(x[0]) for x in used]
            gn = g_all[idx]
            sig = np.repeat([x[2] for x in used], counts)
            sig2 = np.repeat([x[2] ** 2 for x in used], counts)  # the scalar path's sigma**2, as a float
            rows_all = _normal_rows(
                np.concatenate([x[1] for x in used]), gn / row_norms(gn)[:, None], sig, sig2, o.robust
            )
        qdgj = []
        a = 0
        m = 0
        for q, x in zip(qs, nrm, strict=True):
            sl = slice(a, a + len(q))
            a += len(q)
            rows = None
            if x is not None:
                ns = slice(m, m + len(x[0]))
                m += len(x[0])
                n_obj, wn, rhon, wnn, nn, cross = rows_all
                rows = (n_obj[ns], wn[ns], rhon[ns], wnn[ns], nn[ns], tuple(c[ns] for c in cross))
            rw = (w_all[sl], rho_all[sl], Jw_all[sl], wr_all[sl], rows)
            qdgj.append((q, d_all[sl], g_all[sl], J_all[sl], rw))
        dgs = iter(qdgj)
        out = []
        for s, parts in zip(slots, evals, strict=True):
            Hi, bi, ci = self._slot_combine(s, [self._frame_terms(T, fr, nv, next(dgs)) for T, fr, nv in parts])
            if s.proj is not None:
                Hi, bi = s.proj.T @ Hi @ s.proj, s.proj.T @ bi
            out.append((Hi, bi, ci))
        return out

    def _total(self, slots, v_before, dt_first):
        n = len(slots)
        H = np.zeros((6 * n, 6 * n))
        b = np.zeros(6 * n)
        cost = 0.0
        datas = []
        for i, (Hi, bi, ci) in enumerate(self._window_terms(slots)):
            datas.append(Hi)
            H[6 * i : 6 * i + 6, 6 * i : 6 * i + 6] += Hi
            b[6 * i : 6 * i + 6] += bi
            cost += ci
        # after the degeneracy test and projection (see TrackerOptions.sigma_colour)
        for i, (Hc, bc, cc) in sorted(self._window_colour_terms(slots).items()):
            H[6 * i : 6 * i + 6, 6 * i : 6 * i + 6] += Hc
            b[6 * i : 6 * i + 6] += bc
            cost += cc
        for i, (Hs, bs, cs) in sorted(self._window_stick_terms(slots).items()):
            H[6 * i : 6 * i + 6, 6 * i : 6 * i + 6] += Hs
            b[6 * i : 6 * i + 6] += bs
            cost += cs
        terms, cm = self._motion_terms(slots, v_before, dt_first)
        cost += cm
        for ids, Js, r, sq in terms:
            W = sq * sq
            Wr = W * r
            for a, Ja in zip(ids, Js, strict=True):
                b[6 * a : 6 * a + 6] += Ja.T @ Wr
                JaW = Ja.T * W
                for c, Jc in zip(ids, Js, strict=True):
                    H[6 * a : 6 * a + 6, 6 * c : 6 * c + 6] += JaW @ Jc
        return H, b, cost, datas

    def _optimise(self, slots: list[_Slot], v_before: np.ndarray) -> tuple[float, int, int]:
        o = self.opts
        n = len(slots)
        dt_first = slots[-1].t - (self.t_last if self.t_last is not None else slots[-1].t - o.nominal_dt)
        for s in slots:
            s.proj = s.proj_touch = s.proj_colour = None
        H, b, cost, datas = self._total(slots, v_before, dt_first)
        dims = 0
        for i, s in enumerate(slots):
            nv = s.n_vision if s.n_vision >= 0 else s.frame.n_vision
            s.reg, d, s.proj = self._degeneracy(datas[i], nv)
            s.T_lin = s.T.copy()
            s.proj_colour = self._colour_projector(datas[i]) if s.colour is not None else None
            recent = self._t_vision is not None and s.t - self._t_vision <= o.touch_blind_vision_s
            if nv < o.touch_weak_vision and (nv > 0 or recent):
                # not in a touch-only run: there nothing else holds the directions the contacts leave free, and the
                # map's errors at least keep them near rest (touch-only SLAM, heavy sessions: 9.8 -> 33 mm with it)
                Hv = None
                if o.touch_vision_ratio > 0 and nv > 0 and s.frame.n_vision:
                    fr = s.frame
                    Hv = self._frame_terms(s.T, TrackingFrame(t=fr.t, vision_points=fr.vision_points), nv)[0]
                s.proj_touch = self._touch_projector(s.T, s.frame, Hv)
            if i == n - 1:
                dims = d
        if any(s.proj is not None or s.proj_touch is not None or s.proj_colour is not None for s in slots):
            H, b, cost, _ = self._total(slots, v_before, dt_first)
        lam = o.lm_lambda
        it = 0
        while it < o.iterations:
            it += 1
            A = H.copy()
            for i, s in enumerate(slots):
                A[6 * i : 6 * i + 6, 6 * i : 6 * i + 6] += s.reg
            A += lam * np.diag(np.diag(A) + 1e-9)
            try:
                delta = -np.linalg.solve(A, b)
            except np.linalg.LinAlgError:
                delta = -np.linalg.lstsq(A, b, rcond=None)[0]
            if not np.all(np.isfinite(delta)):
                break
            old = [s.T.copy() for s in slots]
            for i, s in enumerate(slots):
                d = delta[6 * i : 6 * i + 6].copy()
                nt, nr = np.linalg.norm(d[:3]), np.linalg.norm(d[3:])
                if nt > o.max_step_trans:
                    d[:3] *= o.max_step_trans / nt
                if nr > o.max_step_rot:
                    d[3:] *= o.max_step_rot / nr
                s.T = s.T @ _exp(d)
            step = delta.reshape(-1, 6)
            small = np.abs(step[:, :3]).max() < o.converge_trans and np.abs(step[:, 3:]).max() < o.converge_rot
            if small and o.small_step == "accept":
                break  # converged; ``cost`` stays the last evaluated one (reported only)
            H2, b2, cost2, _ = self._total(slots, v_before, dt_first)
            if cost2 <= cost:
                converged = cost - cost2 < 1e-4 * max(cost, 1e-12) or small
                H, b, cost = H2, b2, cost2
                lam = max(lam / 3.0, 1e-7)
                if converged:
                    break
            else:
                for s, T in zip(slots, old, strict=True):
                    s.T = T
                lam = min(lam * 10.0, 1e4)
        for s in slots:
            s.T[:3, :3] = se3.orthonormalize(s.T[:3, :3])
        return float(cost), it, dims

    def _recover(
        self, cur: _Slot, slots: list[_Slot], v_before: np.ndarray, T_pred: np.ndarray, info: StepInfo
    ) -> bool:
        """Try a few restarts (zero velocity, centroid shift) on the current frame alone; keep the best."""
        fr = cur.frame
        best_T, best_f = cur.T.copy(), info.inlier_frac
        starts = [self.T.copy()]  # previous estimate without velocity
        pts = [p for p in (fr.vision_points, fr.touch_points) if p is not None and len(p)]
        if pts:
            P = np.concatenate(pts)
            # Move the object so the points' centroid projects onto the surface (translation-only seed).
            for T0 in (T_pred, self.T):
                Tt = T0.copy()
                for _ in range(10):
                    q = se3.transform_points(_inv(Tt), P)
                    d, g = self.sdf.query(q)
                    shift = -np.median(d[:, None] * g, axis=0)  # object-frame shift of points to surface
                    Tt[:3, 3] -= Tt[:3, :3] @ shift
                starts.append(Tt)
        for T0 in starts:
            s = _Slot(T=T0.copy(), t=cur.t, frame=fr, T_prior=T0.copy())
            saved = self.t_last
            self.t_last = None  # no motion prior during recovery
            try:
                self._optimise([s], np.zeros(6))
            finally:
                self.t_last = saved
            f = self._inlier_frac(s.T, fr)
            if np.isfinite(f) and f > best_f:
                best_T, best_f = s.T.copy(), f
        cur.T = best_T
        info.inlier_frac = best_f
        return bool(best_f >= self.opts.lost_inlier_frac)

    def _bound(self, cur: _Slot, T_pred: np.ndarray) -> None:
        """Keep the estimate finite and within the per-frame correction bound of the prediction."""
        o = self.opts
        if not np.all(np.isfinite(cur.T)):
            cur.T = T_pred.copy()
            return
        dx = _log(_inv(T_pred) @ cur.T)
        nt, nr = np.linalg.norm(dx[:3]), np.linalg.norm(dx[3:])
        f = min(1.0, o.max_correction_trans / max(nt, 1e-12), o.max_correction_rot / max(nr, 1e-12))
        if f < 1.0:
            cur.T = T_pred @ _exp(dx * f)

    def _commit(self, slots: list[_Slot], cur: _Slot, dt: float) -> None:
        o = self.opts
        if self.t_last is not None and dt > 0:
            prev_T = slots[-2].T if len(slots) > 1 else self.T
            prev_t = slots[-2].t if len(slots) > 1 else self.t_last
            v = _log(_inv(prev_T) @ cur.T) / max(cur.t - prev_t, 1e-6)
            if np.all(np.isfinite(v)):
                self.velocity = v
        cur.v = self.velocity.copy()
        self.T = cur.T.copy()
        self.t_last = cur.t
        last_kf = self.keyframes[-1] if self.keyframes else None
        promote = last_kf is None
        if last_kf is not None:
            dx = _log(_inv(last_kf.T) @ cur.T)
            promote = (
                np.linalg.norm(dx[:3]) > o.kf_trans or np.linalg.norm(dx[3:]) > o.kf_rot or cur.t - last_kf.t > o.kf_dt
            )
        if promote and o.window > 1:
            cur.T_prior = cur.T.copy()
            cur.frame = sanitize(
                cur.frame, o.kf_vision_points, o.kf_touch_points, o.max_free_points, seed=o.seed + self._frame_count
            )
            self.keyframes.append(cur)
            self.keyframes = self.keyframes[-(o.window - 1) :]
        # keyframes refined in this window keep their new estimates as priors for the anchor (the oldest too with
        # ``anchor_refresh``)
        for s in self.keyframes:
            s.T_prior = s.T.copy() if (o.anchor_refresh or s is not self.keyframes[0]) else s.T_prior
