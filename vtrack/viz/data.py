"""Load what a session / result folder holds into a backend-neutral scene for the viewers.

Accepted paths (see ``docs/DEVELOPING.md`` for the result layouts):

- a session folder (``manifest.json``);
- a reconstruction result (``result.json`` kind ``reconstruction``: ``mesh.ply`` and/or ``cloud.ply``);
- a tracking result (``result.json`` kind ``tracking``: ``poses.csv``);
- a folder whose direct subfolders are such results (e.g. ``vtrack demo --out DIR``).

A result's ``session`` entry (absolute, or relative to the result folder) brings in the session;
if it is missing the result is still shown, with a note.

Frames: the reconstructed mesh and fused cloud are in the frame named by ``result.json``'s
``"frame"`` (``"object"`` or ``"world"``). Without that key they are taken to be in the object frame
when the session has object poses (fusion of a moving object accumulates in the object frame), else
in the world frame. Object-frame geometry is drawn at the current object pose (estimate or GT).
"""

from __future__ import annotations

import json
import threading
from collections import OrderedDict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from vtrack.errors import InputError
from vtrack.io.poses import read_pose_table

#: Default display budget of cloud points (larger clouds are decimated, touch points kept first).
DEFAULT_MAX_POINTS = 200_000
#: Longest side of tactile/camera images in the side panel, px.
PANEL_IMAGE_PX = 160


# ---------------------------------------------------------------------------------------------
# Path resolution
# ---------------------------------------------------------------------------------------------
@dataclass
class Sources:
    """Folders that make up one view. Any may be None (but not all)."""

    session: Path | None = None
    reconstruction: Path | None = None
    tracking: Path | None = None
    notes: list[str] = field(default_factory=list)
    result_meta: dict[str, dict] = field(default_factory=dict)


def _read_result_json(d: Path) -> dict:
    p = d / "result.json"
    try:
        meta = json.loads(p.read_text())
    except json.JSONDecodeError as e:
        raise InputError(f"corrupt result.json (JSON error at line {e.lineno}: {e.msg})", path=p) from None
    except OSError as e:
        raise InputError(f"cannot read result.json ({e.strerror})", path=p) from None
    if not isinstance(meta, dict):
        raise InputError("result.json must hold a JSON object", path=p, got=type(meta).__name__)
    kind = meta.get("kind")
    if kind not in ("reconstruction", "tracking"):
        raise InputError(
            "unknown result kind", path=p, field="kind", expected="'reconstruction' or 'tracking'", got=kind
        )
    return meta


def _check_result_files(d: Path, kind: str) -> None:
    if kind == "reconstruction" and not ((d / "mesh.ply").exists() or (d / "cloud.ply").exists()):
        raise InputError(
            "incomplete reconstruction result: neither mesh.ply nor cloud.ply is present",
            path=d,
            expected="mesh.ply and/or cloud.ply (written by `vtrack reconstruct`)",
        )
    if kind == "tracking" and not (d / "poses.csv").exists():
        raise InputError(
            "incomplete tracking result: poses.csv is missing", path=d, expected="poses.csv (written by `vtrack track`)"
        )


def _infer_kind(d: Path) -> str | None:
    if (d / "poses.csv").exists():
        return "tracking"
    if (d / "mesh.ply").exists() or (d / "cloud.ply").exists():
        return "reconstruction"
    return None


def _session_of(meta: dict, d: Path, src: Sources) -> None:
    s = meta.get("session")
    if not s:
        return
    p = Path(str(s)).expanduser()
    if not p.is_absolute():
        p = (d / p).resolve()
    if (p / "manifest.json").exists():
        if src.session is None:
            src.session = p
    else:
        src.notes.append(f"session {p} named in {d / 'result.json'} was not found; showing the result only")


def _add_result(d: Path, src: Sources, kind: str | None = None, meta: dict | None = None) -> None:
    if meta is None and (d / "result.json").exists():
        meta = _read_result_json(d)
    if meta is not None:
        kind = meta["kind"]
    if kind is None:
        return
    _check_result_files(d, kind)
    if getattr(src, kind) is None:
        setattr(src, kind, d)
        src.result_meta[kind] = meta or {}
    if meta:
        _session_of(meta, d, src)


def resolve_sources(path: str | Path) -> Sources:
    """Work out which session and result folders ``path`` refers to.

    Raises:
        InputError: the path does not exist, is not a session/result folder, or a result folder is
            incomplete (the message names the missing file).
    """
    p = Path(path).expanduser()
    if not p.exists():
        raise InputError(
            "path does not exist", path=p, expected="a session folder (manifest.json) or a result folder (result.json)"
        )
    if p.is_file():
        if p.name in ("manifest.json", "result.json") or p.suffix.lower() in (".ply", ".csv"):
            p = p.parent
        else:
            raise InputError(
                "expected a folder",
                path=p,
                expected="a session folder (manifest.json) or a result folder (result.json)",
            )
    p = p.resolve()
    src = Sources()
    if (p / "manifest.json").exists():
        src.session = p
        return src
    if (p / "result.json").exists():
        _add_result(p, src)
        return src
    kind = _infer_kind(p)
    if kind is not None:
        src.notes.append(f"{p} has no result.json; treating it as a {kind} result without a session")
        _add_result(p, src, kind=kind)
        return src
    subs = sorted(c for c in p.iterdir() if c.is_dir() and (c / "result.json").exists())
    for c in subs:
        _add_result(c, src)
    if (p / "summary.json").exists() and src.session is None:
        # `vtrack demo` writes summary.json with the generated session's path.
        try:
            summ = json.loads((p / "summary.json").read_text())
            sess = summ.get("stages", {}).get("generate", {}).get("session")
            if sess and (Path(sess) / "manifest.json").exists():
                src.session = Path(sess)
        except (json.JSONDecodeError, OSError, AttributeError):
            src.notes.append(f"{p / 'summary.json'} is unreadable; session not found from it")
    if src.session is None and src.reconstruction is None and src.tracking is None:
        listing = sorted(c.name for c in p.iterdir())[:8]
        raise InputError(
            "not a vtrack session or result folder",
            path=p,
            expected="manifest.json, result.json, mesh.ply/cloud.ply/poses.csv, or subfolders holding result.json",
            got=listing or "an empty folder",
        )
    return src


# ---------------------------------------------------------------------------------------------
# Readers
# ---------------------------------------------------------------------------------------------
def load_mesh(path: Path) -> tuple[np.ndarray, np.ndarray] | None:
    """(vertices (V, 3) float32 m, faces (F, 3) int32) of a mesh file for display; None if it has no faces.

    Raises:
        InputError: unreadable file or non-finite vertices (:func:`vtrack.io.mesh.load_mesh`).
    """
    from vtrack.io.mesh import load_mesh as read_mesh

    V, F = read_mesh(path, allow_empty=True)
    if len(F) == 0:
        return None
    return V.astype(np.float32), F.astype(np.int32)


# ---------------------------------------------------------------------------------------------
# Scene data
# ---------------------------------------------------------------------------------------------
@dataclass
class CloudData:
    """Fused cloud for display, sorted by point time ``t`` (so "up to time t" is a prefix).

    ``points`` (N, 3) float32 m in the reconstruction frame; ``colors[mode]`` (N, 3) uint8 per colour
    scheme of :data:`vtrack.viz.colors.COLOR_MODES`; ``n_total`` points before decimation.
    """

    points: np.ndarray
    t: np.ndarray
    modality: np.ndarray
    colors: dict[str, np.ndarray]
    n_total: int
    has_time: bool

    def __len__(self) -> int:
        return len(self.points)

    def count_until(self, t: float) -> int:
        """Number of (sorted) points with time <= t."""
        return int(np.searchsorted(self.t, t, side="right"))


def decimate_indices(modality: np.ndarray, max_points: int, seed: int = 0) -> np.ndarray:
    """Sorted indices of at most ``max_points`` points. Touch points (modality 1) are kept first
    (they are few and carry the tactile detail), up to at least half of the budget; the rest is a uniform
    random subset of the other points. Deterministic for a given seed."""
    n = len(modality)
    if n <= max_points:
        return np.arange(n)
    rng = np.random.default_rng(seed)
    touch = np.nonzero(np.asarray(modality) == 1)[0]
    other = np.nonzero(np.asarray(modality) != 1)[0]
    # Touch gets at least half the budget, and all of it the other points do not need.
    touch_budget = max(max_points // 2, max_points - len(other))
    if len(touch) > touch_budget:
        touch = rng.choice(touch, touch_budget, replace=False)
    k = max_points - len(touch)
    if len(other) > k:
        other = rng.choice(other, k, replace=False)
    return np.sort(np.concatenate([touch, other]))


def load_cloud(path: Path, max_points: int = DEFAULT_MAX_POINTS, notes: list[str] | None = None) -> CloudData | None:
    """Read ``cloud.ply`` (per-point scalars optional), drop non-finite points, decimate, colour."""
    from vtrack.io.export import read_ply_points
    from vtrack.viz import colors as C

    try:
        d = read_ply_points(path)
    except InputError:
        raise
    except Exception as e:  # truncated binary body, unknown property type, ...
        raise InputError(f"cannot read cloud ({type(e).__name__}: {e})", path=path) from None
    if not all(k in d for k in ("x", "y", "z")):
        raise InputError("cloud has no x/y/z properties", path=path, got=sorted(d))
    n_total = len(d["x"])
    ok = np.isfinite(d["x"]) & np.isfinite(d["y"]) & np.isfinite(d["z"])
    n_ok = int(ok.sum())
    if notes is not None and n_ok < n_total:
        notes.append(f"cloud.ply: dropped {n_total - n_ok} non-finite points")
    if n_ok == 0:
        if notes is not None:
            notes.append("cloud.ply holds no (finite) points")
        return None
    # Select first (decimate, sort by time), then gather only the kept points of each field.
    keep = np.nonzero(ok)[0]
    mod_all = d.get("modality")
    mod_ok = np.zeros(len(keep), np.int64) if mod_all is None else mod_all[keep].astype(np.int64)
    keep = keep[decimate_indices(mod_ok, max_points)]
    if notes is not None and len(keep) < n_ok:
        notes.append(f"cloud decimated for display: {len(keep):,} of {n_ok:,} points")

    def field_or(name: str, default: float) -> np.ndarray:
        v = d.get(name)
        return np.full(len(keep), default, dtype=np.float64) if v is None else v[keep].astype(np.float64)

    t = field_or("t", 0.0)
    t = np.where(np.isfinite(t), t, 0.0)
    order = np.argsort(t, kind="stable")
    keep, t = keep[order], t[order]
    mod = np.zeros(len(keep), np.int64) if mod_all is None else mod_all[keep].astype(np.int64)
    P = np.stack([d["x"][keep], d["y"][keep], d["z"][keep]], axis=1).astype(np.float32)
    tv_touch = np.where(mod == 1, field_or("tactile_value", np.nan), np.nan)
    cols = {
        "modality": C.modality_colors(mod),
        "time": C.scalar_colors(t, cmap="viridis"),
        "tactile value": C.scalar_colors(tv_touch, vmin=0.0, cmap="plasma"),
        "confidence": C.scalar_colors(field_or("confidence", np.nan), 0.0, 1.0, cmap="viridis"),
        "sensor": C.categorical_colors(field_or("sensor_id", 0).astype(np.int64) + 3 * mod),
    }
    if all(k in d for k in ("red", "green", "blue")):
        cols["rgb"] = np.stack([d["red"][keep], d["green"][keep], d["blue"][keep]], axis=1).astype(np.uint8)
    return CloudData(
        points=P, t=t, modality=mod, colors=cols, n_total=n_total, has_time="t" in d and float(np.ptp(t)) > 0
    )


@dataclass
class CameraInfo:
    """A session camera: intrinsics ``K`` (px), image size, static ``T_world_camera`` (OpenCV frame)."""

    name: str
    K: np.ndarray
    width: int
    height: int
    T_world_camera: np.ndarray
    stream: Any = None

    @property
    def fov_y(self) -> float:
        return float(2.0 * np.arctan2(self.height / 2.0, self.K[1, 1]))


@dataclass
class FrameState:
    """Everything that changes with the timeline at frame ``index`` (time ``t``, s).

    Poses are 4x4 world-frame transforms; ``None`` when unavailable. ``panels`` maps a tactile sensor
    or camera name to an RGB uint8 image strip for the side panel.
    """

    index: int
    t: float
    T_world_object_gt: np.ndarray | None
    T_world_object_est: np.ndarray | None
    link_poses: dict[str, np.ndarray]
    sensor_poses: dict[str, np.ndarray]
    panels: dict[str, np.ndarray]
    camera_images: dict[str, np.ndarray]
    n_cloud: int


def _resize(img: np.ndarray, longest: int, nearest: bool = False) -> np.ndarray:
    """Shrink so the longest side is ``longest`` px (never enlarges)."""
    import cv2

    h, w = img.shape[:2]
    s = longest / max(h, w)
    if s >= 1.0:
        return img
    return cv2.resize(
        img,
        (max(1, round(w * s)), max(1, round(h * s))),
        interpolation=cv2.INTER_NEAREST if nearest else cv2.INTER_AREA,
    )


def _hstack(images: list[np.ndarray], gap: int = 3) -> np.ndarray:
    h = max(i.shape[0] for i in images)
    parts = []
    for k, im in enumerate(images):
        if im.shape[0] != h:
            pad = np.full((h - im.shape[0], im.shape[1], 3), 255, np.uint8)
            im = np.concatenate([im, pad], axis=0)
        parts.append(im)
        if k < len(images) - 1:
            parts.append(np.full((h, gap, 3), 255, np.uint8))
    return np.ascontiguousarray(np.concatenate(parts, axis=1))


def _hand_cache_path(urdf: Path) -> Path | None:
    """Cache file of a hand's link-frame visual meshes, keyed by the URDF folder's file stats (a changed
    URDF or mesh file gives a new key). Loading STL meshes costs ~1 s; the cache ~20 ms."""
    import hashlib

    from vtrack.paths import cache_dir

    try:
        root = Path(urdf).resolve().parent
        stats = sorted(
            (str(p.relative_to(root)), p.stat().st_mtime_ns, p.stat().st_size) for p in root.rglob("*") if p.is_file()
        )
    except OSError:
        return None
    key = hashlib.sha1(json.dumps([str(Path(urdf).resolve()), stats]).encode()).hexdigest()[:16]
    return cache_dir() / "viz" / f"hand-{key}.npz"


def _load_hand_cache(urdf: Path) -> dict[str, list[tuple[np.ndarray, np.ndarray]]] | None:
    p = _hand_cache_path(urdf)
    if p is None or not p.exists():
        return None
    try:
        with np.load(p, allow_pickle=False) as z:
            links = [str(x) for x in z["links"]]
            out: dict[str, list[tuple[np.ndarray, np.ndarray]]] = {}
            for k, link in enumerate(links):
                out.setdefault(link, []).append((z[f"v{k}"], z[f"f{k}"]))
            return out
    except Exception:  # corrupt / partial cache file: rebuild
        return None


def _save_hand_cache(urdf: Path, meshes: dict[str, list[tuple[np.ndarray, np.ndarray]]]) -> None:
    p = _hand_cache_path(urdf)
    if p is None:
        return
    arrays: dict[str, np.ndarray] = {}
    links = []
    for link, items in meshes.items():
        for V, F in items:
            k = len(links)
            links.append(link)
            arrays[f"v{k}"], arrays[f"f{k}"] = V, F
    try:
        p.parent.mkdir(parents=True, exist_ok=True)
        tmp = p.with_name(p.name + f".{threading.get_ident()}.tmp.npz")
        np.savez(tmp, links=np.array(links), **arrays)
        tmp.replace(p)
    except OSError:
        pass  # a read-only cache only costs speed


class ViewData:
    """A session and/or results, loaded for display; geometry static, the rest per frame.

    Args:
        path: session folder, result folder or a folder of results (see module docstring).
        max_points: display budget for the fused cloud.
        load_hand: build the hand's forward kinematics (needs the URDF of the scene).
    """

    def __init__(self, path: str | Path, max_points: int = DEFAULT_MAX_POINTS, load_hand: bool = True) -> None:
        from vtrack.io.session import open_session

        self.path = Path(path)
        src = resolve_sources(path)
        self.sources = src
        self.notes: list[str] = list(src.notes)
        self.session = open_session(src.session) if src.session is not None else None
        self.scene = None
        if self.session is not None and self.session.scene_dict is not None:
            try:
                self.scene = self.session.scene(check_files=False)
            except InputError as e:
                self.notes.append(f"embedded scene unreadable ({e}); hand and sensor names unavailable")

        # -- reconstruction ------------------------------------------------------------------
        self.cloud: CloudData | None = None
        self.mesh: tuple[np.ndarray, np.ndarray] | None = None
        rec = src.reconstruction
        if rec is not None:
            if (rec / "cloud.ply").exists():
                self.cloud = load_cloud(rec / "cloud.ply", max_points, self.notes)
            if (rec / "mesh.ply").exists():
                self.mesh = load_mesh(rec / "mesh.ply")
                if self.mesh is None:
                    self.notes.append(f"{rec / 'mesh.ply'} has no faces")
            if self.cloud is None and self.mesh is None and self.session is None:
                raise InputError("reconstruction result holds no points and no faces, and no session to show", path=rec)

        # -- tracking ------------------------------------------------------------------------
        self.est: dict | None = None
        if src.tracking is not None:
            self.est = read_pose_table(src.tracking / "poses.csv")
            valid = np.isfinite(self.est["T_est"]).all(axis=(1, 2))
            self._est_t, self._est_T = self.est["t"][valid], self.est["T_est"][valid]
            lost = int((~valid).sum())
            if lost:
                self.notes.append(f"poses.csv: {lost} rows without a valid estimate (track lost)")

        # -- ground truth from the session ---------------------------------------------------
        self.gt_t: np.ndarray | None = None
        self.gt_T: np.ndarray | None = None
        if self.session is not None and "gt/object_pose" in self.session:
            s = self.session["gt/object_pose"]
            if s.n:
                self.gt_t = s.t
                self.gt_T = s["T_world_object"][:].astype(np.float64)
        if self.gt_T is None and self.est is not None and self.est["T_gt"] is not None:
            self.gt_t, self.gt_T = self.est["t"], self.est["T_gt"]
        self.gt_mesh = self._load_gt_mesh()

        meta = src.result_meta.get("reconstruction", {})
        frame = meta.get("frame")
        if frame not in ("object", "world"):
            frame = "object" if (self.gt_T is not None or self.est is not None) else "world"
        self.recon_frame: str = frame

        # -- sensors -------------------------------------------------------------------------
        self.cameras: list[CameraInfo] = []
        self.tactile: list[str] = []
        self.hand = None
        self.joints = None
        self._link_meshes: dict[str, list[tuple[np.ndarray, np.ndarray]]] = {}
        if self.session is not None:
            for name, s in sorted(self.session.streams.items()):
                if name.startswith("camera/") and "K" in s.attrs:
                    self.cameras.append(
                        CameraInfo(
                            name.split("/", 1)[1],
                            np.asarray(s.attrs["K"], np.float64),
                            int(s.attrs.get("width", 640)),
                            int(s.attrs.get("height", 480)),
                            np.asarray(s.attrs.get("T_world_camera", np.eye(4))),
                            s,
                        )
                    )
                elif name.startswith("tactile/") and s.n:
                    self.tactile.append(name.split("/", 1)[1])
            if "joints" in self.session and self.session["joints"].n:
                self.joints = self.session["joints"]
            if load_hand and self.scene is not None and self.scene.hand is not None and self.joints is not None:
                self._setup_hand()
        self.height_vmax_mm = 2.0
        if self.scene is not None and self.scene.sim is not None:
            self.height_vmax_mm = float(max(self.scene.sim.penetration_mm[1], 0.1)) * 1.25
        self.times = self._timeline()
        if (
            self.cloud is not None
            and self.cloud.has_time
            and (self.cloud.t[0] > self.times[-1] + 1e-6 or self.cloud.t[-1] < self.times[0] - 1e-6)
        ):
            # Point times in another time base than the session: "up to the current time" is meaningless.
            self.notes.append("cloud point times lie outside the session's time span; showing the whole cloud")
            self.cloud.has_time = False
        # Side-panel images per frame, JPEG-compressed (~100 KB per frame instead of ~1 MB raw): with
        # them cached, scrubbing and playback cost no zarr reads (3-6 ms each, ~13 per frame).
        # Least recently used frames are dropped beyond ``image_cache_bytes``.
        self._img_cache: OrderedDict[int, dict[str, bytes]] = OrderedDict()
        self._img_cache_size = 0
        self._img_lock = threading.Lock()
        self.image_cache_bytes = 256 << 20
        if self.session is None and self.cloud is None and self.mesh is None and self.est is None:
            raise InputError("nothing to show", path=self.path)

    # ---------------------------------------------------------------------------------------
    def _load_gt_mesh(self) -> tuple[np.ndarray, np.ndarray] | None:
        cand: list[tuple[Path, float]] = []
        if self.session is not None:
            # the viewer shows ground truth beside an estimate when a session still has it (gt/, or the
            # assets/ of sessions written before the gt/ layout); the pipeline never reads it
            for p in (self.session.path / "gt" / "object.ply", self.session.path / "assets" / "object.ply"):
                if p.exists():
                    cand.append((p, 1.0))
            if self.scene is not None and self.scene.object.mesh is not None:
                cand.append((Path(self.scene.object.mesh), float(self.scene.object.scale)))
        for p, scale in cand:
            if Path(p).exists():
                m = load_mesh(Path(p))
                if m is not None:
                    return (m[0] * np.float32(scale), m[1])
        return None

    def _setup_hand(self) -> None:
        from vtrack.kinematics.hand import HandKinematics

        try:
            hand = HandKinematics.from_scene(self.scene)
            cached = _load_hand_cache(hand.urdf_path)
            if cached is not None:
                self._link_meshes = cached
            else:
                names = self.joints.attrs.get("joint_names")
                q0 = hand.reorder(self.joints["q"][0][None], names)
                links = hand.hand_mesh_links()
                meshes = hand.hand_meshes(q0[0])
                T0 = hand.link_poses(q0)
                # Meshes back into their link frames, so each frame only moves link nodes.
                for link, (V, F) in zip(links, meshes, strict=True):
                    Tinv = np.linalg.inv(T0[link][0])
                    self._link_meshes.setdefault(link, []).append(
                        ((V @ Tinv[:3, :3].T + Tinv[:3, 3]).astype(np.float32), F.astype(np.int32))
                    )
                _save_hand_cache(hand.urdf_path, self._link_meshes)
        except InputError as e:
            self.notes.append(f"hand not shown: {e}")
            self._link_meshes = {}
            return
        except Exception as e:  # missing mesh files, bad URDF contents
            self.notes.append(f"hand not shown ({type(e).__name__}: {e})")
            self._link_meshes = {}
            return
        self.hand = hand

    def _timeline(self) -> np.ndarray:
        """Frame times (s): the first tactile stream, else camera, joints, GT pose, estimate, cloud."""
        if self.session is not None:
            order = (
                [f"tactile/{n}" for n in self.tactile]
                + [f"camera/{c.name}" for c in self.cameras]
                + ["joints", "gt/object_pose"]
            )
            for name in order:
                if name in self.session and self.session[name].n:
                    return np.asarray(self.session[name].t, np.float64)
        if self.est is not None:
            return self.est["t"]
        if self.gt_t is not None:
            return self.gt_t
        if self.cloud is not None and self.cloud.has_time:
            return np.unique(np.round(self.cloud.t, 4))[:: max(1, len(np.unique(self.cloud.t)) // 300)]
        return np.zeros(1)

    @property
    def link_meshes(self) -> dict[str, list[tuple[np.ndarray, np.ndarray]]]:
        """Hand visual meshes in their link frames (vertices m float32, faces int32)."""
        return self._link_meshes

    @property
    def n_frames(self) -> int:
        return len(self.times)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """World-frame axis-aligned bounds (m) of the content at the first frame, for camera placement."""
        pts = []
        st = self.frame(0, with_images=False)
        T = self.object_pose(st)
        if self.cloud is not None:
            P = self.cloud.points[:: max(1, len(self.cloud) // 5000)].astype(np.float64)
            pts.append(P @ T[:3, :3].T + T[:3, 3] if self.recon_frame == "object" else P)
        if self.gt_mesh is not None and st.T_world_object_gt is not None:
            G = st.T_world_object_gt
            pts.append(self.gt_mesh[0].astype(np.float64) @ G[:3, :3].T + G[:3, 3])
        if self.mesh is not None:
            V = self.mesh[0].astype(np.float64)
            pts.append(V @ T[:3, :3].T + T[:3, 3] if self.recon_frame == "object" else V)
        for Ts in st.sensor_poses.values():
            pts.append(Ts[None, :3, 3])
        if self.gt_T is not None:
            ok = np.isfinite(self.gt_T[:, 0, 3])
            pts.append(self.gt_T[ok, :3, 3])
        if not pts:
            return np.full(3, -0.1), np.full(3, 0.1)
        A = np.concatenate([p for p in pts if len(p)], axis=0) if any(len(p) for p in pts) else np.zeros((1, 3))
        A = A[np.isfinite(A).all(1)]
        if not len(A):
            return np.full(3, -0.1), np.full(3, 0.1)
        return A.min(0), A.max(0)

    def object_pose(self, st: FrameState, source: str = "estimate") -> np.ndarray:
        """Pose at which object-frame geometry is drawn: the estimate if asked and valid, else GT, else I."""
        for T in (
            (st.T_world_object_est, st.T_world_object_gt)
            if source == "estimate"
            else (st.T_world_object_gt, st.T_world_object_est)
        ):
            if T is not None and np.all(np.isfinite(T)):
                return T
        return np.eye(4)

    @staticmethod
    def _nearest(ts: np.ndarray, t: float) -> int:
        j = int(np.clip(np.searchsorted(ts, t), 1, max(len(ts) - 1, 1)))
        if len(ts) == 1:
            return 0
        return j - 1 if abs(t - ts[j - 1]) <= abs(ts[j] - t) else j

    def frame(self, i: int, with_images: bool = True) -> FrameState:
        """State at timeline frame ``i`` (clamped to the valid range)."""
        i = int(np.clip(i, 0, self.n_frames - 1))
        t = float(self.times[i])
        gt = est = None
        if self.gt_T is not None:
            gt = self.gt_T[self._nearest(self.gt_t, t)]
            gt = gt if np.all(np.isfinite(gt)) else None
        if self.est is not None and len(self._est_t):
            est = self._est_T[self._nearest(self._est_t, t)]
        links: dict[str, np.ndarray] = {}
        sensors: dict[str, np.ndarray] = {}
        if self.hand is not None:
            q = self.joints["q"][int(self.joints.index_at(t)[0])][None]
            if np.all(np.isfinite(q)):
                q = self.hand.reorder(q, self.joints.attrs.get("joint_names"))
                lp = self.hand.link_poses(q, links=list(self._link_meshes))
                links = {k: v[0] for k, v in lp.items()}
                sensors = {k: v[0] for k, v in self.hand.sensor_poses(q).items()}
        panels: dict[str, np.ndarray] = {}
        cams: dict[str, np.ndarray] = {}
        if with_images and self.session is not None:
            panels, cams = self.images(i)
        n_cloud = len(self.cloud) if self.cloud is not None else 0
        return FrameState(i, t, gt, est, links, sensors, panels, cams, n_cloud)

    def images(self, i: int) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
        """Side-panel strips per tactile sensor and RGB image per camera at frame ``i`` (cached)."""
        import cv2

        i = int(np.clip(i, 0, self.n_frames - 1))
        with self._img_lock:
            enc = self._img_cache.get(i)
            if enc is not None:
                self._img_cache.move_to_end(i)
        if enc is None:
            enc = self._encode_images(float(self.times[i]))
            with self._img_lock:
                if i not in self._img_cache:
                    self._img_cache[i] = enc
                    self._img_cache_size += sum(len(b) for b in enc.values())
                while self._img_cache_size > self.image_cache_bytes and len(self._img_cache) > 1:
                    _, old = self._img_cache.popitem(last=False)
                    self._img_cache_size -= sum(len(b) for b in old.values())
        panels, cams = {}, {}
        for key, buf in enc.items():
            img = cv2.imdecode(np.frombuffer(buf, np.uint8), cv2.IMREAD_COLOR)[..., ::-1]
            kind, name = key.split(":", 1)
            (panels if kind == "tactile" else cams)[name] = np.ascontiguousarray(img)
        return panels, cams

    def _encode_images(self, t: float) -> dict[str, bytes]:
        import cv2

        imgs = {f"tactile:{k}": v for k, v in self._tactile_panels(t).items()}
        for c in self.cameras:
            if c.stream is not None and c.stream.n and "rgb" in c.stream.fields:
                j = int(c.stream.index_at(t)[0])
                imgs[f"camera:{c.name}"] = _resize(np.asarray(c.stream["rgb"][j], np.uint8), PANEL_IMAGE_PX * 2)
        out = {}
        for k, img in imgs.items():
            ok, buf = cv2.imencode(".jpg", np.ascontiguousarray(img[..., ::-1]), [cv2.IMWRITE_JPEG_QUALITY, 92])
            if ok:
                out[k] = buf.tobytes()
        return out

    @property
    def image_cache_full(self) -> bool:
        with self._img_lock:
            return self._img_cache_size > 0.9 * self.image_cache_bytes

    def is_cached(self, i: int) -> bool:
        with self._img_lock:
            return i in self._img_cache

    def _tactile_panels(self, t: float) -> dict[str, np.ndarray]:
        from vtrack.viz.colors import colorize_height, mask_image

        out = {}
        for name in self.tactile:
            s = self.session[f"tactile/{name}"]
            parts = []
            if "image" in s.fields:
                img = np.asarray(s["image"][int(s.index_at(t)[0])], np.uint8)
                if img.ndim == 3 and img.shape[2] == 3:
                    img = img[..., ::-1]  # BGR (OpenCV) -> RGB for display
                elif img.ndim == 2:
                    img = np.repeat(img[..., None], 3, axis=2)
                parts.append(_resize(img, PANEL_IMAGE_PX))
            g = f"gt/tactile/{name}"
            if g in self.session and self.session[g].n:
                gs = self.session[g]
                j = int(gs.index_at(t)[0])
                # Shrink first, colour after: colouring the full-resolution map cost ~8 ms per sensor.
                if "height_mm" in gs.fields:
                    h = np.asarray(gs["height_mm"][j], np.float32)
                    h = _resize(np.where(np.isfinite(h), h, np.float32(np.nan)), PANEL_IMAGE_PX)
                    parts.append(colorize_height(h, self.height_vmax_mm))
                if "contact" in gs.fields:
                    parts.append(
                        mask_image(_resize(np.asarray(gs["contact"][j], np.uint8), PANEL_IMAGE_PX, nearest=True))
                    )
            if parts:
                out[name] = _hstack(parts)
        return out

    def summary(self) -> dict[str, Any]:
        """Short description for the info panel and logs."""
        return {
            "session": str(self.sources.session) if self.sources.session else None,
            "reconstruction": str(self.sources.reconstruction) if self.sources.reconstruction else None,
            "tracking": str(self.sources.tracking) if self.sources.tracking else None,
            "frames": self.n_frames,
            "duration_s": float(self.times[-1] - self.times[0]) if self.n_frames > 1 else 0.0,
            "cloud_points_shown": len(self.cloud) if self.cloud is not None else 0,
            "cloud_points_total": self.cloud.n_total if self.cloud is not None else 0,
            "mesh_faces": len(self.mesh[1]) if self.mesh is not None else 0,
            "gt_mesh": self.gt_mesh is not None,
            "hand": self.hand is not None,
            "cameras": [c.name for c in self.cameras],
            "tactile": list(self.tactile),
            "recon_frame": self.recon_frame,
        }
