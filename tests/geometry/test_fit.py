"""Sphere / circle fits: exact recovery, outlier rejection, degenerate sets."""

from __future__ import annotations

import numpy as np
import pytest

from vtrack.errors import InputError
from vtrack.geometry.fit import fit_sphere, robust_sphere


def _cap(n, centre, radius, half_angle_deg, noise, rng):
    """n points on the cap of half-angle ``half_angle_deg`` about +z of a sphere, with Gaussian noise (m)."""
    z = rng.uniform(np.cos(np.radians(half_angle_deg)), 1.0, n)
    phi = rng.uniform(0, 2 * np.pi, n)
    s = np.sqrt(1 - z * z)
    u = np.column_stack([s * np.cos(phi), s * np.sin(phi), z])
    return centre + (radius + rng.normal(0, noise, n))[:, None] * u


def test_fit_sphere_recovers_an_exact_sphere_and_circle():
    rng = np.random.default_rng(0)
    c = np.array([0.1, -0.2, 0.05])
    P = _cap(200, c, 0.036, 70, 0.0, rng)
    cf, r = fit_sphere(P)
    assert np.allclose(cf, c, atol=1e-9) and r == pytest.approx(0.036, abs=1e-9)
    t = rng.uniform(0, np.pi, 50)
    (cx, cy), r2 = fit_sphere(np.column_stack([3 + 7 * np.cos(t), -1 + 7 * np.sin(t)]))
    assert (cx, cy, r2) == pytest.approx((3, -1, 7), abs=1e-9)


def test_robust_sphere_ignores_a_fifth_of_outliers():
    rng = np.random.default_rng(1)
    c = np.array([-0.027, 0.004, -0.014])
    P = _cap(800, c, 0.0365, 60, 0.0003, rng)
    P[:160] = c + rng.uniform(-0.03, 0.03, (160, 3))  # 20 % far off
    c_plain, r_plain = fit_sphere(P)
    cr, rr, rms, keep = robust_sphere(P, floor=0.001)
    assert np.linalg.norm(cr - c) < 0.001 and abs(rr - 0.0365) < 0.001  # outliers near the shell stay in
    assert rms < 0.0005
    assert keep[160:].mean() > 0.97 and keep[:160].mean() < 0.2
    # the plain fit is pulled by the outliers: the robust one is what makes the difference
    assert abs(r_plain - 0.0365) > 3 * abs(rr - 0.0365)


def test_degenerate_sets_give_an_infinite_radius_or_a_clear_error():
    rng = np.random.default_rng(2)
    plane = np.column_stack([rng.uniform(-1, 1, (50, 2)), np.zeros(50)])
    _, r = fit_sphere(plane)
    assert not np.isfinite(r)
    c, r, rms, keep = robust_sphere(np.zeros((10, 3)), floor=0.001)
    assert not np.isfinite(r) and np.isnan(rms) and np.isfinite(c).all()
    with pytest.raises(InputError, match="points"):
        fit_sphere(np.array([[0.0, 0.0, np.nan]] * 5))
    with pytest.raises(InputError, match="points"):
        fit_sphere(np.zeros((3, 3)))
