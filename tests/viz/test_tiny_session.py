"""The viewer on the simulator's cached tiny session of the default scene (Allegro + 4 DIGIT + cam0)."""

from __future__ import annotations

import numpy as np


def test_tiny_session_view_and_screenshot(tiny_session, tmp_path):
    from vtrack.viz.data import ViewData
    from vtrack.viz.screenshot import render_scene
    from vtrack.viz.viewer import Viewer

    d = ViewData(tiny_session)
    assert d.hand is not None, d.notes
    assert len(d.tactile) == 4 and [c.name for c in d.cameras] == ["cam0"]
    assert d.gt_T is not None and d.gt_mesh is not None
    st = d.frame(d.n_frames // 2)
    assert set(st.sensor_poses) == set(d.tactile)
    # Fingertip sensors sit around the grasped object: within 15 cm of its centre.
    c = st.T_world_object_gt[:3, 3]
    dist = [float(np.linalg.norm(T[:3, 3] - c)) for T in st.sensor_poses.values()]
    assert max(dist) < 0.15, dist
    for name, strip in st.panels.items():
        assert strip.ndim == 3 and strip.shape[2] == 3 and strip.shape[1] > strip.shape[0], name
    v = Viewer(d, port=0, log=lambda m: None)
    try:
        ms = [v.update_frame(i) for i in range(0, d.n_frames, max(1, d.n_frames // 10))]
        assert np.isfinite(ms).all()
        v.update_frame(st.index)
        for link, node in v.hand_nodes.items():
            assert np.allclose(node.position, st.link_poses[link][:3, 3], atol=1e-6), link
        for s, node in v.sensor_nodes.items():
            assert np.allclose(node.position, st.sensor_poses[s][:3, 3], atol=1e-6), s
    finally:
        v.stop()
    img = render_scene(d, size=(320, 240))
    assert img.shape[0] == 240 and img.shape[1] > 320  # tactile panel column
    assert (np.abs(img[:, :320].astype(np.int32) - 255).max(-1) > 30).mean() > 0.02
