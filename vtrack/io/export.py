"""Export clouds and meshes: PLY (binary, with any per-point scalar fields) and GLB (via trimesh)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from vtrack.errors import InputError
from vtrack.geometry.pointcloud import as_points


def write_ply_points(
    path: str | Path,
    points: np.ndarray,
    *,
    colors: np.ndarray | None = None,
    normals: np.ndarray | None = None,
    scalars: dict[str, np.ndarray] | None = None,
) -> Path:
    """Write a binary little-endian PLY point cloud.

    Args:
        points: (N, 3) metres.
        colors: optional (N, 3) uint8 RGB (or floats in [0, 1]).
        normals: optional (N, 3).
        scalars: optional extra per-point fields (e.g. ``modality``, ``confidence``), written as int32
            (integer/bool), double (float64) or float (other floats) properties that Open3D/MeshLab/
            CloudCompare keep.
    """
    P = as_points(points)
    n = len(P)
    cols: list[tuple[str, str, np.ndarray]] = [("x", "f4", P[:, 0]), ("y", "f4", P[:, 1]), ("z", "f4", P[:, 2])]
    if normals is not None:
        N = np.asarray(normals, dtype=np.float32).reshape(n, 3)
        cols += [("nx", "f4", N[:, 0]), ("ny", "f4", N[:, 1]), ("nz", "f4", N[:, 2])]
    if colors is not None:
        C = np.asarray(colors)
        if C.dtype.kind == "f":
            C = np.clip(C * 255.0 + 0.5, 0, 255)
        C = C.astype(np.uint8).reshape(n, 3)
        cols += [("red", "u1", C[:, 0]), ("green", "u1", C[:, 1]), ("blue", "u1", C[:, 2])]
    for name, v in (scalars or {}).items():
        v = np.asarray(v).reshape(-1)
        if len(v) != n:
            raise InputError(
                "scalar field length differs from the number of points", field=name, expected=str(n), got=len(v)
            )
        # float64 stays double: e.g. epoch timestamps need it (float32 steps are 128 s apart there).
        kind = "i4" if v.dtype.kind in "uib" else ("f8" if v.dtype == np.float64 else "f4")
        cols.append((name, kind, v))
    dtype = np.dtype([(c, "<" + t) for c, t, _ in cols])
    arr = np.empty(n, dtype=dtype)
    for c, _, v in cols:
        arr[c] = v
    ply_type = {"f4": "float", "f8": "double", "u1": "uchar", "i4": "int"}
    header = ["ply", "format binary_little_endian 1.0", "comment vtrack point cloud (metres)", f"element vertex {n}"]
    header += [f"property {ply_type[t]} {c}" for c, t, _ in cols]
    header.append("end_header")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "wb") as f:
        f.write(("\n".join(header) + "\n").encode("ascii"))
        f.write(arr.tobytes())
    return path


def read_ply_points(path: str | Path) -> dict[str, np.ndarray]:
    """Read a binary PLY written by :func:`write_ply_points` back into a dict of arrays."""
    path = Path(path)
    if not path.exists():
        raise InputError("file does not exist", path=path)
    raw = path.read_bytes()
    end = raw.find(b"end_header\n")
    if not raw.startswith(b"ply") or end < 0:
        raise InputError("not a PLY file", path=path)
    header = raw[:end].decode("ascii", "replace").splitlines()
    if "format binary_little_endian 1.0" not in header:
        raise InputError("only binary little-endian PLY is supported here", path=path)
    n = 0
    props: list[tuple[str, str]] = []
    rev = {"float": "<f4", "uchar": "u1", "int": "<i4", "double": "<f8"}
    for line in header:
        parts = line.split()
        if parts[:2] == ["element", "vertex"]:
            n = int(parts[2])
        elif parts and parts[0] == "property":
            props.append((parts[2], rev[parts[1]]))
    data = np.frombuffer(raw[end + len(b"end_header\n") :], dtype=np.dtype(props), count=n)
    return {name: np.array(data[name]) for name, _ in props}


def export_mesh(
    path: str | Path, vertices: np.ndarray, faces: np.ndarray, vertex_colors: np.ndarray | None = None
) -> Path:
    """Write a triangle mesh; format from the suffix (.ply, .glb, .obj, .stl)."""
    import trimesh

    path = Path(path)
    if path.suffix.lower() not in {".ply", ".glb", ".obj", ".stl"}:
        raise InputError("unsupported mesh format", path=path, expected=".ply, .glb, .obj or .stl")
    mesh = trimesh.Trimesh(np.asarray(vertices), np.asarray(faces), vertex_colors=vertex_colors, process=False)
    path.parent.mkdir(parents=True, exist_ok=True)
    mesh.export(path)
    return path


def export_points_glb(path: str | Path, points: np.ndarray, colors: np.ndarray | None = None) -> Path:
    """Write a point cloud as GLB (glTF POINTS primitive) for web viewers."""
    import trimesh

    P = as_points(points)
    pc = trimesh.PointCloud(P, colors=colors)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    trimesh.Scene(pc).export(path, file_type="glb")
    return path
