"""The viser viewer in-process (no browser): timeline, cloud bins, GUI controls, play/pause."""

from __future__ import annotations

import time

import numpy as np
import pytest


@pytest.fixture(scope="module")
def viewer(view_fixture):
    from vtrack.viz.data import ViewData
    from vtrack.viz.viewer import Viewer

    logs: list[str] = []
    v = Viewer(ViewData(view_fixture["demo"]), port=0, log=logs.append)
    v.logs = logs
    yield v
    v.stop()


def _shown(v) -> int:
    return sum(s for s, h in zip(v.bins.shown, v.bins.handles, strict=True) if h.visible)


def test_opens_at_last_frame_with_whole_cloud(viewer):
    d = viewer.data
    assert int(viewer.slider.value) == d.n_frames - 1
    assert _shown(viewer) == len(d.cloud) == 6000
    assert viewer.port > 0 and viewer.url.startswith("http://127.0.0.1:")
    assert any("showing frame 12/12" in m for m in viewer.logs)


def test_scrubbing_shows_cloud_prefix_and_moves_object(viewer):
    d = viewer.data
    for i in (0, 5, 3, 11, 7):
        viewer.slider.value = i
        assert viewer.wait_idle(20)
        assert _shown(viewer) == d.cloud.count_until(d.times[i])
        T = d.object_pose(d.frame(i, with_images=False), "estimate")
        assert np.allclose(viewer.obj_node.position, T[:3, 3], atol=1e-6)
    # Bins hold contiguous, time-ordered slices: a partially shown bin re-sends only its prefix.
    viewer.slider.value = 5
    viewer.wait_idle(20)
    n5 = d.cloud.count_until(d.times[5])
    k = int(np.searchsorted(viewer.bins.edges, n5, side="right")) - 1
    assert viewer.bins.shown[k] == n5 - viewer.bins.edges[k] or n5 == viewer.bins.edges[k]
    assert all(not h.visible for h in viewer.bins.handles[k + 1 :])


def test_gui_controls(viewer):
    d = viewer.data
    viewer.accumulate.value = False
    viewer.slider.value = 0
    viewer.wait_idle(20)
    assert _shown(viewer) == len(d.cloud)
    viewer.color_dd.value = "time"
    assert viewer.bins.mode == "time"
    c0 = viewer.bins.handles[0].colors
    assert c0.shape == (viewer.bins.shown[0], 3) and c0.dtype == np.uint8
    viewer.pose_dd.value = "gt"
    viewer.wait_idle(20)
    assert np.allclose(viewer.obj_node.position, d.frame(0, with_images=False).T_world_object_gt[:3, 3])
    viewer.cb["camera images"].value = False
    assert viewer.cam_frusta["cam0"].image is None
    viewer.cb["camera images"].value = True
    viewer.slider.value = 1
    viewer.wait_idle(20)
    assert viewer.cam_frusta["cam0"].image.shape == (48, 64, 3)
    viewer.cb["hand"].value = False
    assert all(not h.visible for h in viewer.hand_nodes.values())
    viewer.cb["hand"].value = True
    viewer.accumulate.value = True
    viewer.pose_dd.value = "estimate"
    viewer.color_dd.value = "modality"


def test_play_pause_and_step(viewer):
    viewer.slider.value = 0
    viewer.wait_idle(20)
    viewer.fps.value = 30
    before = len(viewer.frame_ms)
    viewer._toggle_play()
    assert viewer.play_btn.label == "Pause"
    time.sleep(1.5)
    viewer._toggle_play()
    assert viewer.play_btn.label == "Play"
    viewer.wait_idle(20)
    # Playback stepped through frames (under heavy machine load it may not reach 30 fps).
    assert len(viewer.frame_ms) - before >= 5
    viewer._step("|<")
    assert int(viewer.slider.value) == 0
    viewer._step("<")
    assert int(viewer.slider.value) == 0  # clamped
    viewer._step(">|")
    assert int(viewer.slider.value) == viewer.data.n_frames - 1
    viewer.wait_idle(20)
    assert all(np.isfinite(viewer.frame_ms))
