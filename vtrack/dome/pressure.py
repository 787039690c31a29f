"""Is the internal pressure observable from the image? Oracle floor and a confined-inflation ablation (#26).

The simulator's force is ``F = -n (k_n(P) V + P A) + k_t A s`` with ``k_n(P) = k0 (1 + 4 P / P_max)``
(:mod:`vtrack.dome.simulate`), and the press is displacement-controlled: the deformation does not depend on
P. So an estimator that reads the deformation (V, A, n, s) *exactly* but cannot see P can do no better than
guessing the median pressure; :func:`oracle_force_floor` computes that floor on a test set (evaluation code:
it replays the simulator's press parameters, never used by the pipeline). A no-pressure net that beats the
floor must be reading P from its inputs - here the radial inflation of the shell (0.03 mm/kPa, a common-mode
marker shift of ~0.19 px at 10 kPa, visible also in the at-pressure reference frame).

:func:`pressure_ablation` retrains the GNN + patch force nets with and without P (same recipe, same frozen
shipped reconstruction GNN) on data simulated with a different inflation, e.g. 0 (a double shell that confines
the inflation of the pressurised inner layer, FusionTouch S3): there P is unobservable from the image, the
no-pressure net must stay above the floor and the with/without gap shows what the pressure input is worth.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from vtrack.dome.model import DomeConfig


def replay_presses(n: int, seed: int, cfg: DomeConfig) -> list:
    """The :class:`Press` parameters of ``make_dataset(n, seed, cfg)`` (same random stream)."""
    from vtrack.dome.simulate import DomeSimulator, sample_press

    sim = DomeSimulator(cfg)
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        press = sample_press(rng, cfg)
        sim.sample(rng, press)  # advances the stream exactly as make_dataset does
        out.append(press)
    return out


def _force_terms(press, sim) -> tuple[np.ndarray, float, float, np.ndarray]:
    """(inward normal n, indentation volume V mm^3, contact area A mm^2, tangential force N) of one press."""
    from vtrack.dome.simulate import KT_N_PER_MM3, _profile, _tangent_basis

    c = sim.cfg
    if press.shape == "none":
        return np.zeros(3), 0.0, 0.0, np.zeros(3)
    n = press.direction
    e1, e2 = _tangent_basis(n)
    p = sim.geo.dense_dirs * c.radius_mm
    rel = p - n * c.radius_mm
    h = _profile(press.shape, rel @ e1, rel @ e2, press.size_mm, press.angle_rad)
    delta = np.clip(press.depth_mm - (c.radius_mm - p @ n) - h, 0.0, None)
    delta[sim.geo.dense_dirs[:, 2] < np.cos(np.deg2rad(c.cap_deg)) - 1e-9] = 0.0
    vol = float(delta.sum() * sim.area_per_src)
    area = float((delta > 0).sum() * sim.area_per_src)
    shear = press.shear_mm[0] * e1 + press.shear_mm[1] * e2
    return n, vol, area, KT_N_PER_MM3 * area * shear


def force_metrics(pred: np.ndarray, gt: np.ndarray) -> dict[str, float]:
    """Table S6 columns: overall MAE / RMSE and per-axis MAE (N)."""
    e = np.asarray(pred, np.float64) - np.asarray(gt, np.float64)
    a = np.abs(e)
    return {
        "mae": float(a.mean()),
        "rmse": float(np.sqrt((e**2).mean())),
        "mae_fx": float(a[:, 0].mean()),
        "mae_fy": float(a[:, 1].mean()),
        "mae_fz": float(a[:, 2].mean()),
    }


def oracle_force_floor(n: int = 300, seed: int = 12345, cfg: DomeConfig | None = None) -> dict:
    """Force error (N) of estimators that know the deformation exactly: with the true P (0 up to float error)
    and without it (P guessed as the median of U(0, P_max), the MAE-optimal guess since P is drawn
    independently of the press). The latter is a floor for any no-pressure estimator whose inputs do not show P.
    Also checks that the replayed forces equal the dataset's labels."""
    from vtrack.dome.simulate import K0_N_PER_MM3, TENSION_GAIN, DomeSimulator, make_dataset

    cfg = cfg or DomeConfig()
    sim = DomeSimulator(cfg)
    terms = [_force_terms(p, sim) for p in replay_presses(n, seed, cfg)]
    data = make_dataset(n, seed, cfg)
    F = np.asarray(data["force_n"], np.float64)
    u = np.asarray(data["pressure_kpa"], np.float64) / cfg.pressure_max_kpa

    def forces(uh: np.ndarray) -> np.ndarray:
        return np.array(
            [
                -nn * (K0_N_PER_MM3 * (1 + TENSION_GAIN * x) * v + 1e-3 * cfg.pressure_max_kpa * x * a) + ft
                for (nn, v, a, ft), x in zip(terms, uh, strict=True)
            ]
        )

    exact = forces(u)
    if np.abs(exact - F).max() > 1e-4:
        raise RuntimeError("replayed presses do not reproduce the dataset's forces (simulator changed?)")
    return {
        "oracle_with_p": force_metrics(exact, F),
        "oracle_no_p": force_metrics(forces(np.full_like(u, 0.5)), F),
        "zero_force": force_metrics(np.zeros_like(F), F),
    }


def pressure_ablation(
    inflation_mm_per_kpa: float = 0.0,
    n_train: int = 2000,
    n_test: int = 300,
    epochs: int = 12,
    seed: int = 0,
    test_seed: int = 12345,
    log=print,
) -> dict:
    """Retrain the shipped GNN's force nets (``patch_graph``, with / without P; same recipe as the shipped ones,
    reconstruction GNN frozen) on data simulated with ``inflation_mm_per_kpa``; Table S6 metrics on the held-out
    set and the oracle floor of that set. Training data go to ``vtrack.paths.cache_dir()``."""
    import torch

    from vtrack.dome.bundle import bundle_train_config, load_bundle, read_bundle
    from vtrack.dome.model import DomeGeometry
    from vtrack.dome.reconstruct import default_weights
    from vtrack.dome.simulate import make_dataset
    from vtrack.dome.train import Batcher, predict, train_spec_force

    torch.set_num_threads(1)
    path = default_weights("gnn")
    model, _, cfg0, _ = load_bundle(path, with_heads=False)
    cfg = dataclasses.replace(cfg0, inflation_mm_per_kpa=float(inflation_mm_per_kpa))
    tc = dataclasses.replace(
        bundle_train_config(read_bundle(path)), n_train=n_train, epochs_force_net=epochs, seed=seed
    )
    geo = DomeGeometry(cfg)
    tr, te = make_dataset(n_train, seed, cfg, progress=True), make_dataset(n_test, test_seed, cfg)
    btr = Batcher("gnn", tr, geo, f"{n_train}-{seed}-{cfg.to_dict()}")
    bte = Batcher("gnn", te, geo, f"{n_test}-{test_seed}-{cfg.to_dict()}")
    heads = train_spec_force(model, "gnn", btr, tc, log, keys=("p", "nop"))
    pred = predict(model, heads, bte)
    gt = np.asarray(te["force_n"])
    res = {
        "inflation_mm_per_kpa": float(inflation_mm_per_kpa),
        "n_train": n_train,
        "n_test": n_test,
        "epochs": epochs,
        "gnn_patch_with_p": force_metrics(pred["force"], gt),
        "gnn_patch_no_p": force_metrics(pred["force_nop"], gt),
        **oracle_force_floor(n_test, test_seed, cfg),
    }
    res["gain_with_p"] = 1.0 - res["gnn_patch_with_p"]["mae"] / res["gnn_patch_no_p"]["mae"]
    return res
