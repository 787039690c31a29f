"""``vtrack bench``: speed-against-error benchmarks written to ``--out`` (default results/benchmarks)."""

from __future__ import annotations

import importlib
from pathlib import Path

import typer

from vtrack.bench import STAGES
from vtrack.errors import VtrackError


def register(app: typer.Typer) -> None:
    @app.command("bench")
    def bench(
        stage: str = typer.Argument("all", help=" | ".join([*STAGES, "all"])),
        quick: bool = typer.Option(False, "--quick", help="fewer operating points and frames (< 3 min total)"),
        out: Path = typer.Option(
            None,
            "--out",
            help="output folder (default results/benchmarks under the current folder; "
            "docs/benchmarks refreshes the repository's tables)",
        ),
        seeds: str = typer.Option(
            None,
            "--seeds",
            help="simulator seeds of the session benchmarks tracking, heavy, speed and fusion, e.g. 0,1,2 (default 0): "
            "per-seed means over objects, then their mean and sd over seeds",
        ),
    ) -> None:
        """Run stage benchmarks: error against ms at several operating points, Pareto plot per stage."""
        import os

        from vtrack.bench import STAGES
        from vtrack.bench.harness import write_results
        from vtrack_apps.output import print_table

        if out is not None:
            os.environ["VTRACK_BENCH_DIR"] = str(out)
        if seeds is not None:
            from vtrack.bench.harness import bench_seeds

            os.environ["VTRACK_BENCH_SEEDS"] = seeds
            bench_seeds()  # a bad list fails here, before any stage runs
        names = list(STAGES) if stage == "all" else [stage]
        for name in names:
            if name not in STAGES:
                raise VtrackError(f"unknown benchmark stage '{name}' (choose from {', '.join(STAGES)} or all)")
        for name in names:
            try:
                mod = importlib.import_module(STAGES[name])
            except ModuleNotFoundError as e:
                if stage == "all":
                    typer.secho(f"skipping {name}: not available ({e})", fg=typer.colors.YELLOW, err=True)
                    continue
                raise VtrackError(f"benchmark stage '{name}' is not available: {e}") from None
            typer.echo(f"[bench] {name} ({'quick' if quick else 'full'}) ...")
            table = mod.run(quick=quick)
            paths = write_results(table)
            print_table(f"bench {name}", table.rows)
            typer.echo(f"[bench] wrote {', '.join(str(p) for p in paths.values())}")
