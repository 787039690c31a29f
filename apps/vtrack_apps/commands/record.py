"""``vtrack record oak|tactile``: record live sensors into a session (crash-safe, Ctrl-C stops cleanly)."""

from __future__ import annotations

from pathlib import Path

import typer


def _base_scene(scene: Path | None) -> dict | None:
    if scene is None:
        return None
    from vtrack.scene.load import load_scene

    return load_scene(scene, check_files=False).to_dict()


def register(app: typer.Typer) -> None:
    rec = typer.Typer(help="Record live sensors (OAK-D, DIGIT / GelSight Mini) into a session.", no_args_is_help=True)
    app.add_typer(rec, name="record")

    @rec.command("oak")
    def oak(
        out: Path = typer.Option(..., "--out", help="session directory to write"),
        name: str = typer.Option("oak", "--name", help="camera name in the session"),
        width: int = typer.Option(640, "--width", help="colour/depth width, px"),
        height: int = typer.Option(400, "--height", help="colour/depth height, px"),
        fps: float = typer.Option(30.0, "--fps", help="frame rate, Hz"),
        imu: bool = typer.Option(False, "--imu", help="also record the IMU"),
        seconds: float = typer.Option(None, "--seconds", help="stop after this many seconds (default: Ctrl-C)"),
        frames: int = typer.Option(None, "--frames", help="stop after this many frames"),
        flush_every: int = typer.Option(10, "--flush-every", help="commit every N frames (crash-safety step)"),
        device: str = typer.Option(None, "--device", help="device id or IP (default: first found)"),
        scene: Path = typer.Option(None, "--scene", help="scene YAML to embed (the camera entry is added)"),
        simulate: bool = typer.Option(
            False, "--simulate", help="no device: synthetic frames through a host-only depthai pipeline"
        ),
        force: bool = typer.Option(False, "--force", help="overwrite an existing session"),
    ) -> None:
        """Record colour + depth aligned to colour (and IMU) from an OAK-D with device timestamps."""
        from vtrack.io.recorders.oakd import OakConfig, record_oak, record_oak_simulated
        from vtrack_apps.output import print_table

        cfg = OakConfig(name=name, width=width, height=height, fps=fps, imu=imu, device=device)
        if simulate:
            stats = record_oak_simulated(
                out,
                cfg,
                n_frames=frames or int(round((seconds or 2.0) * fps)),
                flush_every=flush_every,
                overwrite=force,
                scene=_base_scene(scene),
            )
        else:
            stats = record_oak(
                out,
                cfg,
                seconds=seconds,
                max_frames=frames,
                flush_every=flush_every,
                overwrite=force,
                scene=_base_scene(scene),
            )
        print_table(f"recorded {out}", stats.to_dict())

    @rec.command("tactile")
    def tactile(
        out: Path = typer.Option(..., "--out", help="session directory to write"),
        camera: list[str] = typer.Option(
            ...,
            "--camera",
            help="NAME=SOURCE[:TYPE], SOURCE = index, /dev/videoN, serial:S or a "
            "video file; TYPE = digit|gelsight_mini|gelsight (repeatable)",
        ),
        joints_csv: Path = typer.Option(None, "--joints-csv", help="joint states CSV (t, names...)"),
        joints_topic: str = typer.Option(None, "--joints-topic", help="sensor_msgs/JointState topic (ROS)"),
        seconds: float = typer.Option(None, "--seconds", help="stop after this many seconds"),
        frames: int = typer.Option(None, "--frames", help="stop after this many frames per camera"),
        flush_every: int = typer.Option(10, "--flush-every", help="commit every N frames (crash-safety step)"),
        scene: Path = typer.Option(None, "--scene", help="scene YAML to embed (hand, object, tactile specs)"),
        no_realtime: bool = typer.Option(False, "--no-realtime", help="read video files as fast as possible"),
        force: bool = typer.Option(False, "--force", help="overwrite an existing session"),
    ) -> None:
        """Record DIGIT / GelSight Mini cameras (UVC) with the hand's joint states."""
        from vtrack.errors import InputError
        from vtrack.io.recorders.joints import CsvJointSource, RosJointSource
        from vtrack.io.recorders.tactile import TactileCamera, record_tactile
        from vtrack_apps.output import print_table

        cams = []
        for spec in camera:
            name, sep, rest = spec.partition("=")
            if not sep or not name:
                raise InputError("camera spec must be NAME=SOURCE[:TYPE]", field="--camera", got=spec)
            src, typ = rest, "digit"
            head, _, tail = rest.rpartition(":")
            if head and tail in ("digit", "gelsight_mini", "gelsight"):
                src, typ = head, tail
            cams.append(TactileCamera(name=name, source=src, type=typ))
        js = None
        if joints_csv is not None and joints_topic is not None:
            raise InputError("give either --joints-csv or --joints-topic", field="--joints-csv")
        if joints_csv is not None:
            js = CsvJointSource(joints_csv)
        elif joints_topic is not None:
            js = RosJointSource(joints_topic)
        stats = record_tactile(
            out,
            cams,
            joints=js,
            seconds=seconds,
            max_frames=frames,
            flush_every=flush_every,
            overwrite=force,
            scene=_base_scene(scene),
            realtime=not no_realtime,
        )
        print_table(f"recorded {out}", stats.to_dict())

    @rec.command("presses")
    def presses(
        camera: str = typer.Option(..., "--camera", help="device index, /dev/videoN, serial:S or a video file"),
        out: Path = typer.Option(..., "--out", help="press-set folder to write"),
        sensor: str = typer.Option("digit", "--sensor", help="digit | gelsight_mini | gelsight"),
        ball_radius_mm: float = typer.Option(..., "--ball-radius-mm", help="radius of the ball you press, mm"),
        mm_per_px: float = typer.Option(None, "--mm-per-px", help="gel pixel pitch, mm (default: sensor preset)"),
        n: int = typer.Option(
            None, "--n", help="presses to record over the whole gel, edges included (default: preset; DIGIT 100, 60)"
        ),
        background_frames: int = typer.Option(15, "--background-frames", help="untouched frames at the start"),
        frames: int = typer.Option(None, "--frames", help="stop after this many frames"),
        force: bool = typer.Option(False, "--force", help="write into a non-empty folder"),
    ) -> None:
        """Record a ball-press calibration set with a live read-out; then run `vtrack calibrate OUT`."""
        from vtrack.errors import InputError
        from vtrack.io.recorders.presses import record_presses
        from vtrack.tactile.sensors import SENSOR_PRESETS
        from vtrack_apps.output import print_table

        if sensor not in SENSOR_PRESETS:
            raise InputError(
                "unknown tactile sensor type", field="--sensor", expected=" | ".join(SENSOR_PRESETS), got=sensor
            )
        # without --mm-per-px the recorder uses the preset's nominal pitch at the stored frame size (flagged)
        rep = record_presses(
            camera,
            out,
            sensor=sensor,
            ball_radius_mm=ball_radius_mm,
            mm_per_px=mm_per_px,
            n_presses=n,
            background_frames=background_frames,
            max_frames=frames,
            overwrite=force,
            echo=typer.echo,
        )
        print_table(f"recorded presses {out}", rep.to_dict())
        if rep.presses_saved < 5:
            typer.echo(f"warning: only {rep.presses_saved} presses: calibrate needs at least 5")
