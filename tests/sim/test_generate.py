"""Synthetic sessions: format, geometry of the ground truth, determinism, occlusion, CLI."""

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
def exact_session(scene, tmp_path_factory):
    """0.2 s without any sensor noise (depth/tactile/joints), for the geometric checks."""
    from vtrack.sim.generate import generate_session

    sc = scene.model_copy(deep=True)
    sc.sim = sc.sim.model_copy(update={"depth_noise": 0.0, "tactile_noise": 0.0, "joint_noise": 0.0})
    return generate_session(sc, tmp_path_factory.mktemp("sim") / "exact", seconds=0.2, seed=3)


def _mesh_distance(vertices, faces, points):
    import open3d as o3d

    rs = o3d.t.geometry.RaycastingScene()
    m = o3d.t.geometry.TriangleMesh()
    m.vertex.positions = o3d.core.Tensor(np.asarray(vertices, np.float32))
    m.triangle.indices = o3d.core.Tensor(np.asarray(faces, np.int32))
    rs.add_triangles(m)
    return rs.compute_distance(o3d.core.Tensor(np.asarray(points, np.float32))).numpy()


def test_tiny_session_is_valid(tiny_session):
    from vtrack.io.session import open_session
    from vtrack.kinematics.hand import HandKinematics

    r = open_session(tiny_session)
    assert r.complete
    sc = r.scene(check_files=True)  # embedded scene resolves the sensors' calibrations in assets/
    assert sc.object.mesh is None and sc.object.T_world_object is None  # what a user would know: neither
    assert all(t.calibration == tiny_session / "assets" / "calibration" / f"{t.name}.npz" for t in sc.tactile)
    hk = HandKinematics.from_scene(sc)
    assert r["joints"].attrs["joint_names"] == hk.joint_names
    assert len(r["joints"]) == 60 and len(r["gt/object_pose"]) == 60
    for s in hk.sensor_names:
        assert len(r[f"tactile/{s}"]) == 60 and len(r[f"gt/tactile/{s}"]) == 60
        assert r[f"tactile/{s}"]["image"].shape == (60, 320, 240, 3)
    cam = r["camera/cam0"]
    assert len(cam) == 30 and cam["depth"].dtype == np.uint16
    vis = r["gt/camera/cam0"]["visible_fraction"][:]
    assert np.all((vis >= 0) & (vis <= 1)) and vis.mean() > 0.7  # occlusion "none"
    # Fingers move smoothly (first-contact branch switches are smoothed; a posture that would
    # press too deep is kept exact instead, so rare jumps remain): <= 5 % of steps over 0.05 rad.
    step = np.abs(np.diff(r["joints"]["q"][:], axis=0)).max(1)
    assert np.mean(step > 0.05) <= 0.05 and np.median(step) < 0.02
    # The object mesh is stored centred (bounding-box centre at the object-frame origin).
    import trimesh

    m = trimesh.load(r.path / "gt" / "object.ply")
    assert np.abs(m.bounds.mean(0)).max() < 1e-6
    assert m.is_watertight


def test_rendered_depth_lies_on_object_and_hand(exact_session):
    from vtrack.geometry.camera import PinholeCamera
    from vtrack.geometry.se3 import transform_points
    from vtrack.io.session import open_session
    from vtrack.kinematics.hand import HandKinematics
    from vtrack.sim.objects import load_object_mesh

    r = open_session(exact_session)
    cam = r["camera/cam0"]
    K = np.asarray(cam.attrs["K"])
    pc = PinholeCamera(cam.attrs["width"], cam.attrs["height"], K[0, 0], K[1, 1], K[0, 2], K[1, 2])
    T_wc = np.asarray(cam.attrs["T_world_camera"])
    obj = load_object_mesh(r.path / "gt" / "object.ply")
    hk = HandKinematics.from_scene(r.scene())
    i = 3
    t = cam.t[i]
    pts, rc = pc.unproject(cam["depth"][i], depth_scale=cam.attrs["depth_scale"])
    pw = transform_points(T_wc, pts)
    on_obj = r["gt/camera/cam0"]["mask"][i][rc[:, 0], rc[:, 1]] > 0
    assert on_obj.sum() > 500 and (~on_obj).sum() > 500
    T_wo = r["gt/object_pose"].sample("T_world_object", [t], mode="linear")[0]
    d_obj = _mesh_distance(obj.vertices, obj.faces, transform_points(np.linalg.inv(T_wo), pw[on_obj]))
    q = hk.reorder(r["joints"].sample("q", [t], mode="linear")[0], r["joints"].attrs["joint_names"])
    meshes = hk.hand_meshes(q)
    v = np.concatenate([m[0] for m in meshes])
    f = np.concatenate(
        [m[1] + off for m, off in zip(meshes, np.cumsum([0] + [len(m[0]) for m in meshes[:-1]]), strict=True)]
    )
    d_hand = _mesh_distance(v, f, pw[~on_obj])
    assert np.median(d_obj) < 1e-3
    assert np.median(d_hand) < 1e-3  # hand rendered from decimated meshes: small extra error
    assert np.percentile(d_obj, 95) < 2e-3


def test_tactile_contacts_lie_on_object_surface(exact_session):
    from vtrack.geometry.se3 import transform_points
    from vtrack.geometry.tactile_frame import height_to_points
    from vtrack.io.session import open_session
    from vtrack.kinematics.hand import HandKinematics
    from vtrack.sim.objects import load_object_mesh

    r = open_session(exact_session)
    hk = HandKinematics.from_scene(r.scene())
    obj = load_object_mesh(r.path / "gt" / "object.ply")
    n_pts = 0
    for s in hk.sensor_names:
        gt = r[f"gt/tactile/{s}"]
        mpp = gt.attrs["mm_per_px"]
        T_ws = hk.sensor_poses_at(r["joints"], gt.t)[s]
        T_wo = r["gt/object_pose"].sample("T_world_object", gt.t, mode="linear")
        for i in range(0, len(gt), 3):
            h, c = gt["height_mm"][i], gt["contact"][i] > 0
            if not c.any():
                continue
            p, _ = height_to_points(h, mpp, mask=c, stride=2)
            p_o = transform_points(np.linalg.inv(T_wo[i]) @ T_ws[i], p)
            d = _mesh_distance(obj.vertices, obj.faces, p_o)
            n_pts += len(d)
            assert np.percentile(d, 99) < 0.5e-3, (s, i, float(d.max()))
    assert n_pts > 1000


def test_penetration_within_configured_range(tiny_session):
    import json

    from vtrack.io.session import open_session

    r = open_session(tiny_session)
    lo, hi = r.scene().sim.penetration_mm
    info = json.loads((tiny_session / "manifest.json").read_text())["created"]
    n_ctrl = 0
    for s, flags in info["contact_controlled"].items():
        hmax = r[f"gt/tactile/{s}"]["height_mm"][:].reshape(len(flags), -1).max(1)
        ctrl = np.asarray(flags, bool)
        n_ctrl += ctrl.sum()
        # While a finger holds the object its max indentation is in the configured range
        # (0.05 mm tolerance: bisection on a 0.5 mm grid vs the full-resolution height map).
        assert np.all((hmax[ctrl] >= lo - 0.05) & (hmax[ctrl] <= hi + 0.05)), (s, hmax[ctrl].min(), hmax[ctrl].max())
        # Re-grasps may touch lighter, but never deeper than the range.
        assert hmax.max() <= hi + 0.05
        assert info["touching_fraction"][s] >= 0.4
    # Every sensor touches most of the time.
    assert n_ctrl > 0.7 * 4 * 60
    assert np.mean(list(info["touching_fraction"].values())) > 0.8


def test_same_seed_same_session(scene, tmp_path):
    from vtrack.io.session import open_session
    from vtrack.sim.generate import generate_session

    a = open_session(generate_session(scene, tmp_path / "a", seconds=0.1, seed=7))
    b = open_session(generate_session(scene, tmp_path / "b", seconds=0.1, seed=7))
    c = open_session(generate_session(scene, tmp_path / "c", seconds=0.1, seed=8))
    for name, field in [
        ("camera/cam0", "depth"),
        ("camera/cam0", "rgb"),
        ("tactile/digit_thumb", "image"),
        ("joints", "q"),
        ("gt/tactile/digit_middle", "height_mm"),
    ]:
        np.testing.assert_array_equal(a[name][field][:], b[name][field][:])
    assert not np.array_equal(a["camera/cam0"]["depth"][:], c["camera/cam0"]["depth"][:])


def test_occlusion_levels_order(scene, tmp_path):
    from vtrack.io.session import open_session
    from vtrack.sim.generate import generate_session

    vis = {}
    for occ in ("none", "medium", "heavy"):
        r = open_session(generate_session(scene, tmp_path / occ, seconds=0.1, occlusion=occ))
        vis[occ] = float(r["gt/camera/cam0"]["visible_fraction"][:].mean())
        assert r.scene().sim.occlusion == occ
    assert vis["none"] > 0.7
    assert vis["none"] > vis["medium"] > vis["heavy"]
    assert vis["heavy"] < 0.3


def test_bad_inputs(scene, tmp_path):
    from vtrack.sim.generate import generate_session

    with pytest.raises(InputError):
        generate_session(scene, tmp_path / "x", seconds=0.1, occlusion="total")
    with pytest.raises(InputError):
        generate_session(scene, tmp_path / "x", seconds=-1)
    with pytest.raises(InputError):
        generate_session(scene, tmp_path / "x", seconds=0.1, object_mesh=tmp_path / "missing.ply")
    (tmp_path / "exists").mkdir()
    with pytest.raises(InputError):
        generate_session(scene, tmp_path / "exists", seconds=0.1)
    no_hand = scene.model_copy(deep=True)
    no_hand.hand = None
    with pytest.raises(InputError):
        generate_session(no_hand, tmp_path / "y", seconds=0.1)


def test_cli_generate(scene, tmp_path):
    from typer.testing import CliRunner
    from vtrack_apps.cli import app

    from vtrack.io.session import open_session
    from vtrack.paths import default_scene_path

    out = tmp_path / "cli"
    res = CliRunner().invoke(
        app,
        [
            "generate",
            str(default_scene_path()),
            "--out",
            str(out),
            "--seconds",
            "0.1",
            "--seed",
            "2",
            "--occlusion",
            "medium",
            "--quiet",
        ],
    )
    assert res.exit_code == 0, res.output
    r = open_session(out)
    assert r.scene().sim.seed == 2 and len(r["camera/cam0"]) == 3
    res = CliRunner().invoke(app, ["generate", str(default_scene_path()), "--out", str(out), "--seconds", "0.1"])
    # Exists without --force: an InputError (the console entry point prints it as one line, exit 2).
    assert isinstance(res.exception, InputError)


def test_lipschitz_envelope():
    from vtrack.sim.grasp import lipschitz_envelope

    s = np.array([0.5, 0.5, 0.2, 0.2, 0.5, 0.5, 0.9, 0.9])
    e = lipschitz_envelope(s, 0.1)
    np.testing.assert_allclose(e, [0.4, 0.3, 0.2, 0.2, 0.3, 0.4, 0.5, 0.6])
    assert np.all(e <= s) and np.abs(np.diff(e)).max() <= 0.1 + 1e-12


def test_inside_out_mesh_is_loaded_with_outward_winding(tmp_path) -> None:
    """The gel ray caster reads back-face hits as a buried gel, so the loader must fix inverted meshes."""
    import trimesh

    from vtrack.sim.objects import load_object_mesh

    box = trimesh.creation.box((0.04, 0.05, 0.06))
    box.invert()
    assert box.volume < 0
    box.export(tmp_path / "inside_out.ply")
    m = load_object_mesh(tmp_path / "inside_out.ply")
    assert trimesh.Trimesh(m.vertices, m.faces, process=False).volume > 0
