"""Pressure observability (issue #26): the oracle floor without P and the confined-inflation sensor."""

from __future__ import annotations

import dataclasses

import numpy as np

from vtrack.dome.model import DomeConfig
from vtrack.dome.pressure import force_metrics, oracle_force_floor
from vtrack.dome.simulate import DomeSimulator, Press


def test_oracle_floor_reproduces_the_labels_and_bounds_blind_estimators() -> None:
    r = oracle_force_floor(24, 7)  # raises if the replayed presses do not give the dataset's forces
    assert r["oracle_with_p"]["mae"] < 1e-5
    # not knowing P costs a real share of the force, but far less than predicting zero force
    assert 0.1 * r["zero_force"]["mae"] < r["oracle_no_p"]["mae"] < 0.6 * r["zero_force"]["mae"]
    assert r["oracle_no_p"]["mae_fz"] > r["oracle_no_p"]["mae_fx"]  # the normal force carries the P term


def test_force_metrics_columns() -> None:
    gt = np.zeros((2, 3))
    pred = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -2.0]])
    m = force_metrics(pred, gt)
    assert m["mae"] == 0.5 and m["mae_fx"] == 0.5 and m["mae_fz"] == 1.0
    assert m["rmse"] == np.sqrt(5.0 / 6.0)


def test_confined_inflation_makes_the_markers_independent_of_pressure() -> None:
    press = lambda p: Press("sphere", np.array([0.0, 0.0, 1.0]), 1.0, 3.0, 0.0, np.zeros(2), p)  # noqa: E731
    for infl, moves in ((0.03, True), (0.0, False)):
        sim = DomeSimulator(dataclasses.replace(DomeConfig(), inflation_mm_per_kpa=infl))
        a, b = (sim.deform(press(p)) for p in (0.0, 10.0))
        shift = np.abs(a["disp_markers"] - b["disp_markers"]).max()
        assert (shift > 0.1) == moves
        assert b["force"][2] < a["force"][2] < 0  # the same deformation pushes harder at 10 kPa either way
