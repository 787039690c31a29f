"""Track a recorded session end to end and write the result folder.

``track_session(SESSION, OUT)`` runs on what a real recording has (RGB-D, tactile images, joint states,
calibrations) through the frames layer (:mod:`vtrack.frames`): segmentation without ground truth, touch
from the tactile images. It writes (see docs/tracking.md):

- ``poses.csv``: ``t, x, y, z, qx, qy, qz, qw`` of ``T_world_object`` (:mod:`vtrack.io.poses`), the
  object frame being the one of ``--mesh`` (known shape) or the one SLAM defines, + ``status`` and ``ms``;
- ``metrics.json``: speed (``ms_per_frame_mean`` = frame building incl. segmentation and the tactile
  pipeline + tracker step, disk reads excluded; ``cpu_read_ms_per_frame_mean`` = the CPU time of reading
  and decoding a frame, apart; ``poses_per_s``), initialisation, and, when ground truth is
  available for SCORING (``gt=`` session, or the session's own ``gt/``), pose errors from
  :mod:`vtrack.eval.session_gt`;
- ``result.json`` (``{"kind": "tracking", ...}``) and ``error.png`` (error over time, when scored).

Initialisation, without ground truth:
- SLAM: the object frame is defined by the data: origin at the centroid of the first frame's segmented
  points and contacts, axes of the world;
- known shape: ``init_pose`` (a user prior), else global registration of the first frames against the
  mesh (:mod:`vtrack.tracking.globalreg`).
``init="gt"`` starts from the first ground-truth pose (an ORACLE ablation, optionally perturbed by
``init_perturb``), the protocol of NeuralFeels' tracking experiments.
"""

from __future__ import annotations

import os
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from vtrack.errors import InputError
from vtrack.geometry import se3
from vtrack.io.jsonio import write_json
from vtrack.threads import single_thread_blas
from vtrack.tracking.stick import contact_rigidity, fingers_stick, stick_term_on, sticking_contacts_for

SHAPES = ("known_shape", "slam")
METHODS = ("ours", "icp")
INITS = ("auto", "gt")


def perturb_pose(T: np.ndarray, trans_m: float, rot_rad: float, seed: int = 0) -> np.ndarray:
    """``T`` moved by exactly ``trans_m`` along a random direction and rotated by ``rot_rad`` about a
    random axis through the object origin (object frame)."""
    rng = np.random.default_rng(seed)
    u = rng.normal(size=3)
    u /= np.linalg.norm(u)
    a = rng.normal(size=3)
    a /= np.linalg.norm(a)
    out = np.asarray(T, dtype=np.float64) @ se3.make_transform(se3.so3_exp(a * rot_rad))
    out[:3, 3] += u * trans_m
    return out


def build_tracker(
    shape: str, mesh: Path | None, T_init: np.ndarray, method: str = "ours", scene: Any = None, **opts: Any
):
    """The tracker for a mode: ``ours`` known_shape/slam or the ``icp`` baseline."""
    from vtrack import registry

    if method == "icp":
        if mesh is None:
            raise InputError("the ICP baseline needs the object mesh", field="--mesh")
        return registry.load("tracking.icp")(mesh, T_init, **opts)
    if method != "ours":
        raise InputError("unknown method", field="method", expected="|".join(METHODS), got=method)
    if shape not in SHAPES:
        raise InputError("unknown shape mode", field="shape", expected="|".join(SHAPES), got=shape)
    cls = registry.load(f"tracking.{shape}")
    if shape == "slam":
        return cls(T_init, **opts)
    if mesh is None:
        raise InputError("known-shape tracking needs the object mesh", field="--mesh", expected="a mesh file")
    return cls(mesh, T_init, **opts)


def centroid_frame(frame: Any) -> np.ndarray | None:
    """An object frame defined by the data: origin at the centroid of a tracking frame's object points
    (segmented vision + contacts), world axes; None when the frame has no object point."""
    P = [a for a in (frame.vision_points, frame.touch_points) if a is not None and len(a)]
    if not P:
        return None
    T = np.eye(4)
    T[:3, 3] = np.concatenate(P).mean(0)
    return T


def slam_origin(frames: Any, max_look: int = 10) -> tuple[np.ndarray, str]:
    """The SLAM object frame from the first of ``max_look`` frames that has object points
    (:func:`centroid_frame`)."""
    for i in range(min(max_look, len(frames))):
        T = centroid_frame(frames.frame(i)[0].tracking_frame())
        if T is not None:
            frames.reset()
            return T, f"centroid of frame {i}'s object points"
    frames.reset()
    raise InputError(
        "no object points (segmented depth or contacts) in the first frames: SLAM has nothing to "
        "define the object frame",
        path=frames.path,
        expected=f"object seen within {max_look} frames",
    )


def resolve_mesh(mesh: str | Path | None, scene: Any) -> Path | None:
    """The known shape: ``--mesh`` if given, else the scene's ``object.mesh`` (a user-given file)."""
    if mesh is not None:
        p = Path(mesh)
        if not p.is_file():
            raise InputError("mesh file not found", path=p, field="--mesh", expected="a mesh file (PLY/OBJ/STL, m)")
        return p
    m = getattr(getattr(scene, "object", None), "mesh", None)
    return Path(m) if m is not None and Path(m).is_file() else None


def register_known_shape(mesh: Path, tracking_frames: list, symmetric: bool) -> tuple[np.ndarray, dict]:
    """``T_world_object`` of a known mesh from tracking frames by global registration (no prior)."""
    from vtrack.io.mesh import load_mesh
    from vtrack.tracking.globalreg import global_register

    V, F = load_mesh(mesh)
    t0 = time.perf_counter()
    hyps = global_register(V, F, tracking_frames, symmetric=symmetric)
    if not hyps:
        raise InputError(
            "global registration found no pose of the mesh in the first frames",
            path=mesh,
            field="--init-pose",
            expected="a pose prior (--init-pose) or more visible object",
        )
    return hyps[0].T_world_object, {
        "init_seconds": time.perf_counter() - t0,
        "init_hypotheses": len(hyps),
        "init_score": float(hyps[0].score),
    }


def known_shape_init(frames: Any, mesh: Path, symmetric: bool, n_frames: int = 3) -> tuple[np.ndarray, dict]:
    """``T_world_object`` of a known mesh from the first ``n_frames`` frames of a session."""
    t0 = time.perf_counter()
    tfs = [frames.frame(i)[0].tracking_frame() for i in range(min(n_frames, len(frames)))]
    frames.reset()
    t_frames = time.perf_counter() - t0
    T, info = register_known_shape(mesh, tfs, symmetric)
    info["init_seconds"] += t_frames  # time to a first pose: building the frames + registration
    return T, info


def warm_up(shape: str = "known_shape", method: str = "ours", write: bool = True, **_: Any) -> None:
    """Import what :func:`track_session` will use (batch workers call this before timing starts)."""
    import importlib

    mods = [
        "vtrack.frames.session",
        "vtrack.frames.segmentation",
        "vtrack.frames.touch",
        "vtrack.tactile.pipeline",
        "vtrack.eval.pose_metrics",
        "vtrack.tracking.sdf_grid",
        "vtrack.io.session",
        "vtrack.kinematics.hand",
        "vtrack.scene.load",
        "scipy.spatial",
        "trimesh",
        "yourdfpy",
        "zarr",
        "open3d",
        "cv2",
    ]
    if method == "icp":
        mods.append("vtrack.tracking.icp")
    else:
        mods.append("vtrack.tracking.slam" if shape == "slam" else "vtrack.tracking.tracker")
    if write:
        mods.append("matplotlib.pyplot")
    for m in mods:
        importlib.import_module(m)


#: Tactile working resolution and point stride for tracking (offline and live): tracking needs far fewer
#: contact points than mapping; 1/4 x 2 on a DIGIT keeps a point every 0.6 mm at a third of the cost of
#: the pipeline's default (1/2 x 3), with the same accuracy on the demo session (motion error 2.64 mm).
TRACK_TOUCH_DOWNSAMPLE = 4
TRACK_TOUCH_STRIDE = 2

#: Known shape, vision + touch on a session: contact-to-surface sigma, m (``TrackerOptions.sigma_touch``, 1 mm
#: by default, is kept for touch alone and synthetic contacts). Contacts read from tactile images lie ~0.5 mm off
#: the mesh at the true pose (median, the 6 YCB sessions; GT height maps too) and, at 1 mm, pulled the depth fit
#: off: from the GT first pose, potted meat 0.55 -> 0.34 mm ADD-S, banana 0.36 -> 0.28 mm at 3 mm (vision-only
#: 0.24 / 0.29 mm); docs/tracking.md.
KNOWN_SIGMA_TOUCH_WITH_VISION = 0.003

#: Known shape, vision + touch: in frames that see fewer than this many segmented points (heavy occlusion) the contacts
#: carry the pose at ``sigma_touch_weak`` (``TrackerOptions.touch_weak_vision``). 2 s heavy-occlusion YCB sessions,
#: blind, ADD-S mean of 6 objects: 5.46 -> 4.49 mm (vision-only 9.87); none / medium unchanged (docs/benchmarks/
#: heavy_occlusion.md).
KNOWN_TOUCH_WEAK_VISION = (150, 0.0015)


def known_shape_touch_defaults(opts: dict[str, Any], modalities: Sequence[str]) -> dict[str, Any]:
    """Fill the known-shape tracker's contact settings for vision + touch into ``opts`` (explicit values win):
    contacts at :data:`KNOWN_SIGMA_TOUCH_WITH_VISION` and the weak-vision regime :data:`KNOWN_TOUCH_WEAK_VISION`.
    One rule for offline :func:`track_session` and the live track consumer. Returns ``opts``."""
    if {"vision", "touch"} <= set(modalities):
        opts.setdefault("sigma_touch", KNOWN_SIGMA_TOUCH_WITH_VISION)
        opts.setdefault("touch_weak_vision", KNOWN_TOUCH_WEAK_VISION[0])
        opts.setdefault("sigma_touch_weak", KNOWN_TOUCH_WEAK_VISION[1])
    return opts


def colour_term_on(shape: str, opts: dict) -> bool:
    """Whether the tracker built from ``shape`` and ``opts`` uses the colour term (``sigma_colour`` > 0; SLAM's
    default is on, known shape's off), i.e. whether its frames need colour feature tracks."""
    from vtrack.tracking.slam import SLAM_COLOUR_SIGMA

    default = SLAM_COLOUR_SIGMA if shape == "slam" else 0.0
    return float(opts.get("sigma_colour", default) or 0.0) > 0


# one BLAS thread unless the process's thread cap was set: the trackers' small solves only spin a second one
@single_thread_blas()
def track_session(
    session_dir: str | Path,
    out_dir: str | Path,
    shape: str = "known_shape",
    modalities: tuple[str, ...] | list[str] = ("vision", "touch"),
    method: str = "ours",
    *,
    mesh: str | Path | None = None,
    init_pose: np.ndarray | None = None,
    init: str = "auto",
    init_perturb: tuple[float, float] | None = None,
    gt: str | Path | None = None,
    tactile_source: str = "pipeline",
    segmentation: str = "pipeline",
    max_frames: int = 0,
    seed: int = 0,
    depth_stride: int = 4,
    touch_stride: int = TRACK_TOUCH_STRIDE,
    touch_downsample: int | str = TRACK_TOUCH_DOWNSAMPLE,
    write: bool = True,
    return_poses: bool = False,
    keep_frames: dict | None = None,
    keep_step: int = 1,
    select_runs: bool = False,
    select_contacts: bool = False,
    prefetch: str | bool = "off",
    **opts: Any,
) -> Any:
    """Run a tracker over a session; return the metrics dict (also written to ``out_dir``).

    Args:
        session_dir: session directory (``vtrack.io.session`` format); ground truth is not needed.
        out_dir: result folder (created).
        shape: ``known`` (SDF of ``mesh``) or ``slam`` (shape reconstructed online).
        modalities: ("vision",), ("touch",) or both.
        method: ``ours`` or ``icp`` (Open3D point-to-plane baseline, vision only).
        mesh: the known shape (object frame, m); default the scene's ``object.mesh``.
        init_pose: ``T_world_object`` prior of the first frame (4x4); known shape without it: global
            registration; SLAM without it: the first frame's centroid.
        init: ``auto`` (above) or ``gt`` (ORACLE: the first ground-truth pose, perturbed by ``init_perturb``
            = (metres, radians)).
        gt: session with ground truth to SCORE against (default: this session if it has ``gt/``).
        tactile_source / segmentation: ``pipeline`` (default) or ``gt`` (oracle ablations); segmentation also
            ``gt_colour`` / ``gt_points`` (oracle: the renderer's mask for the colour tracks / the depth points only).
        max_frames: track only the first frames (0 = all).
        return_poses: return ``(metrics, (times, T_world_object))`` instead of the metrics alone.
        keep_frames: a dict that receives ``frames`` (the SessionFrames) and ``built`` (every
            ``keep_step``-th ``(index, Frame)``), so a reconstruction reuses them instead of recomputing;
            for SLAM also ``poses_frontend`` (the poses before the back end's refinement, an ablation); and
            ``tracker`` (the tracker after the last frame, e.g. its keyframes); with SLAM's second pass also
            ``second_pass_frames`` (the tracking frames it re-tracked) and ``poses_first_pass``.
        depth_stride / touch_stride / touch_downsample: pixel stride of the depth images, point stride and
            working-resolution factor of the tactile pipeline (tracking needs far fewer points than mapping:
            4 x 2 on a DIGIT keeps a point every 0.6 mm at a third of the pipeline's cost).
        select_runs: SLAM, offline (opt-in): track the session again with each setting of
            :data:`~vtrack.tracking.slam.SLAM_SELECT_ALTERNATIVES` (same frames, built once) and keep the run whose
            final map agrees best with its own depth points (:func:`~vtrack.tracking.slam.map_consistency_mm`; blind);
            the metrics say ``select_scores_mm`` and ``selected_run`` (0 = the default setting).
        select_contacts: SLAM with touch, offline (opt-in, ``vtrack track --contacts auto``): track the session again
            with :data:`~vtrack.tracking.slam.SLAM_STICKING_CONTACTS` (same frames) and keep that run when the
            contacts move as one rigid body and it explains its depth points about as well
            (:func:`~vtrack.tracking.stick.fingers_stick`; blind); the metrics say ``contacts_choice``.
        prefetch: build the frames in a child process ahead of the tracker (:mod:`vtrack.frames.prefetch`):
            ``on`` / ``off`` / ``auto`` (long sessions on >= 2 CPUs; the CLI's default), ``single`` (on, the
            tactile pipelines in the same child rather than one of their own: an ablation). The same poses; the
            metrics' ``frames_wall_s`` and ``poses_per_s`` show the wall time, ``prefetch_processes`` the children.
        **opts: tracker options (:class:`~vtrack.tracking.window.TrackerOptions` fields, ...).
    """
    from vtrack.frames.session import ORACLE_SEGMENTATIONS, SessionFrames

    if shape not in SHAPES:
        raise InputError("unknown shape mode", field="shape", expected="known_shape|slam", got=shape)
    if init not in INITS:
        raise InputError("unknown initialisation", field="init", expected="auto | gt (oracle)", got=init)
    if select_runs and (shape != "slam" or method != "ours"):
        raise InputError(
            "run selection is for SLAM", field="select_runs", expected="shape slam, method ours", got=shape
        )
    modalities = tuple(modalities)
    if select_contacts:
        if shape != "slam" or method != "ours" or "touch" not in modalities:
            raise InputError(
                "the contact-mode choice is for SLAM with touch",
                field="select_contacts",
                expected="shape slam, method ours, touch among the modalities",
                got=f"{shape}, {method}, {','.join(modalities)}",
            )
        if select_runs or stick_term_on(opts):
            raise InputError(
                "the contact-mode choice runs the sticking-contact preset itself",
                field="select_contacts",
                expected="without select_runs or sigma_stick",
            )
    if method == "icp":
        modalities = ("vision",)
    frames_kwargs = dict(
        modalities=modalities,
        tactile_source=tactile_source,
        segmentation=segmentation,
        depth_stride=depth_stride,
        touch_stride=touch_stride,
        max_frames=max_frames,
        touch_downsample=touch_downsample,
        # the colour term's feature tracks: RGB is read only when the tracker uses them (SLAM by default)
        colour=method == "ours" and colour_term_on(shape, opts),
        colour_opts=opts.pop("colour_opts", None),
        segmentation_opts=opts.pop("segmentation_opts", None),
    )
    from vtrack.frames.prefetch import PrefetchedFrames, worth_prefetching

    # frames built in a child process on the other core while this one tracks (offline, long sessions): the same
    # frames, the wall time per frame about max(build, track) instead of their sum. Started first, so that its
    # start (imports, opening the session: 2-3 s in a new process) overlaps this process's own set-up below; with
    # ``auto`` it is ended again if the session turns out short.
    # (a directory only: an open reader given instead cannot be reopened in the child)
    on_disk = isinstance(session_dir, (str, os.PathLike))
    ahead = (
        PrefetchedFrames(session_dir, frames_kwargs, touch_process=prefetch != "single")
        if on_disk and worth_prefetching(prefetch, None)
        else None
    )
    frames = SessionFrames(session_dir, **frames_kwargs)
    if ahead is not None and not worth_prefetching(prefetch, len(frames)):
        ahead.close()
        ahead = None
    mesh_path = resolve_mesh(mesh, frames.scene) if (shape == "known_shape" or method == "icp") else None
    if (shape == "known_shape" or method == "icp") and mesh_path is None:
        raise InputError(
            "known-shape tracking needs the object mesh",
            path=frames.path,
            field="--mesh",
            expected="--mesh PATH (object frame, m) or object.mesh in the scene; or use --shape slam",
        )
    from vtrack.eval.session_gt import SessionGroundTruth

    gt_data = SessionGroundTruth.find(gt, frames.path)
    oracle: list[str] = []
    init_info: dict[str, Any] = {}
    if init == "gt":
        if gt_data is None:
            raise InputError("init 'gt' (oracle) needs ground truth", path=frames.path, field="--gt")
        _, T_mg = gt_data.alignment(mesh_path)
        T_init = gt_data.poses_at(frames.times[:1])[0] @ (np.eye(4) if T_mg is None else se3.invert(T_mg))
        init_from = "ground truth (first frame) [oracle]"
        oracle.append("init")
    elif init_pose is not None:
        T_init = np.asarray(init_pose, np.float64)
        if T_init.shape != (4, 4) or not se3.is_rigid(T_init, tol=1e-4):
            raise InputError("initial pose must be a 4x4 rigid transform", field="--init-pose")
        init_from = "user prior (--init-pose)"
    elif shape == "slam":
        T_init, init_from = slam_origin(frames)
    else:
        T_init, init_info = known_shape_init(frames, mesh_path, bool(frames.scene.object.symmetric))
        init_from = "global registration of the first frames"
    if init_perturb is not None:
        T_init = perturb_pose(T_init, float(init_perturb[0]), float(init_perturb[1]), seed)
        init_from += f" perturbed by {init_perturb[0] * 1e3:.1f} mm / {np.degrees(init_perturb[1]):.1f} deg"
    if tactile_source == "gt":
        oracle.append("tactile")
    if segmentation in ORACLE_SEGMENTATIONS:
        oracle.append("segmentation")
    if shape == "known_shape" and method == "ours":
        known_shape_touch_defaults(opts, modalities)
    tracker = build_tracker(shape, mesh_path, T_init, method=method, **opts)
    n = len(frames)
    est = np.zeros((n, 4, 4))
    ms = np.zeros(n)
    ms_prep = np.zeros(n)
    cpu_ms = np.zeros(n)
    status: list[str] = []
    if keep_frames is not None:
        keep_frames.update(frames=frames, built=[], tracker=tracker)
    reloc = (
        Relocalisation(tracker, mesh_path, bool(frames.scene.object.symmetric))
        if (shape == "known_shape" and method == "ours")
        else None
    )
    cpu_read = np.zeros(n)
    # SLAM's second pass (offline) re-tracks the session start against the final map: keep those tracking frames
    second_s = float(getattr(tracker, "second_pass_s", 0.0) or 0.0)
    early: list = []
    tfs: list = []  # every tracking frame, replayed by the alternative runs (select_runs, select_contacts)
    from vtrack.tracking.slam import SLAM_STICKING_CONTACTS

    # the contact ids go with every frame when the sticking run may be chosen after (the default run ignores them)
    sticker = sticking_contacts_for({**opts, **(SLAM_STICKING_CONTACTS if select_contacts else {})}, modalities)
    built = ahead.frames(expected=n) if ahead is not None else None
    build_cpu = 0.0
    t_loop = t_done = time.perf_counter()
    for i in range(n):
        if built is not None:
            # the frame from the child: its read and build CPU come with it; the wall time of a frame is from the
            # end of the previous one (the wait for this frame included)
            t0 = t_done
            _, fr, cpu_read[i], build_cpu = next(built)
            c0, t1 = time.process_time(), time.perf_counter()
        else:
            c0 = time.process_time()
            raw = frames.read(i)  # disk read + decompression: not part of the per-frame tracking cost ...
            cpu_read[i] = (time.process_time() - c0) * 1e3  # ... reported apart (a live pipeline gets decoded arrays)
            c0, t0 = time.process_time(), time.perf_counter()
            fr = frames.build(raw)
            t1 = time.perf_counter()
        tf = fr.tracking_frame()
        if sticker is not None:
            sticker.annotate(fr, tf)
        est[i] = tracker.step(tf)
        st = tracker.last_info.status if tracker.last_info else "ok"
        if reloc is not None:
            T_new, st = reloc.update(tf, est[i], st)
            est[i] = T_new
        t_done = time.perf_counter()
        ms[i] = (t_done - t0) * 1e3
        ms_prep[i] = (t1 - t0) * 1e3
        cpu_ms[i] = (time.process_time() - c0) * 1e3 + build_cpu  # build + track, wherever the build ran
        status.append(st)
        if second_s > 0 and frames.times[i] - frames.times[0] <= second_s:
            early.append(tf)
        if select_runs or select_contacts:
            tfs.append(tf)
        if keep_frames is not None and i % max(1, int(keep_step)) == 0:
            keep_frames["built"].append((i, fr))
    wall_loop = time.perf_counter() - t_loop
    prefetch_cpu_s = 0.0
    if ahead is not None:
        next(built, None)  # the child's last message (its CPU time); the generator then ends it
        prefetch_cpu_s = ahead.cpu_s
    if not np.all(np.isfinite(est)):
        raise RuntimeError("tracker produced non-finite poses")  # guarded against; should never happen
    est, second, est_front, backend = _offline_passes(tracker, early, est, frames.times, keep_frames)
    selection: dict[str, Any] = {}
    sticking = sticker is not None and stick_term_on(opts)  # the kept run's term
    if select_runs or select_contacts:
        # offline: the same tracking frames through SLAM again with each alternative setting; the run kept is chosen
        # from the data alone (no ground truth in the choice)
        from vtrack.tracking.slam import SLAM_SELECT_ALTERNATIVES, map_consistency_mm, select_run, sphere_in_force

        c0 = time.process_time()
        alts = SLAM_SELECT_ALTERNATIVES if select_runs else (SLAM_STICKING_CONTACTS,)
        runs = [(tracker, est, status, second, est_front, backend, keep_frames)]
        for alt in alts:
            tr = build_tracker(shape, mesh_path, T_init, method=method, **{**opts, **alt})
            e = np.zeros_like(est)
            st_alt: list[str] = []
            for i, tf in enumerate(tfs):
                e[i] = tr.step(tf)
                st_alt.append(tr.last_info.status if tr.last_info else "ok")
            if not np.all(np.isfinite(e)):
                raise RuntimeError("tracker produced non-finite poses")  # guarded against; should never happen
            kf_alt: dict | None = None if keep_frames is None else {}
            est_a, second_a, front_a, backend_a = _offline_passes(tr, early, e, frames.times, kf_alt)
            runs.append((tr, est_a, st_alt, second_a, front_a, backend_a, kf_alt))
        # how well each run's depth points sit on its own final map
        scores = [map_consistency_mm(r[0], tfs, r[1]) for r in runs]
        if select_runs:
            spheres = [sphere_in_force(r[0]) for r in runs]
            best = select_run(scores, spheres)
            selection = {
                "select_scores_mm": [float(x) for x in scores],
                "select_sphere_prior": spheres,
                "selected_run": best,
                "select_alternatives": [dict(a) for a in SLAM_SELECT_ALTERNATIVES],
            }
        else:
            rigidity, pairs = contact_rigidity(tfs)
            sticking = fingers_stick(rigidity, scores[0], scores[1])
            best = int(sticking)
            selection = {
                "contacts_choice": {
                    "chosen": "stick" if sticking else "slide",
                    "rigidity": rigidity,
                    "rigid_pairs": pairs,
                    "consistency_mm": {"slide": float(scores[0]), "stick": float(scores[1])},
                }
            }
        tracker, est, status, second, est_front, backend, kf_best = runs[best]
        if keep_frames is not None and best > 0:
            keep_frames.update(kf_best or {}, tracker=tracker)  # the kept run's tracker and offline-pass poses
        selection["select_cpu_s"] = time.process_time() - c0
    metrics: dict[str, Any] = {
        "mode": "icp" if method == "icp" else shape,
        "method": method,
        "modalities": list(modalities),
        "tactile_source": tactile_source if "touch" in modalities else "none",
        "segmentation": segmentation if "vision" in modalities else "none",
        # the kept run had the sticking-contact term (``sigma_stick`` > 0 with touch: ``--contacts stick``, or
        # ``--contacts auto``'s choice)
        "sticking_contacts": sticking,
        "oracle": oracle,
        "blind": not oracle,
        "frames": n,
        "init": init_from,
        **init_info,
        "mesh": str(mesh_path) if mesh_path else None,
        "ms_per_frame_mean": float(ms.mean()),
        "ms_per_frame_median": float(np.median(ms)),
        "ms_per_frame_p95": float(np.percentile(ms, 95)),
        "ms_prep_mean": float(ms_prep.mean()),
        # CPU time of this process: a steadier measure than wall time on a shared machine
        "cpu_ms_per_frame_mean": float(cpu_ms.mean()),
        "cpu_read_ms_per_frame_mean": float(cpu_read.mean()),  # reading + decoding the session (not included above)
        "poses_per_s": float(1e3 / max(ms.mean(), 1e-9)),
        # frames built in a child process (prefetch) on the other core: the loop's wall time per frame is about
        # max(build, track); cpu_ms_per_frame_mean counts both processes' work either way
        "prefetch": ahead is not None,
        "prefetch_processes": ahead.processes if ahead is not None else 0,
        "frames_wall_s": float(wall_loop),
        "first_wait_s": float(ms_prep[0] / 1e3) if n else 0.0,  # the wait for the first frame (the child's start)
        **({"prefetch_child_cpu_s": float(prefetch_cpu_s)} if ahead is not None else {}),
        "status_counts": {s: status.count(s) for s in sorted(set(status))},
        **({"reloc_attempts": reloc.attempts, "reloc_successes": reloc.successes} if reloc is not None else {}),
        "session": str(Path(session_dir)),
        **second,
        **backend,
        **selection,
    }
    errors = None
    if gt_data is not None:
        from vtrack.eval.session_gt import score_trajectory

        m, errors = score_trajectory(gt_data, frames.times, est, mesh=mesh_path)
        metrics.update(m)
        if est_front is not None and backend.get("refined"):
            # ablation: the front end's poses before the back end (scoring only)
            mf, _ = score_trajectory(gt_data, frames.times, est_front, mesh=mesh_path)
            metrics["frontend"] = {k: mf[k] for k in ("motion_err_mm", "drift_mm", "add_s_mm") if k in mf}
    if hasattr(tracker, "map_metrics"):
        metrics.update(tracker.map_metrics())
    if write:
        _write_outputs(Path(out_dir), frames, est, ms, status, metrics, errors)
    if return_poses:
        return metrics, (frames.times, est)
    return metrics


def _offline_passes(
    tracker: Any, early: list, est: np.ndarray, times: np.ndarray, keep_frames: dict | None
) -> tuple[np.ndarray, dict[str, Any], np.ndarray | None, dict[str, Any]]:
    """SLAM's offline passes after the last frame: the second pass over ``early`` (the first frames' tracking
    frames, re-tracked backwards against the final map) and the back end (``refine_poses``), when the tracker has
    them. Returns ``(T_world_object (N, 4, 4), second-pass metrics, front-end poses or None, back-end metrics)``;
    ``est`` is updated in place by the second pass."""
    second: dict[str, Any] = {}
    if len(early) >= 2:
        if keep_frames is not None:
            keep_frames.update(second_pass_frames=early, poses_first_pass=est.copy())
        c0 = time.process_time()
        est[: len(early)] = tracker.retrack_start(early, est[: len(early)])
        rep = tracker.second_pass_report
        second = {
            "second_pass_frames": len(early),
            "second_pass_cpu_s": time.process_time() - c0,
            "second_pass_max_move_mm": float(rep.get("max_move_mm", 0.0)),
            "second_pass_rejected": bool(rep.get("rejected", False)),
            "second_pass_degenerate_rise": float(rep.get("degenerate_rise", 0.0)),
        }
    est_front = None
    backend: dict[str, Any] = {}
    if hasattr(tracker, "refine_poses"):
        # SLAM back end: keyframe pose graph (registration + loop edges), after the last frame; its cost is
        # reported apart from the per-frame tracking cost
        c0, t0 = time.process_time(), time.perf_counter()
        est_front = est
        est = tracker.refine_poses(times, est)
        if keep_frames is not None:
            keep_frames["poses_frontend"] = est_front
        rep = tracker.backend_report
        backend = {
            "refined": bool(rep.get("refined", False)),
            "backend_s": time.perf_counter() - t0,
            "backend_cpu_s": time.process_time() - c0,
            "keyframes": int(rep.get("keyframes", 0)),
            "registration_edges": int(rep.get("registration_edges", 0)),
            "loop_edges": int(rep.get("loop_edges", 0)),
            "loop_rejected": int(rep.get("loop_rejected", 0)),
        }
    return est, second, est_front, backend


class Relocalisation:
    """Known shape: re-localise after a loss by the same global registration, verified against the tracker.

    After each tracker step, :meth:`update` checks the frame: the tracker reports ``lost``, or its inlier
    fraction (points within 5 mm of the surface) falls below ``suspect_ratio`` x the median of the last good
    frames. A large unseen motion (the object hidden, then back turned and moved) often ends in a look-alike
    pose the tracker calls ``ok`` at a lower inlier fraction, so ``lost`` alone misses it. Then the mesh is
    re-registered on the newest frames near the last good pose (:class:`~vtrack.tracking.globalreg.
    Relocaliser`) and its best hypothesis replaces the estimate when it scores better than the current one by
    ``margin`` (same verification score); the tracker restarts there and the frame says ``relocalised``.
    Failed attempts back off (``every`` frames, doubled after each failure up to 32) to bound the cost
    (~0.3-1 s per attempt).

    Args:
        tracker: a :class:`~vtrack.tracking.tracker.KnownShapeTracker` (its ``grid`` is reused).
        mesh: the known shape (object frame, m).
        symmetric: the object is rotationally symmetric (hypotheses merged under ADD-S).
        keep: newest frames used by the registration.
        suspect_ratio: inlier fraction below this x the recent good median triggers an attempt.
        margin: score gain (in [0, 1]) a hypothesis needs over the current estimate.
        every: frames between attempts while the frame stays suspect (doubled after a failed attempt).
    """

    def __init__(
        self,
        tracker: Any,
        mesh: Path,
        symmetric: bool,
        keep: int = 3,
        suspect_ratio: float = 0.9,
        margin: float = 0.05,
        every: int = 2,
    ) -> None:
        self.tracker, self.mesh, self.symmetric = tracker, mesh, symmetric
        self.recent: list[Any] = []
        self.keep = keep
        self.suspect_ratio, self.margin, self.every = float(suspect_ratio), float(margin), max(1, int(every))
        self.last_ok: np.ndarray | None = None
        self.good_fracs: list[float] = []
        self.attempts = 0
        self.successes = 0
        self._wait = 0
        self._backoff = self.every
        self._reloc: Any = None

    def _suspect(self, status: str) -> bool:
        info = getattr(self.tracker, "last_info", None)
        f = float("nan") if info is None else float(info.inlier_frac)
        if status == "lost":
            return True
        if not np.isfinite(f):
            return False  # no data: nothing to judge
        ref = float(np.median(self.good_fracs)) if len(self.good_fracs) >= 3 else 1.0
        if f >= self.suspect_ratio * ref:
            self.good_fracs = [*self.good_fracs, f][-30:]
            return False
        return True

    def update(self, frame: Any, T: np.ndarray, status: str) -> tuple[np.ndarray, str]:
        """The estimate of this frame after the loss check: ``(T_world_object, status)``."""
        self.recent = [frame, *self.recent][: self.keep]
        if not self._suspect(status):
            self.last_ok = T
            self._backoff = self.every
            self._wait = 0
            return T, status
        if self.last_ok is None:
            return T, status
        if self._wait > 0:
            self._wait -= 1
            return T, status
        if self._reloc is None:
            from vtrack.io.mesh import load_mesh
            from vtrack.tracking.globalreg import Relocaliser

            V, F = load_mesh(self.mesh)
            self._reloc = Relocaliser(V, F, symmetric=self.symmetric, grid=getattr(self.tracker, "grid", None))
        self.attempts += 1
        h = self._reloc.relocalise(self.recent, self.last_ok)
        better = h is not None and (
            status == "lost"
            or self._reloc.score(self.recent, h.T_world_object, self.last_ok)
            >= self._reloc.score(self.recent, T, self.last_ok) + self.margin
        )
        if not better:
            self._wait = self._backoff
            self._backoff = min(2 * self._backoff, 32)
            return T, status
        self.successes += 1
        self._backoff = self.every
        self.tracker.reset(h.T_world_object)  # type: ignore[union-attr]
        return h.T_world_object, "relocalised"  # type: ignore[union-attr]


def _write_outputs(out: Path, frames, est, ms, status, metrics, errors) -> None:
    from vtrack.io.poses import write_poses_csv

    out.mkdir(parents=True, exist_ok=True)
    write_poses_csv(out / "poses.csv", frames.times, est, extra={"status": status, "ms": list(ms)})
    write_json(out / "metrics.json", metrics)
    write_json(
        out / "result.json",
        {
            "kind": "tracking",
            "session": str(frames.path.resolve()),
            "mode": metrics["mode"],
            "modalities": metrics["modalities"],
            "files": ["poses.csv", "metrics.json"] + (["error.png"] if errors else []),
        },
    )
    if errors is not None:
        lost = np.array([s in ("lost",) for s in status])
        key = "add_s_mm" if "add_s_mm" in metrics else "motion_err_mm"
        from vtrack.viz.plots import plot_error_over_time

        plot_error_over_time(
            out / "error.png",
            frames.times,
            [
                {"position (centre)": errors["pos"] * 1e3, "ADD-S": errors["add_s"] * 1e3},
                {"rotation": np.degrees(errors["rot"])},
            ],
            ylabel=["mm", "deg"],
            title=f"{metrics['mode']} / {'+'.join(metrics['modalities'])}: "
            f"drift {metrics['drift_mm']:.2f} mm, ADD-S {metrics[key]:.2f} mm",
            flags=lost,
        )
