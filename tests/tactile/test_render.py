"""Inverse model: height map -> tactile image."""

import numpy as np
import pytest

from vtrack.errors import InputError
from vtrack.tactile.render import lambert_colour_delta, render_tactile_image


def _sphere(h=120, w=160, r_px=30.0, depth_px=8.0, mm_per_px=0.1):
    yy, xx = np.mgrid[0:h, 0:w]
    rho2 = (xx - w / 2) ** 2 + (yy - h / 2) ** 2
    R = (r_px**2 + depth_px**2) / (2 * depth_px)
    z = np.sqrt(np.clip(R**2 - rho2, 0, None)) - (R - depth_px)
    return np.clip(z, 0, None) * mm_per_px


def test_flat_renders_background():
    bg = np.full((40, 50, 3), 120, np.uint8)
    img = render_tactile_image(np.zeros((40, 50)), 0.1, bg)
    assert img.dtype == np.uint8 and img.shape == (40, 50, 3)
    assert np.array_equal(img, bg)


def test_sphere_changes_colour_inside_contact_only():
    h = _sphere()
    bg = np.full((120, 160, 3), 128, np.uint8)
    img = render_tactile_image(h, 0.1, bg, rng=np.random.default_rng(0), noise_std=1.0)
    diff = np.abs(img.astype(float) - 128).sum(-1)
    inside, outside = diff[h > 0.1], diff[h == 0]
    assert inside.mean() > 10 * max(outside.mean(), 0.5)


def test_opposite_slopes_give_different_colours():
    d1 = lambert_colour_delta(np.array([0.5]), np.array([0.0]))
    d2 = lambert_colour_delta(np.array([-0.5]), np.array([0.0]))
    assert np.abs(d1 - d2).max() > 20


def test_background_resized_and_nan_height():
    h = _sphere()
    h[0, 0] = np.nan
    img = render_tactile_image(h, 0.1, np.full((10, 10, 3), 90, np.uint8))
    assert img.shape == (120, 160, 3)


def test_bad_inputs():
    with pytest.raises(InputError):
        render_tactile_image(np.zeros(5), 0.1, np.zeros((5, 5, 3), np.uint8))
    with pytest.raises(InputError):
        render_tactile_image(np.zeros((5, 5)), 0.0, np.zeros((5, 5, 3), np.uint8))


def test_render_with_calibration_path_is_cached(tmp_path):
    from vtrack.tactile import render
    from vtrack.tactile.calibration import lambertian_calibration

    bg = np.full((60, 80, 3), 120, np.uint8)
    p = lambertian_calibration(bg, 0.1).save(tmp_path / "c.npz")
    h = _sphere(60, 80, 20.0, 5.0)
    a = render_tactile_image(h, 0.1, bg, calib=p)
    b = render_tactile_image(h, 0.1, bg, calib=str(p))
    assert np.array_equal(a, b) and len(render._CALIB_CACHE) >= 1
    # the calibration's inverse table of the Lambertian model reproduces the analytic Lambertian render
    c = render_tactile_image(h, 0.1, bg)
    assert np.abs(a.astype(int) - c).mean() < 2.0
    with pytest.raises(InputError, match="not found"):
        render_tactile_image(h, 0.1, bg, calib=tmp_path / "missing.npz")
