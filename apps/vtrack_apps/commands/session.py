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
        for name, bad in r.dropped_frames.items():
            typer.secho(f"note: {name}: {len(bad)} damaged frame(s) hidden (--on-corrupt {r.on_corrupt})", fg="yellow")
        typer.echo("(info reads the manifest and timestamps only; 'vtrack session verify' reads every chunk)")
        report(f"session {session}", rows, json_out)

    @session_app.command("strip-gt")
    def strip_gt_cmd(
        session: Path = typer.Argument(..., help="session directory"),
        out: Path = typer.Option(..., "--out", help="folder of the copy without ground truth"),
        force: bool = typer.Option(False, "--force", help="replace an existing session folder at --out"),
    ) -> None:
        """Copy a session without any ground truth (gt/ streams and files, masks, object mesh and pose)."""
        from vtrack.io.strip import strip_gt
        from vtrack_apps.output import report

        r = strip_gt(session, out, overwrite=force)
        rows = [{"removed": k, "items": ", ".join(v) or "-"} for k, v in r.items()]
        report(f"stripped copy {out}", rows, None)

    @session_app.command("verify")
    def verify(
        session: Path = typer.Argument(..., help="session directory"),
        json_out: Path = typer.Option(None, "--json", help="write the list of problems as JSON"),
    ) -> None:
        """Read every chunk of every array (and check its CRC32C checksum); list damaged frames.

        Exit 0 when every committed frame reads back; exit 2 (one error line on stderr, the damaged
        chunks on stdout) otherwise.
        """
        from vtrack.errors import InputError
        from vtrack.io.session import open_session, verify_session
        from vtrack_apps.output import write_json

        r = open_session(session, on_corrupt="raise")
        problems = verify_session(r)
        frames = sum(s.n for s in r.streams.values())
        if json_out:
            write_json(
                json_out,
                {
                    "session": str(session),
                    "ok": not problems,
                    "frames": frames,
                    "problems": [
                        {
                            "path": str(p.path),
                            "stream": p.stream,
                            "field": p.field,
                            "frames": list(p.frames) if p.frames else None,
                            "message": p.message,
                        }
                        for p in problems
                    ],
                },
            )
        if not problems:
            typer.echo(f"session {session}: OK, {len(r.streams)} streams, {frames} frames, every chunk reads back")
            return
        for p in problems:
            typer.echo(str(p))
        first = problems[0]
        raise InputError(
            f"{len(problems)} damaged chunk(s), first at frames {first.frames[0]}..{first.frames[1] - 1}"
            if first.frames
            else f"{len(problems)} problem(s)",
            path=first.path,
            field=f"{first.stream}/{first.field}",
            expected="every chunk readable (vtrack --on-corrupt skip|stop ... reads around them)",
        )
