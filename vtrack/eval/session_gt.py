"""Ground truth of a synthetic session, for SCORING ONLY (evaluation and benchmarks).

Pipeline code (tactile, frames, fusion, tracking, live) never imports this module; ``vtrack track`` and
``vtrack reconstruct`` call it after the estimate is final, and only when ground truth is available
(``--gt SESSION``, or the session itself still has its ``gt/``).

Frame alignment between an estimate and the ground truth (``alignment`` in the metrics):
- ``mesh``: the estimate is in the frame of the session's GT mesh (the same file content);
- ``source``: the estimate is in the frame of the mesh file the simulator was given
  (``created.object_source``); the simulator recentred it by ``created.T_source_object``;
- ``first_frame``: any other frame (SLAM defines its own): the estimate is mapped onto the GT at the
  first frame, so the errors measure the object's MOTION since then (``motion_*`` metrics; ADD-S-style
  for symmetric objects).
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from vtrack.errors import InputError
from vtrack.geometry import se3

GT_MESH = "gt/object.ply"


def _sha(path: Path) -> str:
    return hashlib.sha1(Path(path).read_bytes()).hexdigest()


@dataclass
class SessionGroundTruth:
    """What the simulator knew about a session."""

    path: Path
    pose_times: np.ndarray
    poses: np.ndarray  # (N, 4, 4) T_world_object
    mesh_path: Path | None
    symmetric: bool
    object_source: Path | None
    T_source_object: np.ndarray | None

    @classmethod
    def load(cls, session: str | Path) -> SessionGroundTruth:
        """Ground truth of ``session``; InputError when it has none (e.g. a stripped copy)."""
        from vtrack.io.session import open_session

        r = open_session(session)
        if "gt/object_pose" not in r or r["gt/object_pose"].n == 0:
            raise InputError(
                "session has no ground truth to score against (gt/object_pose)",
                path=r.path,
                field="gt/object_pose",
                expected="the original synthetic session (--gt)",
            )
        s = r["gt/object_pose"]
        mesh = r.path / GT_MESH
        if not mesh.is_file():
            legacy = r.path / "assets" / "object.ply"  # sessions written before the gt/ layout
            mesh = legacy if legacy.is_file() else None
        created = r.manifest.get("created", {})
        src = created.get("object_source")
        T_so = created.get("T_source_object")
        obj = (r.scene_dict or {}).get("object") or {}
        symmetric = bool(obj.get("symmetric", False)) if isinstance(obj, dict) else False
        return cls(
            r.path,
            np.asarray(s.t, np.float64),
            np.asarray(s["T_world_object"][:], np.float64),
            mesh,
            symmetric,
            Path(src) if src else None,
            None if T_so is None else np.asarray(T_so, np.float64),
        )

    @classmethod
    def find(cls, gt: str | Path | None, session: str | Path) -> SessionGroundTruth | None:
        """Ground truth to score a run on ``session``: the session ``gt`` when given (its absence is an
        error), else the session's own ``gt/`` if it still has one, else None (a real or stripped recording)."""
        if gt is not None:
            return cls.load(gt)
        try:
            return cls.load(session)
        except InputError:
            return None

    def poses_at(self, times: np.ndarray) -> np.ndarray:
        from vtrack.io.poses import PoseTrack

        return PoseTrack(self.pose_times, self.poses).at(times)

    def alignment(self, mesh: str | Path | None) -> tuple[str, np.ndarray | None]:
        """How an estimate in the frame of ``mesh`` maps to the GT object frame: (kind, T_mesh_gtobject)."""
        if mesh is not None and Path(mesh).is_file():
            if self.mesh_path is not None and _sha(Path(mesh)) == _sha(self.mesh_path):
                return "mesh", np.eye(4)
            if (
                self.object_source is not None
                and self.T_source_object is not None
                and self.object_source.is_file()
                and _sha(Path(mesh)) == _sha(self.object_source)
            ):
                return "source", self.T_source_object
        return "first_frame", None

    def model(self) -> tuple[np.ndarray, np.ndarray]:
        from vtrack.io.mesh import load_mesh

        if self.mesh_path is None:
            raise InputError("ground-truth mesh missing", path=self.path / GT_MESH)
        return load_mesh(self.mesh_path)


def score_trajectory(
    gt: SessionGroundTruth, times: np.ndarray, T_est: np.ndarray, mesh: str | Path | None = None
) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """Pose metrics of an estimated trajectory (``T_world_object`` in the frame of ``mesh``, or SLAM's own).

    Returns (metrics, per-frame errors). Always reports the motion errors (first-frame alignment,
    ``motion_add_s_mm`` mean, ``motion_err_mm``: ADD-S for symmetric objects else ADD); with a known frame
    also the absolute ``add_s_mm``, ``drift_mm`` and the rest of :func:`~vtrack.eval.pose_metrics.summarize`.
    """
    from vtrack.eval.pose_metrics import (
        add_s,
        dense_surface_points,
        mesh_symmetry_axis,
        sample_model_points,
        summarize,
        trajectory_errors,
    )

    T_est = np.asarray(T_est, np.float64)
    T_gt = gt.poses_at(times)
    V, F = gt.model()
    pts = sample_model_points(V, F, 1000, seed=0)
    dense = dense_surface_points(V, F)  # ADD-S's closest points (1000 alone put a ~2 mm floor under a spin)
    centre, axis = 0.5 * (V.min(0) + V.max(0)), mesh_symmetry_axis(V, F)
    kind, T_mg = gt.alignment(mesh)
    metrics: dict[str, Any] = {"alignment": kind, "symmetric": gt.symmetric, "scored_against": str(gt.path)}
    # motion since the first frame: the estimate mapped onto the GT at frame 0
    T_motion = T_est @ se3.invert(T_est[0]) @ T_gt[0]
    me = trajectory_errors(T_motion, T_gt, pts, symmetric=gt.symmetric, centre=centre, axis=axis, surface_points=dense)
    key = "add_s" if gt.symmetric else "add"
    metrics.update(
        motion_err_mm=float(me[key].mean() * 1e3),
        motion_add_s_mm=float(me["add_s"].mean() * 1e3),
        # the record's metric before 2026-11-26 (closest point among the 1000 samples), kept for comparison
        motion_add_s_1k_mm=float(add_s(T_motion, T_gt, pts).mean() * 1e3),
        motion_drift_mm=float(me["pos"].mean() * 1e3),
        motion_final_mm=float(me[key][-1] * 1e3),
    )
    errors = me
    if T_mg is not None:
        e = trajectory_errors(
            T_est @ T_mg, T_gt, pts, symmetric=gt.symmetric, centre=centre, axis=axis, surface_points=dense
        )
        metrics.update(summarize(e))
        errors = e
    else:
        metrics.update({k: v for k, v in summarize(me).items()})
        metrics["note"] = "object frame defined by the estimate: errors are object motion since the first frame"
    return metrics, errors


def align_mesh_to_gt(
    gt: SessionGroundTruth,
    V: np.ndarray,
    mesh_frame: str | Path | None,
    poses_times: np.ndarray | None = None,
    poses: np.ndarray | None = None,
) -> tuple[np.ndarray, str]:
    """Vertices of a reconstruction (object frame of the estimate) expressed in the GT object frame.

    With a known frame (the mesh the estimate's poses refer to), the fixed transform; otherwise the
    first-frame alignment of the poses the mesh was fused with (``T_gt0 @ inv(T_est0)``)."""
    kind, T_mg = gt.alignment(mesh_frame)
    if T_mg is None:
        if poses is None or poses_times is None:
            return np.asarray(V, np.float64), "none"
        T_gt0 = gt.poses_at(np.asarray(poses_times[:1]))[0]
        T_mg = se3.invert(T_gt0) @ np.asarray(poses[0], np.float64)  # est-object -> gt-object
        return se3.transform_points(T_mg, np.asarray(V, np.float64)), "first_frame"
    # est frame = mesh frame; gt-object = inv(T_mg) applied to mesh-frame points
    return se3.transform_points(se3.invert(T_mg), np.asarray(V, np.float64)), kind
