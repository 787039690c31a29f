"""``vtrack import feelsight|rosbag|mcap SRC --out SESSION``: convert other tools' recordings."""

from __future__ import annotations

from pathlib import Path

import typer


def _topic_map(items: list[str] | None) -> dict[str, str]:
    from vtrack.errors import InputError

    out = {}
    for it in items or []:
        topic, sep, role = it.partition("=")
        if not sep:
            raise InputError(
                "--map must be TOPIC=ROLE",
                field="--map",
                got=it,
                expected="e.g. /cam/rgb=camera/cam0:rgb, /cam/depth=camera/cam0:depth, "
                "/digit/image=tactile/digit_index, /x=ignore",
            )
        out[topic] = role
    return out


def _finish(report, json_out: Path | None) -> None:
    from vtrack_apps.output import write_json

    for line in report.lines():
        typer.echo(line)
    if json_out:
        write_json(json_out, report.to_dict())


def register(app: typer.Typer) -> None:
    imp = typer.Typer(help="Import recordings from other tools into a vtrack session.", no_args_is_help=True)
    app.add_typer(imp, name="import")

    @imp.command("feelsight")
    def feelsight(
        src: Path = typer.Argument(..., help="FeelSight log folder (holding data.pkl, allegro/, realsense/)"),
        out: Path = typer.Option(..., "--out", help="session directory to write"),
        mesh: Path = typer.Option(None, "--mesh", help="object mesh to reference in the scene"),
        max_frames: int = typer.Option(None, "--max-frames", help="import only the first N frames"),
        no_hand: bool = typer.Option(False, "--no-hand", help="do not add the DIGIT-Allegro hand to the scene"),
        force: bool = typer.Option(False, "--force", help="overwrite an existing session"),
        json_out: Path = typer.Option(None, "--json", help="write the import report as JSON"),
        trust_pickle: bool = typer.Option(
            False,
            "--trust-pickle",
            help="load data.pkl with plain pickle (runs code in the file; "
            "default: numpy arrays and builtin containers only)",
        ),
    ) -> None:
        """Import a FeelSight (NeuralFeels) log: DIGIT images, RealSense RGB-D, joints, object pose."""
        from vtrack.io.importers.feelsight import import_feelsight

        kw = {"hand_urdf": None} if no_hand else {}
        _finish(
            import_feelsight(
                src, out, overwrite=force, max_frames=max_frames, object_mesh=mesh, trust_pickle=trust_pickle, **kw
            ),
            json_out,
        )

    _register_ros_import(
        imp,
        "rosbag",
        "ROS 1 .bag file or ROS 2 bag folder",
        "Import a ROS 1/2 bag (Image, CompressedImage, CameraInfo, JointState, tf).",
        "vtrack.io.importers.rosbag",
        "import_rosbag",
    )
    _register_ros_import(
        imp,
        "mcap",
        "MCAP file",
        "Import an MCAP file (ROS 2 CDR or ROS 1 messages).",
        "vtrack.io.importers.mcap_import",
        "import_mcap",
    )


def _register_ros_import(imp: typer.Typer, name: str, src_help: str, doc: str, module: str, func: str) -> None:
    """One ``vtrack import <name>`` command for a ROS-message importer (same options for bags and MCAP)."""

    def command(
        src: Path = typer.Argument(..., help=src_help),
        out: Path = typer.Option(..., "--out", help="session directory to write"),
        map_: list[str] = typer.Option(None, "--map", help="TOPIC=ROLE override (repeatable)"),
        world_frame: str = typer.Option("world", "--world-frame", help="tf frame of the world"),
        object_frame: str = typer.Option("object", "--object-frame", help="tf child frame of the object"),
        tolerance_ms: float = typer.Option(20.0, "--pair-tolerance-ms", help="colour/depth pairing tolerance"),
        tactile_type: str = typer.Option(None, "--tactile-type", help="digit|gelsight_mini|gelsight"),
        force: bool = typer.Option(False, "--force", help="overwrite an existing session"),
        json_out: Path = typer.Option(None, "--json", help="write the import report as JSON"),
    ) -> None:
        import importlib

        importer = getattr(importlib.import_module(module), func)
        _finish(
            importer(
                src,
                out,
                topic_map=_topic_map(map_),
                overwrite=force,
                world_frame=world_frame,
                object_frame=object_frame,
                pair_tolerance_s=tolerance_ms / 1000.0,
                tactile_type=tactile_type,
            ),
            json_out,
        )

    command.__doc__ = doc
    imp.command(name)(command)
