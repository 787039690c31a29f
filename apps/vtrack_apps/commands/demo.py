"""``vtrack demo``: the main job on the embedded default scene."""

from __future__ import annotations

from pathlib import Path

import typer


def register(app: typer.Typer) -> None:
    @app.command("demo")
    def demo(
        scene: Path = typer.Option(
            None, "--scene", help="scene YAML (default: the embedded scene vtrack/assets/scenes/default.yaml)"
        ),
        out: Path = typer.Option(Path("results/demo"), "--out", help="results folder"),
        seconds: float = typer.Option(None, "--seconds", help="override the session length (s)"),
        json_out: Path = typer.Option(None, "--json", help="also write the summary to this JSON file"),
    ) -> None:
        """Generate a session from the scene, reconstruct and track the object, write results."""
        from vtrack.demo import run_demo
        from vtrack_apps.output import report

        summary = run_demo(scene, out, seconds=seconds)
        flat = {
            "scene": summary["scene"],
            "components": summary["components"],
            "modalities": summary["modalities"],
            "seconds_total": summary["seconds_total"],
        }
        for stage, res in summary["stages"].items():
            if isinstance(res, dict):
                for k in (
                    "blind",
                    "fscore",
                    "chamfer_mm",
                    "motion_err_mm",
                    "drift_mm",
                    "add_s_mm",
                    "poses_per_s",
                    "seconds",
                    "session",
                ):
                    if k in res:
                        flat[f"{stage}.{k}"] = res[k]
        report("vtrack demo", flat, json_out)
        typer.echo(f"results written to {out}")
