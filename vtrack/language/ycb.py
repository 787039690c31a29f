"""YCB surface patches for the material library: contacts of the shared YCB meshes pressed into the gel.

A contact picks an area-weighted random point of the mesh surface, fits a quadric to the mesh vertices within
``FIT_RADIUS_MM`` of it (local frame: the face normal and two tangents) and takes the fitted surface normal
and principal curvatures there. The sensor is placed with its gel facing the surface (sensor +z = -normal),
turned by a random angle about the normal, optionally shifted in its plane (an off-centre contact), and pushed
``depth`` mm into the object; the gel indentation is then ray cast per pixel by the simulator's
:func:`vtrack.sim.grasp.gel_heights` and rendered by the independent optical model like every other material.

The descriptions' tactile attributes come from that geometry (the simulator's truth, never from the image):
the contact's curvature class (flat / curved / sharply curved, from the largest principal curvature) and the
object's dominant class over a fixed sample of its surface. All YCB objects are rigid, so they are "hard" and
their scans carry no texture at the gel's 0.25 mm scale, so they are "smooth". Their true colour, shape and
name are the non-tactile distractor words (correlated with the object, as in the paper's data).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from vtrack.errors import InputError

#: file stem -> (name, true colour, true shape word); the objects of ``shared_data_dir()/objects/ycb``
YCB_OBJECTS: dict[str, tuple[str, str, str]] = {
    "005_tomato_soup_can": ("soup can", "red", "cylindrical"),
    "006_mustard_bottle": ("mustard bottle", "yellow", "oval"),
    "010_potted_meat_can": ("meat can", "blue", "rectangular"),
    "011_banana": ("banana", "yellow", "elongated"),
    "025_mug": ("mug", "red", "cylindrical"),
    "055_baseball": ("baseball", "white", "round"),
}
#: quadric fit neighbourhood (mm) and curvature-radius bounds of the classes (mm)
FIT_RADIUS_MM = 6.0
FLAT_RADIUS_MM = 80.0
SHARP_RADIUS_MM = 15.0
CURVATURE_WORDS = ("flat", "curved", "sharply curved")
#: how far below the gel surface the rays start (mm): deep enough that a ray rarely starts inside the object
CAST_DEPTH_MM = 10.0


def ycb_dir() -> Path:
    from vtrack.paths import shared_data_dir

    return shared_data_dir() / "objects" / "ycb"


@dataclass
class _Mesh:
    vertices_mm: np.ndarray  # (V, 3) object frame, mm
    faces: np.ndarray
    tree: object  # scipy cKDTree over vertices_mm
    raycaster: object  # vtrack.geometry.raycast.Raycaster in metres
    trimesh: object


@lru_cache(maxsize=8)
def _mesh(stem: str) -> _Mesh:
    import trimesh
    from scipy.spatial import cKDTree

    from vtrack.geometry.raycast import Raycaster
    from vtrack.sim.objects import load_object_mesh

    path = ycb_dir() / f"{stem}.ply"
    if not path.exists():
        raise InputError(
            "YCB mesh for the language material library not found",
            path=path,
            expected="the shared data folder (vtrack.paths.shared_data_dir()) with objects/ycb/*.ply",
        )
    m = load_object_mesh(path)
    v_mm = m.vertices * 1000.0
    return _Mesh(v_mm, m.faces, cKDTree(v_mm), Raycaster([(m.vertices, m.faces)]), trimesh.Trimesh(v_mm, m.faces))


def local_surface(stem: str, point_mm: np.ndarray, normal: np.ndarray) -> tuple[np.ndarray, float, np.ndarray]:
    """Quadric fit at a surface point: (unit outward normal, curvature radius mm (of the largest principal
    curvature; inf when flat), (3, 3) frame rows [t1, t2, n])."""
    msh = _mesh(stem)
    n = normal / max(1e-12, float(np.linalg.norm(normal)))
    t1 = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0])
    t1 /= np.linalg.norm(t1)
    t2 = np.cross(n, t1)
    idx = msh.tree.query_ball_point(point_mm, FIT_RADIUS_MM)
    q = msh.vertices_mm[idx] - point_mm
    x, y, z = q @ t1, q @ t2, q @ n
    keep = z > -FIT_RADIUS_MM  # the near sheet only (not the far side of a thin part)
    x, y, z = x[keep], y[keep], z[keep]
    if len(x) < 6:
        return n, float("inf"), np.stack([t1, t2, n])
    A = np.stack([x * x, x * y, y * y, x, y, np.ones_like(x)], 1)
    c, *_ = np.linalg.lstsq(A, z, rcond=None)
    H = np.array([[2 * c[0], c[1]], [c[1], 2 * c[2]]])
    kmax = float(np.abs(np.linalg.eigvalsh(H)).max())
    n_fit = n - c[3] * t1 - c[4] * t2  # gradient of the fitted height at the point
    n_fit /= np.linalg.norm(n_fit)
    t1 = np.cross(n_fit, t2)
    t1 /= np.linalg.norm(t1)
    t2 = np.cross(n_fit, t1)
    return n_fit, (1.0 / kmax if kmax > 1e-9 else float("inf")), np.stack([t1, t2, n_fit])


def curvature_word(radius_mm: float) -> str:
    if radius_mm >= FLAT_RADIUS_MM:
        return "flat"
    return "curved" if radius_mm >= SHARP_RADIUS_MM else "sharply curved"


def sample_surface(stem: str, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """One area-weighted random surface point (mm) and its face normal."""
    tm = _mesh(stem).trimesh
    f = int(rng.choice(len(tm.faces), p=tm.area_faces / tm.area))
    a, b = rng.random(2)
    if a + b > 1:
        a, b = 1 - a, 1 - b
    tri = tm.vertices[tm.faces[f]]
    p = tri[0] + a * (tri[1] - tri[0]) + b * (tri[2] - tri[0])
    return np.asarray(p), np.asarray(tm.face_normals[f])


@lru_cache(maxsize=8)
def dominant_curvature(stem: str, n: int = 200) -> str:
    """The object's most frequent contact curvature class over ``n`` fixed random surface points."""
    rng = np.random.default_rng(4242)
    words = []
    for _ in range(n):
        p, nrm = sample_surface(stem, rng)
        words.append(curvature_word(local_surface(stem, p, nrm)[1]))
    vals, counts = np.unique(words, return_counts=True)
    return str(vals[int(np.argmax(counts))])


def sensor_pose(
    stem: str, rng: np.random.Generator, depth_mm: float, angle_deg: float, offset_px: tuple[float, float], mm_per_px
):
    """(T_object_sensor (4, 4) in metres, curvature radius mm) of one press of object ``stem``."""
    p, nrm = sample_surface(stem, rng)
    n, radius, frame = local_surface(stem, p, nrm)
    a = np.deg2rad(angle_deg)
    x = np.cos(a) * frame[0] + np.sin(a) * frame[1]
    z = -n  # the gel faces the surface; rays go along +z into the object
    y = np.cross(z, x)
    off = (offset_px[0] * x + offset_px[1] * y) * mm_per_px
    # the contact point shows at +offset in the image: the sensor origin sits at -offset from it, depth mm deep
    origin = p - depth_mm * n - off
    T = np.eye(4)
    T[:3, 0], T[:3, 1], T[:3, 2] = x, y, z
    T[:3, 3] = origin / 1000.0
    return T, radius


def press_height(
    stem: str, T_object_sensor: np.ndarray, width: int, height: int, mm_per_px: float, depth_mm: float
) -> np.ndarray:
    """Gel indentation (mm, (height, width) float32) of one press, ray cast by the simulator.

    The press depth is the deepest indentation, as for the procedural materials: where the surface rises
    toward the gel away from the chosen spot (a concave part, a neighbouring rim), the sensor stops there."""
    from vtrack.sim.grasp import gel_heights

    h = gel_heights(_mesh(stem).raycaster, T_object_sensor[None], width, height, mm_per_px, CAST_DEPTH_MM)[0]
    h = np.asarray(h, np.float32)
    return np.clip(h - (float(h.max()) - depth_mm), 0.0, None).astype(np.float32)
