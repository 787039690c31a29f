"""Forward kinematics of the shipped Allegro+DIGIT URDF against yourdfpy, sensor frames, interpolation."""

from __future__ import annotations

import numpy as np
import pytest

from vtrack.errors import InputError


@pytest.fixture(scope="module")
def scene(shared_data):
    from vtrack.paths import default_scene_path
    from vtrack.scene import load_scene

    return load_scene(default_scene_path())


@pytest.fixture(scope="module")
def hk(scene):
    from vtrack.kinematics.hand import HandKinematics

    return HandKinematics.from_scene(scene)


def test_joint_order_is_index_middle_ring_thumb(hk):
    assert hk.joint_names == [f"joint_{i}.0" for i in range(16)]
    assert hk.sensor_names == ["digit_index", "digit_middle", "digit_ring", "digit_thumb"]


def test_fk_matches_yourdfpy(hk, scene):
    import yourdfpy

    u = yourdfpy.URDF.load(str(scene.hand.urdf), load_meshes=False)
    rng = np.random.default_rng(0)
    lo, hi = np.maximum(hk.lower, -3), np.minimum(hk.upper, 3)
    Q = rng.uniform(lo - 0.3, hi + 0.3, size=(12, hk.n_joints))
    T = hk.link_poses(Q)
    Twb = scene.hand.T_world_base.as_matrix()
    worst = 0.0
    for i, q in enumerate(Q):
        u.update_cfg(dict(zip(hk.joint_names, q, strict=True)))
        for link in hk.link_names:
            ref = Twb @ u.get_transform(link, u.base_link)
            worst = max(worst, float(np.abs(T[link][i] - ref).max()))
    assert worst < 1e-9


def test_single_and_batched_agree(hk):
    q = np.linspace(0.1, 0.5, hk.n_joints)
    a = hk.link_poses(q)["link_3.0_tip"]
    b = hk.link_poses(np.stack([q, q]))["link_3.0_tip"]
    assert a.shape == (1, 4, 4) and b.shape == (2, 4, 4)
    np.testing.assert_allclose(a[0], b[1], atol=1e-15)


def test_sensor_frame_at_gel_centre_facing_palm(hk):
    # README: at q = 0 the index gel centre is (0.022, -0.0556, 0.1364) m and faces +x.
    T = hk.sensor_poses(np.zeros(hk.n_joints))["digit_index"][0]
    Twb = hk.T_world_base
    p_base = np.linalg.inv(Twb) @ T[:, 3]
    np.testing.assert_allclose(p_base[:3], [0.022, -0.0556, 0.1364], atol=2e-4)
    z_base = np.linalg.inv(Twb)[:3, :3] @ T[:3, 2]
    assert z_base[0] > 0.99
    assert abs(np.linalg.det(T[:3, :3]) - 1.0) < 1e-12


def test_sensor_poses_at_interpolates(hk, tmp_path):
    from vtrack.io.session import SessionWriter, open_session
    from vtrack.io.streams import joints_stream

    q0, q1 = np.zeros(hk.n_joints), np.full(hk.n_joints, 0.4)
    # Stored in a different column order: must be matched by name.
    names = list(reversed(hk.joint_names))
    with SessionWriter(tmp_path / "s") as w:
        w.add_stream("joints", joints_stream(names, 60.0))
        w.append("joints", 0.0, q=q0[::-1])
        w.append("joints", 1.0, q=q1[::-1])
    js = open_session(tmp_path / "s")["joints"]
    got = hk.sensor_poses_at(js, [0.5])["digit_middle"][0]
    want = hk.sensor_poses(0.5 * (q0 + q1))["digit_middle"][0]
    np.testing.assert_allclose(got, want, atol=1e-12)


def test_hand_meshes_follow_fk(hk):
    q = np.full(hk.n_joints, 0.3)
    meshes = hk.hand_meshes(q)
    links = hk.hand_mesh_links()
    assert len(meshes) == len(links) >= 17
    tip = hk.link_poses(q)["link_3.0_tip"][0]
    v, f = meshes[links.index("link_3.0_tip")]
    local = (v - tip[:3, 3]) @ tip[:3, :3]
    # DIGIT mesh bounds in the tip frame (README): x in [-0.0122, 0.0201], z in [0.0005, 0.0346].
    assert local[:, 0].min() == pytest.approx(-0.0122, abs=5e-4)
    assert local[:, 2].max() == pytest.approx(0.0346, abs=5e-4)
    assert f.dtype == np.int32 and f.max() < len(v)


def test_bad_inputs(hk):
    with pytest.raises(InputError):
        hk.link_poses(np.zeros(3))
    with pytest.raises(InputError):
        hk.link_poses(np.full(hk.n_joints, np.nan))
    with pytest.raises(InputError):
        hk.link_poses(np.zeros(hk.n_joints), links=["nope"])
