"""Grasp placement, object trajectory and fingertip contacts by inverse kinematics.

World frame = the hand's world frame of the scene (``hand.T_world_base``). The object is placed
between the four fingertips of a nominal grasp posture: its shortest bounding-box axis along the
squeeze direction (fingers vs thumb), its longest along the line of fingertips. It then rotates
about ``sim.rotation_axis`` (object frame, through the object centre) at ``sim.rotation_speed`` (with a
smooth 0.5 s ramp-in) and translates by a small Lissajous wobble of ``sim.translation_amplitude``.

Each finger closes along a one-parameter *closing synergy* ``q(s) = q_open + s (q_closed - q_open)``
(its own joints only, inside the joint limits) until its gel is indented by the target depth ``d``:
for every frame and finger, ``s`` is found by batched bisection on the ray-cast gel indentation
(max of the height map), so the penetration is exact (to ~0.02 mm) whenever the finger reaches the
object, and contacts slide over the surface as the object turns. ``d`` follows a slow per-finger
schedule inside ``sim.penetration_mm``. The object's rest position is chosen by a grid search so
that every finger meets it mid-way along its synergy with the largest contact patch. Finger
gaiting opens one finger at a time (contact breaks) and closes it again (contact re-made).
The general batched IK (:mod:`vtrack.kinematics.ik`) then optionally re-aligns each gel with the
surface normal while keeping the depth (``align_normals``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vtrack.geometry import se3
from vtrack.geometry.raycast import Raycaster
from vtrack.kinematics.hand import HandKinematics
from vtrack.sim.objects import ObjectMesh

#: Allegro closing synergy (rad, joint_0.0 .. joint_15.0): open and closed postures, thumb opposed.
# Both sweeps converge in front of the palm: fingers curl down and back, the thumb up and back.
ALLEGRO_OPEN = np.array([0.0, 0.2, 0.2, 0.2, 0.0, 0.2, 0.2, 0.2, 0.0, 0.2, 0.2, 0.2, 1.35, 0.4, 0.0, 0.0])
ALLEGRO_CLOSED = np.array([0.0, 1.5, 1.6, 1.5, 0.0, 1.5, 1.6, 1.5, 0.0, 1.5, 1.6, 1.5, 1.35, 0.4, 0.6, 1.7])

FINE_STRIDE_MM = 0.5  # grid of the indentation checks (thin features such as can rims are ~1 mm)
MAX_CLOSING_RATE = 1.2  # synergy units per second (~1.7 rad/s per joint): no finger jumps
LIFT_S = 0.12  # how far (in synergy units) a gaiting finger opens
# contact_mode "stick" (see _stick_plan)
STICK_POS_TOL = 0.3e-3  # m, the gel origin follows its object-fixed target at least this well ...
STICK_NORMAL_TOL = 0.2  # rad, ... and its normal; else the finger gaits
STICK_NORMAL_WEIGHT = 0.01  # m/rad: the contact's position matters more than the gel's tilt
STICK_GAIT_S = 0.1  # s, one gait (open, move back, re-close)
STICK_DRIFT_TOL = 0.7e-3  # m, ... and the patch centre stays this close to where it was in the object frame
STICK_DEPTH_TOL_MM = 0.3  # a contact-phase frame's indentation stays this close to the phase's first frame


@dataclass
class GraspPlan:
    """Result of planning: everything sampled at ``times`` (s)."""

    times: np.ndarray  # (N,)
    T_world_object: np.ndarray  # (N, 4, 4)
    q: np.ndarray  # (N, J) true joint angles, rad
    in_contact_phase: dict[str, np.ndarray]  # sensor -> (N,) bool (not lifted by gaiting, surface found)
    target_penetration_mm: dict[str, np.ndarray]  # sensor -> (N,)
    measured_penetration_mm: dict[str, np.ndarray]  # sensor -> (N,) max gel indentation (coarse grid)
    T0: np.ndarray  # (4, 4) rest pose of the object
    axis_world: np.ndarray  # (3,) rotation axis, world
    speed: float  # rad/s
    amplitude: float  # m

    def object_pose_at(self, times: np.ndarray) -> np.ndarray:
        """Exact ``T_world_object`` (N, 4, 4) at any times (s) (the trajectory is analytic)."""
        return object_trajectory(self.T0, np.asarray(times, np.float64), self.axis_world, self.speed, self.amplitude)

    def q_at(self, times: np.ndarray) -> np.ndarray:
        """Joint vectors (N, J) at any times, linearly interpolated (as readers interpolate)."""
        t = np.asarray(times, np.float64)
        return np.stack([np.interp(t, self.times, self.q[:, j]) for j in range(self.q.shape[1])], axis=1)


def lipschitz_envelope(s: np.ndarray, step: float) -> np.ndarray:
    """Largest sequence <= ``s`` changing by at most ``step`` per sample (forward + backward pass).

    When the first contact jumps to another part of the object (a rim, an edge), the finger opens
    early and moves over smoothly instead of teleporting; it never presses deeper than planned.
    """
    e = np.asarray(s, dtype=np.float64).copy()
    for i in range(1, len(e)):
        e[i] = min(e[i], e[i - 1] + step)
    for i in range(len(e) - 2, -1, -1):
        e[i] = min(e[i], e[i + 1] + step)
    return e


def closing_synergy(hk: HandKinematics) -> tuple[np.ndarray, np.ndarray]:
    """(q_open, q_closed) (J,) rad of the hand's closing synergy (Allegro preset, else from limits)."""
    if hk.joint_names == [f"joint_{i}.0" for i in range(16)]:
        return hk.clip_to_limits(ALLEGRO_OPEN), hk.clip_to_limits(ALLEGRO_CLOSED)
    lo = np.where(np.isfinite(hk.lower), hk.lower, -1.0)
    hi = np.where(np.isfinite(hk.upper), hk.upper, 1.0)
    return lo + 0.1 * (hi - lo), lo + 0.9 * (hi - lo)


def _finger_columns(hk: HandKinematics) -> dict[str, list[int]]:
    return {s: hk.chain_joints(hk.sensor_links[s]) for s in hk.sensor_names}


def _posture(
    q_open: np.ndarray, q_closed: np.ndarray, cols: dict[str, list[int]], s_by_sensor: dict[str, np.ndarray]
) -> np.ndarray:
    """(N, J) joint vectors with each finger's joints at its synergy value (other joints open)."""
    n = len(next(iter(s_by_sensor.values())))
    q = np.repeat(q_open[None], n, 0)
    for s, c in cols.items():
        if s in s_by_sensor:
            q[:, c] = q_open[c] + s_by_sensor[s][:, None] * (q_closed[c] - q_open[c])
    return q


def _max_indentation(
    hk, obj_rc, T_ow, q, sensor, spec, stride_mm: float = FINE_STRIDE_MM
) -> tuple[np.ndarray, np.ndarray]:
    """Max gel indentation (mm) and contact-pixel fraction of ``sensor`` for postures ``q`` (N, J)."""
    T = hk.sensor_poses(q)[sensor]
    stride = max(1, int(round(stride_mm / spec.mm_per_px)))
    h = gel_heights(
        obj_rc, T_ow @ T, spec.width, spec.height, spec.mm_per_px, spec.gel_thickness_mm, stride=stride
    ).reshape(len(q), -1)
    return h.max(1).astype(np.float64), (h > spec.contact_threshold_mm).mean(1)


def _closest_contacts(obj_rc: Raycaster, T_wo: np.ndarray, gel_world: np.ndarray, gel_normal: np.ndarray):
    """Closest object surface point (world) and outward normal for gel centres (N, 3), world frame."""
    T_ow = se3.invert(T_wo)
    g_o = se3.transform_points(T_ow, gel_world[:, None])[:, 0]
    p, nrm = obj_rc.closest(g_o)
    p_w = se3.transform_points(T_wo, p[:, None])[:, 0]
    n_w = np.einsum("nij,nj->ni", T_wo[:, :3, :3], nrm)
    # Faceted normals may point inwards for a gel already inside: always push the gel back out.
    flip = np.einsum("ni,ni->n", n_w, gel_normal) > 0
    return p_w, np.where(flip[:, None], -n_w, n_w)


def _close_to_depth(
    hk,
    obj_rc,
    T_ow,
    q_open,
    q_closed,
    cols,
    sensor,
    spec,
    depth_mm: np.ndarray,
    scan: int = 12,
    iters: int = 8,
    guess: np.ndarray | None = None,
    window: float = 0.04,
) -> tuple[np.ndarray, np.ndarray]:
    """Per frame, the synergy value where ``sensor`` first reaches ``depth_mm`` of indentation.

    The closing motion is scanned coarsely (first level that is deep enough = first contact, as a
    real finger stops there), then bisected inside that interval. Returns ``s`` (N,) and
    ``reached`` (N,): False where the closed hand never reaches the depth (then ``s`` = 1).
    With ``guess`` (N,), frames whose depth is bracketed by ``guess +- window`` skip the scan.
    """
    n = len(T_ow)
    if guess is not None:
        lo = np.clip(guess - window, 0.0, 1.0)
        hi = np.clip(guess + window, 0.0, 1.0)
        h_lo, _ = _max_indentation(hk, obj_rc, T_ow, _posture(q_open, q_closed, cols, {sensor: lo}), sensor, spec)
        h_hi, _ = _max_indentation(hk, obj_rc, T_ow, _posture(q_open, q_closed, cols, {sensor: hi}), sensor, spec)
        ok = (h_lo < depth_mm) & (h_hi >= depth_mm)
        s_out = np.ones(n)
        reached = np.zeros(n, bool)
        if (~ok).any():
            bad = np.nonzero(~ok)[0]
            s_out[bad], reached[bad] = _close_to_depth(
                hk, obj_rc, T_ow[bad], q_open, q_closed, cols, sensor, spec, depth_mm[bad], scan, iters
            )
        if ok.any():
            good = np.nonzero(ok)[0]
            a, b = lo[good], hi[good]
            for _ in range(iters):
                mid = 0.5 * (a + b)
                h, _ = _max_indentation(
                    hk, obj_rc, T_ow[good], _posture(q_open, q_closed, cols, {sensor: mid}), sensor, spec
                )
                deep = h >= depth_mm[good]
                b = np.where(deep, mid, b)
                a = np.where(deep, a, mid)
            s_out[good] = 0.5 * (a + b)
            reached[good] = True
        return s_out, reached
    levels = np.linspace(0.0, 1.0, scan + 1)
    first = np.full(n, -1)
    for k, lv in enumerate(levels):
        todo = first < 0
        if not todo.any():
            break
        h, _ = _max_indentation(
            hk, obj_rc, T_ow[todo], _posture(q_open, q_closed, cols, {sensor: np.full(todo.sum(), lv)}), sensor, spec
        )
        idx = np.nonzero(todo)[0]
        first[idx[h >= depth_mm[todo]]] = k
    reached = first > 0
    hi = np.where(reached, levels[np.maximum(first, 0)], 1.0)
    lo = np.where(reached, levels[np.maximum(first - 1, 0)], 1.0)
    for _ in range(iters):
        mid = 0.5 * (lo + hi)
        h, _ = _max_indentation(hk, obj_rc, T_ow, _posture(q_open, q_closed, cols, {sensor: mid}), sensor, spec)
        deep = h >= depth_mm
        hi = np.where(deep, mid, hi)
        lo = np.where(deep, lo, mid)
    return np.where(reached, 0.5 * (lo + hi), 1.0), reached


def object_rest_pose(hk: HandKinematics, obj: ObjectMesh, q_ref: np.ndarray) -> np.ndarray:
    """Object orientation (and a first centre) between the fingertips of posture ``q_ref``: shortest
    extent along the squeeze direction (fingers -> thumb), longest along the line of fingertips."""
    sp = hk.sensor_poses(q_ref)
    names = hk.sensor_names
    g = np.stack([sp[s][0, :3, 3] for s in names])
    thumb = [i for i, s in enumerate(names) if "thumb" in s]
    fingers = [i for i in range(len(names)) if i not in thumb]
    if thumb and fingers:
        squeeze = g[fingers].mean(0) - g[thumb].mean(0)
        centre = 0.5 * (g[fingers].mean(0) + g[thumb].mean(0))
        spread = g[fingers[-1]] - g[fingers[0]] if len(fingers) > 1 else np.cross(squeeze, [1.0, 0, 0])
    else:  # no thumb: squeeze along the mean gel normal, object just in front of the gels
        nrm = np.stack([sp[s][0, :3, 2] for s in names]).mean(0)
        squeeze = -nrm
        centre = g.mean(0) + nrm * 0.5 * float(obj.extents.min())
        spread = g[-1] - g[0] if len(g) > 1 else np.cross(squeeze, [1.0, 0, 0])
    z = squeeze / max(np.linalg.norm(squeeze), 1e-12)
    y = spread - z * (spread @ z)
    if np.linalg.norm(y) < 1e-9:
        y = np.cross(z, [1.0, 0.0, 0.0])
    y /= np.linalg.norm(y)
    x = np.cross(y, z)
    R_world_target = np.stack([x, y, z], axis=1)
    # Object axes sorted by extent: shortest -> squeeze (z), middle -> x, longest -> spread (y).
    order = np.argsort(obj.extents)
    R_target_obj = np.zeros((3, 3))
    for target_axis, obj_axis in zip((2, 0, 1), order, strict=True):
        R_target_obj[target_axis, obj_axis] = 1.0
    if np.linalg.det(R_target_obj) < 0:
        R_target_obj[0] *= -1.0
    return se3.make_transform(R_world_target @ R_target_obj, centre)


def object_trajectory(
    T0: np.ndarray, times: np.ndarray, axis, speed: float, amplitude: float, ramp_s: float = 0.5
) -> np.ndarray:
    """(N, 4, 4) object poses: rotation about a world ``axis`` through the object centre at ``speed``
    rad/s (cosine ramp-in over ``ramp_s``), plus a Lissajous translation of ``amplitude`` m."""
    t = np.asarray(times, dtype=np.float64)
    a = np.asarray(axis, dtype=np.float64)
    a = a / max(np.linalg.norm(a), 1e-12)
    # angle = speed * integral of the ramp, so angular velocity rises smoothly from 0.
    r = np.clip(t / max(ramp_s, 1e-9), 0.0, 1.0)
    ramp_int = np.where(t < ramp_s, ramp_s * (r - np.sin(np.pi * r) / np.pi) / 2.0, t - ramp_s / 2.0)
    angle = speed * ramp_int
    R = se3.so3_exp(a[None] * angle[:, None])
    env = 0.5 - 0.5 * np.cos(np.pi * r)
    trans = (
        amplitude
        * env[:, None]
        * np.stack(
            [np.sin(2 * np.pi * 0.37 * t), np.sin(2 * np.pi * 0.23 * t + 1.0), np.sin(2 * np.pi * 0.29 * t + 2.0)],
            axis=1,
        )
    )
    T = np.repeat(T0[None], len(t), axis=0)
    T[:, :3, :3] = R @ T0[:3, :3]
    T[:, :3, 3] = T0[:3, 3] + trans
    return T


def gel_heights(
    obj_rc: Raycaster,
    T_object_sensor: np.ndarray,
    width: int,
    height: int,
    mm_per_px: float,
    thickness_mm: float,
    stride: int = 1,
    max_rays: int = 400_000,
) -> np.ndarray:
    """Gel indentation height maps (mm, >= 0) by casting one ray per pixel along the gel normal.

    Rays start ``thickness_mm`` below the gel surface (inside the sensor) and go along +z of the
    sensor frame; an object surface met before the gel surface (z < 0) indents the gel by -z.
    At full resolution (``stride`` 1) a 4-px pre-pass finds where the object is near the gel and
    only that window (plus a margin) is cast per pixel; pixels outside it are 0.

    Args:
        obj_rc: ray caster holding the object mesh in the object frame.
        T_object_sensor: (N, 4, 4) sensor poses in the object frame.
        stride: sample every ``stride``-th pixel (coarse maps for the IK feedback).

    Returns:
        (N, ceil(H/stride), ceil(W/stride)) float32 heights in mm, clipped to the gel thickness.
    """
    if stride == 1 and min(width, height) >= 32:
        return _gel_heights_windowed(obj_rc, T_object_sensor, width, height, mm_per_px, thickness_mm, max_rays)
    rows = np.arange(0, height, stride)
    cols = np.arange(0, width, stride)
    return _cast_heights(obj_rc, T_object_sensor, rows, cols, width, height, mm_per_px, thickness_mm, max_rays)


def _cast_heights(
    obj_rc, T_object_sensor, rows, cols, width, height, mm_per_px, thickness_mm, max_rays, probe_mm: float = 0.0
) -> np.ndarray:
    s = mm_per_px / 1000.0
    X, Y = np.meshgrid((cols - (width - 1) / 2.0) * s, (rows - (height - 1) / 2.0) * s)
    thk = thickness_mm / 1000.0
    o_s = np.stack([X, Y, np.full_like(X, -thk)], axis=-1).reshape(-1, 3)
    out = np.zeros((len(T_object_sensor), len(rows), len(cols)), dtype=np.float32)
    chunk = max(1, max_rays // len(o_s))
    for i0 in range(0, len(T_object_sensor), chunk):
        T = T_object_sensor[i0 : i0 + chunk]
        o = np.matmul(o_s[None], np.swapaxes(T[:, :3, :3], 1, 2)) + T[:, None, :3, 3]
        d = np.broadcast_to(T[:, None, :3, 2], o.shape)
        hit = obj_rc.cast(o, d)
        t = hit["t"]
        # probe_mm > 0 reports surfaces up to probe_mm *outside* the gel as negative heights.
        h = np.where(np.isfinite(t), (thk - t) * 1000.0, -np.inf)  # z_hit = -thk + t
        # A first hit on a back face (normal along the ray) means the ray started inside the object:
        # the gel is buried, i.e. fully indented. Without this a finger stepping past the thin
        # surface shell between two scan levels reads "no contact" and closes through the object.
        inside = np.isfinite(t) & (np.einsum("...i,...i->...", hit["normal"], d) > 0)
        h = np.where(inside, thickness_mm, h)
        out[i0 : i0 + chunk] = np.clip(h, -probe_mm, thickness_mm).reshape(len(T), len(rows), len(cols))
    return out


def _gel_heights_windowed(obj_rc, T_os, width, height, mm_per_px, thickness_mm, max_rays, step: int = 4):
    rows_c = np.arange(0, height, step)
    cols_c = np.arange(0, width, step)
    # Probe 3 mm beyond the gel so the window also covers thin features between coarse samples.
    coarse = _cast_heights(obj_rc, T_os, rows_c, cols_c, width, height, mm_per_px, thickness_mm, max_rays, probe_mm=3.0)
    out = np.zeros((len(T_os), height, width), dtype=np.float32)
    near = coarse > -3.0
    for i in np.nonzero(near.any(axis=(1, 2)))[0]:
        rr, cc = np.nonzero(near[i])
        r0 = max(0, (rr.min() - 2) * step)
        r1 = min(height, (rr.max() + 3) * step)
        c0 = max(0, (cc.min() - 2) * step)
        c1 = min(width, (cc.max() + 3) * step)
        win = _cast_heights(
            obj_rc,
            T_os[i : i + 1],
            np.arange(r0, r1),
            np.arange(c0, c1),
            width,
            height,
            mm_per_px,
            thickness_mm,
            max_rays,
        )[0]
        out[i, r0:r1, c0:c1] = np.maximum(win, 0.0)
    return out


def _fit_rest_pose(
    hk, obj, obj_rc, tactile_specs, q_open, q_closed, cols, depth_mm: float, n_s: int = 41, iters: int = 20
) -> np.ndarray:
    """Rest pose where every gel can lie flush on the object.

    For finger f at synergy value s the gel centre is P_f(s) with inward normal N_f(s); the object
    centre that makes that gel flush is c_f(s) = P_f(s) + (r_f(s) - d) N_f(s), where r_f(s) is the
    object's radius in direction -N_f(s) (ray cast from the centre; exact for spheres, close for
    convex shapes). The rest centre is the point closest to all four curves c_f (alternating
    nearest point / mean, like 1-means), with the orientation of :func:`object_rest_pose`.
    """
    T0 = object_rest_pose(hk, obj, _posture(q_open, q_closed, cols, {s: np.full(1, 0.3) for s in cols})[0])
    R0 = T0[:3, :3]
    sv = np.linspace(0.1, 0.9, n_s)
    curves = []
    for s in hk.sensor_names:
        T = hk.sensor_poses(_posture(q_open, q_closed, cols, {s: sv}))[s]
        P, N = T[:, :3, 3], T[:, :3, 2]
        d_obj = (-N) @ R0  # directions in the object frame (rows: R0^T @ -N)
        hit = obj_rc.cast(np.zeros_like(d_obj), d_obj)
        r = np.where(np.isfinite(hit["t"]), hit["t"], np.nan)
        curves.append(P + (r - depth_mm / 1000.0)[:, None] * N)
    pts = np.concatenate([c[np.isfinite(c).all(1)] for c in curves])
    if len(pts) == 0:
        return T0
    c = pts.mean(0)
    for _ in range(iters):
        near = []
        for cv in curves:
            ok = np.isfinite(cv).all(1)
            if ok.any():
                near.append(cv[ok][np.argmin(np.linalg.norm(cv[ok] - c, axis=1))])
        c = np.mean(near, axis=0)
    T = T0.copy()
    T[:3, 3] = c
    return T


def _tune_first_joints(
    hk, obj_rc, T_ow, q_open, q_closed, cols, tactile_specs, depth_mm: float, offsets: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Per finger, shift its first joint (abduction / thumb rotation) in the synergy so the gel meets
    the object flush: the offset giving the largest contact patch at the target depth over a few
    sample frames (a gel touching with its edge gives a thin sliver; flush gives a patch)."""
    offsets = np.linspace(-0.3, 0.3, 7) if offsets is None else offsets
    q_open, q_closed = q_open.copy(), q_closed.copy()
    m = len(T_ow)
    for s in hk.sensor_names:
        j = cols[s][0]
        lo = hk.lower[j] if np.isfinite(hk.lower[j]) else -np.inf
        hi = hk.upper[j] if np.isfinite(hk.upper[j]) else np.inf
        best, best_score = 0.0, -np.inf
        for off in offsets:
            qo, qc = q_open.copy(), q_closed.copy()
            qo[j] = np.clip(qo[j] + off, lo, hi)
            qc[j] = np.clip(qc[j] + off, lo, hi)
            sv, ok = _close_to_depth(
                hk, obj_rc, T_ow, qo, qc, cols, s, tactile_specs[s], np.full(m, depth_mm), scan=10, iters=5
            )
            _, area = _max_indentation(hk, obj_rc, T_ow, _posture(qo, qc, cols, {s: sv}), s, tactile_specs[s])
            score = float(np.where(ok, area, -1.0).mean()) - 0.02 * abs(off)  # prefer small changes
            if score > best_score:
                best, best_score = off, score
        q_open[j] = np.clip(q_open[j] + best, lo, hi)
        q_closed[j] = np.clip(q_closed[j] + best, lo, hi)
    return q_open, q_closed


def plan_grasp(
    hk: HandKinematics,
    obj: ObjectMesh,
    obj_rc: Raycaster,
    sim,
    tactile_specs: dict,
    times: np.ndarray,
    rng: np.random.Generator,
    align_normals: bool = False,
) -> GraspPlan:
    """Object trajectory and joint angles keeping every fingertip in contact (see module docstring).

    Args:
        sim: the scene's :class:`~vtrack.scene.schema.SimSpec` (penetration range, motion, gaiting).
        tactile_specs: sensor name -> :class:`~vtrack.scene.schema.TactileSpec` (gel geometry).
        times: (N,) joint-state times, s.
    """
    n = len(times)
    names = hk.sensor_names
    q_open, q_closed = closing_synergy(hk)
    cols = _finger_columns(hk)
    lo, hi = (float(v) for v in sim.penetration_mm)
    span = hi - lo
    T0 = _fit_rest_pose(hk, obj, obj_rc, tactile_specs, q_open, q_closed, cols, lo + 0.5 * span)
    # sim.rotation_axis is given in the object frame (bounding-box-centred mesh axes).
    axis_world = T0[:3, :3] @ np.asarray(sim.rotation_axis, dtype=np.float64)
    T_wo = object_trajectory(T0, times, axis_world, sim.rotation_speed, sim.translation_amplitude)
    T_ow = se3.invert(T_wo)
    q_open, q_closed = _tune_first_joints(
        hk,
        obj_rc,
        T_ow[np.linspace(0, n - 1, min(n, 6)).astype(int)],
        q_open,
        q_closed,
        cols,
        tactile_specs,
        lo + 0.5 * span,
    )

    d_target, lift = {}, {}
    fingers = [s for s in names if "thumb" not in s]
    for s in names:
        period = rng.uniform(1.5, 3.0)
        phase = rng.uniform(0, 2 * np.pi)
        d_target[s] = lo + span * (0.5 + 0.3 * np.sin(2 * np.pi * times / period + phase))
        lift[s] = np.zeros(n)
        if sim.finger_gaiting and s in fingers:
            # One finger at a time: each opens for 0.5 s in a cycle of 0.5 s per finger + 1 s.
            cycle = 0.5 * len(fingers) + 1.0
            start = 1.0 + 0.5 * fingers.index(s)
            u = ((times - start) % cycle) / 0.5
            lifting = (times >= start) & (u < 1.0)
            lift[s] = np.where(lifting, LIFT_S * np.sin(np.pi * np.clip(u, 0, 1)) ** 2, 0.0)

    s_val, phase_ok, meas = {}, {}, {}
    for s in names:
        # Full scan for every frame: the *first* contact along the closing motion (a local bracket
        # around the previous solution may find a later, deeper branch).
        sv, ok = _close_to_depth(hk, obj_rc, T_ow, q_open, q_closed, cols, s, tactile_specs[s], d_target[s])
        dt = float(np.median(np.diff(times))) if n > 1 else 1.0
        s_env = lipschitz_envelope(sv, MAX_CLOSING_RATE * dt)
        # Opening is not always safe: the gel's lower part can swing into the object. Where the
        # smoothed posture would press deeper than the range, keep the planned (exact) one.
        h_env, _ = _max_indentation(hk, obj_rc, T_ow, _posture(q_open, q_closed, cols, {s: s_env}), s, tactile_specs[s])
        bad = np.nonzero(h_env > hi)[0]
        if bad.size:
            # Move only as far towards the planned posture as needed (smallest jump in range).
            a, b = np.zeros(bad.size), np.ones(bad.size)
            for _ in range(8):
                mid = 0.5 * (a + b)
                s_try = s_env[bad] + mid * (sv[bad] - s_env[bad])
                h_try, _ = _max_indentation(
                    hk, obj_rc, T_ow[bad], _posture(q_open, q_closed, cols, {s: s_try}), s, tactile_specs[s]
                )
                ok_try = h_try <= hi
                b = np.where(ok_try, mid, b)
                a = np.where(ok_try, a, mid)
            s_env[bad] = s_env[bad] + b * (sv[bad] - s_env[bad])
        s_val[s] = np.clip(s_env - lift[s], 0.0, 1.0)
        phase_ok[s] = ok & (lift[s] <= 0.0)
    q = _posture(q_open, q_closed, cols, s_val)
    if align_normals:
        q = _align_gels(hk, obj_rc, T_wo, q, tactile_specs, d_target, phase_ok)
    stick = getattr(sim, "contact_mode", "slide") == "stick"
    if stick:
        q, phase_ok, d_target = _stick_plan(hk, obj_rc, T_wo, q, phase_ok, cols, tactile_specs, q_open, q_closed, times)
    for s in names:
        meas[s], _ = _max_indentation(hk, obj_rc, T_ow, q, s, tactile_specs[s], stride_mm=FINE_STRIDE_MM)
        # A first contact can jump (e.g. onto a rim) inside a bisection bracket: not a controlled contact.
        # (stick: the IK follows the object to STICK_POS_TOL, so the depth may be off by about that much)
        phase_ok[s] &= np.abs(meas[s] - d_target[s]) < (STICK_DEPTH_TOL_MM + 0.05 if stick else 0.15)
    return GraspPlan(
        times,
        T_wo,
        q,
        phase_ok,
        d_target,
        meas,
        T0,
        axis_world,
        float(sim.rotation_speed),
        float(sim.translation_amplitude),
    )


def _stick_plan(
    hk, obj_rc, T_wo, q_slide, phase_slide, cols, tactile_specs, q_open, q_closed, times
) -> tuple[np.ndarray, dict[str, np.ndarray], dict[str, np.ndarray]]:
    """``contact_mode: stick``: fingers in contact follow the object, then gait when they cannot.

    Per finger, a contact phase starts where the sliding plan holds a controlled contact (``phase_slide``): the
    sensor's pose in the object frame at that frame, ``T_os``, is frozen and the finger's joints are solved per
    frame by the batched IK (:func:`vtrack.kinematics.ik.solve_sensor_ik`) so the gel follows ``T_wo @ T_os``
    (origin exactly, normal softly: a finger has 4 joints). The phase ends at the first frame the IK misses by more
    than ``STICK_POS_TOL`` (m) or ``STICK_NORMAL_TOL`` (rad) (workspace / joint limits), or the patch centre moves
    by more than ``STICK_DRIFT_TOL`` on the object or its depth by ``STICK_DEPTH_TOL_MM``: the finger then gaits for
    ``STICK_GAIT_S`` (opens by up to ``LIFT_S`` synergy units while blending back to its sliding-plan posture, no
    contact phase) and a new phase starts on the point it closes on. Fingers are independent chains, so each is
    solved alone. Returns the joint vectors (N, J), the contact phases and the target depths (the depth at each
    phase's first frame; mm).
    """
    from vtrack.kinematics.ik import solve_sensor_ik

    n = len(T_wo)
    dt = float(np.median(np.diff(times))) if n > 1 else 1.0
    n_gait = max(2, int(round(STICK_GAIT_S / dt)))
    q = q_slide.copy()
    sp = hk.sensor_poses(q_slide)
    T_ow = se3.invert(T_wo)
    phase = {s: np.zeros(n, bool) for s in hk.sensor_names}
    depth = {}
    for s in hk.sensor_names:
        c = cols[s]
        c_slide, d_s = patch_centres(hk, obj_rc, T_ow, q_slide, s, tactile_specs[s])
        depth[s] = d_s.copy()
        i = 0
        while i < n:
            if not phase_slide[s][i]:
                i += 1
                continue
            T_os = T_ow[i] @ sp[s][i]
            tgt = T_wo[i:] @ T_os
            res = solve_sensor_ik(
                hk,
                q[i],
                {s: tgt[:, :3, 3]},
                {s: tgt[:, :3, 2]},
                q_init=q[i],
                iterations=30,
                normal_weight=STICK_NORMAL_WEIGHT,
                rest_weight=1e-4,
            )
            c_ik, d_ik = patch_centres(hk, obj_rc, T_ow[i:], res.q, s, tactile_specs[s])
            bad = (res.position_error[s] > STICK_POS_TOL) | (res.normal_error[s] > STICK_NORMAL_TOL)
            bad |= np.abs(d_ik - d_s[i]) > STICK_DEPTH_TOL_MM  # the tilted gel would press in or lift off
            # a tilted gel rolls its patch over the surface: the contact must stay where it was made
            with np.errstate(invalid="ignore"):
                bad |= ~(np.linalg.norm(c_ik - c_slide[i], axis=1) <= STICK_DRIFT_TOL)
            bad[0] = False  # the phase's first frame is the sliding plan's own (exact) posture
            e = int(np.argmax(bad)) if bad.any() else len(bad)
            end = i + e
            q[i:end, c] = res.q[:e][:, c]
            phase[s][i:end] = True
            depth[s][i:end] = d_s[i]
            # gait: open and move back to the sliding plan's posture (reached at the end of the gait)
            last = q[end - 1, c].copy()
            for k, j in enumerate(range(end, min(n, end + n_gait))):
                u = (k + 1) / n_gait
                w = u * u * (3.0 - 2.0 * u)
                lift = LIFT_S * np.sin(np.pi * u) ** 2
                q[j, c] = (1.0 - w) * last + w * q_slide[j, c] - lift * (q_closed[c] - q_open[c])
            q[end : end + n_gait] = hk.clip_to_limits(q[end : end + n_gait])
            i = end + n_gait
    return q, phase, depth


def patch_centres(
    hk, obj_rc: Raycaster, T_ow: np.ndarray, q: np.ndarray, sensor: str, spec, stride_mm: float = FINE_STRIDE_MM
) -> tuple[np.ndarray, np.ndarray]:
    """Contact patch centre of ``sensor`` in the OBJECT frame (N, 3), m (indentation-weighted centroid of the gel
    height map above the contact threshold, on the gel surface; NaN without contact) and the max indentation (N,),
    mm, for postures ``q`` (N, J) and object poses ``T_ow`` (N, 4, 4) = T_object_world."""
    stride = max(1, int(round(stride_mm / spec.mm_per_px)))
    T_os = T_ow @ hk.sensor_poses(q)[sensor]
    h = gel_heights(obj_rc, T_os, spec.width, spec.height, spec.mm_per_px, spec.gel_thickness_mm, stride=stride)
    rows = (np.arange(0, spec.height, stride) - (spec.height - 1) / 2.0) * spec.mm_per_px / 1000.0
    cols = (np.arange(0, spec.width, stride) - (spec.width - 1) / 2.0) * spec.mm_per_px / 1000.0
    w = np.maximum(h - spec.contact_threshold_mm, 0.0).astype(np.float64)
    tot = w.sum((1, 2))
    with np.errstate(invalid="ignore", divide="ignore"):
        cy = (w.sum(2) @ rows) / tot
        cx = (w.sum(1) @ cols) / tot
    c_s = np.stack([cx, cy, np.zeros_like(cx)], axis=1)
    return se3.transform_points(T_os, c_s[:, None])[:, 0], h.reshape(len(h), -1).max(1).astype(np.float64)


def contact_drift_mm(hk: HandKinematics, obj_rc: Raycaster, plan: GraspPlan, tactile_specs: dict) -> dict[str, list]:
    """Ground truth (scoring and tests only): per sensor and contact phase of ``plan`` (runs of
    ``in_contact_phase`` of >= 2 frames), the largest distance (mm) of the contact patch centre
    (:func:`patch_centres`) in the OBJECT frame from where it was at the phase's first frame. A sliding contact
    drifts by the path it slides."""
    T_ow = se3.invert(plan.T_world_object)
    out: dict[str, list] = {}
    for s in hk.sensor_names:
        c_o, _ = patch_centres(hk, obj_rc, T_ow, plan.q, s, tactile_specs[s])
        ph = plan.in_contact_phase[s] & np.isfinite(c_o).all(1)
        drifts = []
        i = 0
        while i < len(ph):
            if not ph[i]:
                i += 1
                continue
            j = i
            while j < len(ph) and ph[j]:
                j += 1
            if j - i >= 2:
                drifts.append(float(np.linalg.norm(c_o[i:j] - c_o[i], axis=1).max() * 1e3))
            i = j
        out[s] = drifts
    return out


def _align_gels(hk, obj_rc, T_wo, q_syn, tactile_specs, d_target, active, iters: int = 4) -> np.ndarray:
    """Refine touching postures with the batched IK so each gel lies flush on the surface.

    Target: the gel centre ``d`` inside the closest surface point along its normal, gel normal
    against the surface normal; the indentation measured on the height map is fed back into ``d``.
    Frames/fingers not in contact keep their synergy posture (they are the IK's rest posture).
    """
    from vtrack.kinematics.ik import solve_sensor_ik

    names = hk.sensor_names
    T_ow = se3.invert(T_wo)
    d_cmd = {s: d_target[s].copy() for s in names}
    q = q_syn.copy()
    for it in range(iters):
        sp = hk.sensor_poses(q)
        tp, tn = {}, {}
        for s in names:
            g = sp[s][:, :3, 3]
            p, n_w = _closest_contacts(obj_rc, T_wo, g, sp[s][:, :3, 2])
            tp[s] = p - n_w * (d_cmd[s] / 1000.0)[:, None]
            tn[s] = -n_w
        q_new = solve_sensor_ik(
            hk,
            q_syn,
            tp,
            tn,
            active=active,
            q_init=q,
            iterations=12,
            normal_weight=0.05,
            tangent_weight=0.3,
            rest_weight=0.01,
        ).q
        # Inactive fingers keep their synergy posture exactly.
        for s in names:
            c = hk.chain_joints(hk.sensor_links[s])
            q_new[np.ix_(~active[s], c)] = q_syn[np.ix_(~active[s], c)]
        q = q_new
        if it < iters - 1:
            for s in names:
                m, _ = _max_indentation(hk, obj_rc, T_ow, q, s, tactile_specs[s], stride_mm=FINE_STRIDE_MM)
                d_cmd[s] = np.clip(d_cmd[s] + (d_target[s] - m), -5.0, 5.0)
    return q
