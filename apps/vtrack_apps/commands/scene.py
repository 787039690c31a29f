"""``vtrack scene``: check a scene file and show what it would load."""

from __future__ import annotations

from pathlib import Path

import typer


def register(app: typer.Typer) -> None:
    scene_app = typer.Typer(help="Scene files: validate and inspect.", no_args_is_help=True)
    app.add_typer(scene_app, name="scene")

    @scene_app.command("check")
    def check(
        scene: Path = typer.Argument(..., help="scene YAML"),
        json_out: Path = typer.Option(None, "--json", help="write the summary as JSON"),
    ) -> None:
        """Validate a scene YAML and list the components it needs."""
        from vtrack.registry import required_components
        from vtrack.scene import load_scene
        from vtrack_apps.output import report

        s = load_scene(scene)
        # A validation command must open what generate/reconstruct will open, not only parse the YAML.
        loaded: dict[str, str] = {}
        if s.object.mesh:
            import warnings

            from vtrack.sim.objects import load_object_mesh

            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                m = load_object_mesh(s.object.mesh, s.object.scale)
            for w in caught:
                typer.secho(f"warning: {w.message}", fg="yellow", err=True)
            ext = m.extents * 1000.0
            loaded["object mesh"] = f"{len(m.faces)} triangles, {ext[0]:.0f}x{ext[1]:.0f}x{ext[2]:.0f} mm"
        if s.hand:
            from vtrack.kinematics.hand import HandKinematics

            hk = HandKinematics.from_scene(s)
            loaded["hand URDF"] = f"{hk.n_joints} joints, {len(hk.link_names)} links, {len(hk.sensor_names)} sensors"
        report(
            f"scene {s.name}",
            {
                **loaded,
                "object": str(s.object.mesh) if s.object.mesh else "unknown shape",
                "hand": str(s.hand.urdf) if s.hand else "none",
                "cameras": [c.name for c in s.cameras],
                "tactile": [f"{t.name}:{t.type}" for t in s.tactile],
                "reconstruction": s.pipeline.reconstruction,
                "tracking": s.pipeline.tracking,
                "modalities": s.effective_modalities,
                "components": required_components(s),
            },
            json_out,
        )
