"""Typed component configs: defaults in one dataclass, options by name over it, a typo is one clear error."""

from __future__ import annotations

import pytest

from vtrack.errors import InputError


def test_tsdf_config_defaults_and_overrides():
    from vtrack.fusion.tsdf import TSDFConfig, TSDFReconstructor

    r = TSDFReconstructor()
    assert r.config == TSDFConfig() and r.voxel_size == 0.002
    r = TSDFReconstructor(TSDFConfig(voxel_size=0.004, touch_weight=5.0), block_count=500)
    assert (r.voxel_size, r.touch_weight, r.config.block_count) == (0.004, 5.0, 500)
    with pytest.raises(InputError, match="unknown TSDF option") as e:
        TSDFReconstructor(voxel_siz=0.004)
    assert e.value.field == "voxel_siz" and "voxel_size" in str(e.value)


def test_neural_sdf_config_and_offline_iterations(monkeypatch):
    from vtrack.fusion.neural_sdf import NeuralSDFConfig, NeuralSDFReconstructor
    from vtrack.fusion.reconstruct import reconstruct_observations

    r = NeuralSDFReconstructor(batch=256)
    assert r.config == NeuralSDFConfig(batch=256) and r.opts["batch"] == 256 and r.opts["hidden"] == 64
    with pytest.raises(InputError, match="unknown neural SDF option"):
        NeuralSDFReconstructor(bach=256)
    # the batch paths pass their options through the same check (a typo is not silently ignored)
    with pytest.raises(InputError, match="lerning_rate"):
        reconstruct_observations([], "neural_sdf", lerning_rate=1e-3)
    with pytest.raises(InputError, match="voxel"):
        reconstruct_observations([], "tsdf", voxel=0.002)


def test_live_consumers_come_from_the_registry(tmp_path):
    from vtrack import registry
    from vtrack.live.consumers import LiveReconstructConfig, NullConsumer, ReconstructConsumer, make_consumer

    assert isinstance(make_consumer("null", tmp_path), NullConsumer)
    assert {k for k in registry.COMPONENTS if k.startswith("live.")} == {"live.null", "live.track", "live.reconstruct"}
    with pytest.raises(InputError, match="unknown live consumer") as e:
        make_consumer("recon", tmp_path)
    assert e.value.expected == "track|reconstruct|null"
    with pytest.raises(InputError, match="unknown live reconstruction option"):
        ReconstructConsumer(tmp_path, voxel=0.01)  # checked before the session is opened
    assert LiveReconstructConfig().voxel_size == 0.004


def test_calibrate_cli_takes_its_defaults_from_train_options(monkeypatch, tmp_path):
    """`vtrack calibrate` once trained a 32-wide MLP while TrainOptions said 64: the CLI now only passes what
    the user gave."""
    from typer.testing import CliRunner
    from vtrack_apps.cli import app

    import vtrack.tactile.calibrate_set as cs
    from vtrack.tactile.calibration import TrainOptions

    seen = []

    def spy(pressset, *, opts, **kw):
        seen.append(opts)
        raise InputError("stop here")

    monkeypatch.setattr(cs, "calibrate_press_set", spy)
    out = str(tmp_path / "c.npz")
    CliRunner().invoke(app, ["calibrate", str(tmp_path), "--out", out, "--method", "mlp"])
    CliRunner().invoke(app, ["calibrate", str(tmp_path), "--out", out, "--method", "mlp", "--mlp-hidden", "16"])
    assert seen == [TrainOptions(), TrainOptions(mlp_hidden=16)]


def test_tactile_config_defaults_and_overrides():
    import numpy as np

    from vtrack.tactile.pipeline import TactileConfig, TactilePipeline

    bg = np.full((48, 64, 3), 120, np.uint8)
    p = TactilePipeline(None, mm_per_px=0.06, background=bg, downsample=2, gate_k=3.0)
    assert p.config == TactileConfig(downsample=2, gate_k=3.0) and (p.downsample, p.gate_k) == (2, 3.0)
    assert TactilePipeline(None, mm_per_px=0.06, config=TactileConfig(solver="fft")).solver == "fft"
    with pytest.raises(InputError, match="unknown tactile pipeline option") as e:
        TactilePipeline(None, mm_per_px=0.06, contact_treshold_mm=0.1)
    assert e.value.field == "contact_treshold_mm"


def test_frames_layer_builds_segmenter_and_tactile_pipelines_through_the_registry(blind_session, monkeypatch):
    from vtrack import registry
    from vtrack.frames.session import SessionFrames

    seen: list[str] = []
    orig = registry.load
    monkeypatch.setattr(registry, "load", lambda key: seen.append(key) or orig(key))
    sf = SessionFrames(blind_session, ("vision", "touch"))
    assert "tactile" in seen and "segmentation" in seen
    assert all(type(c.segmenter).__name__ == "HandAwareSegmenter" for c in sf.cams)


def test_bool_options_refuse_strings_and_numbers():
    import numpy as np

    from vtrack.tracking.slam import SLAMTracker
    from vtrack.tracking.window import TrackerOptions

    # "no" would read as true: refused with the field named
    for bad in ("no", 1, None):
        with pytest.raises(InputError) as e:
            TrackerOptions.from_dict({"anchor_refresh": bad})
        assert e.value.field == "anchor_refresh"
    with pytest.raises(InputError, match="true or false"):
        SLAMTracker(np.eye(4), recover="yes")
    assert TrackerOptions.from_dict({"anchor_refresh": np.bool_(True)}).anchor_refresh
    assert TrackerOptions.from_dict({"recover": False}).recover is False
