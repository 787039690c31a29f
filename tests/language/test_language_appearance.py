"""vtrack.language correlated-appearance study: training texts whose colour / shape words belong to the material
(a given sample always looks the same), held-out texts written with another appearance, and the steering
evaluation over it (strength chosen on the validation contacts)."""

from __future__ import annotations

import numpy as np
import pytest

from vtrack.testing.language import LANGUAGE_EXTRA_MISSING, have_language_extra, procedural_set

needs_extra = pytest.mark.skipif(not have_language_extra(), reason=LANGUAGE_EXTRA_MISSING)


def _clause(t: str) -> str:
    return t.rsplit("it looks ", 1)[1]


def test_instance_and_other_appearance_texts() -> None:
    """'instance': every contact of a material carries the material's own colour / shape pair, and the 20
    materials' pairs differ; 'other': never the material's own pair; 'random' is the canonical text set."""
    from vtrack.errors import InputError
    from vtrack.language.materials import instance_appearance

    data = procedural_set(per_material=4, n_materials=20)
    own = instance_appearance(data.materials)
    inst = data.texts(seed=5, appearance="instance")
    other = data.texts(seed=5, appearance="other")
    by_mat: dict[int, set[str]] = {}
    for m, t in zip(data.material, inst, strict=True):
        by_mat.setdefault(int(m), set()).add(_clause(t))
        assert _clause(t) == f"{own[int(m)][0]} and {own[int(m)][1]}."
    assert all(len(v) == 1 for v in by_mat.values())
    assert len({next(iter(v)) for v in by_mat.values()}) == 20
    for m, t in zip(data.material, other, strict=True):
        assert _clause(t) != f"{own[int(m)][0]} and {own[int(m)][1]}."
    assert len({_clause(t) for t in other}) > 20  # drawn per contact, not per material
    # the tactile part is the same text whatever the appearance, and 'random' is the canonical set
    assert [t.rsplit(". it looks", 1)[0] for t in inst] == [t.rsplit(". it looks", 1)[0] for t in other]
    assert data.texts(seed=5, appearance="random") == data.texts(seed=5)
    with pytest.raises(InputError):
        data.texts(appearance="blue")


@needs_extra
def test_correlated_training_and_steering_evaluation_on_a_tiny_set() -> None:
    """A model trained on instance-appearance texts (describer targets with the clause) and the study's
    evaluation: strength 0 of every validation sweep is the unsteered validation R@1, the chosen strengths come
    from the grids, the random-direction share is a fraction and the describer names a colour / shape."""
    import torch

    from vtrack.language.appearance import (
        GENERATION_ALPHAS,
        RETRIEVAL_ALPHAS,
        steering_correlated,
        trained_design_rows,
    )
    from vtrack.language.model import Steering, train

    torch.set_num_threads(1)
    per, n_mat = 8, 6
    rng = np.random.default_rng(0)
    # a per-material pattern plus noise, so the images carry the material
    base = rng.normal(0, 0.5, (n_mat, 3, 60, 80)).astype(np.float32)
    imgs = np.repeat(base, per, 0) + rng.normal(0, 0.1, (n_mat * per, 3, 60, 80)).astype(np.float32)
    data = procedural_set(per_material=per, n_materials=n_mat, images=imgs)
    data.split = np.where(data.contact < 4, "train", np.where(data.contact < 6, "val", "test"))
    model = train(data, steering=Steering("none"), epochs=3, batch=8, seed=0, appearance="instance", lm_appearance=True)
    assert model.meta["appearance"] == "instance" and model.meta["max_len"] > 24
    assert {"red", "blue", "square", "round"} <= set(model.vocab)
    r = steering_correlated(model, data, n_random=2)
    for key, rows in r["sweep_val"].items():
        grid = (RETRIEVAL_ALPHAS | GENERATION_ALPHAS)[key.split()[-1].lower()]
        assert [a for a, _ in rows] == list(grid)
        assert r["chosen_on_val"][key] in grid
        if key.split()[-1] in ("P1", "PRE", "P1W"):
            assert rows[0][1] == pytest.approx(r["val_none_r1"])
    for pos in ("P1", "PRE", "P1W", "P4", "P3"):
        assert 0.0 <= r["test"][f"A-N {pos}"]["share_random_at_least_as_good"] <= 1.0
        assert r["test"][f"random {pos}"]["n"] == 2
    none = r["none"]
    for row in ("other_appearance", "instance_appearance", "no_appearance", "canonical_texts"):
        assert 0.0 <= none[row]["r1"] <= 1.0 and np.isfinite(none[row]["silhouette"])
    assert 0.0 <= r["attention_on_appearance"] <= 1.0
    assert 0.0 <= none["generation"]["appearance_share"] <= 1.0
    # the trained-design rows score the model as it is (its own steering: none here), on the same texts
    rows = trained_design_rows(model, data)
    assert rows["other_appearance"]["r1"] == pytest.approx(none["other_appearance"]["r1"])
    assert rows["generation"]["bleu1"] == pytest.approx(none["generation"]["bleu1"])
