"""Hard cases of the simulator and the hand kinematics: nothing diverges, returns NaN or crashes."""

from __future__ import annotations

import numpy as np
import pytest

from vtrack.errors import InputError

pytestmark = pytest.mark.stability


@pytest.fixture(scope="module")
def scene(shared_data):
    from vtrack.paths import default_scene_path
    from vtrack.scene import load_scene

    return load_scene(default_scene_path())


@pytest.fixture(scope="module")
def hk(scene):
    from vtrack.kinematics.hand import HandKinematics

    return HandKinematics.from_scene(scene)


def _write_mesh(path, mesh):
    mesh.export(str(path))
    return path


def _finite_session(path):
    from vtrack.io.session import open_session

    r = open_session(path)
    assert r.complete
    for name, st in r.streams.items():
        for f, arr in st.fields.items():
            a = arr[:]
            if a.dtype.kind == "f":
                assert np.all(np.isfinite(a)), (name, f)
    return r


def test_object_too_small_to_grasp(scene, tmp_path):
    """A 1 cm ball: fingers may close without touching; heights stay 0, nothing NaN."""
    import trimesh

    from vtrack.sim.generate import generate_session

    mesh = _write_mesh(tmp_path / "ball.ply", trimesh.creation.icosphere(radius=0.005))
    r = _finite_session(generate_session(scene, tmp_path / "s", seconds=0.1, object_mesh=mesh))
    assert r["gt/tactile/digit_middle"]["height_mm"][:].max() <= 3.0


def test_thin_flat_object(scene, tmp_path):
    import trimesh

    from vtrack.sim.generate import generate_session

    mesh = _write_mesh(tmp_path / "plate.ply", trimesh.creation.box(extents=(0.06, 0.09, 0.003)))
    r = _finite_session(generate_session(scene, tmp_path / "s", seconds=0.1, object_mesh=mesh))
    h = r["gt/tactile/digit_thumb"]["height_mm"][:]
    assert h.min() >= 0.0 and h.max() <= 3.0


def test_single_frame_session(scene, tmp_path):
    from vtrack.sim.generate import generate_session

    r = _finite_session(generate_session(scene, tmp_path / "s", seconds=1 / 60))
    assert len(r["joints"]) == 1 and len(r["camera/cam0"]) == 1


def test_mesh_in_millimetres_is_rejected(scene, tmp_path):
    import trimesh

    from vtrack.sim.generate import generate_session

    mesh = _write_mesh(tmp_path / "mm.ply", trimesh.creation.box(extents=(60.0, 90.0, 30.0)))
    with pytest.raises(InputError, match="implausible"):
        generate_session(scene, tmp_path / "s", seconds=0.1, object_mesh=mesh)


def test_not_a_mesh_is_rejected(scene, tmp_path):
    from vtrack.sim.generate import generate_session

    bad = tmp_path / "bad.ply"
    bad.write_text("this is not a mesh")
    with pytest.raises(InputError):
        generate_session(scene, tmp_path / "s", seconds=0.1, object_mesh=bad)


def test_fk_extreme_angles_stay_rigid(hk):
    q = np.full((3, hk.n_joints), 1e4)
    q[1] = -1e4
    for T in hk.link_poses(q).values():
        assert np.all(np.isfinite(T))
        R = T[:, :3, :3]
        np.testing.assert_allclose(R @ np.swapaxes(R, 1, 2), np.broadcast_to(np.eye(3), R.shape), atol=1e-9)


def test_ik_unreachable_targets_respect_limits(hk):
    from vtrack.kinematics.ik import solve_sensor_ik

    q0 = np.zeros(hk.n_joints)
    far = {s: np.array([[5.0, 5.0, 5.0], [0.0, 0.0, 0.0]]) for s in hk.sensor_names}
    nrm = {s: np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 1.0]]) for s in hk.sensor_names}  # zero normal: degenerate
    res = solve_sensor_ik(hk, q0, far, nrm, iterations=20)
    assert np.all(np.isfinite(res.q))
    assert np.all(res.q >= hk.lower - 1e-12) and np.all(res.q <= hk.upper + 1e-12)
    with pytest.raises(InputError):
        solve_sensor_ik(hk, q0, {hk.sensor_names[0]: np.full((1, 3), np.nan)})


def test_gel_far_from_object_is_flat():
    import trimesh

    from vtrack.geometry.raycast import Raycaster
    from vtrack.sim.grasp import gel_heights

    m = trimesh.creation.icosphere(radius=0.03)
    rc = Raycaster([(m.vertices, m.faces)])
    T = np.repeat(np.eye(4)[None], 2, 0)
    T[0, :3, 3] = [0.0, 0.0, -0.5]  # 0.5 m away, facing the ball
    T[1, :3, 3] = [0.0, 0.0, 0.5]  # facing away
    h = gel_heights(rc, T, 24, 32, 0.9, 3.0)
    assert h.shape == (2, 32, 24) and np.all(h == 0.0)
    # Pressed 1 mm into the ball: max indentation 1 mm at the centre.
    T1 = np.eye(4)[None].copy()
    T1[0, :3, 3] = [0.0, 0.0, -0.029]
    h1 = gel_heights(rc, T1, 24, 32, 0.5, 3.0)
    assert h1.max() == pytest.approx(1.0, abs=0.05)
