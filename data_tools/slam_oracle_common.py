"""Shared set-up of the ORACLE SLAM diagnoses (data_tools/slam_oracle_*.py). They read the session's GT for
labelled ablations only; the pipeline never does."""

from __future__ import annotations

import numpy as np

from vtrack.eval.session_gt import SessionGroundTruth
from vtrack.geometry import se3
from vtrack.tracking import run as R


class OracleMotion:
    """The GT object motion expressed in SLAM's own object frame (SLAM starts at its first estimate ``T0``, not
    at the GT pose): ``pose(t) = G(t) G(t0)^-1 T0``, 4x4, world frame. ``install()`` wraps
    ``run.build_tracker`` so that ``T0`` and ``t0`` are recorded when the session's tracker is built / first
    stepped."""

    def __init__(self, session_path) -> None:
        self.g = SessionGroundTruth.load(session_path)
        self.T0: np.ndarray | None = None
        self.t0: float | None = None

    def pose(self, t: float) -> np.ndarray:
        G = self.g.poses_at(np.array([t, self.t0]))
        return G[0] @ se3.invert(G[1]) @ self.T0

    def install(self, on_tracker=None) -> None:
        """Wrap ``run.build_tracker``; ``on_tracker(tracker)`` may wrap the new tracker further."""
        orig = R.build_tracker

        def build(shape, mesh, T_init, **kw):
            self.T0 = T_init.copy()
            tr = orig(shape, mesh, T_init, **kw)
            if on_tracker is not None:
                on_tracker(tr)
            # outermost, so t0 is known before any wrapper of on_tracker asks for a pose
            step = tr.step

            def first_time(frame):
                if self.t0 is None:
                    self.t0 = frame.t
                return step(frame)

            tr.step = first_time
            return tr

        R.build_tracker = build
