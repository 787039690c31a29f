"""``vtrack reconstruct``: object reconstruction from a session (poses from tracking, a file, or GT oracle)."""

from __future__ import annotations

from pathlib import Path

import typer

from vtrack_apps.commands.track import CONTACTS_HELP, PREFETCH_HELP


def register(app: typer.Typer) -> None:
    @app.command("reconstruct")
    def reconstruct(
        session: Path = typer.Argument(..., help="session directory"),
        out: Path = typer.Option(..., "--out", help="result folder (mesh.ply, cloud.ply, metrics.json, ...)"),
        method: str = typer.Option("neural_sdf", "--method", help="tsdf | neural_sdf"),
        modalities: str = typer.Option("vision,touch", "--modalities", help="vision, touch or vision,touch"),
        poses: str = typer.Option(
            "track", "--poses", help="track (SLAM, or known shape with --mesh) | FILE (poses.csv) | gt (ORACLE)"
        ),
        mesh: Path = typer.Option(None, "--mesh", help="known object shape for tracking (object frame, m)"),
        gt: Path = typer.Option(None, "--gt", help="session with ground truth to score against (scoring only)"),
        tactile_source: str = typer.Option(
            "pipeline", "--tactile-source", help="pipeline (tactile images) | gt (ORACLE height maps)"
        ),
        segmentation: str = typer.Option(
            "pipeline",
            "--segmentation",
            help="pipeline (no GT) | gt (ORACLE masks) | none | gt_colour / gt_points (ORACLE mask for one use only)",
        ),
        online: bool = typer.Option(False, "--online", help="neural SDF: frame-by-frame with a time budget"),
        iters: int = typer.Option(0, "--iters", help="neural SDF offline iterations (0 = OFFLINE_ITERS)"),
        voxel_mm: float = typer.Option(0.0, "--voxel-mm", help="TSDF voxel size in mm (0 = TSDFConfig default)"),
        second_pass: float = typer.Option(
            None,
            "--second-pass",
            help="--poses track with SLAM: track the first SECONDS again, backwards, against the final map before "
            "fusing (default: the whole session; 0 = off)",
        ),
        colour_grow: int = typer.Option(
            0,
            "--colour-grow",
            help="--poses track, heavy occlusion (opt-in): grow the colour tracks' mask by this many depth pixels "
            "(as `vtrack track --colour-grow`; docs/benchmarks/heavy_mask_ablation.md)",
        ),
        contacts: str = typer.Option("slide", "--contacts", help="--poses track without --mesh: " + CONTACTS_HELP),
        prefetch: str = typer.Option("auto", "--prefetch", help="--poses track: " + PREFETCH_HELP),
        no_screenshot: bool = typer.Option(False, "--no-screenshot", help="skip screenshot.png"),
        json_out: Path = typer.Option(None, "--json", help="also write the metrics to this JSON file"),
    ) -> None:
        """Fuse vision and touch into an object mesh; write mesh, cloud, metrics and a screenshot."""
        from vtrack.fusion.reconstruct import reconstruct_session
        from vtrack_apps.output import report

        if second_pass and (mesh is not None or poses != "track"):
            from vtrack.errors import InputError

            raise InputError(
                "--second-pass re-tracks against SLAM's map",
                field="--second-pass",
                expected="--poses track without --mesh",
            )
        from vtrack_apps.commands.track import colour_grow_opts, contacts_opts, prefetch_mode

        if colour_grow > 0 and poses != "track":
            from vtrack.errors import InputError

            raise InputError(
                "the colour tracks' mask growth applies to tracking",
                field="--colour-grow",
                expected="--poses track",
                got=poses,
            )
        stick_opts = contacts_opts(
            contacts, modalities, mesh is None and poses == "track", "--poses track without --mesh"
        )
        track_opts = {**colour_grow_opts(colour_grow), **stick_opts}
        if poses == "track":
            track_opts["prefetch"] = prefetch_mode(prefetch)
        if second_pass is not None and mesh is None and poses == "track":
            track_opts["second_pass_s"] = second_pass
        opts = {}
        if iters > 0:
            opts["n_iters"] = iters
        if voxel_mm > 0:
            opts["voxel_size"] = voxel_mm / 1000.0
        m = reconstruct_session(
            session,
            out,
            method=method,
            modalities=modalities,
            poses=poses,
            mesh=mesh,
            gt=gt,
            tactile_source=tactile_source,
            segmentation=segmentation,
            online=online,
            screenshot=not no_screenshot,
            # SLAM's own second pass (the whole session) unless given; a known shape has none
            track_opts=track_opts or None,
            **opts,
        )
        keys = (
            "method",
            "modalities",
            "poses",
            "blind",
            "oracle",
            "tactile_source",
            "fscore",
            "precision",
            "recall",
            "chamfer_mm",
            "normal_consistency",
            "seconds",
            "ms_per_frame",
            "frames",
        )
        report(f"reconstruct {session}", {k: m.get(k) for k in keys}, json_out)
        if json_out:
            from vtrack_apps.output import write_json

            write_json(json_out, m)
        typer.echo(f"wrote {out}/mesh.ply, poses.csv, cloud.ply, metrics.json, result.json")
