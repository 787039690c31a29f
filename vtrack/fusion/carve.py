"""Space carving: where the cameras saw through, there is no object (numpy + scipy, no torch, no open3d).

Every vision observation keeps a free-space image (:attr:`vtrack.fusion.observations.Observation.free_depth`):
along each pixel's ray, space is empty up to the depth the sensor measured (whatever it hit: object, hand,
occluder, background) and along the whole ray where the sensor got no return away from the object mask. A
voxel of the object-frame box is carved when ``min_votes`` frames see it empty, ``margin`` in front of the
measured depth. The object rotates in the hand, so the background rays of many views carve the sides that
no depth pixel of the object ever reached: the visual hull of the segmented silhouettes, in the object
frame of the given poses.

:class:`CarveGrid` holds the carved voxels and two fields used by the neural SDF
(:mod:`vtrack.fusion.neural_sdf`): a lower bound on the SDF in carved space (the distance to the nearest
uncarved voxel less one cell: the surface cannot be closer) and the signed distance to the carved hull,
used to cut away a reconstructed surface that lies in carved space.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vtrack.fusion.cloud import VISION


@dataclass
class CarveGrid:
    """Carved voxels of a cubic object-frame box.

    Attributes:
        lo: (3,) box corner, m. cell: voxel size, m. free: (n, n, n) bool, carved (seen empty) voxel centres
            ``lo + cell * (i, j, k)``. votes: (n, n, n) frames that saw each voxel empty.
        bound: (n, n, n) float32 lower bound of the SDF, m: distance to the nearest uncarved voxel minus one
            cell in carved voxels, ``-inf`` elsewhere.
        hull: (n, n, n) float32 signed distance to the carved region's boundary, m, positive in carved space,
            shifted by ``-cell`` (the hull grown by one cell), for cutting meshes.
    """

    lo: np.ndarray
    cell: float
    free: np.ndarray
    votes: np.ndarray
    bound: np.ndarray
    hull: np.ndarray

    @property
    def shape(self) -> tuple[int, int, int]:
        return self.free.shape  # type: ignore[return-value]

    def centres(self, index: np.ndarray) -> np.ndarray:
        """Object-frame centres (K, 3) m of voxel indices (K, 3)."""
        return self.lo + self.cell * np.asarray(index, np.float64)

    def consistent(self, points: np.ndarray, max_votes: int = 2) -> np.ndarray:
        """(N,) bool: the points' voxels were seen empty by at most ``max_votes`` frames (an observed surface
        point that many other views saw through is an outlier: segmentation leak, wrong pose). Points outside
        the box are consistent (no evidence)."""
        return _votes_at(self.votes, self.lo, self.cell, points) <= max_votes

    def sample(self, xyz: np.ndarray, field: str = "hull") -> np.ndarray:
        """Trilinear interpolation of ``hull`` (or ``bound``) at object-frame points (N, 3) m; outside the box
        the nearest boundary value."""
        from scipy.ndimage import map_coordinates

        vol = getattr(self, field)
        u = (np.asarray(xyz, np.float64) - self.lo) / self.cell
        u = np.clip(u, 0, np.array(self.shape) - 1)
        return map_coordinates(vol, u.T, order=1, mode="nearest")


def _votes_at(votes: np.ndarray, lo: np.ndarray, cell: float, points: np.ndarray) -> np.ndarray:
    """Empty votes of the voxel nearest to each point (0 outside the box)."""
    n = np.array(votes.shape)
    ijk = np.round((np.asarray(points, np.float64).reshape(-1, 3) - lo) / cell).astype(np.int64)
    inside = np.all((ijk >= 0) & (ijk < n), axis=1)
    out = np.zeros(len(ijk), np.int64)
    q = ijk[inside]
    out[inside] = votes[q[:, 0], q[:, 1], q[:, 2]]
    return out


def free_votes(
    observations: list, points: np.ndarray, *, margin: float = 0.003, origin: np.ndarray | None = None
) -> np.ndarray:
    """How many vision frames saw each point empty (N,) int16: the point projects into the frame's free-space
    image and lies at least ``margin`` (m, camera z) in front of the pixel's free depth.

    points (N, 3): object frame, m, or relative to ``origin`` (3,) m when given (float32 coordinates near a box
    stay precise). Observations without ``free_depth`` / ``K`` (touch) give no votes.
    """
    P = np.asarray(points, np.float32).reshape(-1, 3)
    o0 = np.zeros(3) if origin is None else np.asarray(origin, np.float64)
    votes = np.zeros(len(P), np.int16)
    for o in observations:
        if o.modality != VISION or o.free_depth is None or o.K is None:
            continue
        T = np.asarray(o.T_view_object, np.float64)
        R = T[:3, :3].astype(np.float32)
        t = (T[:3, :3] @ o0 + T[:3, 3]).astype(np.float32)
        C = P @ R.T + t
        z = C[:, 2]
        K = np.asarray(o.K, np.float64)
        s = max(1, int(o.free_stride))
        fd = o.free_depth
        h, w = fd.shape
        with np.errstate(divide="ignore", invalid="ignore"):
            u = (K[0, 0] * C[:, 0] / z + K[0, 2]) / s
            v = (K[1, 1] * C[:, 1] / z + K[1, 2]) / s
        ok = (z > 0.01) & (u >= 0) & (u < w) & (v >= 0) & (v < h)
        idx = np.nonzero(ok)[0]
        col = u[idx].astype(np.int64)
        row = v[idx].astype(np.int64)
        empty = z[idx] + margin < fd[row, col]
        votes[idx[empty]] += 1
    return votes


def carve(
    observations: list,
    lo: np.ndarray,
    size: float,
    *,
    cell: float = 0.002,
    margin: float = 0.003,
    min_votes: int = 2,
    protect: np.ndarray | None = None,
    protect_radius: float = 0.002,
    protect_max_votes: int | None = None,
) -> CarveGrid | None:
    """Carve the cubic box ``[lo, lo + size]`` (object frame, m) with the free-space images of ``observations``.

    Args:
        observations: :class:`~vtrack.fusion.observations.Observation` list; vision ones with ``free_depth``
            and ``K`` are used (poses folded into ``T_view_object``).
        cell: voxel size, m. margin: a voxel is empty in a frame when it lies at least this far (camera z, m)
            in front of the pixel's free depth (depth noise, pose error).
        min_votes: frames that must see a voxel empty (one wrong pose alone must not carve the object).
        protect: (N, 3) observed surface points (vision and touch): voxels within ``protect_radius`` of one are
            never carved (surface evidence wins over a free ray when poses disagree).
        protect_max_votes: points in a voxel that more than this many frames saw empty are not protected
            (outliers: segmentation leaks, a wrong pose; see :meth:`CarveGrid.consistent`); None = all are.

    Returns None when no observation carries free-space evidence.
    """
    from scipy.ndimage import distance_transform_edt

    views = [o for o in observations if o.modality == VISION and o.free_depth is not None and o.K is not None]
    if not views:
        return None
    lo = np.asarray(lo, np.float64)
    n = int(np.clip(np.ceil(size / cell) + 1, 8, 256))
    ax = (np.arange(n) * cell).astype(np.float32)
    X, Y, Z = np.meshgrid(ax, ax, ax, indexing="ij")
    P = np.stack([X.ravel(), Y.ravel(), Z.ravel()], axis=1)  # relative to lo (float32 precision near the box)
    votes = free_votes(views, P, margin=margin, origin=lo)
    votes = votes.reshape(n, n, n)
    free = votes >= max(1, int(min_votes))
    if protect is not None and len(protect):
        Q = np.asarray(protect, np.float64)
        Q = Q[np.isfinite(Q).all(1)]
        if protect_max_votes is not None:
            Q = Q[_votes_at(votes, lo, cell, Q) <= protect_max_votes]
        r = int(np.ceil(protect_radius / cell))
        ijk = np.round((Q - lo) / cell).astype(np.int64)
        inside = np.all((ijk >= 0) & (ijk < n), axis=1)
        keep = np.zeros((n, n, n), bool)
        ijk = ijk[inside]
        for di in range(-r, r + 1):
            for dj in range(-r, r + 1):
                for dk in range(-r, r + 1):
                    q = np.clip(ijk + (di, dj, dk), 0, n - 1)
                    keep[q[:, 0], q[:, 1], q[:, 2]] = True
        free &= ~keep
    if not free.any() or free.all():
        bound = np.full((n, n, n), -np.inf, np.float32)
        hull = np.full((n, n, n), -1.0 if not free.any() else 1.0, np.float32)
        return CarveGrid(lo, cell, free, votes, bound, hull)
    d_out = distance_transform_edt(free) * cell  # carved voxel -> nearest uncarved
    d_in = distance_transform_edt(~free) * cell  # uncarved voxel -> nearest carved
    bound = np.where(free, d_out - cell, -np.inf).astype(np.float32)
    hull = (np.where(free, d_out, -d_in) - cell).astype(np.float32)
    return CarveGrid(lo, cell, free, votes, bound, hull)
