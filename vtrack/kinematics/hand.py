"""Batched forward kinematics of a robot hand from its URDF, and tactile sensor poses.

The URDF is parsed once with ``yourdfpy`` (no meshes loaded for FK); FK itself is plain float64
numpy, batched over frames: for N joint vectors every link transform is computed with one
``(N, 4, 4)`` matrix product per joint, so FK of a whole session costs milliseconds.

Frames: ``T_world_link = T_world_base @ T_base_link(q)``; a tactile sensor's frame (see
:mod:`vtrack.geometry.tactile_frame`) is ``T_world_sensor = T_world_link @ T_link_sensor`` with the
mount from the scene (``hand.sensors[i].T_link_sensor``). Joint vectors are in radians, in the
order of :attr:`HandKinematics.joint_names`.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np

from vtrack.errors import InputError


@dataclass
class _Joint:
    name: str
    type: str
    parent: str
    child: str
    origin: np.ndarray  # (4, 4) T_parent_jointframe
    axis: np.ndarray  # (3,) unit axis in the joint frame
    index: int  # column in q, or -1 for fixed joints
    lower: float
    upper: float


def _natural_key(name: str) -> list[Any]:
    """Sort ``joint_2.0`` before ``joint_10.0`` (numbers compared as numbers)."""
    return [float(p) if re.fullmatch(r"\d+(\.\d+)?", p) else p for p in re.split(r"(\d+(?:\.\d+)?)", name)]


def _axis_angle(axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """(N, 3, 3) rotations about a fixed unit ``axis`` by ``angle`` (N,) rad (Rodrigues)."""
    eye, K, KK = _rodrigues_terms(tuple(np.asarray(axis, np.float64).tolist()))  # (the same floats, cheaper)
    s = np.sin(angle)[:, None, None]
    c = np.cos(angle)[:, None, None]
    return eye + s * K + (1.0 - c) * KK


@lru_cache(maxsize=256)
def _rodrigues_terms(axis: tuple[float, float, float]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(I, K, K @ K), each (1, 3, 3), of a joint axis (K: its cross-product matrix): fixed per joint, built once
    (forward kinematics runs every frame)."""
    K = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    out = (np.eye(3)[None], K[None], (K @ K)[None])
    for a in out:
        a.flags.writeable = False
    return out


class HandKinematics:
    """Forward kinematics of a URDF hand plus the tactile sensors mounted on its links.

    Args:
        urdf: path of the URDF file.
        T_world_base: (4, 4) pose of the URDF root link in the world frame.
        sensors: ``{sensor name: (link name, T_link_sensor (4, 4))}``.
        joint_names: column order of joint vectors; default: actuated joints sorted by name with
            numbers compared numerically (``joint_0.0 ... joint_15.0`` for the Allegro hand, i.e.
            index, middle, ring, thumb; NOT the URDF file order).

    Raises:
        InputError: unreadable URDF, unknown link or joint name.
    """

    def __init__(
        self,
        urdf: str | Path,
        T_world_base: np.ndarray | None = None,
        sensors: dict[str, tuple[str, np.ndarray]] | None = None,
        joint_names: list[str] | None = None,
    ) -> None:
        import yourdfpy

        self.urdf_path = Path(urdf)
        if not self.urdf_path.exists():
            raise InputError("URDF file does not exist", path=self.urdf_path)
        # Check the XML first: yourdfpy logs parser noise on malformed files and then fails with an
        # unrelated AttributeError; the XML parser's own message (with line/column) is the useful one.
        import logging
        import xml.etree.ElementTree as ET

        try:
            xml_root = ET.parse(self.urdf_path).getroot()
        except (ET.ParseError, OSError, UnicodeDecodeError) as e:
            raise InputError(f"URDF is not well-formed XML ({e})", path=self.urdf_path) from None
        if xml_root.tag != "robot":
            raise InputError("not a URDF (root element is not <robot>)", path=self.urdf_path, got=xml_root.tag)
        yl = logging.getLogger("yourdfpy")
        level = yl.level
        yl.setLevel(logging.CRITICAL)  # its warnings go to stderr as noise; errors are re-raised below
        try:
            model = yourdfpy.URDF.load(str(self.urdf_path), load_meshes=False, build_scene_graph=False)
        except Exception as e:  # yourdfpy raises several types for malformed files
            raise InputError(f"cannot parse URDF ({type(e).__name__}: {e})", path=self.urdf_path) from None
        finally:
            yl.setLevel(level)
        self._model = model
        robot = model.robot
        actuated = [j.name for j in robot.joints if j.type != "fixed" and j.mimic is None]
        if any(j.mimic is not None for j in robot.joints):
            raise InputError("mimic joints are not supported", path=self.urdf_path)
        if joint_names is None:
            joint_names = sorted(actuated, key=_natural_key)
        else:
            joint_names = list(joint_names)
            if sorted(joint_names) != sorted(actuated):
                raise InputError(
                    "joint_names must list every actuated joint of the URDF once",
                    path=self.urdf_path,
                    field="hand.joint_names",
                    expected=sorted(actuated, key=_natural_key),
                    got=joint_names,
                )
        self.joint_names: list[str] = joint_names
        col = {n: i for i, n in enumerate(joint_names)}

        link_set = {lk.name for lk in robot.links}
        for j in robot.joints:
            for role, ln in (("parent", j.parent), ("child", j.child)):
                if ln not in link_set:
                    raise InputError(
                        f"joint '{j.name}' has a {role} link that is not defined",
                        path=self.urdf_path,
                        field=f"joint {j.name}/{role}",
                        expected="a <link> name of the URDF",
                        got=ln,
                    )
        children = {j.child for j in robot.joints}
        roots = [lk.name for lk in robot.links if lk.name not in children]
        if len(roots) != 1:
            raise InputError("URDF must have exactly one root link", path=self.urdf_path, got=roots)
        self.root_link: str = roots[0]
        by_parent: dict[str, list] = {}
        for j in robot.joints:
            by_parent.setdefault(j.parent, []).append(j)
        # Topological order (parents before children) so FK is one pass.
        self._joints: list[_Joint] = []
        stack = [self.root_link]
        while stack:
            parent = stack.pop()
            for j in by_parent.get(parent, []):
                origin = np.eye(4) if j.origin is None else np.asarray(j.origin, dtype=np.float64)
                axis = np.array([1.0, 0.0, 0.0]) if j.axis is None else np.asarray(j.axis, dtype=np.float64)
                axis = axis / max(np.linalg.norm(axis), 1e-12)
                lim = j.limit
                free = lim is None or j.type == "continuous"
                lo = -np.inf if free or lim.lower is None else float(lim.lower)
                hi = np.inf if free or lim.upper is None else float(lim.upper)
                self._joints.append(
                    _Joint(j.name, j.type, j.parent, j.child, origin, axis, col.get(j.name, -1), lo, hi)
                )
                stack.append(j.child)
        self.link_names: list[str] = [self.root_link] + [j.child for j in self._joints]
        reached = {j.name for j in self._joints}
        unreached = [j.name for j in robot.joints if j.name not in reached]
        if unreached:  # a cycle or a second tree: FK would silently ignore these joints
            raise InputError(
                "joints not connected to the root link (cycle or disconnected tree)",
                path=self.urdf_path,
                field="joint",
                expected=f"a tree rooted at '{self.root_link}'",
                got=unreached[:5],
            )
        self.lower = np.array([next(j.lower for j in self._joints if j.name == n) for n in joint_names])
        self.upper = np.array([next(j.upper for j in self._joints if j.name == n) for n in joint_names])

        self.T_world_base = np.eye(4) if T_world_base is None else np.asarray(T_world_base, dtype=np.float64)
        sensors = sensors or {}
        for s, (link, _) in sensors.items():
            if link not in self.link_names:
                raise InputError(
                    f"sensor '{s}' is mounted on an unknown link",
                    path=self.urdf_path,
                    field="hand.sensors.link",
                    expected=f"one of {self.link_names}",
                    got=link,
                )
        self.sensor_names: list[str] = list(sensors)
        self.sensor_links: dict[str, str] = {s: v[0] for s, v in sensors.items()}
        self.T_link_sensor: dict[str, np.ndarray] = {s: np.asarray(v[1], dtype=np.float64) for s, v in sensors.items()}
        self._mesh_cache: dict[str, list[tuple[np.ndarray, np.ndarray]]] | None = None

    # ------------------------------------------------------------------------------------
    @classmethod
    def from_scene(cls, scene) -> HandKinematics:
        """Build from a :class:`~vtrack.scene.schema.Scene` (uses ``scene.hand``)."""
        if scene.hand is None:
            raise InputError("the scene has no hand", path=getattr(scene, "source", None), field="hand")
        h = scene.hand
        sensors = {m.sensor: (m.link, m.T_link_sensor.as_matrix()) for m in h.sensors}
        return cls(h.urdf, h.T_world_base.as_matrix(), sensors, h.joint_names)

    @property
    def n_joints(self) -> int:
        return len(self.joint_names)

    def _as_q(self, q) -> tuple[np.ndarray, bool]:
        q = np.asarray(q, dtype=np.float64)
        single = q.ndim == 1
        q2 = q[None] if single else q
        if q2.ndim != 2 or q2.shape[1] != self.n_joints:
            raise InputError("wrong joint vector shape", field="q", expected=f"(N, {self.n_joints})", got=q.shape)
        if not np.all(np.isfinite(q2)):
            raise InputError("joint vector has NaN/Inf", field="q")
        return q2, single

    def clip_to_limits(self, q: np.ndarray) -> np.ndarray:
        """``q`` clipped to the URDF joint limits (rad)."""
        return np.clip(q, self.lower, self.upper)

    def link_poses(self, q, links: list[str] | None = None) -> dict[str, np.ndarray]:
        """``T_world_link`` for joint vectors ``q`` ((J,) or (N, J), rad).

        Returns a dict link name -> (N, 4, 4) float64 (N = 1 for a single q), including the root.
        """
        q2, _ = self._as_q(q)
        n = q2.shape[0]
        want = None if links is None else set(links)
        if want is not None:
            unknown = want - set(self.link_names)
            if unknown:
                raise InputError(
                    "unknown link", field="links", expected=f"names in {self.link_names}", got=sorted(unknown)
                )
        T = {self.root_link: np.broadcast_to(self.T_world_base, (n, 4, 4)).copy()}
        for j in self._joints:
            Tp = T[j.parent] @ j.origin
            if j.type in ("revolute", "continuous"):
                M = np.zeros((n, 4, 4))
                M[:, :3, :3] = _axis_angle(j.axis, q2[:, j.index])
                M[:, 3, 3] = 1.0
                Tp = Tp @ M
            elif j.type == "prismatic":
                M = np.broadcast_to(np.eye(4), (n, 4, 4)).copy()
                M[:, :3, 3] = j.axis[None] * q2[:, j.index, None]
                Tp = Tp @ M
            elif j.type != "fixed":
                raise InputError(f"unsupported joint type '{j.type}'", path=self.urdf_path, field=j.name)
            T[j.child] = Tp
        if want is not None:
            return {k: v for k, v in T.items() if k in want}
        return T

    def chain_joints(self, link: str) -> list[int]:
        """Columns (in :attr:`joint_names`) of the movable joints between the root and ``link``."""
        parent_joint = {j.child: j for j in self._joints}
        if link not in self.link_names:
            raise InputError("unknown link", field="link", expected=f"one of {self.link_names}", got=link)
        cols = []
        while link in parent_joint:
            j = parent_joint[link]
            if j.index >= 0:
                cols.append(j.index)
            link = j.parent
        return cols[::-1]

    def jacobian(
        self, q, link: str, T_link_point: np.ndarray | None = None, poses: dict[str, np.ndarray] | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Geometric Jacobian of a frame rigidly attached to ``link``.

        Args:
            q: (N, J) or (J,) joint vectors, rad.
            link: link carrying the frame; ``T_link_point`` its (4, 4) offset (default identity).
            poses: optional precomputed :meth:`link_poses` of ``q`` (saves a FK pass).

        Returns:
            ``T_world_point`` (N, 4, 4) and ``J`` (N, 6, J): rows 0-2 linear velocity (m/rad) of the
            frame origin, rows 3-5 angular velocity (rad/rad), both in the world frame.
        """
        q2, _ = self._as_q(q)
        T = self.link_poses(q2) if poses is None else poses
        Tp = T[link] @ (np.eye(4) if T_link_point is None else np.asarray(T_link_point, dtype=np.float64))
        p = Tp[:, :3, 3]
        J = np.zeros((q2.shape[0], 6, self.n_joints))
        by_col = {j.index: j for j in self._joints if j.index >= 0}
        for c in self.chain_joints(link):
            j = by_col[c]
            Tc = T[j.child]  # joint motion keeps the child origin on the axis; axis fixed in child frame
            w = Tc[:, :3, :3] @ j.axis
            if j.type == "prismatic":
                J[:, :3, c] = w
            else:
                J[:, :3, c] = np.cross(w, p - Tc[:, :3, 3])
                J[:, 3:, c] = w
        return Tp, J

    def sensor_poses(self, q) -> dict[str, np.ndarray]:
        """``T_world_sensor`` (N, 4, 4) per tactile sensor for joint vectors ``q`` (rad)."""
        T = self.link_poses(q, links=list(set(self.sensor_links.values())))
        return {s: T[self.sensor_links[s]] @ self.T_link_sensor[s] for s in self.sensor_names}

    def sensor_poses_at(self, joints_stream, times) -> dict[str, np.ndarray]:
        """``T_world_sensor`` (N, 4, 4) at ``times`` (s), with q linearly interpolated in time.

        Args:
            joints_stream: the session's ``joints`` :class:`~vtrack.io.session.StreamReader`; its
                ``joint_names`` attribute may order columns differently (matched by name).
            times: (N,) query times, s (clamped to the stream's time range).
        """
        q = joints_stream.sample("q", np.atleast_1d(np.asarray(times, dtype=np.float64)), mode="linear")
        return self.sensor_poses(self.reorder(q, joints_stream.attrs.get("joint_names")))

    def reorder(self, q: np.ndarray, names: list[str] | None) -> np.ndarray:
        """Columns of ``q`` (ordered as ``names``) rearranged into :attr:`joint_names` order."""
        if names is None or list(names) == self.joint_names:
            return np.asarray(q, dtype=np.float64)
        missing = set(self.joint_names) - set(names)
        if missing:
            raise InputError(
                "joint stream lacks joints of the hand",
                field="joints.joint_names",
                expected=self.joint_names,
                got=list(names),
            )
        idx = [list(names).index(n) for n in self.joint_names]
        return np.asarray(q, dtype=np.float64)[..., idx]

    # ------------------------------------------------------------------------------------
    def link_meshes(self) -> dict[str, list[tuple[np.ndarray, np.ndarray]]]:
        """Visual meshes per link in the link frame (loaded once, trimesh)."""
        if self._mesh_cache is not None:
            return self._mesh_cache
        import trimesh

        from vtrack.io.mesh import load_trimesh

        out: dict[str, list[tuple[np.ndarray, np.ndarray]]] = {}
        base = self.urdf_path.parent
        for link in self._model.robot.links:
            for vis in link.visuals:
                g = vis.geometry
                if g is None:
                    continue
                if g.mesh is not None:
                    fn = Path(g.mesh.filename.replace("package://", ""))
                    fn = fn if fn.is_absolute() else base / fn
                    m = load_trimesh(fn, process=True, field=f"{link.name} visual mesh")
                    if g.mesh.scale is not None:
                        m.apply_scale(np.asarray(g.mesh.scale, dtype=np.float64))
                elif g.box is not None:
                    m = trimesh.creation.box(extents=g.box.size)
                elif g.cylinder is not None:
                    m = trimesh.creation.cylinder(radius=g.cylinder.radius, height=g.cylinder.length)
                elif g.sphere is not None:
                    m = trimesh.creation.icosphere(radius=g.sphere.radius)
                else:
                    continue
                if vis.origin is not None:
                    m.apply_transform(np.asarray(vis.origin, dtype=np.float64))
                out.setdefault(link.name, []).append(
                    (np.asarray(m.vertices, np.float64), np.asarray(m.faces, np.int32))
                )
        self._mesh_cache = out
        return out

    def hand_meshes(self, q) -> list[tuple[np.ndarray, np.ndarray]]:
        """World-frame ``(vertices (V, 3) m, faces (F, 3) int32)`` of every visual mesh for ONE q."""
        q2, _ = self._as_q(q)
        if q2.shape[0] != 1:
            raise InputError(
                "hand_meshes takes one joint vector", field="q", expected=f"({self.n_joints},)", got=np.shape(q)
            )
        T = self.link_poses(q2)
        out = []
        for link, meshes in self.link_meshes().items():
            Tl = T[link][0]
            for v, f in meshes:
                out.append((v @ Tl[:3, :3].T + Tl[:3, 3], f))
        return out

    def hand_mesh_links(self) -> list[str]:
        """Link name of each entry returned by :meth:`hand_meshes` (same order)."""
        return [link for link, meshes in self.link_meshes().items() for _ in meshes]


_HAND_MESH_CACHE: dict[str, list] = {}


def decimated_link_meshes(hk: HandKinematics, max_faces: int = 2500) -> dict[str, list[tuple[np.ndarray, np.ndarray]]]:
    """Link-frame visual meshes of a hand, decimated to ``max_faces`` per part for per-frame rendering (the
    simulator's ray casting, the segmenter's hand splatting); cached in memory and in ``cache_dir()`` per URDF."""
    import hashlib

    from vtrack.paths import cache_dir

    key = str(hk.urdf_path)
    if key in _HAND_MESH_CACHE:
        return _HAND_MESH_CACHE[key]
    digest = hashlib.sha1(hk.urdf_path.read_bytes() + str(max_faces).encode()).hexdigest()[:12]
    disk = cache_dir() / "hand_meshes" / f"{hk.urdf_path.stem}-{digest}.npz"
    out: dict[str, list] = {}
    if disk.exists():
        z = np.load(disk)
        for k in sorted(z.files, key=lambda x: int(x.split("|")[1])):
            link, i, part = k.split("|")
            if part == "v":
                out.setdefault(link, []).append((z[k], z[f"{link}|{i}|f"]))
        _HAND_MESH_CACHE[key] = out
        return out
    import open3d as o3d

    for link, meshes in hk.link_meshes().items():
        for v, f in meshes:
            if len(f) > max_faces:
                m = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(v), o3d.utility.Vector3iVector(f))
                m = m.simplify_quadric_decimation(max_faces)
                v, f = np.asarray(m.vertices), np.asarray(m.triangles, dtype=np.int32)
            out.setdefault(link, []).append((v, f))
    disk.parent.mkdir(parents=True, exist_ok=True)
    arrays, i = {}, 0
    for link, meshes in out.items():
        for v, f in meshes:
            arrays[f"{link}|{i}|v"], arrays[f"{link}|{i}|f"] = v, f
            i += 1
    tmp = disk.with_name(disk.stem + ".tmp.npz")
    np.savez(tmp, **arrays)
    tmp.replace(disk)
    _HAND_MESH_CACHE[key] = out
    return out
