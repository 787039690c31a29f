"""Slip: image-gradient change signal and a partial-slip (stuck centre, slipping annulus) detector.

- :func:`slip_signal`: ``||grad I_t - grad I_{t-1}||_F`` (Sobel gradients of the grey image, grey levels/px),
  normalised by the number of pixels considered (contact mask or whole image) so it is size-independent.
- :func:`partial_slip`: under a tangential load the contact centre sticks to the object (its markers move
  with it) while an annulus slips (its markers lag); the detector compares annulus and centre displacements.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def _grad(img: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    import cv2

    g = np.asarray(img)
    if g.ndim == 3:
        g = cv2.cvtColor(np.ascontiguousarray(g, np.uint8), cv2.COLOR_BGR2GRAY)
    g = np.nan_to_num(g.astype(np.float32))
    return cv2.Sobel(g, cv2.CV_32F, 1, 0, ksize=3) / 8.0, cv2.Sobel(g, cv2.CV_32F, 0, 1, ksize=3) / 8.0


def slip_signal(img_t: np.ndarray, img_prev: np.ndarray, mask: np.ndarray | None = None) -> float:
    """RMS change of the image gradient between two frames (grey levels / px); 0 for identical frames."""
    gx1, gy1 = _grad(img_t)
    gx0, gy0 = _grad(img_prev)
    d2 = (gx1 - gx0) ** 2 + (gy1 - gy0) ** 2
    if mask is not None and np.asarray(mask).any():
        d2 = d2[np.asarray(mask, bool)]
    return float(np.sqrt(d2.mean())) if d2.size else 0.0


@dataclass
class SlipState:
    signal: float  # slip_signal of this frame against the previous one
    baseline: float  # running median of the signal (sensor noise level)
    slipping: bool  # signal exceeds ``ratio`` x baseline (and an absolute floor)


class SlipDetector:
    """Frame-to-frame slip signal with a running noise baseline."""

    def __init__(self, ratio: float = 3.0, floor: float = 0.5, history: int = 30) -> None:
        self.ratio, self.floor, self.history = ratio, floor, history
        self.prev: np.ndarray | None = None
        self.values: list[float] = []

    def update(self, image: np.ndarray, mask: np.ndarray | None = None) -> SlipState:
        if self.prev is None:
            self.prev = image
            return SlipState(0.0, 0.0, False)
        s = slip_signal(image, self.prev, mask)
        self.prev = image
        base = float(np.median(self.values)) if self.values else s
        slipping = bool(len(self.values) >= 3 and s > max(self.ratio * base, self.floor))
        if not slipping:  # only non-slip frames update the noise baseline
            self.values = (self.values + [s])[-self.history :]
        return SlipState(s, base, slipping)


@dataclass
class PartialSlip:
    centre_disp_px: float  # median |displacement| of markers in the centre disc
    annulus_ratio: float  # median annulus displacement along the centre motion / centre displacement
    slip_fraction: float  # fraction of annulus markers lagging by more than ``lag`` of the centre motion
    partial: bool  # centre stuck and moving, annulus slipping
    full: bool  # centre itself lags (gross slip) -- needs the object motion to tell; see ``object_disp_px``


def partial_slip(
    points_px: np.ndarray,
    disp_px: np.ndarray,
    centre_px: np.ndarray,
    radius_px: float,
    *,
    inner: float = 0.5,
    lag: float = 0.3,
    min_disp_px: float = 0.5,
    min_fraction: float = 0.3,
    object_disp_px: np.ndarray | None = None,
) -> PartialSlip:
    """Partial-slip test on a marker displacement field inside a contact of radius ``radius_px``.

    Markers with ``r < inner * radius`` form the centre, ``inner * radius <= r <= radius`` the annulus.
    A marker slips when its displacement along the centre motion is below ``(1 - lag)`` of the centre's.
    With ``object_disp_px`` (e.g. from the tracker), the centre lagging the object means full slip.
    """
    P = np.asarray(points_px, float)
    D = np.asarray(disp_px, float)
    ok = np.isfinite(D).all(1) & np.isfinite(P).all(1)
    P, D = P[ok], D[ok]
    r = np.linalg.norm(P - np.asarray(centre_px, float), axis=1) / max(radius_px, 1e-9)
    cen, ann = r < inner, (r >= inner) & (r <= 1.0)
    if cen.sum() == 0 or ann.sum() == 0:
        return PartialSlip(0.0, 1.0, 0.0, False, False)
    dc = np.median(D[cen], axis=0)
    mag = float(np.linalg.norm(dc))
    if mag < min_disp_px:
        return PartialSlip(mag, 1.0, 0.0, False, False)
    u = dc / mag
    along = D[ann] @ u / mag
    frac = float(np.mean(along < 1.0 - lag))
    full = False
    if object_disp_px is not None:
        od = float(np.linalg.norm(object_disp_px))
        full = od > min_disp_px and mag < (1.0 - lag) * od
    return PartialSlip(mag, float(np.median(along)), frac, bool(frac >= min_fraction and not full), bool(full))
