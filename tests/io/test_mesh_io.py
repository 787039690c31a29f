"""The one mesh reader (vtrack.io.mesh): every bad file gets a one-line InputError naming it."""

from __future__ import annotations

import numpy as np
import pytest

from vtrack.errors import InputError
from vtrack.io.export import export_mesh
from vtrack.io.mesh import load_mesh, load_trimesh

TET_V = np.array([[0, 0, 0], [0.01, 0, 0], [0, 0.01, 0], [0, 0, 0.01]], float)
TET_F = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])


def test_round_trip_keeps_vertices_order_and_scale(tmp_path):
    p = export_mesh(tmp_path / "t.ply", TET_V, TET_F)
    V, F = load_mesh(p)
    assert V.dtype == np.float64 and F.dtype == np.int64
    assert np.allclose(V, TET_V) and np.array_equal(F, TET_F)
    V_mm, _ = load_mesh(p, scale=1000.0)
    assert np.allclose(V_mm, TET_V * 1000.0)
    assert load_trimesh(p, process=True).is_watertight


def test_missing_corrupt_empty_and_nonfinite_meshes_are_refused(tmp_path):
    with pytest.raises(InputError, match="does not exist") as e:
        load_mesh(tmp_path / "nope.ply", field="object.mesh")
    assert "object.mesh" in str(e.value) and "nope.ply" in str(e.value)
    junk = tmp_path / "junk.ply"
    junk.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 99\n\x00\x01")
    with pytest.raises(InputError, match="cannot read mesh|no triangles|not a triangle mesh"):
        load_mesh(junk)
    empty = tmp_path / "empty.obj"
    empty.write_text("# nothing\n")
    with pytest.raises(InputError, match="no triangles|not a triangle mesh|cannot read"):
        load_mesh(empty)
    bad = tmp_path / "nan.obj"
    bad.write_text("v 0 0 0\nv 1 0 0\nv nan 1 0\nf 1 2 3\n")
    with pytest.raises(InputError, match="non-finite"):
        load_mesh(bad)


def test_allow_empty_returns_empty_arrays(tmp_path):
    pts = tmp_path / "points.obj"
    pts.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\n")  # vertices only: a valid file without triangles
    try:
        V, F = load_mesh(pts, allow_empty=True)
    except InputError as e:  # trimesh may read a face-less OBJ as a point cloud: still a clear refusal
        assert "not a triangle mesh" in str(e)
    else:
        assert V.shape == (0, 3) and F.shape == (0, 3)
