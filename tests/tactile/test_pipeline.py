"""TactilePipeline: geometry of contact points, contact statistics, scene construction, real presses."""

import numpy as np
import pytest

from vtrack.errors import InputError
from vtrack.tactile.contact import contact_mask, contact_stats
from vtrack.tactile.pipeline import TactilePipeline
from vtrack.tactile.render import render_tactile_image
from vtrack.tactile.synthetic import sphere_height

S = 0.1  # mm/px


def _press(cx=90.0, cy=50.0, depth_px=6.0, H=120, W=160):
    h = sphere_height(H, W, cx, cy, 40.0, depth_px, S)
    bg = np.full((H, W, 3), 120, np.uint8)
    return h, bg, render_tactile_image(h, S, bg)


@pytest.mark.parametrize("downsample", [1, 2])
def test_points_in_sensor_frame(downsample):
    h, bg, img = _press()
    f = TactilePipeline(None, mm_per_px=S, background=bg, downsample=downsample).process(img)
    assert f.in_contact and f.points.shape[1] == 3 and f.points.shape == f.normals.shape
    # centroid of the contact points sits over the ball centre: x = (90 - 79.5) * 0.1 mm, y = (50 - 59.5) * 0.1 mm
    c = f.points[:, :2].mean(0)
    assert c[0] == pytest.approx(1.05e-3, abs=0.15e-3)
    assert c[1] == pytest.approx(-0.95e-3, abs=0.15e-3)
    assert f.points[:, 2].max() < 0  # indentation is into the gel: z = -h
    assert -f.points[:, 2].min() == pytest.approx(h.max() / 1000, rel=0.15)
    assert np.allclose(np.linalg.norm(f.normals, axis=1), 1.0)
    # normals tilt away from the centre (outward normal of the ball surface as seen from the gel)
    d = f.points[:, :2] - c
    far = np.linalg.norm(d, axis=1) > 1.5e-3
    assert (np.sum(f.normals[far, :2] * d[far], axis=1) < 0).mean() > 0.9
    assert f.height_mm.shape == (120, 160) and f.contact.shape == (120, 160)


def test_contact_stats_of_ellipse():
    H, W = 100, 120
    yy, xx = np.mgrid[0:H, 0:W]
    m = ((xx - 60) / 30.0) ** 2 + ((yy - 50) / 10.0) ** 2 < 1
    h = np.where(m, 0.3, 0.0)
    mask = contact_mask(h, 0.05)
    assert np.array_equal(mask, m)
    s = contact_stats(h, mask, 0.1)
    assert s.area_px == m.sum() and s.area_mm2 == pytest.approx(np.pi * 3 * 1, rel=0.03)
    assert s.centroid_px == pytest.approx((60, 50), abs=0.01)
    assert s.axes_px[0] == pytest.approx(30, rel=0.05) and s.axes_px[1] == pytest.approx(10, rel=0.05)
    assert abs(np.sin(s.angle_rad)) < 1e-6
    assert s.max_depth_mm == pytest.approx(0.3)


def test_contact_mask_threshold_noise_aware():
    h = np.full((20, 20), 0.08)
    assert contact_mask(h, 0.05).all()
    assert not contact_mask(h, 0.05, noise_mm=0.03).any()  # 3 sigma = 0.09 mm > 0.08


def test_from_scene_default():
    from vtrack.paths import default_scene_path
    from vtrack.registry import build
    from vtrack.scene import load_scene

    scene = load_scene(default_scene_path())
    p = build("tactile", scene)
    assert isinstance(p, TactilePipeline)
    assert set(p.sensors) == {t.name for t in scene.tactile if t.type != "dome"}
    spec = scene.tactile[0]
    assert p.image_shape == (spec.height, spec.width) and p.mm_per_px == spec.mm_per_px
    h = sphere_height(spec.height, spec.width, spec.width / 2, spec.height / 2, 30, 5, spec.mm_per_px)
    bg = np.full((spec.height, spec.width, 3), 110, np.uint8)
    p.set_background(bg)
    f = p.process(render_tactile_image(h, spec.mm_per_px, bg))
    assert f.stats.max_depth_mm == pytest.approx(h.max(), rel=0.15)
    # multi-sensor dispatch: process(sensor_name, image). A synthetic scene (``sim`` section, no background
    # file) uses the simulator's background, so a session that starts in contact still works.
    other = scene.tactile[1].name
    bg2 = p.for_sensor(other).background
    assert bg2 is not None and bg2.shape == (spec.height, spec.width, 3)
    from vtrack.tactile.sensors import default_background

    t1 = scene.tactile[1]
    assert np.array_equal(bg2, default_background(t1.type, t1.width, t1.height, t1.background))
    assert not p.process(other, bg2).in_contact
    f2 = p.process(other, render_tactile_image(h, spec.mm_per_px, bg2))
    assert f2.stats.max_depth_mm == pytest.approx(h.max(), rel=0.15)
    assert f2.stats.centroid_px == pytest.approx((spec.width / 2, spec.height / 2), abs=2.0)
    with pytest.raises(InputError):
        TactilePipeline.from_scene(scene, sensor_name="nope")


def test_real_press_contact_matches_label(gelsight_set, mlp_calib):
    pipe = TactilePipeline(mlp_calib, downsample=2)
    ps = gelsight_set
    press = ps.presses[7]  # held out
    f = pipe.process(ps.image(press))
    cx, cy = press.center_xy_px
    assert f.stats.centroid_px == pytest.approx((cx, cy), abs=6.0)
    # contact region: the labelled disc plus the gel's smooth skirt
    r_eq = np.sqrt(f.stats.area_px / np.pi)
    assert press.contact_radius_px * 0.9 < r_eq < press.contact_radius_px * 1.6
    assert 0.8 < f.stats.max_depth_mm < 2.5


@pytest.mark.parametrize("solver", ["dct", "fft", "lsq"])
def test_solvers_in_pipeline(solver):
    h, bg, img = _press()
    f = TactilePipeline(None, mm_per_px=S, background=bg, solver=solver).process(img)
    assert f.stats.max_depth_mm == pytest.approx(h.max(), rel=0.1)
    assert np.abs(f.height_mm[h == 0]).max() < 0.1 * h.max()
    with pytest.raises(InputError):
        TactilePipeline(None, mm_per_px=S, solver="bogus")


def test_auto_downsample_follows_the_benchmark_operating_points():
    """The default working resolution is picked from the image size (Pareto front of `vtrack bench tactile`)."""
    from vtrack.tactile.pipeline import auto_downsample

    assert auto_downsample((120, 160)) == 1
    assert auto_downsample((240, 320)) == 2 and auto_downsample((320, 240)) == 2  # GelSight Mini, DIGIT
    assert auto_downsample((480, 640)) == 4
    bg = np.full((240, 320, 3), 120, np.uint8)
    pipe = TactilePipeline(None, mm_per_px=0.06, background=bg)
    assert pipe.downsample == 2
    assert TactilePipeline(None, mm_per_px=0.06, background=bg, downsample=1).downsample == 1
    with pytest.raises(InputError, match="downsample"):
        TactilePipeline(None, mm_per_px=0.06, background=bg, downsample="fast")
