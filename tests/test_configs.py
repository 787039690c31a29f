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
