"""`vtrack live`'s advice when a run does not keep up (`vtrack.live.pipeline.live_advice`)."""

from __future__ import annotations

from vtrack.live.pipeline import live_advice


def _res(rtf: float, rtf_cpu: float, tactile: float = 0.0, runq: float | None = 6.0) -> dict:
    return {
        "summary": {
            "real_time_factor": rtf,
            "real_time_factor_cpu": rtf_cpu,
            "dropped_tactile_pct": tactile,
            "dropped_camera_pct": 12.5,
            "runq_ms_mean": runq,
        },
        "consumers": {
            "track": {"real_time_factor": rtf, "real_time_factor_cpu": rtf_cpu},
            "track.touch": {"real_time_factor": 3.1, "real_time_factor_cpu": 3.6},
        },
    }


def test_no_advice_when_the_run_keeps_up() -> None:
    assert live_advice(_res(1.3, 1.9)) == []
    assert live_advice({"summary": {}, "consumers": {}}) == []  # a run without figures (nothing replayed)


def test_short_of_cores_and_too_slow_are_told_apart() -> None:
    short = live_advice(_res(0.9, 1.4))
    assert short[0] == "real-time factor 0.9 < 1: worker 'track' cannot keep up (12.5 % of the camera frames dropped)"
    assert "short of cores" in short[1] and "waited 6 ms per step" in short[1]
    assert "--speed 0.5" in short[2] and "vtrack track" in short[2]
    slow = live_advice(_res(0.6, 0.8, runq=None))
    assert "too slow" in slow[1] and not any("short of cores" in s for s in slow)


def test_tactile_drops_are_reported_on_their_own() -> None:
    out = live_advice(_res(1.2, 1.8, tactile=7.25))
    assert len(out) == 1 and out[0].startswith("7.25 % of the tactile frames dropped")
    assert live_advice(_res(1.2, 1.8, tactile=4.9)) == []
