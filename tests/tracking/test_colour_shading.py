"""Shading removal for the colour tracks (vtrack.tracking.colour, ``ColourOptions.shading = "sh"``): a 2nd-order
spherical-harmonics lighting model of the intensity against the depth's normals, divided out.

Synthetic renders with a known albedo, known geometry and a light the code does not know; the estimate must come
from the image and the depth alone."""

from __future__ import annotations

import numpy as np
import pytest

from vtrack.errors import InputError
from vtrack.tracking.colour import (
    ColourOptions,
    FeatureTracks,
    fit_sh_lighting,
    normals_from_depth,
    remove_shading_sh,
    sh_basis,
)

K = np.array([[300.0, 0.0, 160.0], [0.0, 300.0, 120.0], [0.0, 0.0, 1.0]])
H, W = 240, 320


def _rays() -> np.ndarray:
    v, u = np.mgrid[0:H, 0:W].astype(float)
    d = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], -1)
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


def _sphere(radius: float = 0.05, centre=(0.0, 0.0, 0.4)):
    """Depth (m), mask, true camera-frame normals (towards the camera) and points of a sphere."""
    d = _rays()
    c = np.asarray(centre)
    b = d @ c
    disc = b * b - (c @ c - radius**2)
    hit = disc > 0
    t = np.where(hit, b - np.sqrt(np.maximum(disc, 0.0)), 0.0)
    P = d * t[..., None]
    n = (P - c) / radius
    return P[..., 2] * hit, hit, n, P


def _albedo(P: np.ndarray) -> np.ndarray:
    return 0.75 + 0.25 * np.sin(P[..., 0] * 300.0) * np.cos(P[..., 1] * 200.0)


def test_sh_fit_recovers_a_known_albedo_from_a_lambert_render_with_known_normals():
    _, hit, n, P = _sphere()
    # a light the 2nd-order SH represent (ambient + a directional term + a quadratic fall-off), strongly varying
    L = np.array([0.3, -0.4, -0.85])
    L /= np.linalg.norm(L)
    shade = 0.5 + 0.4 * (n @ L) + 0.2 * (n[..., 2] ** 2)
    alb = _albedo(P)
    img = 150.0 * alb * shade
    c = fit_sh_lighting(img[hit], n[hit])
    est = img[hit] / (sh_basis(n[hit]) @ c)
    a = alb[hit]
    rel = np.abs(est / est.mean() - a / a.mean())
    assert np.median(rel) < 0.01, np.median(rel)
    # the raw image is far from the albedo (the shading varies ~3x over the sphere)
    raw = img[hit] / img[hit].mean()
    assert np.median(np.abs(raw - a / a.mean())) > 0.1


def test_shading_removal_from_noisy_depth_recovers_the_albedo():
    z, hit, n, P = _sphere()
    rng = np.random.default_rng(0)
    zn = np.where(hit, z + rng.normal(0.0, 0.0007, z.shape), 0.0)  # ~the simulated camera's depth noise
    normals, ok = normals_from_depth(zn, hit, K, blur_px=1.0)
    ang = np.degrees(np.arccos(np.clip((normals * n).sum(-1)[ok], -1, 1)))
    assert ok.sum() > 0.9 * hit.sum() and np.median(ang) < 6.0, (ok.sum(), hit.sum(), np.median(ang))
    L = np.array([0.3, -0.4, -0.85])
    L /= np.linalg.norm(L)
    alb = _albedo(P)
    img = np.clip(150.0 * alb * (0.55 * np.abs((n * _rays()).sum(-1)) + 0.35 * np.abs(n @ L) + 0.15), 0, 255)
    out, valid = remove_shading_sh(img.astype(np.uint8), hit, zn, K, depth_blur_px=1.0)
    assert np.all(np.isfinite(out)) and valid.sum() > 0.9 * hit.sum()
    a = alb[valid]
    assert np.corrcoef(a, out[valid])[0, 1] > 0.85  # albedo recovered (the shading model is not exact here) ...
    assert np.corrcoef(a, img[valid])[0, 1] < 0.7  # ... from an image whose shading hides it
    assert np.all(out[~valid] == 128.0)


def test_flat_and_degenerate_inputs_are_nan_free():
    # a fronto-parallel plane: every normal the same, the SH normal matrix is rank 1
    z = np.full((H, W), 0.4)
    m = np.zeros((H, W), bool)
    m[60:180, 80:240] = True
    alb = 0.75 + 0.25 * np.sin(np.arange(W) / 7.0)[None, :].repeat(H, 0)
    img = (160.0 * alb).astype(np.float32)
    out, valid = remove_shading_sh(img, m, z, K)
    assert np.all(np.isfinite(out)) and valid.sum() > 0.9 * m.sum()
    # constant shading: the albedo image is the image scaled to mean 128 on the object
    exp = 128.0 * img[valid] / img[valid].mean()
    assert np.max(np.abs(out[valid] - exp)) < 0.5
    # no depth, NaN depth, an empty mask, a black image: 128 everywhere, nothing valid, no warning
    with np.errstate(all="raise"):
        for zz, mm, ii in [
            (np.zeros((H, W)), m, img),
            (np.full((H, W), np.nan), m, img),
            (z, np.zeros((H, W), bool), img),
            (z, m, np.zeros((H, W), np.float32)),
        ]:
            o, v = remove_shading_sh(ii, mm, zz, K)
            assert np.all(np.isfinite(o))
            if not v.any():
                assert np.all(o == 128.0)
    assert np.all(fit_sh_lighting(np.zeros(0), np.zeros((0, 3))) == 0)


def test_tracks_with_sh_shading_follow_a_textured_sphere_and_fall_back_without_depth():
    z, hit, n, P = _sphere()
    L = np.array([0.3, -0.4, -0.85])
    L /= np.linalg.norm(L)
    shade = 0.3 + 0.6 * np.clip(n @ L, 0, None)
    # a sharp albedo texture (a printed label), shifted by 2 px between the frames
    rng = np.random.default_rng(1)
    tex = (rng.random((H // 4 + 2, W // 4 + 2)) > 0.5).repeat(4, 0).repeat(4, 1)
    imgs = [np.clip(200.0 * (0.6 + 0.4 * tex[1 : H + 1, s : W + s]) * shade, 0, 255).astype(np.uint8) for s in (2, 0)]
    ft = FeatureTracks({"shading": "sh", "max_features": 40})
    ids0, uv0 = ft.update(imgs[0], hit, z, K)
    ids1, uv1 = ft.update(imgs[1], hit, z, K)
    common, i0, i1 = np.intersect1d(ids0, ids1, return_indices=True)
    assert len(common) >= 10
    dx = uv1[i1] - uv0[i0]
    assert np.median(dx[:, 0]) == pytest.approx(2.0, abs=0.1) and abs(np.median(dx[:, 1])) < 0.1
    # without a depth the "sh" mode is the "local" one
    a = FeatureTracks({"shading": "sh"}).update(imgs[0], hit)
    b = FeatureTracks({"shading": "local"}).update(imgs[0], hit)
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])


def test_lighting_accumulated_over_frames_keeps_its_model_through_an_empty_frame():
    _, hit, n, P = _sphere()
    L = np.array([0.3, -0.4, -0.85])
    L /= np.linalg.norm(L)
    img = 150.0 * _albedo(P) * (0.5 + 0.4 * (n @ L))
    state: dict = {}
    c1 = fit_sh_lighting(img[hit], n[hit], state=state, memory=0.9)
    # the same frame again: the accumulated model is the single frame's (to rounding)
    c2 = fit_sh_lighting(img[hit], n[hit], state=state, memory=0.9)
    assert np.allclose(c1, c2, rtol=1e-3, atol=1e-3 * np.abs(c1).max())
    # a frame without object pixels: the model of the earlier frames, not zeros
    c3 = fit_sh_lighting(np.zeros(0), np.zeros((0, 3)), state=state, memory=0.9)
    assert np.allclose(c3, c1, rtol=1e-3, atol=1e-3 * np.abs(c1).max())
    with pytest.raises(InputError):
        ColourOptions.from_dict({"sh_memory": 1.5})


def test_bad_shading_option_is_an_input_error():
    with pytest.raises(InputError):
        ColourOptions.from_dict({"shading": "retinex"})
    with pytest.raises(InputError):
        ColourOptions.from_dict({"pre_blur_px": -1.0})


def test_normalise_shading_is_the_masked_division_bit_for_bit():
    """:func:`normalise_shading` gives exactly ``128 g / mean`` on the masked pixels with a mean above 1 and 128
    elsewhere (the boolean-indexed formula it replaced), on a textured, shaded image with a ragged mask, a dark
    patch (mean below 1) and a one-pixel-wide crop."""
    import cv2

    from vtrack.tracking.colour import normalise_shading

    rng = np.random.default_rng(5)
    yy, xx = np.mgrid[0:90, 0:120]
    grey = np.clip(60 + 100 * np.exp(-((xx - 50) ** 2 + (yy - 40) ** 2) / 2000.0) + rng.normal(0, 12, xx.shape), 0, 255)
    grey = grey.astype(np.uint8)
    grey[:50, :50] = 0  # a dark corner: its local mean falls below 1
    mask = ((xx - 60) ** 2 / 45.0**2 + (yy - 45) ** 2 / 30.0**2 < 1) | (rng.random(xx.shape) < 0.05)
    mask[:50, :50] = True
    for g, m, blur in ((grey, mask, 7.0), (grey, mask, 2.5), (grey[:, 40:41], mask[:, 40:41], 7.0)):
        gf, mf = g.astype(np.float32), m.astype(np.float32)
        nd = cv2.GaussianBlur(np.dstack([gf * mf, mf]), (0, 0), blur).reshape(g.shape + (2,))
        mean = nd[..., 0] / np.maximum(nd[..., 1], 1e-3)
        want = np.full(g.shape, 128.0, np.float32)
        ok = m & (mean > 1.0)
        want[ok] = 128.0 * gf[ok] / mean[ok]
        got = normalise_shading(g, m, blur)
        assert got.dtype == np.float32 and np.array_equal(got, want)
        assert (~ok & m).any() or g.shape[1] == 1
