"""Shared piece of the colour-track lag diagnostics (slam6_lag.py, slam7_track_lag.py; GT for diagnosis only)."""

import numpy as np

from vtrack.geometry import se3


def lateral_slip(
    G: np.ndarray, i: int, i0: int, p0: np.ndarray, pw: np.ndarray, cam: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A track first seen at world point ``p0`` in frame ``i0`` and now at ``pw`` in frame ``i``: (m, e, ray) with
    ``m`` the true displacement of ``p0`` under the object's GT motion ``G`` (T_world_object per frame) and ``e`` the
    track's slip from where that motion carries it, both lateral to the viewing ray from the camera centre ``cam``
    (world, m), and that unit ray."""
    ps = (G[i] @ se3.invert(G[i0]) @ np.r_[p0, 1.0])[:3]
    ray = (ps - cam) / np.linalg.norm(ps - cam)
    m, e = ps - p0, pw - ps
    m -= ray * (ray @ m)
    e -= ray * (ray @ e)
    return m, e, ray
