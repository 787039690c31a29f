"""``poses.csv``: a time series of object poses, and :class:`PoseTrack` to sample it at any time.

Format (one header row, one row per frame)::

    t,x,y,z,qx,qy,qz,qw[,status,ms]

``t`` in seconds (session clock), ``x, y, z`` in metres and the unit quaternion ``qx, qy, qz, qw``
(scalar last) of ``T_world_object``: the object frame in the world frame. The object frame is the one
of the mesh written beside it (``mesh.ply``) or of the mesh the user gave (``--mesh``). Extra columns
(``status``, ``ms``) are optional and ignored when reading.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vtrack.errors import InputError
from vtrack.geometry import se3

POSE_COLUMNS = ("t", "x", "y", "z", "qx", "qy", "qz", "qw")


@dataclass
class PoseTrack:
    """Object poses ``T_world_object`` (N, 4, 4) at strictly increasing times ``t`` (N,), s."""

    t: np.ndarray
    T: np.ndarray

    def __post_init__(self) -> None:
        self.t = np.asarray(self.t, np.float64).reshape(-1)
        self.T = np.asarray(self.T, np.float64).reshape(-1, 4, 4)
        if len(self.t) != len(self.T) or len(self.t) == 0:
            raise InputError(
                "a pose track needs as many poses as times (at least one)",
                field="poses",
                expected=f"{len(self.t)} poses",
                got=len(self.T),
            )
        if not (np.all(np.isfinite(self.t)) and np.all(np.isfinite(self.T))):
            raise InputError("poses contain NaN/Inf", field="poses")
        if np.any(np.diff(self.t) <= 0):
            raise InputError("pose times must be strictly increasing", field="poses.t")

    def __len__(self) -> int:
        return len(self.t)

    def at(self, times: np.ndarray) -> np.ndarray:
        """``T_world_object`` (M, 4, 4) at ``times`` (s): SE(3) interpolation between the bracketing
        poses, held constant before the first and after the last pose."""
        ts = np.asarray(times, np.float64).reshape(-1)
        if len(self.t) == 1:
            return np.repeat(self.T[:1], len(ts), axis=0)
        j = np.clip(np.searchsorted(self.t, ts, side="right") - 1, 0, len(self.t) - 2)
        a = np.clip((ts - self.t[j]) / (self.t[j + 1] - self.t[j]), 0.0, 1.0)
        return se3.interpolate(self.T[j], self.T[j + 1], a).reshape(-1, 4, 4)

    def transformed(self, T_object_newobject: np.ndarray) -> PoseTrack:
        """The same motion expressed for another object frame: ``T_world_newobject = T @ T_object_newobject``."""
        return PoseTrack(self.t.copy(), self.T @ np.asarray(T_object_newobject, np.float64))


def write_poses_csv(
    path: str | Path, times: np.ndarray, T_world_object: np.ndarray, extra: dict[str, list] | None = None
) -> Path:
    """Write ``poses.csv`` (see module docstring); ``extra`` adds columns (e.g. ``status``, ``ms``)."""
    path = Path(path)
    T = np.asarray(T_world_object, np.float64).reshape(-1, 4, 4)
    q = se3.matrix_to_quat(T[:, :3, :3]).reshape(-1, 4)
    extra = extra or {}
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow([*POSE_COLUMNS, *extra])
        for i, t in enumerate(np.asarray(times, np.float64)):
            row = [f"{t:.6f}", *[f"{v:.7f}" for v in T[i, :3, 3]], *[f"{v:.7f}" for v in q[i]]]
            row += [v[i] if isinstance(v[i], str) else f"{v[i]:.3f}" for v in extra.values()]
            w.writerow(row)
    return path


def read_pose_table(path: str | Path) -> dict[str, np.ndarray | None]:
    """Read ``poses.csv`` (``t, x, y, z, qx, qy, qz, qw`` and optional ``gt_*`` columns).

    Returns ``{"t": (N,), "T_est": (N, 4, 4), "T_gt": (N, 4, 4) or None, "in_order": bool}`` sorted by time
    (``in_order``: the file was already strictly increasing in ``t``). Rows with a
    non-finite or zero-norm estimate keep NaN matrices (a lost track), so callers can skip them.

    Raises:
        InputError: missing columns, no rows, or non-finite timestamps.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError("poses file not found", path=path, expected="a poses.csv (t,x,y,z,qx,qy,qz,qw)")
    try:
        with open(path, newline="") as f:
            reader = csv.reader(f)
            header = [h.strip() for h in next(reader, [])]
            rows = [r for r in reader if r and any(c.strip() for c in r)]
    except (OSError, UnicodeDecodeError, csv.Error) as e:
        raise InputError(f"unreadable poses file ({type(e).__name__})", path=path) from None
    need = POSE_COLUMNS
    missing = [c for c in need if c not in header]
    if missing:
        raise InputError(
            "poses.csv lacks required columns",
            path=path,
            field=",".join(missing),
            expected="header t,x,y,z,qx,qy,qz,qw[,gt_x,...,gt_qw]",
            got=header,
        )
    if not rows:
        raise InputError("poses.csv has no rows", path=path)
    # Only the pose columns are numeric; others (e.g. the tracker's ``status``) are ignored.
    names = [c for c in header if c in need or (c.startswith("gt_") and c[3:] in POSE_COLUMNS[1:])]
    idx = [header.index(c) for c in names]
    A = np.full((len(rows), len(names)), np.nan)
    for r, row in enumerate(rows):
        if len(row) != len(header):
            raise InputError(
                f"poses.csv row {r + 2} has {len(row)} fields", path=path, expected=f"{len(header)} (as the header)"
            )
        for k, j in enumerate(idx):
            cell = row[j].strip()
            if cell:
                try:
                    A[r, k] = float(cell)
                except ValueError:
                    raise InputError(
                        f"poses.csv row {r + 2} holds a non-numeric value {cell!r}",
                        path=path,
                        field=names[k],
                        expected="a number or empty",
                    ) from None
    col = {h: i for i, h in enumerate(names)}
    t = A[:, col["t"]]
    if not np.all(np.isfinite(t)):
        raise InputError("poses.csv has non-finite timestamps", path=path, field="t")
    in_order = bool(np.all(np.diff(t) > 0))
    order = np.argsort(t, kind="stable")
    A, t = A[order], t[order]

    def mats(prefix: str) -> np.ndarray:
        xyz = A[:, [col[prefix + c] for c in ("x", "y", "z")]]
        q = A[:, [col[prefix + c] for c in ("qx", "qy", "qz", "qw")]]
        nq = np.linalg.norm(q, axis=1)
        ok = np.isfinite(xyz).all(1) & np.isfinite(q).all(1) & (nq > 1e-9)
        T = np.full((len(A), 4, 4), np.nan)
        if ok.any():
            T[ok] = np.eye(4)
            T[ok, :3, :3] = se3.quat_to_matrix(q[ok] / nq[ok, None])
            T[ok, :3, 3] = xyz[ok]
        return T

    T_gt = mats("gt_") if all("gt_" + c in col for c in POSE_COLUMNS[1:]) else None
    return {"t": t, "T_est": mats(""), "T_gt": T_gt, "in_order": in_order}


def read_poses_csv(path: str | Path) -> PoseTrack:
    """Read a ``poses.csv`` into a :class:`PoseTrack` (sorted by time): every estimate must be a valid pose
    (use :func:`read_pose_table` to read a tracker's output with lost frames and ``gt_*`` columns)."""
    table = read_pose_table(path)
    if not table["in_order"]:
        raise InputError("poses file timestamps must be strictly increasing", path=path, field="t")
    T = table["T_est"]
    if not np.all(np.isfinite(T)):
        raise InputError("poses file has NaN/Inf values or zero quaternions", path=path)
    try:
        return PoseTrack(table["t"], T)
    except InputError as e:
        raise InputError(e.args[0] if e.args else "invalid poses", path=path) from None


def parse_pose(spec: str) -> np.ndarray:
    """A ``T_world_object`` prior from ``"x,y,z,qx,qy,qz,qw"`` (m, scalar-last quaternion) or from the first
    row of a ``poses.csv`` file."""
    p = Path(spec)
    if p.suffix.lower() == ".csv" or p.is_file():
        return read_poses_csv(p).T[0]
    try:
        v = [float(x) for x in spec.replace(" ", "").split(",")]
    except ValueError:
        v = []
    if len(v) != 7 or not np.all(np.isfinite(v)) or np.linalg.norm(v[3:]) < 1e-9:
        raise InputError(
            "bad pose", field="--init-pose", expected="x,y,z,qx,qy,qz,qw (m) or a poses.csv file", got=spec
        )
    T = np.eye(4)
    T[:3, :3] = se3.quat_to_matrix(np.asarray(v[3:]) / np.linalg.norm(v[3:]))
    T[:3, 3] = v[:3]
    return T
