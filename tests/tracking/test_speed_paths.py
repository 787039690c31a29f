"""The fast paths of blind tracking give the reference implementation's values (issue #19 speed work).

Each fast path is pinned to the straightforward implementation it replaced, on frames of a real (simulated)
session: the vectorised tactile drift estimate, the tactile pipeline's points-only path, and the window tracker's
one-query-per-window data terms.
"""

from __future__ import annotations

import numpy as np
import pytest

from vtrack.tactile.calibration import _MODE_KERNEL, _MODE_RANGE, drift_offset


def _drift_offset_reference(image, background, max_spread=6.0, step=0):
    """The per-channel loop :func:`drift_offset` had before it was vectorised (copied verbatim)."""
    if step <= 0:
        step = max(1, int(np.sqrt(np.asarray(image).shape[0] * np.asarray(image).shape[1] / 1200.0)))
    a = np.asarray(image)[::step, ::step].reshape(-1, 3).astype(np.int16)
    b = np.asarray(background)[::step, ::step].reshape(-1, 3)
    if a.size == 0:
        return np.zeros(3), 0.0
    d = a - b
    off = np.zeros(3)
    if max_spread >= 0:
        for c in range(3):
            counts = np.bincount(
                np.clip(d[:, c], -_MODE_RANGE, _MODE_RANGE) + _MODE_RANGE, minlength=2 * _MODE_RANGE + 1
            ).astype(np.float64)
            counts = np.convolve(counts, _MODE_KERNEL, mode="same")
            m = float(np.argmax(counts) - _MODE_RANGE)
            near = np.abs(d[:, c] - m) <= 2.0
            off[c] = float(d[near, c].mean()) if near.any() else m
        flat = (np.abs(d - off) <= max(max_spread, 1.0)).all(axis=1)
        if np.abs(off).max() < 1.0 or flat.mean() < 1.0 / 3.0:
            off = np.zeros(3)
    row = np.asarray(image)[::step].astype(np.int16) - np.asarray(background)[::step]
    adj = np.abs(np.diff(row, axis=1)).reshape(-1, 3)
    sigma = 1.4826 * np.median(adj, axis=0) / np.sqrt(2.0) if adj.size else np.zeros(3)
    return off, float(0.8 * sigma.sum())


def test_vectorised_drift_offset_equals_the_per_channel_loop():
    rng = np.random.default_rng(3)
    bg = rng.integers(40, 200, size=(60, 80, 3), dtype=np.uint8)
    cases = [bg.copy()]
    shifted = np.clip(bg.astype(np.int16) + np.array([7, -5, 3]) + rng.integers(-2, 3, bg.shape), 0, 255)
    cases.append(shifted.astype(np.uint8))  # global drift: a non-zero offset
    pressed = shifted.copy()
    pressed[10:50, 10:70] = np.clip(pressed[10:50, 10:70] + rng.integers(-90, 90, (40, 60, 3)), 0, 255)
    cases.append(pressed.astype(np.uint8))  # most of the gel deformed: no flat reference, offset 0
    cases.append(np.zeros_like(bg))  # saturating drift beyond the searched range
    for img in cases:
        for spread in (6.0, -1.0, 0.5):
            off, level = drift_offset(img, bg, spread)
            off_r, level_r = _drift_offset_reference(img, bg, spread)
            np.testing.assert_array_equal(off, off_r)
            assert level == level_r
    assert np.abs(drift_offset(cases[1], bg)[0] - [7, -5, 3]).max() < 0.5  # the drift it exists to find


@pytest.fixture(scope="module")
def touch_frames(tiny_session):
    from vtrack.frames.session import SessionFrames

    fr = SessionFrames(tiny_session, touch_stride=2, touch_downsample=4)
    raws = [fr.read(i) for i in range(0, len(fr), 3)]
    return fr, [(s, img) for r in raws for s, img in r["touch"]]


def test_tactile_contact_only_gives_the_points_of_process(touch_frames):
    from vtrack import registry

    fr, items = touch_frames
    Pipe = registry.load("tactile")
    specs = {t.name: t for t in fr.scene.tactile}
    n_points = 0
    for sensor in {s for s, _ in items}:
        a = Pipe._from_spec(specs[sensor], point_stride=2, downsample=4)  # process(): the reference
        b = Pipe._from_spec(specs[sensor], point_stride=2, downsample=4)  # contact_only(): the fast path
        for s, img in items:
            if s != sensor:
                continue
            ref = a.process(img, full_res=False)
            P, N, quality = b.contact_only(img)
            assert quality == ref.quality
            np.testing.assert_array_equal(P, ref.points)
            np.testing.assert_array_equal(N, ref.normals)
            n_points += len(P)
    assert n_points > 100  # the session's fingers touch the object: real contacts were compared


def test_flat_gel_short_cut_gives_a_zero_height_map(touch_frames):
    fr, items = touch_frames
    s, img = items[0]
    pipe = fr.touch.pipelines[s]
    bg = pipe._bg_work
    # the flat gel itself (the pipeline's background at full size): no colour change, height exactly zero
    flat = np.asarray(pipe.background)
    _, hw, gate, quality, _ = pipe._height_work(flat)
    assert quality == "ok" and not gate.any() and hw.shape == bg.shape[:2]
    assert hw.dtype == np.float32 and not hw.any()
    P, _, _ = pipe.contact_only(flat)
    assert len(P) == 0


@pytest.mark.parametrize(
    "opts",
    [
        {},
        {
            "touch_weak_vision": 100000,
            "sigma_touch_weak": 0.0015,
            "sigma_normal_weak": 0.5,
            "robust": "cauchy",
            "free_margin": 0.001,
        },
    ],
    ids=["defaults", "weak-vision-cauchy"],
)
def test_window_terms_with_one_query_equal_the_per_slot_terms(tiny_session, opts):
    """SLAM on the first frames of a session: at every evaluation the batched window terms (one SDF query and one
    pass of robust weights for the whole window) equal the per-slot terms (each slot's SDF queried and weighted on
    its own), bit for bit; with SLAM's defaults (one-sided contacts: a sigma per row) and with every frame in the
    weak-vision regime under the Cauchy kernel."""
    from vtrack.frames.session import SessionFrames
    from vtrack.tracking.run import slam_origin
    from vtrack.tracking.slam import SLAMTracker

    frames = SessionFrames(tiny_session, touch_stride=2, touch_downsample=4, max_frames=14)
    T0, _ = slam_origin(frames)
    trk = SLAMTracker(T0, **opts)
    checked = []
    batched = trk._window_terms

    def both(slots):
        out = batched(slots)
        for s, (H, b, c) in zip(slots, out, strict=True):
            T = s.T if s.proj is None else None
            if T is None:
                continue  # projected slots: same code path after the pose, covered by the unprojected ones
            Hr, br, cr = trk._slot_terms(s, T)
            np.testing.assert_array_equal(H, Hr)
            np.testing.assert_array_equal(b, br)
            assert c == cr
            checked.append(len(slots))
        return out

    trk._window_terms = both
    for i in range(len(frames)):
        trk.step(frames.frame(i)[0].tracking_frame())
    assert len(checked) > 20 and max(checked) == trk.opts.window  # full windows were compared


def test_scalar_se3_exp_and_log_match_the_matrix_forms():
    """The window tracker's written-out exp / log equal the hat-matrix formulas (and invert each other)."""
    from vtrack.geometry import se3
    from vtrack.tracking.window import _exp, _log

    def hat(v):
        return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])

    rng = np.random.default_rng(1)
    for scale in (1e-7, 1e-4, 1e-2, 0.3, 2.0):
        for _ in range(50):
            xi = rng.normal(size=6) * scale
            phi, th2 = xi[3:], float(xi[3:] @ xi[3:])
            if th2 < 1e-10:
                A, B, C = 1.0 - th2 / 6.0, 0.5 - th2 / 24.0, 1.0 / 6.0 - th2 / 120.0
            else:
                th = np.sqrt(th2)
                A, B, C = np.sin(th) / th, (1.0 - np.cos(th)) / th2, (th - np.sin(th)) / (th2 * th)
            K = hat(phi)
            T_ref = np.eye(4)
            T_ref[:3, :3] = np.eye(3) + A * K + B * K @ K
            T_ref[:3, 3] = (np.eye(3) + B * K + C * K @ K) @ xi[:3]
            T = _exp(xi)
            np.testing.assert_allclose(T, T_ref, rtol=0, atol=1e-13)
            np.testing.assert_allclose(T, se3.make_transform(se3.so3_exp(phi), T[:3, 3]), rtol=0, atol=1e-12)
            if np.linalg.norm(phi) < 3.0:
                np.testing.assert_allclose(_log(T), xi, rtol=1e-9, atol=1e-12)


def test_written_out_row_norms_and_ray_residuals_equal_the_numpy_reductions_bit_for_bit():
    """The tracker's results must not move with its speed-ups: ``row_norms`` equals ``np.linalg.norm(axis=1)`` and
    ``_ray_residuals`` (sums written out, rays passed in or not) equals its einsum formulation, to the last bit, on
    values spread over many magnitudes (where a different summation order shows)."""
    from vtrack.geometry import se3
    from vtrack.geometry.pointcloud import row_norms
    from vtrack.tracking.window import _ray_directions, _ray_residuals

    rng = np.random.default_rng(7)
    for n in (1, 3, 40, 517):
        x = rng.normal(size=(n, 3)) * np.exp(rng.normal(size=(n, 3)) * 4)
        assert np.array_equal(row_norms(x), np.linalg.norm(x, axis=1))
        R = np.stack([se3.so3_exp(rng.normal(size=3) * s) for s in rng.choice([1e-6, 0.1, 3.0], n)])
        t = rng.normal(size=(n, 3)) * 0.3
        Q = rng.normal(size=(n, 3)) * np.exp(rng.normal(size=(n, 3)) * 3)
        C = rng.normal(size=(n, 3))
        P = C + rng.normal(size=(n, 3)) * np.exp(rng.normal(size=(n, 1)))
        # the einsum formulation the written-out one replaced
        Rq = np.einsum("nij,nj->ni", R, Q)
        d = P - C
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        e = Rq + t - C
        r_ref = e - d * np.sum(d * e, axis=1, keepdims=True)
        J_ref = np.empty((n, 3, 6))
        J_ref[:, :, :3] = R
        hx = np.zeros((n, 3, 3))
        hx[:, 0, 1], hx[:, 0, 2] = -Rq[:, 2], Rq[:, 1]
        hx[:, 1, 0], hx[:, 1, 2] = Rq[:, 2], -Rq[:, 0]
        hx[:, 2, 0], hx[:, 2, 1] = -Rq[:, 1], Rq[:, 0]
        J_ref[:, :, 3:] = -hx @ R
        J_ref -= d[:, :, None] * np.einsum("nk,nkj->nj", d, J_ref)[:, None, :]
        for rays in (None, _ray_directions(P, C)):
            r, J = _ray_residuals(R, t, P, Q, C, rays)
            assert np.array_equal(r, r_ref) and np.array_equal(J, J_ref)


def test_sanitize_row_gathers_equal_masked_indexing_bit_for_bit():
    """sanitize gathers rows with take on flat indices: the same arrays as boolean / fancy row indexing, on frames with
    non-finite rows, missing normals and streams over and under their budgets."""
    from vtrack.tracking.frame import TrackingFrame, _subsample, sanitize

    rng = np.random.default_rng(5)
    for nv, nt, nf in ((0, 0, 0), (30, 5, 3), (700, 250, 90)):
        V, P, N, F = (rng.normal(size=(n, 3)) for n in (nv, nt, nt, nf))
        for A in (V, P, N, F):
            A[rng.random(len(A)) < 0.1, rng.integers(0, 3)] = np.nan
        fr = TrackingFrame(t=0.5, vision_points=V, touch_points=P, touch_normals=N, free_points=F)
        out = sanitize(fr, 400, 160, 64, seed=7)
        r = np.random.default_rng(7)  # the reference: the masked-indexing form, the same draws in the same order
        Vr = V[np.isfinite(V).all(1)]
        Vr = Vr[_subsample(len(Vr), 400, r)]
        ok = np.isfinite(P).all(1)
        Pr, Nr = P[ok], N[ok]
        nn = np.linalg.norm(Nr, axis=1)
        good = np.isfinite(nn) & (nn > 1e-9)
        Nr = np.where(good[:, None], Nr / np.where(good, nn, 1.0)[:, None], np.nan)
        k = _subsample(len(Pr), 160, r)
        Pr, Nr = Pr[k], Nr[k]
        Fr = F[np.isfinite(F).all(1)]
        Fr = Fr[_subsample(len(Fr), 64, r)]
        for a, b in ((out.vision_points, Vr), (out.touch_points, Pr), (out.touch_normals, Nr), (out.free_points, Fr)):
            assert a.shape == b.shape and np.array_equal(a, b, equal_nan=True)
