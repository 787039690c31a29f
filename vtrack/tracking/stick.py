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

from collections.abc import Iterable, Iterator, Mapping
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
        # sensor -> (patch centre on the gel, id, the id's first patch centre on the gel), sensor frame, m
        self._state: dict[str, tuple[np.ndarray, int, np.ndarray]] = {}
        self._next = 0

    def annotate(self, frame: Any, tf: TrackingFrame) -> TrackingFrame:
        """Add ``stick_ids`` (K,), ``stick_points`` (K, 3, world, m: the gel point under the id's FIRST patch centre,
        carried by the sensor pose), ``stick_patch_points`` (K, 3, world, m: the current patch centre) and
        ``stick_normals`` (K, 3, the object's outward normal: minus the gel normal) to ``tf.info`` from ``frame``
        (a :class:`vtrack.frames.session.Frame`: its per-sensor ``contacts`` and ``sensor_poses``); returns ``tf``.

        Why the gel point: a gel that sticks to the object without rolling moves with it, so every point of the gel is
        fixed on the object, the one under the first patch centre included. The patch centre itself is not: it moves
        with the patch's shape (on the soup can's side it drifts on the object about a quarter as far as the object
        moves while the simulated finger sticks). A patch that travels on the gel (rolling, slipping) starts a new id,
        and so a new gel point. The tracker anchors the gel points and :func:`contact_rigidity` tests them
        (docs/benchmarks/contacts_gel.md)."""
        ids: list[int] = []
        patch: list[np.ndarray] = []
        gel: list[np.ndarray] = []
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
                cid, first = self._next, ctr
                self._next += 1
            else:
                cid, first = prev[1], prev[2]
            self._state[s] = (ctr, cid, first)
            ids.append(cid)
            patch.append(T_ws[:3, :3] @ ctr + T_ws[:3, 3])
            gel.append(T_ws[:3, :3] @ first + T_ws[:3, 3])
            nrm.append(-T_ws[:3, 2])  # the object's outward normal = minus the gel normal
        for s in [s for s in self._state if s not in seen]:  # contact broken: the next one is a new contact
            del self._state[s]
        tf.info["stick_ids"] = np.array(ids, np.int64)
        tf.info["stick_points"] = np.array(gel, np.float64).reshape(-1, 3)
        tf.info["stick_patch_points"] = np.array(patch, np.float64).reshape(-1, 3)
        tf.info["stick_normals"] = np.array(nrm, np.float64).reshape(-1, 3)
        return tf


def stick_term_on(opts: Mapping[str, Any]) -> bool:
    """Whether tracker options ``opts`` turn the sticking-contact term on (``sigma_stick`` > 0)."""
    return float(opts.get("sigma_stick", 0.0) or 0.0) > 0


def sticking_contacts_for(opts: Mapping[str, Any], modalities: Iterable[str]) -> StickingContacts | None:
    """The :class:`StickingContacts` a run with tracker options ``opts`` (:class:`~vtrack.tracking.window.
    TrackerOptions` fields) and ``modalities`` needs: one when the sticking-contact term is on (``sigma_stick`` > 0)
    with touch, else None. One rule for the offline run (:func:`vtrack.tracking.run.track_session`) and the live
    track consumer (:class:`vtrack.live.consumers.TrackConsumer`), so both give the tracker the same ids."""
    if "touch" not in tuple(modalities) or not stick_term_on(opts):
        return None
    from vtrack.tracking.window import TrackerOptions

    return StickingContacts(float(opts.get("stick_patch_move", TrackerOptions.stick_patch_move)))


#: ``--contacts auto`` (offline SLAM, :func:`vtrack.tracking.run.track_session` ``select_contacts``): the session is
#: tracked with the default settings and again with :data:`vtrack.tracking.slam.SLAM_STICKING_CONTACTS` on the same
#: frames, and the sticking run is kept only when both blind tests pass:
#: - the fingers move as one rigid body with the object (:func:`contact_rigidity` of the contacts' gel points at most
#:   ``STICK_RIGIDITY_MAX``): gels stuck to one object keep their distances while they move; fingers sliding over it
#:   need not;
#: - the sticking run explains its depth points about as well as the default run
#:   (:func:`~vtrack.tracking.slam.map_consistency_mm` at most ``STICK_CONSISTENCY_RATIO_MAX`` times the default's;
#:   the preset weighs depth less, so even where the fingers stick its score is up to ~1.15x the default's).
#: The consistency ratio was chosen on blind 2 s heavy-occlusion sessions of both simulator contact modes, seeds 0-2
#: (docs/benchmarks/contacts_auto_live.md); the rigidity bound on the gel points on seeds 0-5 (sticking fingers
#: 0.013-0.095, sliding ones 0.121-1.01: the middle of the gap), checked on seeds 6-8 and at medium / no occlusion
#: (docs/benchmarks/contacts_gel.md).
STICK_RIGIDITY_MAX = 0.11
STICK_CONSISTENCY_RATIO_MAX = 1.13


def contact_tracks(frames: Iterable[TrackingFrame], key: str = "stick_points") -> dict[int, dict[float, np.ndarray]]:
    """The sticking-contact ids of ``frames`` (annotated by :meth:`StickingContacts.annotate`) as tracks: id -> {time
    (s): world point (3,), m}: the gel point (``key`` ``stick_points``) or the patch centre (``stick_patch_points``)."""
    tracks: dict[int, dict[float, np.ndarray]] = {}
    for tf in frames:
        for cid, P in zip(tf.info.get("stick_ids", ()), tf.info.get(key, ()), strict=True):
            tracks.setdefault(int(cid), {})[float(tf.t)] = np.asarray(P, np.float64)
    return tracks


def contact_pairs(
    tracks: Mapping[int, Mapping[float, np.ndarray]], min_life: int = 5
) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """Each pair of the id tracks ``tracks`` (:func:`contact_tracks`) alive together for at least ``min_life`` frames:
    their points (K, 3 each, m) at the K times they share, in time order."""
    long = [tr for tr in tracks.values() if len(tr) >= min_life]
    for a in range(len(long)):
        for b in range(a + 1, len(long)):
            ts = sorted(set(long[a]) & set(long[b]))
            if len(ts) >= min_life:
                yield np.array([long[a][t] for t in ts]), np.array([long[b][t] for t in ts])


def contact_rigidity(
    frames: Iterable[TrackingFrame], min_life: int = 5, min_move: float = 1e-4, key: str = "stick_points"
) -> tuple[float, int]:
    """How far the sticking-contact ids of ``frames`` (annotated by :meth:`StickingContacts.annotate`, in time order)
    are from moving as one rigid body: over the pairs of ids that live together for at least ``min_life`` frames and
    move (mean displacement of the two points over their common life above ``min_move``, m), the median of
    |change of their distance| / their mean displacement (dimensionless; 0 for points fixed to one rigid body).
    The points are the ids' gel points (``key`` ``stick_points``, the default: see :meth:`StickingContacts.annotate`)
    or their patch centres (``stick_patch_points``, the test before 2026-11-28 14:00 UTC). Returns (index, number of
    pairs); (NaN, 0) without such pairs."""
    idx: list[float] = []
    for A, B in contact_pairs(contact_tracks(frames, key), min_life):
        move = 0.5 * (np.linalg.norm(A[-1] - A[0]) + np.linalg.norm(B[-1] - B[0]))
        if move > min_move:  # a pair that does not move says nothing about rigidity
            idx.append(abs(np.linalg.norm(A[-1] - B[-1]) - np.linalg.norm(A[0] - B[0])) / move)
    return (float(np.median(idx)) if idx else float("nan")), len(idx)


def fingers_stick(rigidity: float, consistency_default_mm: float, consistency_stick_mm: float) -> bool:
    """``--contacts auto``'s choice: True (keep the sticking run) when the contacts move rigidly and the sticking run
    explains its depth points about as well as the default one (see :data:`STICK_RIGIDITY_MAX`); False when either
    test fails or cannot be made (NaN: no moving pair of contacts, no frame with enough depth points)."""
    ok = np.isfinite([rigidity, consistency_default_mm, consistency_stick_mm]).all() and consistency_default_mm > 0
    return bool(
        ok
        and rigidity <= STICK_RIGIDITY_MAX
        and consistency_stick_mm <= STICK_CONSISTENCY_RATIO_MAX * consistency_default_mm
    )
