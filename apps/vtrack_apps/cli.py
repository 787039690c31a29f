"""The ``vtrack`` command line (typer).

Commands are discovered from ``vtrack_apps.commands``: each module there defines
``register(app: typer.Typer) -> None``. Command modules keep heavy imports inside the command
functions so that ``vtrack --help`` stays fast.
"""

from __future__ import annotations

import importlib
import pkgutil
import sys

import typer

from vtrack.errors import VtrackError

app = typer.Typer(
    name="vtrack",
    help="3D visuo-tactile reconstruction and in-hand object tracking.",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    add_completion=False,
    rich_markup_mode="rich",
)


@app.callback()
def _root(
    threads: int = typer.Option(
        0,
        "--threads",
        help="threads of every numeric back-end: BLAS/OpenMP, OpenCV, "
        "torch (0 = library default; 1 for single-core speed figures).",
    ),
    on_corrupt: str = typer.Option(
        None,
        "--on-corrupt",
        help="session frames whose data chunks are damaged: raise (default), skip them, or stop at the first",
    ),
) -> None:
    """vtrack: tactile height maps, world-frame visuo-tactile fusion, in-hand tracking."""
    if on_corrupt is not None:
        import os

        from vtrack.errors import InputError

        if on_corrupt not in ("raise", "skip", "stop"):
            raise InputError("unknown value", field="--on-corrupt", expected="raise, skip or stop", got=on_corrupt)
        # The session reader reads this (vtrack.io.session.ON_CORRUPT_ENV), so every command honours it.
        os.environ["VTRACK_ON_CORRUPT"] = on_corrupt
    if threads > 0:
        from vtrack.threads import limit_threads

        limit_threads(threads)


def _register_commands() -> None:
    from vtrack_apps import commands

    for info in sorted(pkgutil.iter_modules(commands.__path__), key=lambda m: m.name):
        if info.name.startswith("_"):
            continue
        mod = importlib.import_module(f"vtrack_apps.commands.{info.name}")
        register = getattr(mod, "register", None)
        if register is not None:
            register(app)


_register_commands()


def main() -> None:
    """Console entry point: user errors print one clear line and exit with status 2."""
    try:
        app()
    except VtrackError as e:
        # Always one line, even if a message carries a library's multi-line text.
        typer.secho(f"error: {' '.join(str(e).split())}", fg=typer.colors.RED, err=True)
        sys.exit(2)
    except KeyboardInterrupt:
        typer.secho("interrupted", err=True)
        sys.exit(130)


if __name__ == "__main__":
    main()
