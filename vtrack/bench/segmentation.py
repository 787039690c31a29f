"""``vtrack bench segmentation``: object-mask IoU against ms per frame of
:class:`vtrack.frames.segmentation.HandAwareSegmenter` (no ground truth in the pipeline).

Sessions: simulated sessions of the default scene (``vtrack.sim.generate``) for each YCB object in
``shared/data/objects/ycb`` x occlusion none / medium / heavy (cached in ``cache_dir()``). Each camera
frame is segmented at stride 4 (160x120 of 640x480) with the FK-posed hand, the tactile sensor origins
from FK and no contacts; IoU is computed at that resolution against the GT mask (``gt/camera/<cam>``
field ``mask``, or ``camera/<cam>`` field ``mask`` in older sessions) subsampled the same way. Frames
whose GT mask is empty are skipped. Rows: one per object x occlusion (median / mean IoU, CPU ms per
frame) plus ablation rows (hand removal off, crop off, temporal off) on the soup can.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np

from vtrack.bench.harness import BenchTable
from vtrack.errors import InputError

OCCLUSIONS = ("none", "medium", "heavy")


def gt_mask_field(reader: Any, cam: str) -> tuple[Any, str]:
    """(stream, field) holding the GT object mask of camera ``cam`` (new ``gt/`` location first)."""
    for name in (f"gt/camera/{cam}", f"camera/{cam}"):
        if name in reader and "mask" in reader[name].fields:
            return reader[name], "mask"
    raise InputError(
        "session has no ground-truth object mask",
        path=reader.path,
        field=f"gt/camera/{cam}.mask",
        expected="uint8 (H, W) mask",
    )


def segmenter_for_session(reader: Any, cam: str, stride: int, options: Any = None) -> Any:
    """A :class:`HandAwareSegmenter` for camera ``cam`` of a session at pixel ``stride``."""
    from vtrack.frames.segmentation import HandAwareSegmenter
    from vtrack.geometry.camera import PinholeCamera
    from vtrack.kinematics.hand import HandKinematics

    s = reader[f"camera/{cam}"]
    K = np.asarray(s.attrs["K"], dtype=np.float64)
    W, H = int(s.attrs["width"]), int(s.attrs["height"])
    k = int(stride)
    # Pixel (i*k) of the full image is pixel i of the strided one: same centre offset scaled by 1/k.
    pc = PinholeCamera(len(range(0, W, k)), len(range(0, H, k)), K[0, 0] / k, K[1, 1] / k, K[0, 2] / k, K[1, 2] / k)
    scene = reader.scene()
    kin = HandKinematics.from_scene(scene) if scene is not None and scene.hand is not None else None
    return HandAwareSegmenter(kin, pc, np.asarray(s.attrs["T_world_camera"]), options)


def evaluate_session(
    path: str | Path,
    cam: str | None = None,
    stride: int = 4,
    options: Any = None,
    max_frames: int | None = None,
    q_noise_rad: float = 0.0,
    min_visible: float = 0.1,
) -> dict[str, Any]:
    """Segment every camera frame of a session and score it against the GT mask.

    ``q_noise_rad`` adds Gaussian encoder noise (std, rad, seeded) to the joint vector the segmenter gets:
    the simulator renders the hand with the URDF meshes at the recorded joints, so this is the FK error
    (encoder, backlash, hand-model) a real hand adds.

    Frames whose GT ``visible_fraction`` (object silhouette not hidden by the hand) is below
    ``min_visible`` are not IoU-scored (the BOP benchmark's 10 % visibility rule); ``hidden_empty`` is,
    over those frames, whether the segmenter returned an empty mask.

    Returns ``iou`` (per frame), ``ms`` (CPU ms of ``segment`` per frame), ``hand_left`` (fraction of
    GT-hand pixels, i.e. valid depth outside the GT mask, kept in the mask), ``hidden_empty``, ``frames``.
    """
    from vtrack.io.session import open_session

    r = open_session(path)
    cams = sorted(n[len("camera/") :] for n in r.streams_of_kind("rgbd"))
    if not cams:
        raise InputError("session has no camera stream", path=path, field="camera/<cam>")
    cam = cam or cams[0]
    seg = segmenter_for_session(r, cam, stride, options)
    s = r[f"camera/{cam}"]
    gts, gtf = gt_mask_field(r, cam)
    scale = float(s.attrs.get("depth_scale", 0.001))
    joints = r["joints"] if "joints" in r else None
    n = len(s) if max_frames is None else min(len(s), max_frames)
    ious, times, hand_left, hidden = [], [], [], []
    vis = gts["visible_fraction"][:] if "visible_fraction" in gts.fields else None
    rng = np.random.default_rng(0)
    for i in range(n):
        t = float(s.t[i])
        depth = s["depth"][i][::stride, ::stride].astype(np.float32) * np.float32(scale)
        gt = gts[gtf][i][::stride, ::stride].astype(bool)
        q = None
        if joints is not None and seg.kin is not None:
            q = seg.kin.reorder(joints.sample("q", np.array([t]), mode="linear")[0], joints.attrs.get("joint_names"))
            if q_noise_rad > 0:
                q = q + rng.normal(0.0, q_noise_rad, q.shape)
        c0 = time.process_time()
        res = seg.segment(depth, q)
        times.append((time.process_time() - c0) * 1e3)
        if not gt.any():
            continue
        if vis is not None and float(vis[i]) < min_visible:
            # BOP convention: an object less than min_visible unoccluded is not scored; what matters
            # there is that the segmenter does not make up an object (hidden_empty)
            hidden.append(not res.mask.any())
            continue
        inter = np.logical_and(res.mask, gt).sum()
        ious.append(float(inter / max(np.logical_or(res.mask, gt).sum(), 1)))
        other = (depth > 0) & ~gt
        if other.any():
            hand_left.append(float((res.mask & other).sum() / other.sum()))
    return {
        "iou": np.asarray(ious),
        "ms": np.asarray(times),
        "hand_left": np.asarray(hand_left),
        "hidden_empty": np.asarray(hidden, bool),
        "frames": n,
    }


def _scores(m: dict[str, Any]) -> dict[str, Any]:
    """Table columns of one :func:`evaluate_session` result."""
    return dict(
        frames=m["frames"],
        scored=len(m["iou"]),
        iou_median=_med(m["iou"]),
        iou_mean=_mean(m["iou"]),
        iou_min=float(m["iou"].min()) if len(m["iou"]) else float("nan"),
        hand_left=_mean(m["hand_left"]),
        hidden=len(m["hidden_empty"]),
        hidden_empty=_mean(m["hidden_empty"].astype(float)),
        ms=_med(m["ms"]),
        ms_mean=_mean(m["ms"]),
    )


def run(quick: bool = False) -> BenchTable:
    """Build the segmentation benchmark table (see module docstring)."""
    from vtrack.frames.segmentation import SegmentationOptions
    from vtrack.testing.sim import DEFAULT_OBJECT, ycb_objects, ycb_session
    from vtrack.threads import limit_threads

    limit_threads(1)
    t_start = time.perf_counter()
    table = BenchTable(stage="segmentation", error_key="iou_median", time_key="ms", higher_is_better=True)
    objects = ycb_objects()
    if quick:
        objects = [o for o in objects if o in (DEFAULT_OBJECT, "006_mustard_bottle")] or objects[:2]
    seconds = 1.0 if quick else 2.0
    frames = 15 if quick else None
    per_occ: dict[str, list[float]] = {o: [] for o in OCCLUSIONS}
    for obj in objects:
        for occ in OCCLUSIONS:
            m = evaluate_session(ycb_session(obj, occ, seconds), max_frames=frames)
            per_occ[occ] += m["iou"].tolist()
            table.add(method="hand-aware", setting=f"{obj[4:]} {occ}", object=obj, occlusion=occ, **_scores(m))
    for occ, v in per_occ.items():
        a = np.asarray(v)
        table.add(
            method="hand-aware",
            setting=f"all objects {occ}",
            object="all",
            occlusion=occ,
            frames=len(a),
            scored=len(a),
            iou_median=_med(a),
            iou_mean=_mean(a),
            iou_min=float(a.min()) if len(a) else float("nan"),
            hand_left=float("nan"),
            ms=float("nan"),
        )
    # Ablations on the default object: what each step buys.
    can = DEFAULT_OBJECT if DEFAULT_OBJECT in objects else objects[0]
    ablations = {
        "no hand removal": (SegmentationOptions(hand_removal=False), 0.0),
        "splat silhouette only": (SegmentationOptions(exact_silhouette=False, fill_hand_edge=False), 0.0),
        "FK error: joint noise 1 deg": (SegmentationOptions(), np.deg2rad(1.0)),
        "FK error: joint noise 2 deg": (SegmentationOptions(), np.deg2rad(2.0)),
        "no crop": (SegmentationOptions(crop=False), 0.0),
        "no temporal": (SegmentationOptions(temporal=False), 0.0),
        "dilate 0": (SegmentationOptions(hand_dilate_px=0), 0.0),
        "dilate 2": (SegmentationOptions(hand_dilate_px=2), 0.0),
    }
    for name, (opts, q_noise) in ablations.items():
        for occ in ("none", "medium") if quick else OCCLUSIONS:
            m = evaluate_session(
                ycb_session(can, occ, seconds), options=opts, max_frames=frames, q_noise_rad=float(q_noise)
            )
            table.add(method=f"ablation: {name}", setting=f"{can[4:]} {occ}", object=can, occlusion=occ, **_scores(m))
    table.notes += [
        f"{'quick' if quick else 'full'} run, {time.perf_counter() - t_start:.0f} s wall; single thread; "
        f"{seconds:g} s sessions of the default scene (Allegro + 4 DIGIT, camera 640x480 at 30 Hz).",
        "IoU at stride 4 (160x120) against the simulator's GT object mask subsampled the same way; "
        "frames with an empty GT mask are not scored, nor (BOP's rule) frames where less than 10 % of the "
        "object's silhouette is unoccluded (`hidden`; `hidden_empty` = fraction of those where the segmenter "
        "returned no object). `ms` = median CPU ms of `segment()` per frame.",
        "hand_left = fraction of valid depth pixels outside the GT object mask (hand) kept in the mask.",
        "Inputs: depth + joint angles (FK) + sensor origins from FK; no contacts, no ground truth.",
    ]
    return table


def _med(a: np.ndarray) -> float:
    return float(np.median(a)) if len(a) else float("nan")


def _mean(a: np.ndarray) -> float:
    return float(np.mean(a)) if len(a) else float("nan")
