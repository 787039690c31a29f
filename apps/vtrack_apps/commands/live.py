"""``vtrack live SESSION --consumer track|reconstruct|null``: replay a session at real-time rate
through the live pipeline (frames are dropped, not queued, when a consumer falls behind)."""

from __future__ import annotations

from pathlib import Path

import typer

from vtrack_apps.commands.track import CONTACTS_HELP


def register(app: typer.Typer) -> None:
    @app.command("live")
    def live(
        session: Path = typer.Argument(..., help="session directory to replay"),
        consumer: list[str] = typer.Option(["null"], "--consumer", help="track | reconstruct | null (repeatable)"),
        speed: float = typer.Option(1.0, "--speed", help="playback speed (1 = real time)"),
        seconds: float = typer.Option(None, "--seconds", help="replay only the first seconds"),
        loop: int = typer.Option(1, "--loop", help="replay the session this many times"),
        max_lag_ms: float = typer.Option(50.0, "--max-lag-ms", help="source skips frames later than this"),
        reader: str = typer.Option(
            "process",
            "--reader",
            help="decode frames in a child 'process' (default: no GIL contention with the tracker) or a 'thread'",
        ),
        json_out: Path = typer.Option(None, "--json", help="write the statistics as JSON"),
        mesh: Path = typer.Option(None, "--mesh", help="track: known object shape (object frame, m); default SLAM"),
        init_pose: str = typer.Option(
            None, "--init-pose", help="track with --mesh: first-frame prior x,y,z,qx,qy,qz,qw or a poses.csv"
        ),
        poses: Path = typer.Option(
            None, "--poses", help="reconstruct: poses.csv of T_world_object (e.g. from vtrack track)"
        ),
        touch_worker: str = typer.Option(
            None,
            "--touch-worker",
            help="track: tactile pipeline in a child 'process' (default), a 'thread' or 'off' (in the camera step)",
        ),
        frames_worker: str = typer.Option(
            None,
            "--frames-worker",
            help="track: segmentation in its own child 'process' (default: a stage ahead of the tracker), 'inline' in "
            "the tracker's step or 'shared' with the touch process",
        ),
        transport: str = typer.Option(
            "shm",
            "--transport",
            help="with --reader process: frames decoded into a shared-memory ring read in place ('shm', default) "
            "or pickled through pipes ('pipe')",
        ),
        camera_stride: int = typer.Option(None, "--camera-stride", help="track: track every k-th camera frame"),
        max_camera_stride: int = typer.Option(
            None,
            "--max-camera-stride",
            help="track: skip camera frames (stride up to this) while the tracker's steps exceed 0.9 camera periods",
        ),
        colour: bool = typer.Option(
            None,
            "--colour/--no-colour",
            help="track: the colour term (feature tracks on the camera's RGB image; SLAM's default) or depth only",
        ),
        contacts: str = typer.Option("slide", "--contacts", help="track, SLAM: " + CONTACTS_HELP),
    ) -> None:
        """Replay SESSION in real time into live consumers; report achieved rates and dropped frames."""
        import os

        from vtrack.threads import THREAD_ENV, limit_threads

        if not any(os.environ.get(k) for k in THREAD_ENV):
            # The pipeline's parallelism is its processes (tracker, touch, reader); a BLAS/OpenMP pool in each
            # only spins against the others on the cores they share. `vtrack --threads N live` overrides.
            limit_threads(1)
        from vtrack.io.poses import parse_pose
        from vtrack.live.consumers import make_consumer, replay_fields, replay_streams
        from vtrack.live.pipeline import LivePipeline, live_advice
        from vtrack.live.sources import SessionReplaySource
        from vtrack_apps.commands.track import contacts_opts
        from vtrack_apps.output import print_table, write_json

        # the live tracker reads vision and touch (touch is left out only where a sensor has no calibration)
        stick_opts = contacts_opts(contacts, ("vision", "touch"), mesh is None, "no --mesh (SLAM)", offline=False)

        per_kind = {
            "track": {
                "mesh": mesh,
                "init_pose": parse_pose(init_pose) if init_pose else None,
                "touch_worker": touch_worker,
                "frames_worker": frames_worker,
                "camera_stride": camera_stride,
                "max_camera_stride": max_camera_stride,
                "colour": colour,
                **stick_opts,
            },
            "reconstruct": {"poses": poses},
        }
        cons = [
            make_consumer(c, session, **{k: v for k, v in per_kind.get(c, {}).items() if v is not None})
            for c in consumer
        ]
        src = SessionReplaySource(
            session,
            streams=replay_streams(session, cons),
            speed=speed,
            max_lag_s=max_lag_ms / 1000.0,
            seconds=seconds,
            loop=loop,
            reader=reader,
            fields=replay_fields(cons),
            transport=transport,
        )
        res = LivePipeline(src, cons).run()
        so = res["source"]
        src_rows = [
            {
                "stream": k,
                "emitted": v,
                "rate_hz": so["emitted_rate_hz"].get(k),
                "skipped_late": so["skipped_late"].get(k, 0),
            }
            for k, v in so["emitted"].items()
        ]
        print_table(f"live source ({res['active_s']} s, max lag {res['source']['max_lag_ms']} ms)", src_rows)
        for name, r in res["consumers"].items():
            rows = [{"stream": s, **v} for s, v in r["streams"].items()]
            print_table(
                f"consumer {name}: latency mean {r['latency_ms_mean']} ms, p95 {r['latency_ms_p95']} ms, "
                f"busy {r['busy_fraction']}, result {r['result']}",
                rows,
            )
            if "first_error" in r:
                typer.secho(f"consumer {name}: {r['errors']} error(s), first: {r['first_error']}", fg="yellow")
        sm = res["summary"]
        typer.echo(
            "summary: "
            + ", ".join(f"{k} {v}" for k, v in sm.items())
            + " (real-time factor = capacity / demand of the busiest worker; see docs/recording.md)"
        )
        for line in live_advice(res):
            typer.secho(line, fg="yellow")
        if json_out:
            write_json(json_out, res)
