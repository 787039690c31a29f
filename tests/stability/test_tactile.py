"""Hard cases of the tactile pipeline: degenerate images, noise, drift, bad input, missing files."""

import numpy as np
import pytest

from vtrack.errors import InputError
from vtrack.tactile.pipeline import TactilePipeline
from vtrack.tactile.render import render_tactile_image
from vtrack.tactile.synthetic import sphere_height

pytestmark = pytest.mark.stability

H, W, S = 120, 160, 0.1


def _bg(seed=0):
    rng = np.random.default_rng(seed)
    # a realistic non-uniform background: smooth illumination gradient + texture
    yy, xx = np.mgrid[0:H, 0:W]
    base = np.stack([100 + 0.2 * xx, 130 - 0.1 * yy, 110 + 0.05 * (xx + yy)], -1)
    return np.clip(base + rng.normal(0, 1.0, base.shape), 0, 255).astype(np.uint8)


def _pipe(bg, **kw):
    return TactilePipeline(None, mm_per_px=S, background=bg, **kw)


def _finite(f):
    assert np.isfinite(f.height_mm).all() and np.isfinite(f.points).all() and np.isfinite(f.normals).all()


def test_no_contact():
    bg = _bg()
    f = _pipe(bg).process(bg)
    _finite(f)
    assert not f.in_contact and len(f.points) == 0 and f.points.shape == (0, 3)
    assert np.abs(f.height_mm).max() < 0.01


def test_full_frame_contact():
    bg = _bg()
    yy, xx = np.mgrid[0:H, 0:W]
    h = 0.5 + 0.3 * np.sin(xx / 9.0) * np.sin(yy / 11.0)  # the whole gel pressed by a textured plate
    img = render_tactile_image(h, S, bg)
    f = _pipe(bg, contact_rel=0.0).process(img)
    _finite(f)
    # the mean plate depth is unobservable from slopes; the relief (peak to valley 0.6 mm) must come back
    rel = f.height_mm - f.height_mm.mean()
    assert np.corrcoef(rel.ravel(), (h - h.mean()).ravel())[0, 1] > 0.9
    assert np.ptp(rel) == pytest.approx(0.6, rel=0.25)


def test_tiny_contact():
    bg = _bg()
    h = sphere_height(H, W, 70.3, 40.6, 3.0, 1.5, S)  # ~ 5 px wide contact
    f = _pipe(bg, contact_threshold_mm=0.02).process(render_tactile_image(h, S, bg))
    _finite(f)
    assert f.in_contact and 1 <= f.stats.area_px <= 40
    assert f.stats.centroid_px == pytest.approx((70.3, 40.6), abs=1.5)


@pytest.mark.parametrize("value,quality", [(255, "saturated"), (0, "dark")])
def test_saturated_and_dark_images(value, quality):
    bg = _bg()
    f = _pipe(bg).process(np.full((H, W, 3), value, np.uint8))
    _finite(f)
    assert f.quality == quality and not f.in_contact


def test_partially_saturated_press_is_finite():
    bg = _bg()
    h = sphere_height(H, W, 80, 60, 40, 8, S)
    img = render_tactile_image(h, S, bg, gain=400.0)  # clips to 0/255 inside the contact
    f = _pipe(bg).process(img)
    _finite(f)
    assert f.quality == "ok" and f.in_contact


def test_sensor_noise():
    bg = _bg()
    h = sphere_height(H, W, 80, 60, 40, 6, S)
    rng = np.random.default_rng(3)
    f0 = _pipe(bg).process(render_tactile_image(h, S, bg))
    f = _pipe(bg).process(render_tactile_image(h, S, bg, rng=rng, noise_std=4.0))
    _finite(f)
    assert f.stats.max_depth_mm == pytest.approx(f0.stats.max_depth_mm, rel=0.15)
    assert f.stats.centroid_px == pytest.approx(f0.stats.centroid_px, abs=2.0)
    # noise alone makes no contact
    noise_only = np.clip(bg + rng.normal(0, 4.0, bg.shape), 0, 255).astype(np.uint8)
    assert _pipe(bg).process(noise_only).stats.area_px < 20


def test_background_drift_is_compensated():
    bg = _bg()
    h = sphere_height(H, W, 80, 60, 40, 6, S)
    img = render_tactile_image(h, S, bg)
    drifted = np.clip(img.astype(int) + [12, -9, 6], 0, 255).astype(np.uint8)  # lighting changed
    f0 = _pipe(bg).process(img)
    f = _pipe(bg).process(drifted)
    assert f.drift == pytest.approx((12, -9, 6), abs=1)
    assert f.stats.max_depth_mm == pytest.approx(f0.stats.max_depth_mm, rel=0.1)
    assert f.stats.area_px == pytest.approx(f0.stats.area_px, rel=0.2)
    fo = _pipe(bg, drift_compensation=False).process(drifted)
    assert abs(fo.stats.max_depth_mm - f0.stats.max_depth_mm) > abs(f.stats.max_depth_mm - f0.stats.max_depth_mm)


def test_nan_inf_in_inputs():
    bg = _bg()
    h = sphere_height(H, W, 80, 60, 40, 6, S)
    img = render_tactile_image(h, S, bg).astype(np.float32)
    img[10:20, 10:20] = np.nan
    img[50, :] = np.inf
    img[60, :5] = -np.inf
    f = _pipe(bg).process(img)
    _finite(f)
    assert f.in_contact
    hn = h.copy()
    hn[0, 0] = np.nan
    assert render_tactile_image(hn, S, bg).dtype == np.uint8
    from vtrack.tactile.poisson import integrate

    g = np.full((8, 8), np.nan)
    assert np.isfinite(integrate(g, g, "dct")).all() and np.isfinite(integrate(g, g, "lsq")).all()


def test_wrong_image_size_is_a_clear_error():
    bg = _bg()
    p = _pipe(bg)
    with pytest.raises(InputError, match="120x160"):
        p.process(np.zeros((240, 320, 3), np.uint8))
    with pytest.raises(InputError, match=r"\(H, W, 3\)"):
        p.process(np.zeros((H, W, 4), np.uint8))


def test_wrong_size_against_calibration(lut_calib_small):
    with pytest.raises(InputError, match="differs from the sensor calibration"):
        TactilePipeline(lut_calib_small).process(np.zeros((10, 10, 3), np.uint8))


@pytest.fixture(scope="module")
def lut_calib_small(tmp_path_factory):
    """A real LUT calibration on a few presses of the small Taxim pack (converted to a press set)."""
    from vtrack.paths import shared_data_dir

    src = shared_data_dir() / "taxim_datapack_small" / "dataPack_small.npz"
    if not src.is_file():
        pytest.skip("shared taxim_datapack_small not found")
    import importlib.util

    from vtrack.paths import REPO_ROOT
    from vtrack.tactile.calibration import calibrate
    from vtrack.tactile.pressset import load_press_set

    spec = importlib.util.spec_from_file_location("conv", REPO_ROOT / "data_tools" / "convert_taxim_npz.py")
    conv = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(conv)
    ps = load_press_set(conv.convert(src, tmp_path_factory.mktemp("small")))
    return calibrate(ps, "lut", ps.presses[:6])


def test_missing_files_are_clear_errors(tmp_path):
    from vtrack.tactile.calibration import Calibration
    from vtrack.tactile.pressset import load_press_set, read_bgr

    with pytest.raises(InputError, match="calibration file not found"):
        Calibration.load(tmp_path / "nope.npz")
    with pytest.raises(InputError, match="image file not found"):
        read_bgr(tmp_path / "nope.png")
    with pytest.raises(InputError, match="press-set folder not found"):
        load_press_set(tmp_path / "nope")
    with pytest.raises(InputError, match="calibration file not found"):
        TactilePipeline(tmp_path / "nope.npz")
    (tmp_path / "x.png").write_bytes(b"garbage")
    with pytest.raises(InputError, match="cannot decode"):
        read_bgr(tmp_path / "x.png")


def test_cli_errors_are_one_line(tmp_path):
    import subprocess
    import sys

    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "vtrack_apps.cli",
            "tactile",
            "eval-presses",
            str(tmp_path / "nope"),
            "--calib",
            str(tmp_path / "c.npz"),
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 2
    assert "press-set folder not found" in r.stderr and "Traceback" not in r.stderr


def test_first_frame_in_contact_is_recovered():
    """Without a background the first frame is the reference; if it was a press, the next flat frame resets it."""
    bg = _bg()
    h = sphere_height(H, W, 80, 60, 40, 6, S)
    press = render_tactile_image(h, S, bg)
    p = TactilePipeline(None, mm_per_px=S)
    assert not p.process(press).in_contact  # nothing to compare with yet
    f = p.process(bg)  # gel released: would look like a dent out of the gel
    assert not f.in_contact and np.abs(f.height_mm).max() < 0.05
    f2 = p.process(press)
    assert f2.in_contact and f2.stats.max_depth_mm == pytest.approx(h.max(), rel=0.15)
