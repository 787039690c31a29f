"""Hand-pose simulator and networks (FusionTouch S24-S27, issue #26)."""

from __future__ import annotations

import numpy as np
import pytest

from vtrack.dome.handsim import DIGITS, GRASPS, HAND_DOME, JOINTS, RGB_SIZE, HandDomeSimulator, HandModel

torch = pytest.importorskip("torch")


@pytest.fixture(scope="module")
def sim() -> HandDomeSimulator:
    return HandDomeSimulator()


@pytest.fixture(scope="module")
def samples(sim) -> list[dict]:
    rng = np.random.default_rng(99)
    return [sim.sample(rng) for _ in range(12)]


def test_nominal_wrap_touches_the_shell_and_lifting_releases_it(sim) -> None:
    hand = HandModel()
    q = hand.nominal()
    assert q.shape == (12,) and np.all(np.isfinite(q))
    for d in DIGITS:
        ends = hand._chain(d, q, 0.0)[1:]
        if d.name != "thumb":  # the DIP joint follows the PIP joint: only the proximal end and the tip are set
            ends = [ends[0], ends[-1]]
        # every driven segment end sits 1 mm into the shell (capsule radius)
        np.testing.assert_allclose([np.linalg.norm(e) for e in ends], HAND_DOME.radius_mm + d.radius - 1.0, atol=1e-3)
    caps = hand.capsules(q)
    n_touch = len(sim.presses(caps, np.random.default_rng(0)))
    lifted = q.copy()
    for d in DIGITS:
        for j in d.joints:
            lifted[j] -= 25.0
    assert n_touch >= 10 and len(sim.presses(hand.capsules(lifted), np.random.default_rng(0))) == 0


def test_samples_shapes_grasps_and_what_each_camera_sees(sim, samples) -> None:
    ref = sim.ir_reference()
    S = HAND_DOME.image_size
    for s in samples:
        assert s["rgb"].shape == (RGB_SIZE, RGB_SIZE, 3) and s["rgb"].dtype == np.uint8
        assert s["ir"].shape == (S, S) and s["ir"].dtype == np.uint8
        assert s["angles_deg"].shape == (len(JOINTS),) and s["grasp"] in GRASPS
    # IR: contacts move pins -> local differences well above the sensor noise; more contacts, more change
    diff = [np.abs(s["ir"].astype(float) * ref.mean() / s["ir"].mean() - ref) for s in samples]
    big = np.array([(d > 60).sum() for d in diff])
    nc = np.array([s["n_contacts"] for s in samples])
    assert big.min() > 0 and np.corrcoef(big, nc)[0, 1] > 0.3
    # RGB: the hand (skin, red > blue) covers the palm over the apex (image centre), not the free rim side
    for s in samples:
        img = s["rgb"].astype(float)
        c = img[RGB_SIZE // 2 - 3 : RGB_SIZE // 2 + 3, RGB_SIZE // 2 - 3 : RGB_SIZE // 2 + 3]
        assert c[..., 0].mean() > c[..., 2].mean() + 10


def test_pose_loss_and_metrics_follow_s25_s27() -> None:
    from vtrack.dome.handpose import pose_loss, pose_metrics

    gt = np.zeros((2, 12))
    pred = gt.copy()
    pred[0, 0] = 3.0
    pred[1, :] = 0.5
    e = pred - gt
    want = np.abs(e).mean() + np.sqrt((e**2).mean())
    got = float(pose_loss(torch.tensor(pred), torch.tensor(gt)))
    assert got == pytest.approx(want, abs=1e-5)
    m = pose_metrics(pred, gt)
    assert m["acc1"] == pytest.approx(100 * 23 / 24) and m["acc5"] == 100.0
    assert m["mae_deg"] == pytest.approx(np.abs(e).mean()) and m["max_deg"] == 3.0


def test_shipped_models_recover_the_joint_angles(sim, samples) -> None:
    """The mixed-set nets (``handpose.pt``, kept for the mixed row) on mixed grasps."""
    from vtrack.dome.handpose import HandPosePredictor, load_models, pose_metrics, predict_deg, weights_path

    models, blob = load_models(weights_path("mixed"))
    assert set(models) == {"rgb", "ir", "dual"}
    data = {
        "rgb": np.stack([s["rgb"] for s in samples]),
        "ir": np.stack([s["ir"] for s in samples]),
        "ir_reference": sim.ir_reference(),
        "angles_deg": np.stack([s["angles_deg"] for s in samples]),
    }
    gt = data["angles_deg"]
    prior = pose_metrics(np.broadcast_to(models["dual"].mean.numpy(), gt.shape), gt)["mae_deg"]
    dual = pose_metrics(predict_deg(models["dual"], data), gt)
    assert dual["mae_deg"] < 0.25 * prior and dual["acc5"] > 90
    # the predictor (single frames, gates) agrees with the batched net
    pred = HandPosePredictor(weights_path("mixed"))
    r = pred.predict(samples[0]["rgb"], samples[0]["ir"])
    assert r.valid and r.modality == "dual"
    np.testing.assert_allclose(r.angles_deg, predict_deg(models["dual"], data)[0], atol=1e-3)


def test_predictor_refuses_garbage() -> None:
    from vtrack.dome.handpose import HandPosePredictor
    from vtrack.errors import InputError

    pred = HandPosePredictor()
    S = HAND_DOME.image_size
    noise = np.random.default_rng(0).integers(0, 256, (S, S), dtype=np.uint8)
    assert not pred.predict(ir=noise).valid
    assert not pred.predict(ir=np.zeros((S, S), np.uint8)).valid
    assert not pred.predict(rgb=np.zeros((RGB_SIZE, RGB_SIZE, 3), np.uint8)).valid
    with pytest.raises(InputError):
        pred.predict(ir=np.zeros((10, 10), np.uint8))
    with pytest.raises(InputError):
        pred.predict()


def test_rgb_gate_passes_dome_frames_and_refuses_garbage() -> None:
    """The RGB plausibility model stored with the shipped nets (principal subspace of the training frames):
    fresh simulated frames pass with margin; noise, a checkerboard, a colour gradient, an under-exposed frame and
    a dome frame turned by 90 deg are flagged invalid (before this gate only a blank frame was)."""
    from vtrack.dome.handpose import HandPosePredictor, rgb_gate_scores

    pred = HandPosePredictor()
    assert pred.rgb_gate is not None
    sim, rng = HandDomeSimulator(grasp_set="varied"), np.random.default_rng(2024)
    frames = np.stack([sim.sample(rng)["rgb"] for _ in range(6)])  # seeds unlike the training chunks' (0, 1, 2)
    spe, t2 = rgb_gate_scores(pred.rgb_gate, frames)
    assert spe.max() < 0.8 * float(pred.rgb_gate["spe_max"]) and t2.max() < float(pred.rgb_gate["t2_max"])
    for f in frames:
        r = pred.predict(rgb=f)
        assert r.valid, r.reason
    S = RGB_SIZE
    yy, xx = np.mgrid[:S, :S]
    garbage = {
        "noise": rng.integers(0, 256, (S, S, 3), dtype=np.uint8),
        "checkerboard": np.repeat((((yy // 8 + xx // 8) % 2) * 255).astype(np.uint8)[..., None], 3, 2),
        "gradient": np.stack([xx * 4, yy * 4, np.full_like(xx, 128)], -1).astype(np.uint8),
        "under-exposed": (frames[0] * 0.15).astype(np.uint8),
        "rotated": np.ascontiguousarray(np.rot90(frames[0])),
    }
    for name, g in garbage.items():
        r = pred.predict(rgb=g)
        assert not r.valid and "does not look like this sensor" in r.reason, name


def test_seed_ensemble_predicts_the_mean_of_its_members(tmp_path) -> None:
    """The shipped varied-set file is a seed ensemble: each setting averages the angles of its members."""
    import shutil

    from vtrack.dome.handpose import HandPoseEnsemble, add_ensemble_members, load_models, predict_deg, weights_path

    models, _ = load_models()
    sim = HandDomeSimulator(grasp_set="varied")
    s = sim.sample(np.random.default_rng(5))
    data = {"rgb": s["rgb"][None], "ir": s["ir"][None], "ir_reference": sim.ir_reference()}
    for m in ("rgb", "dual"):
        assert isinstance(models[m], HandPoseEnsemble) and len(models[m].nets) >= 2
        members = np.stack([predict_deg(n, data)[0] for n in models[m].nets])
        assert np.ptp(members, axis=0).max() > 0.05  # independently seeded nets disagree a little
        own = [j for j in range(len(JOINTS)) if j not in models[m].joints]  # joint specialists give the others
        np.testing.assert_allclose(predict_deg(models[m], data)[0][own], members.mean(0)[own], atol=1e-4)
    shutil.copy(weights_path(), tmp_path / "w.pt")
    with pytest.raises(ValueError, match="same recipe"):  # nets of another grasp set are no member
        add_ensemble_members(tmp_path / "w.pt", [weights_path("mixed")])


def test_handpose_cli_predict_and_refusal(tmp_path) -> None:
    """The default nets (varied set) on a varied grasp through the CLI; noise is refused."""
    import json

    import cv2
    from typer.testing import CliRunner
    from vtrack_apps.cli import app

    s = HandDomeSimulator(grasp_set="varied").sample(np.random.default_rng(11))
    cv2.imwrite(str(tmp_path / "rgb.png"), s["rgb"][..., ::-1])
    cv2.imwrite(str(tmp_path / "ir.png"), s["ir"])
    out = tmp_path / "q.json"
    args = ["dome", "handpose", "predict", "--rgb", str(tmp_path / "rgb.png"), "--ir", str(tmp_path / "ir.png")]
    r = CliRunner().invoke(app, [*args, "--json", str(out)])
    assert r.exit_code == 0, r.output
    q = json.loads(out.read_text())
    assert q["modality"] == "dual" and len(q["angles_deg"]) == 12
    got = np.array(list(q["angles_deg"].values()))
    from vtrack.dome.handpose import load_models, predict_deg

    dual = load_models()[0]["dual"]
    ref = HandDomeSimulator(grasp_set="varied").ir_reference()
    data = {"rgb": s["rgb"][None], "ir": s["ir"][None], "ir_reference": ref}
    np.testing.assert_allclose(got, predict_deg(dual, data)[0], atol=2e-3)  # the PNGs are lossless; rounding 1e-3
    err, prior = np.abs(got - s["angles_deg"]), np.abs(dual.mean.numpy() - s["angles_deg"])
    assert err.mean() < 0.5 * prior.mean()  # the images carry the pose (mean-pose guess: ~8 deg on this set)
    cv2.imwrite(str(tmp_path / "noise.png"), np.random.default_rng(1).integers(0, 256, (128, 128), dtype=np.uint8))
    r = CliRunner().invoke(app, ["dome", "handpose", "predict", "--ir", str(tmp_path / "noise.png")])
    # an InputError (the console entry point prints it as one line and exits 2), no angles printed
    from vtrack.errors import InputError

    assert isinstance(r.exception, InputError) and "markers" in str(r.exception) and "angles_deg" not in r.output
    cv2.imwrite(str(tmp_path / "noise_rgb.png"), np.random.default_rng(2).integers(0, 256, (64, 64, 3), np.uint8))
    r = CliRunner().invoke(app, ["dome", "handpose", "predict", "--rgb", str(tmp_path / "noise_rgb.png")])
    assert isinstance(r.exception, InputError) and "RGB frame" in str(r.exception) and "angles_deg" not in r.output


def test_marker_patch_encoder_reads_the_pins_at_their_rest_centres(sim) -> None:
    from vtrack.dome.handpose import MarkerPatchEncoder, ir_reference_centers, prep_ir

    ref = sim.ir_reference()
    c = ir_reference_centers(ref)
    assert 300 <= len(c) <= 331  # the pipeline's extractor on the no-contact frame (331 pins, rim ones may drop)
    enc = MarkerPatchEncoder(c, HAND_DOME.image_size, feat=16, half=3)
    x = torch.from_numpy(prep_ir(ref[None], ref))
    g = x.reshape(1, 2, -1)[:, :, enc.idx]  # (1, 2, M, 49): the patches the encoder reads
    # the centre pixel of every patch is a bright pin of the reference, and the difference channel is 0 there
    centre = g[0, 0, :, g.shape[-1] // 2]
    assert float(centre.mean()) > float(x[0, 0].mean()) + 0.2
    assert float(g[0, 1].abs().max()) < 1e-6
    assert enc(x).shape == (1, 16)


def test_fused_dual_net_starts_at_the_better_branch_per_joint(sim, samples) -> None:
    from vtrack.dome.handpose import HandPoseNet, HandPoseTrainConfig, fuse_dual, predict_deg, split_train_val

    torch.manual_seed(0)
    data = {
        "rgb": np.stack([s["rgb"] for s in samples]),
        "ir": np.stack([s["ir"] for s in samples]),
        "ir_reference": sim.ir_reference(),
        "angles_deg": np.stack([s["angles_deg"] for s in samples]),
    }
    gt = data["angles_deg"].astype(np.float64)
    mean, std = gt.mean(0), gt.std(0) + 1.0
    rgb = HandPoseNet("rgb", mean, std, feat=16, width=4).eval()
    ir = HandPoseNet("ir", mean, std, feat=16, width=4).eval()
    with torch.no_grad():  # make the IR branch the better one on the thumb joints, the RGB one elsewhere
        ir.heads["ir"][-1].bias[:4] = torch.as_tensor((gt[:, :4].mean(0) - mean[:4]) / std[:4], dtype=torch.float32)
    tc = HandPoseTrainConfig(fusion_steps=1, eval_every=1, batch=4, lr=1e-9)
    dual, summ = fuse_dual(rgb, ir, data, tc, log=lambda *_: None)
    _, val = split_train_val(len(gt), tc)
    sub = {k: (v[val] if k != "ir_reference" else v) for k, v in data.items()}
    e = {m: np.abs(predict_deg(n, sub) - gt[val]).mean(0) for m, n in (("rgb", rgb), ("ir", ir), ("dual", dual))}
    better = np.minimum(e["rgb"], e["ir"])
    # gate at sigmoid(+-4): within 2 % of the spread between the branches of the better one, joint by joint
    assert np.all(e["dual"] <= better + 0.02 * np.abs(e["rgb"] - e["ir"]) + 1e-3)
    assert set(summ["gate_start_rgb_joints"]) == {
        j for j, r, i in zip(JOINTS, e["rgb"], e["ir"], strict=True) if r <= i
    }


def test_unobservable_joints_and_information_bound(samples) -> None:
    from vtrack.dome.handpose import information_bound, unobservable_joints

    grasps = np.array(["power", "tripod", "pinch", "hook"])
    un = unobservable_joints(grasps)
    assert un.sum(1).tolist() == [0, 2, 3, 2]  # power: none; tripod: ring/little PIP; pinch: +middle; hook: thumb
    assert un[3, JOINTS.index("thumb_ip")] and not un[3, JOINTS.index("thumb_cmc")]
    q = np.stack([s["angles_deg"] for s in samples]).astype(np.float64)
    g = np.array([s["grasp"] for s in samples])
    mask = unobservable_joints(g)
    nominal = HandModel().nominal()
    # the lifted distal joints lie within +-10 deg of the prior centre (nominal - 25: +-5 variation, 20-30 lift)
    assert np.all(np.abs(q - (nominal - 25.0))[mask] <= 10.0 + 1e-4)
    b = information_bound(q, g)
    want = np.abs(q - (nominal - 25.0))[mask].sum() / q.size
    assert b["mae_deg"] == pytest.approx(want) and b["unobservable_joint_frac"] == pytest.approx(mask.mean())
    assert b["acc5"] >= 100 * (1 - mask.mean()) - 1e-9


def test_handpose_train_cli_refuses_bad_options(tmp_path) -> None:
    from typer.testing import CliRunner
    from vtrack_apps.cli import app

    from vtrack.errors import InputError

    base = ["dome", "handpose", "train", "--out", str(tmp_path / "w.pt")]
    bad = (
        (["--ir-encoder", "graph"], "--ir-encoder"),
        (["--modalities", "rgb,depth"], "--modalities"),
        (["--joint-weights", "thumb_tip=2"], "--joint-weights"),
        (["--joint-weights", "thumb_ip=-1"], "--joint-weights"),
        (["--joint-weights", "thumb_ip"], "--joint-weights"),
        (["--rgb-crop", "50,0,32,2"], "--rgb-crop"),
        (["--rgb-crop", "thumb"], "--rgb-crop"),
    )
    for extra, field in bad:
        r = CliRunner().invoke(app, [*base, *extra])
        assert isinstance(r.exception, InputError) and r.exception.field == field
    assert not (tmp_path / "w.pt").exists()


def test_contact_grasp_set_puts_every_fingertip_on_the_shell() -> None:
    """The faithful grasp set (FusionTouch's participants grasp and deform the dome): every digit's distal
    phalanx presses >= 0.5 mm into the shell, so every digit shows in the IR frame; the mixed set lifts digits."""
    from vtrack.dome.handsim import TIP_MIN_PRESS_MM, handpose_dataset_path

    hand = HandModel()
    rng = np.random.default_rng(3)
    for _ in range(40):
        q, yaw, grasp = hand.sample(rng, "contact")
        assert grasp == "power" and abs(yaw) <= 8.0
        assert np.all(np.abs(q - hand.nominal()) <= 5.0 + 1e-9)  # the touching digits' variation box
        assert min(hand.tip_press_mm(d, q) for d in DIGITS) >= TIP_MIN_PRESS_MM
    # the mixed set's power grasps leave about a third of the fingertips off the shell (measured 0.67 touch)
    tips = []
    for _ in range(200):
        q, _, grasp = hand.sample(rng, "mixed")
        if grasp == "power":
            tips += [hand.tip_press_mm(d, q) >= TIP_MIN_PRESS_MM for d in DIGITS]
    assert 0.4 < np.mean(tips) < 0.9
    sim = HandDomeSimulator(grasp_set="contact")
    s = sim.sample(np.random.default_rng(5))
    q = s["angles_deg"].astype(np.float64)
    assert s["n_contacts"] >= len(DIGITS) and min(sim.hand.tip_press_mm(d, q) for d in DIGITS) >= 0.49
    # the mixed set keeps its cache key (cached simulations stay valid); the contact set gets its own
    assert handpose_dataset_path(10, 1) != handpose_dataset_path(10, 1, "contact")
    assert "grasp_set" not in str(handpose_dataset_path(10, 1))
    with pytest.raises(ValueError, match="grasp set"):
        hand.sample(rng, "open")


def test_ik_puts_each_fingertip_on_its_target() -> None:
    """Inverse kinematics of every digit onto targets drawn on the sphere, across hand placements: the tip (end
    of the distal phalanx) lands on the target, and an unreachable target is refused."""
    from vtrack.dome.handsim import HandPlace

    hand = HandModel()
    rng = np.random.default_rng(4)
    solved = 0
    for _ in range(12):
        place = HandPlace(*rng.uniform(-10, 10, 3), rng.uniform(1, 8), tuple(rng.uniform(-5, 5, 4)))
        q = np.zeros(len(JOINTS))
        q[0] = rng.uniform(-20, 20)
        for d in DIGITS:
            target = hand.tip_target(d, rng.uniform(35, 55), rng.uniform(-2.5, 5.0), q, place)
            qq = hand.digit_ik(d, target, q, place, couple=rng.uniform(0.5, 1.5))
            if qq is None:
                continue
            solved += 1
            tip = hand._chain(d, qq, 0.0, place)[-1]
            assert np.linalg.norm(tip - target) < 1e-3
            others = [j for j in range(len(JOINTS)) if j not in d.joints]
            assert np.array_equal(qq[others], q[others])  # only this digit's flexions move
    assert solved >= 40  # of 60: most of these arcs are within reach (the rest break the MCP limit)
    far = hand.tip_target(DIGITS[1], 150.0, 0.0, np.zeros(len(JOINTS)), HandPlace())
    assert hand.digit_ik(DIGITS[1], far, np.zeros(len(JOINTS)), HandPlace()) is None


def test_varied_grasp_set_has_a_real_joint_spread_with_every_digit_at_the_shell() -> None:
    """The default task: every fingertip presses the visible shell or hovers <= 5 mm over it, and the joints
    spread so widely that the mean pose (no image) is far from 99 % @5 deg."""
    from vtrack.dome.handsim import (
        DIST_LIMITS_DEG,
        PROX_LIMITS_DEG,
        VARIED_HOVER_MM,
        VARIED_MAX_PEN_MM,
        VARIED_TIP_MAX_POLAR_DEG,
    )

    hand = HandModel()
    rng = np.random.default_rng(21)
    Q, T = [], []
    for _ in range(60):
        q, place, touch = hand.sample_varied(rng)
        Q.append(q)
        T.append(touch)
        for i, d in enumerate(DIGITS):
            pen = hand.digit_penetration_mm(d, q, place)
            assert pen <= VARIED_MAX_PEN_MM + 1e-6 and (pen > 0) == touch[i]
            assert pen >= -VARIED_HOVER_MM[1] - 1e-6  # hovering digits stay within a few mm of the shell
            tip = hand._chain(d, q, 0.0, place)[-1]
            assert np.degrees(np.arccos(tip[2] / np.linalg.norm(tip))) <= VARIED_TIP_MAX_POLAR_DEG + 0.5
            assert PROX_LIMITS_DEG[0] - 1e-6 <= q[d.joints[0]] <= PROX_LIMITS_DEG[1] + 1e-6
            assert all(DIST_LIMITS_DEG[0] - 1e-6 <= q[j] <= DIST_LIMITS_DEG[1] + 1e-6 for j in d.joints[1:])
    Q, T = np.array(Q), np.array(T)
    assert 0.6 < T.mean() < 0.95  # most fingertips press, some hover
    assert Q.std(0).mean() > 8.0 and Q.std(0).min() > 4.0
    e = np.abs(Q[30:] - Q[:30].mean(0))  # mean pose of one half as the guess for the other
    assert e.mean() > 6.0 and (e <= 5.0).mean() < 0.6


def test_varied_eval_smoke_and_shipped_weights(tmp_path) -> None:
    """``evaluate_handpose`` on a few held-out varied grasps with the shipped default nets: all keys, finite,
    the image beats the no-image mean pose, the observability measure finds most joints visible; the dual net
    is stored without a second copy of its branches."""
    from vtrack.dome.handpose import evaluate_handpose, load_models, weights_path

    res = evaluate_handpose(None, n_test=6, seed=77, grasp_set="varied")
    for m in ("rgb", "ir", "dual"):
        assert all(np.isfinite(res[m][k]) for k in ("mae_deg", "rmse_deg", "acc1", "acc5"))
    assert res["dual"]["mae_deg"] < 0.5 * res["mean_pose_baseline"]["mae_deg"]
    assert res["information_bound"]["unobservable_joint_frac"] < 0.2
    assert res["test_set"]["grasp_set"] == "varied" and res["weights"] == "handpose_varied.pt"
    models, blob = load_models(weights_path("varied"))
    assert set(models) == {"rgb", "ir", "dual"} and blob["dual_shared"]
    assert not any(k in blob["models"]["dual"] for k in blob["dual_shared"])
    # a seed ensemble: the members store only what differs (their RGB nets and fusion heads, not the IR net)
    assert len(blob["members"]) >= 1 and all(not mb["models"]["ir"] for mb in blob["members"])
    # trained on 15000 grasps whose validation split nests the 9000-grasp one of the (older) thumb specialists
    assert blob["train"]["n_train"] == 15000 and blob["train"]["val_base"] == 9000
    assert blob["specialists"]["joints"] == ["thumb_mcp", "thumb_ip"] and len(blob["specialists"]["nets"]) == 2
    assert weights_path("varied").stat().st_size < 5_000_000


def test_varied_sensor_has_markers_over_the_whole_visible_cap() -> None:
    """The varied set's sensor covers the cap the fingertips reach (<= 74 deg polar) with markers at the same
    spacing; the mixed / contact sensor and the force / reconstruction dome keep their 68 deg layouts."""
    from vtrack.dome.handpose import ir_reference_centers
    from vtrack.dome.handsim import HAND_DOME_FULL, VARIED_TIP_MAX_POLAR_DEG, sensor_config
    from vtrack.dome.model import DomeConfig, DomeGeometry

    assert sensor_config("varied") is HAND_DOME_FULL and sensor_config("mixed") is HAND_DOME
    assert sensor_config("contact") is HAND_DOME and DomeConfig().marker_cap_deg == HAND_DOME.marker_cap_deg == 68.0
    polar = np.degrees(np.arccos(DomeGeometry(HAND_DOME_FULL).marker_dirs[:, 2]))
    assert polar.max() >= VARIED_TIP_MAX_POLAR_DEG - 0.5 and HAND_DOME_FULL.n_markers == 397
    # ring spacing within 2 % of the 68 deg layout's (the field is extended, not thinned)
    full, old = HAND_DOME_FULL.marker_cap_deg / 11, HAND_DOME.marker_cap_deg / 10
    assert abs(full / old - 1) < 0.02
    # the pipeline's extractor finds every pin of the no-contact frame, the rim ones included
    assert len(ir_reference_centers(HandDomeSimulator(grasp_set="varied").ir_reference())) == 397
    with pytest.raises(ValueError):
        sensor_config("nope")


def test_ray_capsule_hits_at_the_right_depth_with_the_right_normal() -> None:
    """The ``haze`` model's ray tracer: exact first-hit distance and outward normal of a capsule; 0 for a ray
    that starts inside one (a pressing phalanx), inf for a miss."""
    from vtrack.dome.handsim import _ray_capsules

    caps = [(np.array([-10.0, 0.0, 10.0]), np.array([10.0, 0.0, 10.0]), 2.0, "index")]
    o = np.array([[0.0, 0.0, 0.0], [5.0, 0.0, 9.0], [0.0, 5.0, 0.0], [14.0, 0.0, 0.0]])
    v = np.array([[0.0, 0.0, 1.0]] * 4)
    d, n = _ray_capsules(o, v, caps)
    np.testing.assert_allclose(d[:2], [8.0, 0.0], atol=1e-9)
    assert np.isinf(d[2])
    np.testing.assert_allclose(n[0], [0.0, 0.0, -1.0], atol=1e-9)
    # past the segment's end: the end sphere (centre (10, 0, 10), r 2) is hit at z = 10 - sqrt(4 - 16) -> miss,
    # at x = 11 it is hit at z = 10 - sqrt(3)
    d2, n2 = _ray_capsules(np.array([[11.0, 0.0, 0.0]]), v[:1], caps)
    np.testing.assert_allclose(d2, [10.0 - np.sqrt(3.0)], atol=1e-9)
    np.testing.assert_allclose(n2[0], [0.5, 0.0, -np.sqrt(3.0) / 2], atol=1e-9)
    assert np.isinf(d[3])


def test_haze_rgb_model_sharp_on_the_shell_and_blurred_off_it() -> None:
    """The visible-light model of the varied set: a phalanx pressing the shell shows a sharp, bright-skin patch;
    the same phalanx 15 mm off the shell is blurred (softer edges, larger footprint) but still seen; the
    ``opacity`` model of the older sets keeps its flat colour. Both models draw the same random numbers, so the
    IR frames of a grasp do not depend on the RGB model."""
    from vtrack.dome.handsim import HAND_DOME_FULL, rgb_model

    sim = HandDomeSimulator(grasp_set="varied")
    assert sim.rgb_model == "haze" and rgb_model("mixed") == rgb_model("contact") == "opacity"
    R, r = HAND_DOME_FULL.radius_mm, 8.0
    n = np.array([np.sin(np.deg2rad(30)), 0.0, np.cos(np.deg2rad(30))])
    t = np.cross(n, [0.0, 1.0, 0.0])

    def image(gap: float) -> np.ndarray:
        c = n * (R + r + gap)
        caps = [(c - 12 * t, c + 12 * t, r, "index")]
        return sim.render_rgb(caps, np.random.default_rng(0), noise=0.0).astype(np.float64)

    empty = sim.render_rgb([(np.full(3, 1e3), np.full(3, 1e3 + 1), 1.0, "x")], np.random.default_rng(0), noise=0)
    empty = empty.astype(np.float64)
    near, far = image(-1.0), image(15.0)
    d_near, d_far = (near - empty)[..., 0], (far - empty)[..., 0]
    assert np.abs(d_near).max() > 50 and np.abs(d_far).max() > 50  # both are seen, not faded out

    def sharpness(d: np.ndarray) -> float:  # steepest step / contrast of the phalanx's own image (rim cancels)
        return max(np.abs(np.diff(d, axis=a)).max() for a in (0, 1)) / np.abs(d).max()

    assert sharpness(d_near) > 1.5 * sharpness(d_far)  # measured 0.52 vs 0.27
    assert (np.abs(d_far) > 10).sum() > 1.4 * (np.abs(d_near) > 10).sum()  # the blur spreads it (126 vs 74 px)
    # skin (red > blue) where the phalanx presses
    patch = near[np.abs(d_near) > 0.8 * np.abs(d_near).max()]
    assert patch[:, 0].mean() > patch[:, 2].mean() + 20
    sim.rgb_model = "opacity"  # the same grasp rendered by the other model: IR identical, RGB not
    b = sim.sample(np.random.default_rng(5))
    sim.rgb_model = "haze"
    a = sim.sample(np.random.default_rng(5))
    assert np.array_equal(a["ir"], b["ir"]) and not np.array_equal(a["rgb"], b["rgb"])
    with pytest.raises(ValueError):
        HandDomeSimulator(grasp_set="varied", rgb_model_name="nope")


def test_per_joint_loss_weights() -> None:
    """Per-joint weights (mean 1) inside both loss terms: equal weights give S25-S27 exactly; a weight of 3 on the
    one wrong joint raises both terms by 3x / sqrt(3)x relative to the normalised unweighted loss."""
    from vtrack.dome.handpose import joint_weight_vector, pose_loss

    assert joint_weight_vector({}) is None
    w = joint_weight_vector({"thumb_ip": 3.0})
    assert abs(float(w.mean()) - 1.0) < 1e-6 and float(w[3] / w[0]) == pytest.approx(3.0)
    gt = torch.zeros(4, 12)
    pred = gt.clone()
    pred[:, 3] = 2.0  # only the thumb IP is wrong
    plain = pose_loss(pred, gt)
    assert float(pose_loss(pred, gt, weights=joint_weight_vector({j: 1.0 for j in JOINTS}))) == pytest.approx(
        float(plain)
    )
    mae, rmse = 2.0 / 12, np.sqrt(4.0 / 12)
    assert float(plain) == pytest.approx(mae + rmse, rel=1e-5)
    assert float(pose_loss(pred, gt, weights=w)) == pytest.approx(
        float(w[3]) * mae + np.sqrt(float(w[3])) * rmse, rel=1e-5
    )
    with pytest.raises(ValueError):
        joint_weight_vector({"thumb_tip": 2.0})


def test_rgb_crop_reads_only_its_window_magnified() -> None:
    """A thumb-crop RGB net sees only its window: a change outside it leaves the output alone, one inside moves it;
    bad crops are refused."""
    from vtrack.dome.handpose import HandPoseNet, parse_rgb_crop

    torch.manual_seed(0)
    crop = parse_rgb_crop("26,0,32,2")
    assert crop == (26, 0, 32, 2) and parse_rgb_crop("") is None
    for bad in ("26,0,32", "40,40,32,2", "0,0,4,2", "0,0,32,9", "a,b,c,d"):
        with pytest.raises(ValueError):
            parse_rgb_crop(bad)
    net = HandPoseNet("rgb", np.zeros(12), np.ones(12), feat=16, width=4, rgb_crop=crop).eval()
    x = torch.rand(1, 3, RGB_SIZE, RGB_SIZE)
    assert net._crop(x).shape == (1, 3, 64, 64)  # 32 px window at 2x
    y0 = net.degrees({"rgb": x})
    out_side, in_side = x.clone(), x.clone()
    out_side[:, :, :20, 40:] = 1.0  # upper right: outside rows 26-57 / cols 0-31
    in_side[:, :, 30:50, 5:25] = 1.0
    assert torch.equal(net.degrees({"rgb": out_side}), y0)
    assert (net.degrees({"rgb": in_side}) - y0).abs().max() > 1e-4


def test_joint_specialists_replace_only_their_joints(tmp_path) -> None:
    """Specialists stored in a weights file give their joints (mix 1) or a blend (mix 0.5) in the RGB and dual
    settings; the other joints and the IR setting are the file's own; a net of another training set is refused."""
    from vtrack.dome.handpose import (
        HandPoseNet,
        HandPoseTrainConfig,
        _build_nets,
        add_joint_specialists,
        load_models,
        predict_deg,
        prep_rgb,
        rotate_frames,
        save_models,
        weights_path,
    )

    base = tmp_path / "w.pt"
    blob = torch.load(weights_path(), map_location="cpu", weights_only=False)
    blob.pop("specialists", None)  # the shipped file's own thumb specialists: start from the ensemble alone
    torch.save(blob, base)
    fields = HandPoseTrainConfig.__dataclass_fields__
    tc = HandPoseTrainConfig(**{k: v for k, v in blob["train"].items() if k in fields})
    torch.manual_seed(1)
    spec = HandPoseNet("rgb", np.full(12, 40.0), np.full(12, 5.0), feat=16, width=4, rgb_crop=(26, 0, 32, 2))
    save_models(tmp_path / "s.pt", {"rgb": spec}, tc, {})
    sim = HandDomeSimulator(grasp_set="varied")
    s = sim.sample(np.random.default_rng(5))
    data = {"rgb": s["rgb"][None], "ir": s["ir"][None], "ir_reference": sim.ir_reference()}
    before = {m: predict_deg(n, data)[0] for m, n in load_models(base)[0].items()}
    ys = predict_deg(load_models(tmp_path / "s.pt")[0]["rgb"], data)[0]
    thumb = [JOINTS.index("thumb_mcp"), JOINTS.index("thumb_ip")]
    others = [j for j in range(12) if j not in thumb]
    for mix in (1.0, 0.5):
        add_joint_specialists(base, [tmp_path / "s.pt"], ["thumb_mcp", "thumb_ip"], mix)
        after = {m: predict_deg(n, data)[0] for m, n in load_models(base)[0].items()}
        for m in ("rgb", "dual"):
            np.testing.assert_allclose(after[m][others], before[m][others], atol=1e-4)
            np.testing.assert_allclose(after[m][thumb], (1 - mix) * before[m][thumb] + mix * ys[thumb], atol=1e-3)
        np.testing.assert_allclose(after["ir"], before["ir"], atol=1e-4)
    # test-time rotation averaging: the specialist's thumb is its mean over the frame turned by -10 / 0 / +10 deg
    # (with a trained specialist, the shipped file's first: the random one above barely reacts to its input)
    shipped = torch.load(weights_path(), map_location="cpu", weights_only=False)["specialists"]["nets"][0]
    save_models(tmp_path / "r.pt", {"rgb": _build_nets({"rgb": shipped}, [])["rgb"]}, tc, {})
    add_joint_specialists(base, [tmp_path / "r.pt"], ["thumb_mcp", "thumb_ip"], 1.0, (-10.0, 0.0, 10.0))
    after = {m: predict_deg(n, data)[0] for m, n in load_models(base)[0].items()}
    x = torch.from_numpy(prep_rgb(data["rgb"]))
    spec_net = load_models(tmp_path / "r.pt")[0]["rgb"]
    ys = predict_deg(spec_net, data)[0]
    with torch.no_grad():
        turned = [
            spec_net.degrees({"rgb": rotate_frames(x, 0.0, None, 0.0, torch.tensor([a]))})[0] for a in (-10, 0, 10)
        ]
    expect = torch.stack(turned).mean(0).numpy()
    assert np.abs(expect[thumb] - ys[thumb]).max() > 1e-3  # the turns do change the specialist's output
    for m in ("rgb", "dual"):
        np.testing.assert_allclose(after[m][others], before[m][others], atol=1e-4)
        np.testing.assert_allclose(after[m][thumb], expect[thumb], atol=1e-3)
    with pytest.raises(ValueError, match="test-time turns"):
        add_joint_specialists(base, [tmp_path / "s.pt"], ["thumb_ip"], 1.0, (float("nan"),))
    tc_other = HandPoseTrainConfig(grasp_set="mixed", n_train=tc.n_train)
    save_models(tmp_path / "o.pt", {"rgb": spec}, tc_other, {})
    with pytest.raises(ValueError, match="same training set"):
        add_joint_specialists(base, [tmp_path / "o.pt"], ["thumb_ip"])
    with pytest.raises(ValueError, match="must name joints"):
        add_joint_specialists(base, [tmp_path / "s.pt"], ["thumb_tip"])


def test_cramer_rao_bound_sees_what_each_camera_can_see() -> None:
    """The CRB of one grasp (thumb pressing, one finger hovering): all 12 joints are pinned far below 5 deg by the
    two frames together (thumb MCP / IP included, the placement and gains free); the hovering finger's joints are
    unbounded in the IR frame alone (no contact, no marker moves) but not in the RGB frame."""
    from vtrack.dome.handpose import grasp_crb

    sim = HandDomeSimulator(grasp_set="varied")
    rng = np.random.default_rng(3)
    while True:  # a grasp with one hovering finger (not the thumb)
        q, place, touch = sim.hand.sample_varied(rng)
        if not touch[1:].all() and touch[0]:
            break
    o = grasp_crb(sim, q, place)
    assert np.all(o["sigma_dual"] < 1.0) and np.all(o["sigma_rgb"] < 2.0)
    assert o["sigma_dual"][[2, 3]].max() < 0.5  # the thumb's MCP / IP split
    hover = [i for i, d in enumerate(DIGITS) if i > 0 and not touch[i]][0]
    assert np.all(o["sigma_ir"][list(DIGITS[hover].joints)] > 100.0)


def test_rgb_rotation_augmentation_is_the_hand_yawed() -> None:
    """The sensor is symmetric about the dome axis: a 90 deg turn of the noise-free frame is the render of the hand
    yawed by 90 deg (exactly), and the augmentation's bilinear turn by -10 deg is the render of the hand yawed by
    +10 deg up to the interpolation (well under the change the yaw itself makes)."""
    from vtrack.dome.handpose import rotate_frames
    from vtrack.dome.handsim import HandPlace

    sim = HandDomeSimulator(grasp_set="varied")
    q, place, _ = sim.hand.sample_varied(np.random.default_rng(2))
    pa = place.to_array()

    def render(yaw: float) -> np.ndarray:
        p = pa.copy()
        p[0] += yaw
        return sim.rgb_float(sim.hand.capsules(q, place=HandPlace.from_array(p))).astype(np.float64)

    a, a90, a10 = render(0.0), render(90.0), render(10.0)
    np.testing.assert_allclose(np.rot90(a, -1), a90, atol=1e-4)
    x = torch.from_numpy(np.ascontiguousarray(a.transpose(2, 0, 1)[None] - 0.5)).float()
    r = rotate_frames(x, 0.0, torch.Generator(), noise=0.0, angles_deg=torch.tensor([-10.0]))[0].numpy()
    r = r.transpose(1, 2, 0) + 0.5
    sigma = 0.015  # the RGB pixel noise
    assert np.sqrt(((r - a10) ** 2).mean()) < 2.0 * sigma < 0.5 * np.sqrt(((a - a10) ** 2).mean())
    g = torch.Generator().manual_seed(0)
    out = rotate_frames(x.repeat(4, 1, 1, 1), 20.0, g)
    assert out.shape == (4, 3, RGB_SIZE, RGB_SIZE) and torch.isfinite(out).all()


def test_nested_split_keeps_the_smaller_runs_validation_grasps() -> None:
    """``val_base``: a run on more grasps keeps the validation grasps of the run on its first ``val_base`` grasps out
    of training (so nets of both runs can be chosen and combined on grasps none of them saw); default unchanged."""
    from dataclasses import asdict

    from vtrack.dome.handpose import HandPoseTrainConfig, split_train_val, trained_within

    small = HandPoseTrainConfig(n_train=900)
    big = HandPoseTrainConfig(n_train=1500, val_base=900)
    tr_s, va_s = split_train_val(900, small)
    tr_b, va_b = split_train_val(1500, big)
    assert set(va_s) <= set(va_b) and set(tr_s) <= set(tr_b)  # nested: both halves of the small split are kept
    assert len(va_b) == 150 and not set(tr_b) & set(va_b) and set(tr_b) | set(va_b) == set(range(1500))
    extra = va_b[va_b >= 900]
    assert 50 <= len(extra) <= 70 and np.ptp(extra) > 300  # a fraction of the new grasps, spread over them
    # the default (0) and a base covering every grasp are the old single permutation
    for cfg in (HandPoseTrainConfig(n_train=1500), HandPoseTrainConfig(n_train=1500, val_base=1500)):
        tr, va = split_train_val(1500, cfg)
        assert set(va) == set(np.random.default_rng(0).permutation(1500)[:150])
    # what may be combined: the same split, or the nested base; not another set, seed or an unrelated size
    assert trained_within(asdict(small), asdict(big)) and trained_within(asdict(big), asdict(big))
    assert not trained_within(asdict(big), asdict(small))
    assert not trained_within(asdict(HandPoseTrainConfig(n_train=600)), asdict(big))
    assert not trained_within(asdict(HandPoseTrainConfig(n_train=900, seed=1)), asdict(big))
    assert not trained_within({"n_train": 900, "seed": 0, "grasp_set": "mixed"}, asdict(big))
