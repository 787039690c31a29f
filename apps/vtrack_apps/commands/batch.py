"""``vtrack batch``: run reconstruction / tracking / evaluation over many sessions (local pool or Ray)."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

import typer

from vtrack.errors import InputError

_HELP = {
    "reconstruct": "Reconstruct every session (mesh.ply, cloud.ply, metrics.json per session).",
    "track": "Track the object in every session (poses.csv, metrics.json per session).",
    "bench": "Reconstruct and track every session; accuracy and time per session and in the summary.",
    "stats": "Quick quality summary of every session (valid depth, motion, tactile activity).",
}


def _parse_options(items: list[str] | None) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for item in items or []:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise InputError("task option must look like KEY=VALUE", field="--option", got=item)
        try:
            out[key] = json.loads(value)
        except json.JSONDecodeError:
            out[key] = value
    return out


class _Progress:
    """Progress across tasks: a rich bar on a terminal, one line per finished task otherwise."""

    def __init__(self, title: str) -> None:
        self.title = title
        self.tty = sys.stderr.isatty()
        self._bar: Any = None
        self._task: Any = None
        self.n = 0
        self.total = 0

    def __call__(self, event: dict[str, Any]) -> None:
        kind = event["type"]
        if kind == "start":
            self.total = event["total"]
            typer.echo(
                f"[batch] {self.title}: {event['total']} task(s), {event['cached']} already complete, "
                f"{event['to_run']} to run",
                err=True,
            )
            if self.tty:
                from rich.progress import BarColumn, MofNCompleteColumn, Progress, TimeElapsedColumn

                self._bar = Progress(
                    "[progress.description]{task.description}",
                    BarColumn(),
                    MofNCompleteColumn(),
                    TimeElapsedColumn(),
                    transient=True,
                )
                self._bar.start()
                self._task = self._bar.add_task(self.title, total=self.total)
        elif kind == "done":
            self.n += 1
            rec = event["record"]
            if self._bar is not None:
                self._bar.advance(self._task)
            elif rec["status"] != "cached":
                sec = rec.get("seconds")
                typer.echo(
                    f"[batch] {self.n}/{self.total} {rec['key']}: {rec['status']}"
                    + (f" in {sec:.2f} s" if isinstance(sec, float) else "")
                    + (f" ({rec['error']})" if rec["status"] == "failed" else ""),
                    err=True,
                )
        elif kind == "retry":
            msg = f"[batch] retrying {event['key']} (attempt {event['attempt']} failed: {event['error']})"
            if self._bar is not None:
                self._bar.console.print(msg, style="yellow", markup=False)
            else:
                typer.echo(msg, err=True)
        elif kind == "end" and self._bar is not None:
            self._bar.stop()


def _run(
    task: str,
    sessions: list[Path],
    out: Path,
    engine: str,
    address: str | None,
    workers: int | None,
    retries: int,
    chunk_frames: int | None,
    force: bool,
    threads: int,
    timeout: float | None,
    params: dict[str, Any],
    pin_cpus: bool | None = None,
) -> None:
    from vtrack.batch.runner import run_batch
    from vtrack_apps.output import print_table

    progress = _Progress(f"batch {task}")
    report = run_batch(
        task,
        sessions,
        out,
        engine=engine,
        workers=workers,
        address=address,
        retries=retries,
        params=params,
        chunk_frames=chunk_frames,
        force=force,
        threads=threads,
        timeout_s=timeout,
        pin_cpus=pin_cpus,
        on_event=progress,
    )
    rows = [
        {
            "key": r["key"],
            "status": r["status"],
            "attempts": r["attempts"],
            "seconds": r.get("seconds") or 0.0,
            "error": (r.get("error") or "")[:80],
        }
        for r in report["results"]
    ]
    print_table(f"batch {task} -> {report['run']['out']}", rows)
    run = report["run"]
    typer.echo(
        f"[batch] {run['ok']} ran, {run['cached']} skipped (complete), {run['failed']} failed; "
        f"engine {run.get('engine', '-')} x{run.get('workers', '-')}; wall {run['wall_seconds']} s"
        + (f", {run['tasks_per_min']} tasks/min" if run.get("tasks_per_min") else "")
    )
    typer.echo(f"[batch] summary: {report['paths']['csv']}, {report['paths']['json']}")
    if run["failed"]:
        raise typer.Exit(1)


def _make_command(batch_app: typer.Typer, task: str) -> None:
    @batch_app.command(task, help=_HELP[task])
    def command(
        sessions: list[Path] = typer.Argument(..., help="session folders, or folders holding sessions"),
        out: Path = typer.Option(..., "--out", help="output folder: OUT/<session>/ + summary.csv/.json"),
        engine: str = typer.Option("local", "--engine", help="local (process pool) | ray"),
        address: str = typer.Option(None, "--address", help="existing Ray cluster (default: start a local one)"),
        workers: int = typer.Option(None, "--workers", help="parallel tasks (default: CPUs)"),
        retries: int = typer.Option(2, "--retries", help="extra attempts for a failed or crashed task"),
        chunk_frames: int = typer.Option(
            None, "--chunk-frames", help="split sessions into chunks of N reference-stream frames"
        ),
        force: bool = typer.Option(False, "--force", help="recompute results that are already complete"),
        threads: int = typer.Option(1, "--task-threads", help="BLAS/OpenMP/torch threads per task"),
        timeout: float = typer.Option(None, "--timeout", help="per-attempt time limit, s"),
        pin_cpus: bool = typer.Option(
            None, "--pin-cpus/--no-pin-cpus", help="pin each task to its own CPUs (default: on unless --address)"
        ),
        modalities: str = typer.Option(None, "--modalities", help="comma list: vision,touch (task option)"),
        option: list[str] = typer.Option(None, "--option", "-o", help="task option KEY=VALUE (JSON values ok)"),
    ) -> None:
        params = _parse_options(option)
        if modalities:
            params["modalities"] = [m.strip() for m in modalities.split(",") if m.strip()]
        _run(
            task,
            sessions,
            out,
            engine,
            address,
            workers,
            retries,
            chunk_frames,
            force,
            threads,
            timeout,
            params,
            pin_cpus,
        )


def register(app: typer.Typer) -> None:
    batch_app = typer.Typer(
        help="Batch runs over many sessions on a process pool or Ray (resumable).", no_args_is_help=True
    )
    app.add_typer(batch_app, name="batch")
    for task in _HELP:
        _make_command(batch_app, task)

    @batch_app.command("scaling")
    def scaling(
        sessions: list[Path] = typer.Argument(..., help="session folders, or folders holding sessions"),
        task: str = typer.Option("reconstruct", "--task", help="reconstruct | track | bench | stats"),
        engine: str = typer.Option("ray", "--engine", help="local | ray"),
        workers: str = typer.Option("1,2", "--workers", help="comma list of worker counts"),
        repeats: int = typer.Option(3, "--repeats", help="runs per worker count (interleaved)"),
        option: list[str] = typer.Option(None, "--option", "-o", help="task option KEY=VALUE"),
        json_out: Path = typer.Option(None, "--json", help="write all runs as JSON"),
        pin_cpus: bool = typer.Option(None, "--pin-cpus/--no-pin-cpus", help="pin tasks to CPUs (default on)"),
    ) -> None:
        """Measure throughput (tasks/min) for each worker count; prints the speed-up."""
        from vtrack.batch.scaling import measure_scaling
        from vtrack_apps.output import print_table, write_json

        counts = [int(w) for w in workers.split(",") if w.strip()]
        res = measure_scaling(
            task,
            sessions,
            engine=engine,
            workers=counts,
            repeats=repeats,
            params=_parse_options(option),
            pin_cpus=pin_cpus,
        )
        print_table(
            f"batch scaling: {task} on {engine}",
            [
                {
                    k: r[k]
                    for k in (
                        "workers",
                        "repeat",
                        "tasks",
                        "wall_seconds",
                        "tasks_per_min",
                        "cpu_utilisation",
                        "loadavg_1min_before",
                    )
                }
                for r in res["runs"]
            ],
        )
        for n, s in res["summary"].items():
            typer.echo(
                f"[scaling] {n} worker(s): median {s['tasks_per_min_median']} tasks/min "
                f"(speed-up {res['speedup_median'][n]:.2f}x)"
                if res["speedup_median"][n]
                else f"[scaling] {n} worker(s): no successful run"
            )
        if json_out:
            write_json(json_out, res)
