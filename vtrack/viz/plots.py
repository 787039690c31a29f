"""Matplotlib plots shared by tracking results and benchmarks (Agg backend, PNG files).

- :func:`plot_error_over_time`: one or more error series against time (e.g. translation mm and
  rotation deg of a tracker, one line per method).
- :func:`plot_pose_errors`: the standard tracking figure from a ``poses.csv`` with ``gt_*`` columns.
- :func:`pareto_front` / :func:`plot_speed_vs_error`: speed-vs-error scatter with the Pareto front.

All functions skip non-finite values (a lost track is a gap in the line, never a zero) and raise
:class:`~vtrack.errors.InputError` on mismatched lengths.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from vtrack.errors import InputError


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig, out: str | Path) -> Path:
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(out)
    _pyplot().close(fig)
    return out


def plot_error_over_time(
    out: str | Path,
    t: np.ndarray | Mapping[str, np.ndarray],
    series: Mapping[str, np.ndarray] | Sequence[Mapping[str, np.ndarray]],
    ylabel: str | Sequence[str] = "error",
    title: str = "",
    xlabel: str = "time (s)",
    flags: np.ndarray | None = None,
    flag_label: str = "lost/recovering",
) -> Path:
    """Plot error series against time.

    Args:
        out: PNG path.
        t: (N,) times in s shared by all series, or ``{name: (N_name,) times}`` per series.
        series: ``{name: (N,) values}`` for one panel, or a list of such dicts for stacked panels
            (e.g. ``[{"ours": trans_mm}, {"ours": rot_deg}]``) sharing the time axis.
        ylabel: y label, or one per panel.
        flags: optional (N,) bool over the shared ``t``: those samples of each panel's first series are
            marked in red (e.g. frames where the tracker was lost).

    Returns:
        The written path.
    """
    plt = _pyplot()
    panels = [series] if isinstance(series, Mapping) else list(series)
    if not panels:
        raise InputError("no series to plot", field="series")
    labels = [ylabel] * len(panels) if isinstance(ylabel, str) else list(ylabel)
    if len(labels) != len(panels):
        raise InputError("one y label per panel", field="ylabel", expected=str(len(panels)), got=len(labels))
    fig, axes = plt.subplots(len(panels), 1, figsize=(7, 2.4 * len(panels) + 0.6), dpi=110, sharex=True, squeeze=False)
    for ax, panel, lab in zip(axes[:, 0], panels, labels, strict=True):
        for name, v in panel.items():
            tt = np.asarray(t[name] if isinstance(t, Mapping) else t, np.float64).reshape(-1)
            vv = np.asarray(v, np.float64).reshape(-1)
            if len(tt) != len(vv):
                raise InputError("time and value lengths differ", field=str(name), expected=str(len(tt)), got=len(vv))
            # NaN breaks the line: lost frames show as gaps.
            vv = np.where(np.isfinite(vv), vv, np.nan)
            ax.plot(tt, vv, lw=1.2, label=str(name))
        if flags is not None and not isinstance(t, Mapping) and np.any(flags):
            first = np.asarray(next(iter(panel.values())), np.float64).reshape(-1)
            f = np.asarray(flags, bool).reshape(-1)
            if len(f) == len(first):
                ax.scatter(np.asarray(t, np.float64)[f], first[f], c="r", s=8, label=flag_label, zorder=3)
        ax.set_ylabel(lab)
        ax.grid(alpha=0.3)
        if len(panel) > 1 or len(panels) == 1:
            ax.legend(fontsize=7)
    axes[-1, 0].set_xlabel(xlabel)
    if title:
        axes[0, 0].set_title(title)
    return _save(fig, out)


def pose_errors(T_est: np.ndarray, T_gt: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-frame translation error (mm) and rotation error (deg); NaN where either pose is invalid."""
    from vtrack.geometry.se3 import rotation_angle

    A = np.asarray(T_est, np.float64).reshape(-1, 4, 4)
    B = np.asarray(T_gt, np.float64).reshape(-1, 4, 4)
    if A.shape != B.shape:
        raise InputError("estimate and GT pose counts differ", field="T_est", expected=str(B.shape), got=A.shape)
    ok = np.isfinite(A).all(axis=(1, 2)) & np.isfinite(B).all(axis=(1, 2))
    trans = np.full(len(A), np.nan)
    rot = np.full(len(A), np.nan)
    if ok.any():
        trans[ok] = np.linalg.norm(A[ok, :3, 3] - B[ok, :3, 3], axis=1) * 1e3
        R = np.einsum("nji,njk->nik", B[ok, :3, :3], A[ok, :3, :3])
        rot[ok] = np.degrees(rotation_angle(R))
    return trans, rot


def plot_pose_errors(poses_csv: str | Path, out: str | Path, title: str = "") -> Path:
    """Translation (mm) and rotation (deg) error over time from a ``poses.csv`` with ``gt_*`` columns.

    Raises:
        InputError: the file has no ground-truth columns.
    """
    from vtrack.io.poses import read_pose_table

    p = read_pose_table(poses_csv)
    if p["T_gt"] is None:
        raise InputError(
            "poses.csv has no ground-truth columns to compare with",
            path=poses_csv,
            expected="gt_x, gt_y, gt_z, gt_qx, gt_qy, gt_qz, gt_qw",
        )
    trans, rot = pose_errors(p["T_est"], p["T_gt"])
    return plot_error_over_time(
        out,
        p["t"],
        [{"translation": trans}, {"rotation": rot}],
        ylabel=["translation error (mm)", "rotation error (deg)"],
        title=title or f"pose error ({Path(poses_csv).parent.name})",
    )


def pareto_front(times: np.ndarray, errors: np.ndarray, higher_is_better: bool = False) -> np.ndarray:
    """Boolean mask of points not dominated in (time, error): nothing else is both at least as fast and
    at least as good, and strictly better in one. Non-finite points are never on the front."""
    t = np.asarray(times, np.float64).reshape(-1)
    e = np.asarray(errors, np.float64).reshape(-1)
    if len(t) != len(e):
        raise InputError("times and errors differ in length", field="errors", expected=str(len(t)), got=len(e))
    if higher_is_better:
        e = -e
    ok = np.isfinite(t) & np.isfinite(e)
    mask = np.zeros(len(t), dtype=bool)
    for i in np.nonzero(ok)[0]:
        dom = ok & (t <= t[i]) & (e <= e[i]) & ((t < t[i]) | (e < e[i]))
        mask[i] = not dom.any()
    return mask


def plot_speed_vs_error(
    out: str | Path,
    rows: Sequence[Mapping[str, Any]],
    time_key: str = "ms",
    error_key: str = "error",
    method_key: str = "method",
    label_key: str | None = "setting",
    higher_is_better: bool = False,
    title: str = "",
    log_x: bool | None = None,
) -> Path:
    """Scatter of error against time per method with the Pareto front dashed.

    Args:
        rows: dicts with at least ``time_key`` and ``error_key`` (e.g. a ``BenchTable.rows``).
        label_key: optional column annotated next to each point (operating point).
        log_x: log time axis; default when all times are positive and span > 10x.
    """
    plt = _pyplot()
    if not rows:
        raise InputError("no rows to plot", field="rows")
    t = np.array([float(r.get(time_key, np.nan)) for r in rows])
    e = np.array([float(r.get(error_key, np.nan)) for r in rows])
    fig, ax = plt.subplots(figsize=(7, 4.5), dpi=110)
    methods = list(dict.fromkeys(str(r.get(method_key, "")) for r in rows))
    for m in methods:
        idx = [i for i, r in enumerate(rows) if str(r.get(method_key, "")) == m]
        ax.scatter(t[idx], e[idx], s=36, label=m or None)
        if label_key:
            for i in idx:
                lab = rows[i].get(label_key, "")
                if lab not in ("", None) and np.isfinite(t[i]) and np.isfinite(e[i]):
                    ax.annotate(
                        str(lab), (t[i], e[i]), fontsize=6, alpha=0.7, xytext=(3, 3), textcoords="offset points"
                    )
    front = pareto_front(t, e, higher_is_better)
    if front.any():
        o = np.argsort(t[front])
        ax.plot(t[front][o], e[front][o], "k--", lw=1, alpha=0.6, label="Pareto front")
    fin = t[np.isfinite(t)]
    if log_x is None:
        log_x = bool(len(fin) and fin.min() > 0 and fin.max() / fin.min() > 10)
    if log_x:
        ax.set_xscale("log")
    ax.set_xlabel(f"{time_key} (lower is faster)")
    ax.set_ylabel(f"{error_key} ({'higher' if higher_is_better else 'lower'} is better)")
    ax.set_title(title or "speed against error")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    return _save(fig, out)
