"""``vtrack bench generate_downstream`` table assembly (the studies themselves train for minutes: bench only)."""

from __future__ import annotations

import pytest

from vtrack.bench.generate_downstream import build_table


def test_build_table_maps_each_part_to_its_error_column():
    cls = [{"method": "CNN, generated", "train": "4/object", "test": "t", "steps": 5, "seeds": 1, "accuracy": 0.3,
            "accuracy_std": 0.0}]  # fmt: skip
    pose = [{"method": "centroid", "train": "none", "test": "t", "seeds": 1, "x_err_px": 3.0, "y_err_px": 4.0,
             "xy_err_px": 5.0}]  # fmt: skip
    force = [{"method": "depth response", "train": "24 real", "test": "t", "seeds": 1, "slope": 0.5,
              "bias_mm": 0.1, "depth_mae_mm": 0.07}]  # fmt: skip
    t = build_table(cls, pose, force)
    assert t.stage == "generate_downstream" and len(t.rows) == 3
    errs = {r["method"].split(":")[0]: r["error"] for r in t.rows}
    assert errs == {"classify": pytest.approx(0.7), "pose real": 5.0, "force diag": 0.07}
    assert t.rows[2]["slope"] == 0.5 and "SIMULATED" in t.rows[0]["setting"] and "REAL" in t.rows[1]["setting"]
    assert build_table([], [], []).rows == []
