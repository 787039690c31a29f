"""``vtrack session``: inspect, validate and export sessions."""

from __future__ import annotations

from pathlib import Path

import typer


def register(app: typer.Typer) -> None:
    session_app = typer.Typer(help="Session folders: info and export.", no_args_is_help=True)
    app.add_typer(session_app, name="session")

    @session_app.command("info")
    def info(
        session: Path = typer.Argument(..., help="session directory"),
        json_out: Path = typer.Option(None, "--json", help="write the summary as JSON"),
    ) -> None:
        """Validate a session and print its streams (frames, duration, measured rate)."""
        from vtrack.io.session import open_session
        from vtrack_apps.output import report

        r = open_session(session)
        rows = [{"stream": k, **{kk: vv for kk, vv in v.items() if kk != "fields"}} for k, v in r.summary().items()]
        if not r.complete:
            typer.secho("note: session was not closed cleanly; showing every committed frame", fg="yellow")
        report(f"session {session}", rows, json_out)
