"""Force estimation: normal force by linear regression on height/contact features, shear force from marker
displacement, and the friction-cone check ``||f_t|| <= mu * f_n``. Forces in N, displacements in mm.

No press set records force, so models are fit from user data (``fit``) -- e.g. a force/torque sensor
recorded alongside the tactile stream; ``predict`` then works per frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vtrack.errors import InputError

FEATURES = ("area_mm2", "volume_mm3", "max_depth_mm", "mean_depth_mm")


def frame_features(frame) -> np.ndarray:
    """(4,) normal-force features of a :class:`~vtrack.tactile.pipeline.TactileFrame` (see ``FEATURES``)."""
    s = frame.stats
    return np.array([s.area_mm2, s.volume_mm3, s.max_depth_mm, s.mean_depth_mm], float)


@dataclass
class ForceEstimate:
    normal_n: float
    shear_n: np.ndarray  # (2,) tangential force in the sensor x, y directions
    in_friction_cone: bool


def friction_cone_ok(f_t: np.ndarray, f_n: float, mu: float) -> bool:
    """``||f_t|| <= mu * f_n`` (False for a pulling/negative normal force with non-zero shear)."""
    ft = float(np.linalg.norm(np.nan_to_num(np.asarray(f_t, float))))
    return bool(ft <= mu * max(float(f_n), 0.0) + 1e-12)


class ForceModel:
    """Linear normal-force model ``f_n = w . features + b`` (ridge) and shear ``f_t = k * shear_mm``."""

    def __init__(self, mu: float = 0.8, ridge: float = 1e-6) -> None:
        self.mu, self.ridge = mu, ridge
        self.w: np.ndarray | None = None
        self.k_shear: float | None = None

    def fit(
        self,
        features: np.ndarray,
        normal_n: np.ndarray,
        shear_mm: np.ndarray | None = None,
        shear_n: np.ndarray | None = None,
    ) -> ForceModel:
        X = np.asarray(features, float)
        y = np.asarray(normal_n, float)
        if X.ndim != 2 or len(X) != len(y) or len(y) < X.shape[1] + 1:
            raise InputError(
                "force fit needs (N, k) features and N >= k + 1 forces", field="features", got=(X.shape, y.shape)
            )
        if not (np.isfinite(X).all() and np.isfinite(y).all()):
            raise InputError("non-finite training data", field="features/normal_n")
        A = np.column_stack([X, np.ones(len(X))])
        scale = np.maximum(np.abs(A).max(0), 1e-12)  # column scaling for conditioning
        As = A / scale
        w = np.linalg.solve(As.T @ As + self.ridge * np.eye(A.shape[1]), As.T @ y)
        self.w = w / scale
        if shear_mm is not None and shear_n is not None:
            d = np.asarray(shear_mm, float).reshape(-1)
            f = np.asarray(shear_n, float).reshape(-1)
            self.k_shear = float(d @ f / max(d @ d, 1e-12))
        return self

    def predict(self, features: np.ndarray) -> np.ndarray:
        if self.w is None:
            raise InputError("force model is not fitted", field="ForceModel")
        X = np.atleast_2d(np.nan_to_num(np.asarray(features, float)))
        return np.column_stack([X, np.ones(len(X))]) @ self.w

    def predict_frame(self, frame) -> ForceEstimate:
        fn = float(self.predict(frame_features(frame))[0]) if frame.stats.area_px else 0.0
        fn = max(fn, 0.0)
        ft = np.zeros(2)
        if self.k_shear is not None and frame.shear is not None and np.isfinite(frame.shear.shear_mm).all():
            ft = self.k_shear * frame.shear.shear_mm
        return ForceEstimate(fn, ft, friction_cone_ok(ft, fn, self.mu))
