"""``vtrack generate``: synthetic in-hand visuo-tactile sessions with ground truth."""

from __future__ import annotations

from enum import StrEnum
from pathlib import Path

import typer


class Occlusion(StrEnum):
    none = "none"
    medium = "medium"
    heavy = "heavy"


def register(app: typer.Typer) -> None:
    @app.command("generate")
    def generate(
        scene: Path = typer.Argument(..., help="scene YAML (e.g. scenes/occlusion_none.yaml)"),
        out: Path = typer.Option(..., "--out", "-o", help="session directory to write"),
        object_mesh: Path = typer.Option(None, "--object", help="override the object: watertight mesh in metres"),
        seconds: float = typer.Option(None, "--seconds", help="duration, s (default: scene sim.seconds)"),
        seed: int = typer.Option(None, "--seed", help="random seed (same seed -> same session)"),
        occlusion: Occlusion = typer.Option(None, "--occlusion", help="camera view: none|medium|heavy"),
        force: bool = typer.Option(False, "--force", help="replace an existing session directory"),
        quiet: bool = typer.Option(False, "--quiet", help="no progress output"),
    ) -> None:
        """Generate a synthetic session (RGB-D, tactile, joints, ground truth) from a scene."""
        import time

        from vtrack.io.session import open_session
        from vtrack.sim.generate import generate_session
        from vtrack_apps.output import report

        t0 = time.perf_counter()
        path = generate_session(
            scene,
            out,
            seconds=seconds,
            seed=seed,
            occlusion=occlusion.value if occlusion is not None else None,
            object_mesh=object_mesh,
            overwrite=force,
            progress=not quiet,
        )
        r = open_session(path)
        rows = [
            {"stream": k, "frames": v["frames"], "duration_s": round(v["duration_s"], 3)}
            for k, v in r.summary().items()
        ]
        report(f"session {path} ({time.perf_counter() - t0:.1f} s)", rows, None)
