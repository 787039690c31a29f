"""Shared CLI output: short rich tables, JSON files, progress bars."""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any, TypeVar

from vtrack.io.jsonio import to_jsonable, write_json

__all__ = ["print_table", "progress", "report", "to_jsonable", "write_json"]

T = TypeVar("T")


def print_table(title: str, rows: dict[str, Any] | list[dict[str, Any]]) -> None:
    """Print a key/value dict or a list of row dicts as a compact rich table."""
    from rich.console import Console
    from rich.table import Table

    def fmt(v: Any) -> str:
        if isinstance(v, float):
            return f"{v:.4g}"
        if isinstance(v, dict):
            return ", ".join(f"{k}={fmt(x)}" for k, x in v.items())
        return str(v)

    table = Table(title=title, show_header=True, header_style="bold")
    if isinstance(rows, dict):
        table.add_column("key")
        table.add_column("value")
        for k, v in rows.items():
            table.add_row(str(k), fmt(v))
    else:
        cols = list(dict.fromkeys(k for r in rows for k in r))
        for c in cols:
            table.add_column(c)
        for r in rows:
            table.add_row(*[fmt(r.get(c, "")) for c in cols])
    Console().print(table)


def report(title: str, results: dict[str, Any] | list[dict[str, Any]], json_path: str | Path | None) -> None:
    """Print results as a table and, if asked, write them as JSON."""
    print_table(title, results)
    if json_path:
        write_json(json_path, results)


def progress(items: Iterable[T], description: str, total: int | None = None) -> Iterator[T]:
    """A progress bar (rich) around an iterable; plain iteration when stdout is not a terminal."""
    import sys

    if not sys.stderr.isatty():
        yield from items
        return
    from rich.progress import track

    yield from track(items, description=description, total=total, transient=True)
