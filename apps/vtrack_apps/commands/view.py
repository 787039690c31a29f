"""``vtrack view``: browser viewer (viser) or offscreen screenshot (pyvista) of a session / result."""

from __future__ import annotations

from pathlib import Path

import typer


def register(app: typer.Typer) -> None:
    @app.command("view")
    def view(
        path: Path = typer.Argument(..., help="session folder, result folder (result.json) or a folder of results"),
        port: int = typer.Option(8080, "--port", help="HTTP/websocket port (next free one if taken; 0 = any)"),
        host: str = typer.Option("127.0.0.1", "--host", help="interface to serve on (0.0.0.0 for other machines)"),
        screenshot: Path = typer.Option(None, "--screenshot", help="render offscreen to this PNG and exit"),
        frame: int = typer.Option(-1, "--frame", help="timeline frame for --screenshot (-1 = last)"),
        size: str = typer.Option("1280x960", "--size", help="screenshot size WxH, px"),
        max_points: int = typer.Option(200_000, "--max-points", help="display budget of cloud points"),
        hdri: bool = typer.Option(False, "--hdri", help="image-based lighting (nicer; slow without a GPU)"),
    ) -> None:
        """Show a session or result in the browser (timeline, clouds, meshes, hand, tactile panels)."""
        from vtrack.errors import InputError

        if max_points < 1:
            raise InputError("must be positive", field="--max-points", got=max_points)
        if screenshot is not None:
            from vtrack.viz.screenshot import parse_size, render_result

            out = render_result(path, screenshot, frame=frame, size=parse_size(size), max_points=max_points)
            typer.echo(f"screenshot written to {out}")
            return
        from vtrack.viz.viewer import serve

        serve(path, host=host, port=port, max_points=max_points, block=True, hdri=hdri)
