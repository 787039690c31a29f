"""PLY/GLB export."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from vtrack.errors import InputError
from vtrack.io.export import export_mesh, export_points_glb, read_ply_points, write_ply_points


def test_ply_round_trip_with_scalars(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    P = rng.normal(size=(100, 3))
    N = rng.normal(size=(100, 3))
    mod = rng.integers(0, 2, 100)
    conf = rng.random(100)
    write_ply_points(
        tmp_path / "c.ply", P, normals=N, colors=rng.random((100, 3)), scalars={"modality": mod, "confidence": conf}
    )
    d = read_ply_points(tmp_path / "c.ply")
    assert np.allclose(d["x"], P[:, 0], atol=1e-6) and np.array_equal(d["modality"], mod)
    assert np.allclose(d["confidence"], conf, atol=1e-6)
    # Open3D reads the same file.
    import open3d as o3d

    pc = o3d.io.read_point_cloud(str(tmp_path / "c.ply"))
    assert len(pc.points) == 100 and pc.has_normals()
    with pytest.raises(InputError, match="modality"):
        write_ply_points(tmp_path / "d.ply", P, scalars={"modality": mod[:5]})


def test_mesh_and_glb_export(tmp_path: Path) -> None:
    import trimesh

    box = trimesh.creation.box((0.1, 0.2, 0.3))
    for suffix in (".ply", ".glb"):
        p = export_mesh(tmp_path / f"m{suffix}", box.vertices, box.faces)
        back = trimesh.load(p, force="mesh")
        assert np.allclose(back.extents, [0.1, 0.2, 0.3])
    export_points_glb(tmp_path / "p.glb", np.random.default_rng(0).normal(size=(50, 3)))
    assert (tmp_path / "p.glb").stat().st_size > 50 * 12
    with pytest.raises(InputError, match="unsupported mesh format"):
        export_mesh(tmp_path / "m.xyz", box.vertices, box.faces)
