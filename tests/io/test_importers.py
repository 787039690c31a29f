"""Importers on fixtures written in each tool's exact on-disk layout."""

from __future__ import annotations

import pickle
import time

import numpy as np
import pytest

from vtrack.errors import InputError
from vtrack.io.session import open_session
from vtrack.testing.recordings import tactile_image, write_feelsight, write_mcap, write_ros1_bag, write_ros2_bag


def test_feelsight_import_round_trip(tmp_path):
    from vtrack.io.importers.feelsight import import_feelsight

    src = write_feelsight(tmp_path / "obj" / "00", n=12)
    rep = import_feelsight(src, tmp_path / "s")
    s = open_session(tmp_path / "s")
    assert s.complete
    assert rep.frames["camera/front-left"] == 12 and rep.frames["joints"] == 12
    assert {f"tactile/digit_{f}" for f in ("index", "middle", "ring", "thumb")} <= set(s.streams)
    cam = s["camera/front-left"]
    np.testing.assert_allclose(cam.t, np.arange(12) / 30.0 + 100.0)
    d = cam["depth"][3]
    assert d[1, 1] == 503 and d[0, 0] == 0  # 0.503 m -> 503 mm; NaN -> 0
    assert abs(int(cam["rgb"][0][0, 0, 0]) - 200) <= 3 and int(cam["rgb"][0][0, 0, 2]) <= 3  # RGB order kept
    assert cam["mask"][0].sum() == 12 * 16
    np.testing.assert_allclose(cam.attrs["K"], [[50, 0, 32], [0, 50, 24], [0, 0, 1]])
    np.testing.assert_allclose(np.asarray(cam.attrs["T_world_camera"])[:3, 3], [0.4, 0.1, 0.2])
    np.testing.assert_allclose(s["joints"]["q"][5], np.linspace(0, 1.5, 16) + 0.05)
    np.testing.assert_allclose(s["gt/object_pose"]["T_world_object"][7][0, 3], 0.007)
    img = s["tactile/digit_index"]["image"][4]
    assert np.abs(img.astype(int) - tactile_image(4, 40, 30)).mean() < 4  # JPEG round trip
    assert s["gt/tactile_raw/digit_index"]["contact"][0].sum() == 100
    sc = s.scene()
    assert sc.hand is not None and len(sc.hand.sensors) == 4 and sc.tactile[0].type == "digit"
    assert (tmp_path / "s" / "assets" / "scene.yaml").exists()
    assert s.manifest["created"]["sensor_info"]["cam_dist"] == 0.022


def test_feelsight_real_layout_without_sim_ground_truth(tmp_path):
    from vtrack.io.importers.feelsight import import_feelsight

    src = write_feelsight(tmp_path / "real", n=5, sim=False)
    rep = import_feelsight(src, tmp_path / "s", hand_urdf=None, max_frames=3)
    s = open_session(tmp_path / "s")
    assert "mask" not in s["camera/front-left"].fields
    assert not any(k.startswith("gt/tactile_raw") for k in s.streams)
    assert rep.frames["tactile/digit_thumb"] == 3 and s.scene().hand is None


def test_feelsight_errors_name_the_file(tmp_path):
    from vtrack.io.importers.feelsight import import_feelsight

    src = write_feelsight(tmp_path / "log", n=6)
    bad = src / "allegro" / "ring" / "image" / "3.jpg"
    bad.write_bytes(bad.read_bytes()[:40])  # truncated JPEG
    with pytest.raises(InputError, match="3.jpg"):
        import_feelsight(src, tmp_path / "s1")
    src2 = write_feelsight(tmp_path / "log2", n=6)
    (src2 / "data.pkl").write_bytes((src2 / "data.pkl").read_bytes()[:100])  # truncated pickle
    with pytest.raises(InputError, match="data.pkl"):
        import_feelsight(src2, tmp_path / "s2")
    src3 = write_feelsight(tmp_path / "log3", n=6)
    (src3 / "realsense" / "front-left" / "depth.npz").write_text("not a zip")  # mislabelled
    with pytest.raises(InputError, match="depth.npz"):
        import_feelsight(src3, tmp_path / "s3")
    src4 = write_feelsight(tmp_path / "log4", n=6)
    data = pickle.loads((src4 / "data.pkl").read_bytes())
    data["allegro"]["joint_state"] = np.zeros((6, 15))
    (src4 / "data.pkl").write_bytes(pickle.dumps(data))
    with pytest.raises(InputError, match="joint_state"):
        import_feelsight(src4, tmp_path / "s4")


def test_feelsight_1000_frames_under_20_s(tmp_path):
    from vtrack.io.importers.feelsight import import_feelsight

    # Real-robot layout (no simulation ground truth): 1 RGB-D camera + 4 DIGIT, 5000 JPEGs.
    src = write_feelsight(tmp_path / "big", n=1000, cam_hw=(48, 64), tac_hw=(40, 30), sim=False)
    t0 = time.perf_counter()
    rep = import_feelsight(src, tmp_path / "s")
    dt = time.perf_counter() - t0
    assert rep.frames["camera/front-left"] == 1000 and rep.frames["tactile/digit_thumb"] == 1000
    assert dt < 20.0, f"1000-frame import took {dt:.1f} s"


def _check_ros_session(path, n):
    s = open_session(path)
    cam = s["camera/camera"]
    assert cam.n == n
    np.testing.assert_allclose(cam.attrs["K"], [[40, 0, 16], [0, 40, 12], [0, 0, 1]])
    np.testing.assert_allclose(np.asarray(cam.attrs["T_world_camera"])[:3, 3], [0.5, 0, 0.3])
    assert [int(cam["rgb"][i][0, 0, 0]) for i in range(n)] == list(range(n))
    assert [int(cam["depth"][i][0, 0]) for i in range(n)] == [500 + i for i in range(n)]
    tac = s["tactile/digit_index"]
    assert tac.n == 2 * n
    np.testing.assert_array_equal(tac["image"][5], tactile_image(5))  # BGR kept exactly
    np.testing.assert_allclose(s["joints"]["q"][4], 0.04)
    assert s["joints"].attrs["joint_names"][0] == "joint_0.0"
    np.testing.assert_allclose(s["gt/object_pose"]["T_world_object"][2][0, 3], 0.002)
    assert np.all(np.diff(tac.t) > 0)
    return s


@pytest.mark.parametrize("kind", ["ros1", "ros2_sqlite3", "ros2_mcap"])
def test_rosbag_import(tmp_path, kind):
    from vtrack.io.importers.rosbag import import_rosbag

    if kind == "ros1":
        src = write_ros1_bag(tmp_path / "in.bag", n=8)
    else:
        src = write_ros2_bag(tmp_path / "in_bag", n=8, storage=kind.split("_")[1])
    rep = import_rosbag(src, tmp_path / "s")
    _check_ros_session(tmp_path / "s", 8)
    assert rep.skipped["topic /chatter (std_msgs/msg/String): not imported"] == 16


def test_mcap_import_with_compressed_tactile(tmp_path):
    from vtrack.io.importers.mcap_import import import_mcap

    src = write_mcap(tmp_path / "in.mcap", n=8, compressed_tactile=True)
    rep = import_mcap(src, tmp_path / "s")
    _check_ros_session(tmp_path / "s", 8)
    assert rep.skipped["topic /notes: unsupported encoding 'jsonschema'"] == 1


def test_topic_map_and_pairing_tolerance(tmp_path):
    from vtrack.io.importers.rosbag import import_rosbag

    src = write_ros2_bag(tmp_path / "in_bag", n=6)
    rep = import_rosbag(
        src,
        tmp_path / "s",
        pair_tolerance_s=0.001,
        topic_map={"/digit_index/image_raw": "tactile/left_pad", "/joint_states": "ignore"},
    )
    s = open_session(tmp_path / "s")
    assert "tactile/left_pad" in s and "joints" not in s
    assert "camera/camera" not in s  # depth is 2 ms after colour: nothing pairs within 1 ms
    assert rep.skipped["camera/camera: colour frame without depth within 1 ms"] == 6


def test_ros_errors_name_the_file(tmp_path):
    from vtrack.io.importers.mcap_import import import_mcap
    from vtrack.io.importers.rosbag import import_rosbag

    bag = write_ros1_bag(tmp_path / "a.bag", n=6)
    cut = tmp_path / "cut.bag"
    cut.write_bytes(bag.read_bytes()[: bag.stat().st_size // 2])
    with pytest.raises(InputError, match="cut.bag"):
        import_rosbag(cut, tmp_path / "s1")
    mc = write_mcap(tmp_path / "a.mcap", n=6)
    cutm = tmp_path / "cut.mcap"
    cutm.write_bytes(mc.read_bytes()[: mc.stat().st_size // 2])
    with pytest.raises(InputError, match="cut.mcap"):
        import_mcap(cutm, tmp_path / "s2")
    fake = tmp_path / "really_mcap.bag"
    fake.write_bytes(mc.read_bytes())
    with pytest.raises(InputError, match="really_mcap.bag.*MCAP"):
        import_rosbag(fake, tmp_path / "s3")
    with pytest.raises(InputError, match="a.bag.*ROS 1 bag"):
        import_mcap(bag, tmp_path / "s4")
    (tmp_path / "empty.mcap").write_bytes(b"")
    with pytest.raises(InputError, match="empty.mcap"):
        import_mcap(tmp_path / "empty.mcap", tmp_path / "s5")
