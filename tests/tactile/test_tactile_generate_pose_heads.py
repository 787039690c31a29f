"""Issue #24: the position-equivariant pose heads of the downstream pose study (``softargmax``, ``heatmap``), the
weighted position loss, the weighted-moment baseline and the error breakdown of :mod:`vtrack.bench.generate`."""

from __future__ import annotations

import numpy as np
import pytest


def test_soft_argmax_recovers_a_known_peak_and_the_centre_of_a_flat_map():
    import torch

    from vtrack.bench.generate import soft_argmax

    H, W = 30, 40
    logits = torch.zeros(3, H, W)
    logits[0, 7, 31] = 50.0  # a sharp peak at cell (x 31, y 7)
    logits[1, 20, 4] = 50.0
    # two equal peaks: the expectation lies halfway between them
    logits[2, 10, 10] = 50.0
    logits[2, 10, 20] = 50.0
    xy, p = soft_argmax(logits)
    assert p.shape == (3, H, W) and torch.allclose(p.sum((1, 2)), torch.ones(3))
    px = ((xy[:, 0] + 1) / 2 * W - 0.5).numpy()  # back to cell indices
    py = ((xy[:, 1] + 1) / 2 * H - 0.5).numpy()
    np.testing.assert_allclose(px, [31.0, 4.0, 15.0], atol=1e-3)
    np.testing.assert_allclose(py, [7.0, 20.0, 10.0], atol=1e-3)
    flat, _ = soft_argmax(torch.zeros(1, H, W))
    np.testing.assert_allclose(flat.numpy(), [[0.0, 0.0]], atol=1e-6)


@pytest.mark.parametrize("head", ["softargmax", "heatmap", "moments"])
def test_position_heads_output_shapes_and_translate_with_the_contact(head):
    """(B, 4) with an angle, (B, 2) position-only; finite; x, y inside [-1, 1]; and the predicted position moves
    with the input contact even untrained (the map is convolutional), i.e. the head is position-equivariant."""
    import torch

    from vtrack.bench.generate import POSE_HEADS

    torch.manual_seed(0)
    x = torch.zeros(2, 5, 60, 80)
    x[0, :3, 25:35, 10:20] = 3.0  # the same contact on the left and on the right
    x[1, :3, 25:35, 60:70] = 3.0
    for n_out in (4, 2):
        net = POSE_HEADS[head](n_out).eval()
        with torch.inference_mode():
            out = net(x)
        assert out.shape == (2, n_out) and torch.isfinite(out).all()
        assert (out[:, :2].abs() <= 1).all()
    # train the map briefly to peak on the contact: then the right contact must read right of the left one
    net = POSE_HEADS[head](4)
    opt = torch.optim.Adam(net.parameters(), lr=3e-3)
    tgt = torch.tensor([[-0.625, 0.0, 1.0, 0.0], [0.625, 0.0, 1.0, 0.0]])
    for _ in range(30):
        loss = ((net(x[:1]) - tgt[:1]) ** 2).mean()  # trained on the LEFT contact only
        opt.zero_grad()
        loss.backward()
        opt.step()
    with torch.inference_mode():
        out = net.eval()(x)
    assert out[1, 0] - out[0, 0] > 0.5  # the unseen right contact is placed far to the right


def test_weighted_position_loss_training_reduces_the_loss():
    """A few Adam steps of :func:`_train_pose_cnn` with the heatmap head and a weighted position loss lower the
    training loss on a tiny set (the step runs, gradients reach the map)."""
    import torch

    from vtrack.bench.generate import _train_pose_cnn

    torch.set_num_threads(1)
    rng = np.random.default_rng(1)
    H, W = 60, 80
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float32)
    X = np.zeros((8, 5, H, W), np.float32)
    T = np.zeros((8, 4), np.float32)
    for k in range(8):
        cx, cy = rng.uniform(15, W - 15), rng.uniform(12, H - 12)
        X[k, :3] = 2.0 * np.exp(-((xx - cx) ** 2 + (yy - cy) ** 2) / 20.0)
        T[k] = [(cx + 0.5) / W * 2 - 1, (cy + 0.5) / H * 2 - 1, 1.0, 0.0]

    def loss(net) -> float:
        with torch.inference_mode():
            se = (net.eval()(torch.from_numpy(X)) - torch.from_numpy(T)) ** 2
        return float((50.0 * se[:, :2].sum(1) + se[:, 2:].sum(1)).mean())

    torch.manual_seed(0)
    from vtrack.bench.generate import POSE_HEADS

    before = loss(POSE_HEADS["heatmap"]())
    net, done = _train_pose_cnn(X, T, 0.0, seed=0, steps=25, head="heatmap", pos_weight=50.0)
    assert done == 25
    after = loss(net)
    assert np.isfinite(after) and after < 0.5 * before


def test_weighted_moments_baseline_finds_a_rendered_cross_pose():
    """The 4-fold weighted-moment baseline recovers a simulated cross's centre within 5 px and its angle (mod
    90 deg) within 2 deg (a cross's second moments are isotropic: the binary-mask PCA has no angle for it)."""
    from vtrack.bench.generate import weighted_moments_pose
    from vtrack.sim.tactile_optics import OpticalModel
    from vtrack.tactile.generate import data as gd
    from vtrack.tactile.sensors import default_background

    W, H, mpp = 320, 240, 0.059
    bg = default_background("gelsight", W, H)
    model = OpticalModel.for_sensor("gelsight", seed=4242)
    for x, y, th in ((100.0, 90.0, 20.0), (230.0, 150.0, 70.0)):
        img = model.render(gd.indenter_height("cross", (H, W), gd.Pose(x, y, th), 0.8, mpp), mpp, bg)
        px, py, pth = weighted_moments_pose(img, bg, sym=4)
        assert abs(px - x) < 5 and abs(py - y) < 5  # mean over 150 test presses: 2.1 / 1.6 px
        assert abs((pth - th + 45) % 90 - 45) < 2.0
    with pytest.raises(ValueError):
        weighted_moments_pose(bg.copy(), bg, sym=4)  # no contact


@pytest.mark.parametrize("theta", [0.0, 17.0, 40.0, 71.0])
def test_moments_angle_reads_the_orientation_of_a_cross_shaped_map(theta):
    """The ``moments`` head's angle is the 4-fold moment of its weight map about the soft-argmax centre: a map
    lit along a cross at ``theta`` (deg, image axes, y down) gives (cos 4 theta, sin 4 theta) within 3 deg,
    wherever the cross sits (the weight-map layers are bypassed to feed the map directly)."""
    import torch

    from vtrack.bench.generate import POSE_HEADS

    net = POSE_HEADS["moments"](4)
    net.wmap = torch.nn.Identity()
    H, W = 30, 40
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float32)
    for cx, cy in ((12.0, 10.0), (27.0, 19.0)):
        t = np.radians(theta)
        u = (xx - cx) * np.cos(t) + (yy - cy) * np.sin(t)
        v = -(xx - cx) * np.sin(t) + (yy - cy) * np.cos(t)
        arms = ((np.abs(v) < 0.8) | (np.abs(u) < 0.8)) & (np.hypot(u, v) < 6)
        logits = torch.from_numpy(np.where(arms, 10.0, -10.0).astype(np.float32))[None, None]
        p = torch.zeros(1, H, W)
        p[0, int(cy), int(cx)] = 1.0  # the soft-argmax centre on the cross
        with torch.no_grad():
            cs = net._moment_angle(logits, p)[0].numpy()
        got = np.degrees(np.arctan2(cs[1], cs[0])) / 4
        assert abs((got - theta + 45) % 90 - 45) < 3.0
        assert 0.3 < np.hypot(*cs) <= 1.0 + 1e-6  # a normalised moment


def test_pose_errors_split_the_x_error_into_bias_tail_and_range_ends():
    from vtrack.bench.generate import _pose_errors

    W, H = 320, 240
    poses = np.array([[100.0, 120.0, 10.0], [160.0, 120.0, 10.0], [250.0, 120.0, 10.0], [60.0, 120.0, 10.0]])
    x = poses[:, 0] + np.array([2.0, 2.0, -10.0, 6.0])  # px errors; 250 and 60 lie at the ends (|x-160| > 80)
    a = np.radians(poses[:, 2] * 4)
    pred = np.stack([x / W * 2 - 1, poses[:, 1] / H * 2 - 1, np.cos(a), np.sin(a)], 1)
    e = _pose_errors(pred, poses, W, H, 4)
    assert e["x_err_px"] == pytest.approx(5.0) and e["x_bias_px"] == pytest.approx(0.0)
    assert e["x_err_edge_px"] == pytest.approx(8.0) and e["x_err_centre_px"] == pytest.approx(2.0)
    assert e["y_err_px"] == pytest.approx(0.0, abs=1e-9) and e["angle_err_deg"] == pytest.approx(0.0, abs=1e-6)
    assert e["x_err_p90_px"] == pytest.approx(np.percentile([2, 2, 10, 6], 90))


def test_pose_study_refuses_an_unknown_generated_label_source():
    import pytest

    from vtrack.bench.generate import pose_study

    with pytest.raises(ValueError, match="gen_labels"):
        pose_study(quick=True, gen_labels="oracle")
