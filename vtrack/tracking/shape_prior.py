"""Sphere prior for the SLAM map: when the map is a ball, track against the ball it measured first.

A ball held in the hand and hidden from the camera (the baseball at medium occlusion: 4 frames with depth points in
150) is tracked by touch alone. Its fingers slide over it while it turns, so two things go wrong in a surfel map:

- every new contact lands on a part of the ball the map has not seen: the grid is ``trunc`` there, the map-aware
  gate drops the contact and nothing holds the ball's centre;
- contacts may sit inside the map's surface at no cost (they read shallow, see ``sigma_touch_inside``), so the map
  fused at the tracked poses creeps inward, and the tracker follows the creeping map.

When the map's surfels lie on a sphere (robust fit, small residual, seen over a cap wide enough to pin the centre
and the radius), :class:`SpherePrior` keeps that sphere and the SLAM grid takes its signed distance in its band: the
object is rigid, so the first well-measured ball stays the object's shape. If the map later stops agreeing with it
(fewer than ``keep_inlier`` of the surfels near it) the prior is dropped for good and the map is the surfels again.

Mode ``sphere-fill`` (an ablation) only fills the voxels that no surfel reaches and re-fits the sphere at each
grid update.

Object frame, metres.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vtrack.geometry.fit import robust_sphere

MODES = ("sphere", "sphere-fill", "none")


@dataclass(frozen=True)
class SpherePriorOptions:
    """Detection gates of the sphere prior (metres)."""

    min_surfels: int = 150  #: fewer map surfels: no fit
    #: the fit uses at most this many surfels (an even stride through the map): it runs at every grid update of
    #: every object until a ball is found, and 512 points pin a sphere far below the map's own noise
    max_fit_points: int = 512
    floor: float = 0.001  #: outlier threshold floor of the robust fit, m
    max_rms: float = 0.0008  #: trimmed RMS residual of the kept surfels, m
    min_inlier: float = 0.8  #: share of the surfels (by count) the robust fit keeps, to detect the sphere ...
    #: ... and the share within ``keep_dist`` of it to keep it once detected (the hidden baseball's map, grown by a
    #: few frames' misplaced depth points, keeps 0.7-0.8)
    keep_inlier: float = 0.6
    keep_dist: float = 0.002
    min_radius: float = 0.01  #: radius range of a graspable ball, m
    max_radius: float = 0.15
    #: largest mean resultant length of the kept surfels' directions from the centre: a cap of half-angle a has
    #: (1 + cos a) / 2, so 0.9 needs a cap wider than ~37 deg (a smaller cap pins neither the centre nor the radius;
    #: the hidden baseball's first maps have 0.80-0.86 and fit its radius within 0.2 mm)
    max_resultant: float = 0.9


@dataclass(frozen=True)
class Sphere:
    """A fitted sphere (object frame): centre (3,) m, radius m, RMS residual m, share of surfels kept."""

    centre: np.ndarray
    radius: float
    rms: float
    inlier: float

    def sdf(self, X: np.ndarray) -> np.ndarray:
        """Signed distance (M,) m of object-frame points (M, 3), negative inside."""
        return np.linalg.norm(np.asarray(X, np.float64) - self.centre, axis=1) - self.radius


def detect_sphere(S: np.ndarray, opts: SpherePriorOptions | None = None, held: bool = False) -> Sphere | None:
    """The sphere the surfels ``S`` (K, 3) lie on, or None when they do not pass every gate of ``opts``
    (``held``: a sphere was in force at the previous update; the inlier gate is then ``keep_inlier``)."""
    o = opts or SpherePriorOptions()
    S = np.asarray(S, np.float64)
    S = S[np.isfinite(S).all(1)]
    if len(S) < max(o.min_surfels, 4):
        return None
    if len(S) > o.max_fit_points:
        S = S[:: -(-len(S) // o.max_fit_points)]
    c, r, rms, keep = robust_sphere(S, floor=o.floor)
    if not (np.isfinite(r) and o.min_radius <= r <= o.max_radius and np.isfinite(rms) and rms <= o.max_rms):
        return None
    inlier = float(keep.mean())
    if inlier < (o.keep_inlier if held else o.min_inlier):
        return None
    u = S[keep] - c
    u /= np.maximum(np.linalg.norm(u, axis=1, keepdims=True), 1e-12)
    if float(np.linalg.norm(u.mean(0))) > o.max_resultant:
        return None
    return Sphere(centre=c, radius=float(r), rms=rms, inlier=inlier)


def write_sphere(
    values: np.ndarray, origin: np.ndarray, voxel: float, trunc: float, sphere: Sphere, only_unobserved: bool
) -> int:
    """Write the sphere's signed distance into the voxels of the grid ``values`` (nx, ny, nz; in place) within
    ``trunc`` of the sphere; ``only_unobserved``: only those holding exactly ``trunc`` (no surfel within reach).
    ``origin`` (3,) is the object-frame position of voxel (0, 0, 0). Returns the number of voxels written."""
    shape = np.array(values.shape)
    o = np.asarray(origin, np.float64)
    lo = np.clip(np.floor((sphere.centre - sphere.radius - trunc - o) / voxel).astype(int), 0, shape)
    hi = np.clip(np.ceil((sphere.centre + sphere.radius + trunc - o) / voxel).astype(int) + 1, 0, shape)
    if (hi <= lo).any():
        return 0
    sub = values[lo[0] : hi[0], lo[1] : hi[1], lo[2] : hi[2]]
    ax = [o[a] + voxel * np.arange(lo[a], hi[a]) - sphere.centre[a] for a in range(3)]
    d = (
        np.sqrt(ax[0][:, None, None] ** 2 + ax[1][None, :, None] ** 2 + ax[2][None, None, :] ** 2) - sphere.radius
    ).astype(np.float32)
    t = np.float32(trunc)
    put = np.abs(d) < t
    if only_unobserved:
        put &= sub == t
    sub[put] = d[put]
    return int(put.sum())


class SpherePrior:
    """The SLAM map's sphere prior (see the module docstring); ``apply`` at every grid update."""

    def __init__(self, mode: str = "sphere", opts: SpherePriorOptions | None = None) -> None:
        self.mode = mode
        self.opts = opts or SpherePriorOptions()
        self.sphere: Sphere | None = None  #: the sphere in force, None when none is
        self.updates = 0  #: grid updates that used a sphere
        self.dropped = False  #: the map stopped agreeing with the kept sphere (never used again)

    def apply(self, grid: np.ndarray, S: np.ndarray, origin: np.ndarray, voxel: float, trunc: float) -> np.ndarray:
        """The tracking grid from the surfels' grid ``grid`` (not changed) and the map's surfels ``S`` (K, 3):
        ``grid`` itself when no sphere is in force, else a copy with the sphere written in (:meth:`update` then
        :meth:`write`)."""
        if self.update(S) is None:
            return grid
        return self.write(grid, origin, voxel, trunc)

    def update(self, S: np.ndarray) -> Sphere | None:
        """Decide, from the map's surfels ``S`` (K, 3, object frame, m), the sphere in force at this grid update
        (detected, kept or dropped); None when none is."""
        if self.mode == "none" or self.dropped:
            return None
        if self.mode == "sphere-fill":
            self.sphere = detect_sphere(S, self.opts, held=self.sphere is not None)
        elif self.sphere is None:
            self.sphere = detect_sphere(S, self.opts)
        elif float(np.mean(np.abs(self.sphere.sdf(S)) < self.opts.keep_dist)) < self.opts.keep_inlier:
            self.sphere, self.dropped = None, True
        return self.sphere

    def write(self, grid: np.ndarray, origin: np.ndarray, voxel: float, trunc: float) -> np.ndarray:
        """A copy of the surfels' grid ``grid`` (nx, ny, nz) with the sphere in force (:meth:`update`) written in."""
        assert self.sphere is not None
        out = grid.copy()
        write_sphere(out, origin, voxel, trunc, self.sphere, only_unobserved=self.mode == "sphere-fill")
        self.updates += 1
        return out

    def metrics(self) -> dict[str, float | str | bool]:
        s = self.sphere
        return {
            "shape_prior": self.mode,
            "sphere_prior_updates": self.updates,
            "sphere_prior_radius_mm": s.radius * 1e3 if s is not None else float("nan"),
            "sphere_prior_dropped": self.dropped,
        }
