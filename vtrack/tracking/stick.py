"""Blind sticking-contact candidates for the tracker's sticking-contact term (``TrackerOptions.sigma_stick``).

In a real in-hand rotation the fingers in contact mostly stick to (or roll on) the object: the object-frame point
under a sticking gel does not change while the contact lasts. :class:`StickingContacts` turns each sensor's contact
into one world point per frame (the indentation-weighted centre of its patch, lifted by forward kinematics like every
contact of :mod:`vtrack.frames.session`) and gives it an id that lasts as long as the contact is unbroken and its patch
stays put on the gel (moves less than ``patch_move`` between frames: a patch that travels over the gel is slipping).
The tactile images' own slip signal (:func:`vtrack.tactile.slip.slip_signal`) is not used: the simulator renders
geometry only (no shear, no texture), so a contact sliding over a smooth surface gives the same image as one
that sticks.
The tracker anchors each id in the object frame and applies the second slip test, against its predicted motion
(:meth:`vtrack.tracking.window.WindowTracker._stick_pairs`). Nothing here reads ground truth.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np

from vtrack.tracking.frame import TrackingFrame


def patch_centre(points: np.ndarray, penetration_mm: np.ndarray) -> np.ndarray | None:
    """Indentation-weighted centre (3,) of a contact patch (sensor frame, m); None for an empty or degenerate one."""
    P = np.asarray(points, np.float64)
    w = np.asarray(penetration_mm, np.float64)
    ok = np.isfinite(P).all(1) & np.isfinite(w) & (w > 0)
    if not ok.any():
        return None
    return (P[ok] * w[ok, None]).sum(0) / w[ok].sum()


class StickingContacts:
    """Per-sensor contact ids and world patch centres for the sticking-contact term.

    Args:
        patch_move: m; a patch centre that moves more than this on the gel between two frames starts a new id.
        min_points: contacts with fewer points are ignored (too small to place a centre).
    """

    def __init__(self, patch_move: float = 0.0008, min_points: int = 3) -> None:
        self.patch_move = float(patch_move)
        self.min_points = int(min_points)
        self._state: dict[str, tuple[np.ndarray, int]] = {}  # sensor -> (patch centre on the gel, id)
        self._next = 0

    def annotate(self, frame: Any, tf: TrackingFrame) -> TrackingFrame:
        """Add ``stick_ids`` (K,), ``stick_points`` (K, 3, world, m) and ``stick_normals`` (K, 3, the object's outward
        normal: minus the gel normal) to ``tf.info`` from ``frame``
        (a :class:`vtrack.frames.session.Frame`: its per-sensor ``contacts`` and ``sensor_poses``); returns ``tf``."""
        ids: list[int] = []
        pts: list[np.ndarray] = []
        nrm: list[np.ndarray] = []
        seen = set()
        for s, c in frame.contacts.items():
            T_ws = frame.sensor_poses.get(s)
            ctr = None
            if c.in_contact and len(c.points) >= self.min_points and T_ws is not None and np.all(np.isfinite(T_ws)):
                ctr = patch_centre(c.points, c.penetration_mm)
            if ctr is None:
                continue
            seen.add(s)
            prev = self._state.get(s)
            if prev is None or np.linalg.norm(ctr - prev[0]) > self.patch_move:
                cid = self._next
                self._next += 1
            else:
                cid = prev[1]
            self._state[s] = (ctr, cid)
            ids.append(cid)
            pts.append(T_ws[:3, :3] @ ctr + T_ws[:3, 3])
            nrm.append(-T_ws[:3, 2])  # the object's outward normal = minus the gel normal
        for s in [s for s in self._state if s not in seen]:  # contact broken: the next one is a new contact
            del self._state[s]
        tf.info["stick_ids"] = np.array(ids, np.int64)
        tf.info["stick_points"] = np.array(pts, np.float64).reshape(-1, 3)
        tf.info["stick_normals"] = np.array(nrm, np.float64).reshape(-1, 3)
        return tf


def sticking_contacts_for(opts: Mapping[str, Any], modalities: Iterable[str]) -> StickingContacts | None:
    """The :class:`StickingContacts` a run with tracker options ``opts`` (:class:`~vtrack.tracking.window.
    TrackerOptions` fields) and ``modalities`` needs: one when the sticking-contact term is on (``sigma_stick`` > 0)
    with touch, else None. One rule for the offline run (:func:`vtrack.tracking.run.track_session`) and the live
    track consumer (:class:`vtrack.live.consumers.TrackConsumer`), so both give the tracker the same ids."""
    if "touch" not in tuple(modalities) or float(opts.get("sigma_stick", 0.0) or 0.0) <= 0:
        return None
    from vtrack.tracking.window import TrackerOptions

    return StickingContacts(float(opts.get("stick_patch_move", TrackerOptions.stick_patch_move)))
