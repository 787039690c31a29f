"""``stats`` batch task: a quick quality summary of a session (cheap, numpy only).

Per RGB-D stream: fraction of valid depth pixels, mean depth (m), world-frame bounding box and the
number of occupied voxels of all back-projected depth points; per tactile stream: mean absolute
change from the first frame (a contact-activity proxy, grey levels); for ``gt/object_pose``: path
length (m) and total rotation (rad). Useful to find broken recordings in a large batch, and the
reference task of the batch engine's own tests (deterministic, no heavy dependencies).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from vtrack.errors import InputError
from vtrack.io.jsonio import write_json


def _select(t: np.ndarray, time_range: tuple[float, float] | None) -> np.ndarray:
    if time_range is None:
        return np.arange(len(t))
    t0, t1 = float(time_range[0]), float(time_range[1])
    if not (np.isfinite(t0) and np.isfinite(t1)) or t1 <= t0:
        raise InputError("empty or invalid time range", field="time_range", expected="t0 < t1", got=[t0, t1])
    return np.nonzero((t >= t0) & (t < t1))[0]


def _rgbd_stats(stream: Any, idx: np.ndarray, voxel_m: float) -> dict[str, Any]:
    K = np.asarray(stream.attrs.get("K"), dtype=np.float64)
    T = np.asarray(stream.attrs.get("T_world_camera", np.eye(4)), dtype=np.float64)
    scale = float(stream.attrs.get("depth_scale", 0.001))
    if K.shape != (3, 3):
        raise InputError("camera stream has no 3x3 intrinsics", field=f"{stream.name}/attrs/K")
    depth_field = stream["depth"]
    h, w = depth_field.shape[1:3]
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    rays = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], -1).reshape(-1, 3)
    keys: list[np.ndarray] = []
    valid_frac, depth_sum, n_pts = [], 0.0, 0
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    for i in idx:
        d = depth_field[int(i)].astype(np.float64).reshape(-1)
        if depth_field.dtype.kind in "ui":  # integer depth is in depth_scale units; float is metres
            d = d * scale
        ok = np.isfinite(d) & (d > 0)
        valid_frac.append(float(ok.mean()))
        if not ok.any():
            continue
        p_cam = rays[ok] * d[ok, None]
        p_world = p_cam @ T[:3, :3].T + T[:3, 3]
        depth_sum += float(d[ok].sum())
        n_pts += int(ok.sum())
        lo, hi = np.minimum(lo, p_world.min(0)), np.maximum(hi, p_world.max(0))
        vox = np.floor(p_world / voxel_m).astype(np.int64)
        # Pack three 21-bit voxel indices into one int64 key for a fast unique.
        vox = (vox + (1 << 20)) & ((1 << 21) - 1)
        keys.append(np.unique((vox[:, 0] << 42) | (vox[:, 1] << 21) | vox[:, 2]))
    occupied = int(np.unique(np.concatenate(keys)).size) if keys else 0
    return {
        "frames": int(len(idx)),
        "valid_depth_fraction": float(np.mean(valid_frac)) if valid_frac else 0.0,
        "mean_depth_m": depth_sum / n_pts if n_pts else None,
        "points": n_pts,
        "occupied_voxels": occupied,
        "bbox_extent_m": (hi - lo).tolist() if n_pts else None,
    }


def _tactile_stats(stream: Any, idx: np.ndarray) -> dict[str, Any]:
    if len(idx) == 0:
        return {"frames": 0, "mean_abs_change": None}
    img = stream["image"]
    ref = img[int(idx[0])].astype(np.float32)
    change = [float(np.abs(img[int(i)].astype(np.float32) - ref).mean()) for i in idx]
    return {"frames": int(len(idx)), "mean_abs_change": float(np.mean(change)), "max_abs_change": float(max(change))}


def _pose_stats(stream: Any, idx: np.ndarray) -> dict[str, Any]:
    from vtrack.geometry.se3 import rotation_angle

    if len(idx) < 2:
        return {"frames": int(len(idx)), "path_length_m": 0.0, "rotation_rad": 0.0}
    T = stream["T_world_object"][idx]
    path = float(np.linalg.norm(np.diff(T[:, :3, 3], axis=0), axis=1).sum())
    rel = np.einsum("nji,njk->nik", T[:-1, :3, :3], T[1:, :3, :3])
    rot = float(np.sum(rotation_angle(rel)))
    return {"frames": int(len(idx)), "path_length_m": path, "rotation_rad": rot}


def session_stats(
    session_dir: str,
    out_dir: str,
    *,
    time_range: tuple[float, float] | None = None,
    frames: tuple[int, int] | None = None,
    voxel_m: float = 0.005,
) -> dict[str, Any]:
    """Summarise a session (or the part of it in ``time_range``, s); writes ``out_dir/stats.json``.

    ``frames`` is accepted for chunked batches but ``time_range`` (always passed with it by the
    batch engine) is what selects the frames of every stream.

    Returns:
        flat metrics: ``<stream>.<stat>`` for every stream summarised.
    """
    from vtrack.io.session import open_session

    if voxel_m <= 0:
        raise InputError("voxel size must be positive", field="voxel_m", got=voxel_m)
    reader = open_session(session_dir)
    per_stream: dict[str, dict[str, Any]] = {}
    for name, s in sorted(reader.streams.items()):
        idx = _select(s.t, time_range)
        if s.kind == "rgbd" and "depth" in s.fields:
            per_stream[name] = _rgbd_stats(s, idx, voxel_m)
        elif s.kind == "tactile" and "image" in s.fields:
            per_stream[name] = _tactile_stats(s, idx)
        elif "T_world_object" in s.fields:
            per_stream[name] = _pose_stats(s, idx)
    out = {
        "session": str(Path(session_dir)),
        "complete": reader.complete,
        "time_range": time_range,
        "frames": frames,
        "streams": per_stream,
    }
    write_json(Path(out_dir, "stats.json"), out, indent=1)
    metrics: dict[str, Any] = {"complete": reader.complete}
    for name, st in per_stream.items():
        for k, v in st.items():
            if not isinstance(v, list):
                metrics[f"{name}.{k}"] = v
    return metrics
