"""Several tactile frames through their sensors' pipelines at once (the four DIGIT of a hand at one time step):
exactly the values of one by one, whatever mix of sensors, drift, bad frames and solvers."""

import numpy as np
import pytest

from vtrack.errors import InputError
from vtrack.tactile.calibration import drift_offset, drift_offsets
from vtrack.tactile.pipeline import TactilePipeline, contact_only_many
from vtrack.tactile.poisson import poisson_dct, poisson_dct_stack
from vtrack.tactile.render import render_tactile_image
from vtrack.tactile.synthetic import sphere_height

S = 0.1  # mm/px
H, W = 120, 160


def _frames():
    """Four sensors (different backgrounds): a press with a colour drift, a press, free gel, a dark frame."""
    rng = np.random.default_rng(3)
    bgs = [np.clip(rng.normal(120 + 10 * k, 2.0, (H, W, 3)), 0, 255).astype(np.uint8) for k in range(4)]
    imgs = []
    for k, bg in enumerate(bgs):
        h = sphere_height(H, W, 60.0 + 15 * k, 50.0 + 5 * k, 40.0, 6.0, S) if k < 2 else np.zeros((H, W))
        img = render_tactile_image(h, S, bg)
        noise = rng.normal(0.0, 1.5, img.shape)
        if k == 0:
            noise += np.array([8.0, -5.0, 3.0])  # illumination drift: removed by the drift estimate
        img = np.clip(img + noise, 0, 255).astype(np.uint8)
        imgs.append(np.zeros_like(img) if k == 3 else img)
    return bgs, imgs


def _pipes(bgs, **opts):
    return [TactilePipeline(None, mm_per_px=S, background=bg, sensor_name=f"s{k}", **opts) for k, bg in enumerate(bgs)]


def _same(a, b):
    assert a[2] == b[2] and a[0].shape == b[0].shape
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[1], b[1])


@pytest.mark.parametrize("downsample", [1, 2])
def test_many_frames_at_once_give_the_values_of_one_by_one(downsample):
    bgs, imgs = _frames()
    one = [p.contact_only(im) for p, im in zip(_pipes(bgs, downsample=downsample), imgs, strict=True)]
    assert len(one[0][0]) > 20 and len(one[1][0]) > 20 and len(one[2][0]) == 0 and one[3][2] == "dark"
    pipes = _pipes(bgs, downsample=downsample)
    # a sensor twice (two queued frames of one sensor) and the frames in another order: still frame by frame
    order = [1, 0, 2, 3, 0]
    many = contact_only_many([pipes[k] for k in order], [imgs[k] for k in order])
    for j, k in enumerate(order):
        _same(many[j], one[k])


def test_pipelines_that_cannot_share_run_on_their_own():
    bgs, imgs = _frames()
    ref = [p.contact_only(im) for p, im in zip(_pipes(bgs, solver="lsq"), imgs, strict=True)]
    pipes = _pipes(bgs, solver="lsq")  # another solver: integrated one by one, the rest still shared
    for a, b in zip(contact_only_many(pipes, imgs), ref, strict=True):
        _same(a, b)
    first = TactilePipeline(None, mm_per_px=S, image_shape=(H, W))  # background from its first frame
    assert not first._batchable()
    out = contact_only_many([first, *_pipes(bgs[1:])], [bgs[0], *imgs[1:]])
    assert first.background is not None and len(out[0][0]) == 0 and len(out[1][0]) > 20
    with pytest.raises(InputError):
        contact_only_many(_pipes(bgs), imgs[:2])


def test_stacked_drift_and_poisson_equal_the_single_frame_functions():
    bgs, imgs = _frames()
    offs, levels = drift_offsets(np.stack(imgs), np.stack(bgs))
    for k in range(4):
        o, lv = drift_offset(imgs[k], bgs[k])
        np.testing.assert_array_equal(offs[k], o)
        assert levels[k] == lv
    assert np.abs(offs[0] - [8.0, -5.0, 3.0]).max() < 1.5 and not offs[1].any()  # the drift is found, only there
    # a stack too deep for int16 bin indices (the int64 path), odd sample counts (the median is one sample)
    many, many_bg = np.stack(imgs * 6)[:, :117, :118], np.stack(bgs * 6)[:, :117, :118]
    offs, levels = drift_offsets(many, many_bg)
    for k in range(len(many)):
        o, lv = drift_offset(many[k], many_bg[k])
        np.testing.assert_array_equal(offs[k], o)
        assert levels[k] == lv
    rng = np.random.default_rng(0)
    gx, gy = rng.normal(size=(2, 3, 31, 47)).astype(np.float32)
    z = poisson_dct_stack(gx, gy)
    for k in range(3):
        np.testing.assert_array_equal(z[k], poisson_dct(gx[k], gy[k], dtype=np.float32))
    gx[1, 3, 4] = np.nan  # a non-finite slope is flat there, as for one map
    np.testing.assert_array_equal(poisson_dct_stack(gx, gy)[1], poisson_dct(gx[1], gy[1], dtype=np.float32))
