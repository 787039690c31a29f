"""``vtrack track``: 6-DoF in-hand object pose tracking from a session (known shape or SLAM)."""

from __future__ import annotations

from pathlib import Path

import typer


def colour_grow_opts(colour_grow: int) -> dict:
    """``track_session`` options of ``--colour-grow N`` (the opt-in colour-mask growth; shared with ``vtrack
    reconstruct``): ``{}`` for 0; a negative N is an InputError naming the flag."""
    if colour_grow < 0:
        from vtrack.errors import InputError

        raise InputError("mask growth must be >= 0", field="--colour-grow", expected=">= 0", got=colour_grow)
    return {"segmentation_opts": {"colour_grow_px": colour_grow}} if colour_grow > 0 else {}


#: ``--contacts`` of ``vtrack track``, ``vtrack reconstruct`` and ``vtrack live`` (no ``auto`` there)
CONTACTS_HELP = (
    "SLAM: how the fingers hold the object: slide (they may slide over it; the default) | stick (they drive it, "
    "sticking or rolling, as in an in-hand rotation: the sticking-contact preset; hurts when they slide) | auto "
    "(offline: both, the sticking run kept when the contacts move rigidly and it fits the depth as well; 2x the "
    "tracking CPU); docs/benchmarks/sticking_contacts.md"
)


def contacts_opts(
    contacts: str, modalities: str | tuple[str, ...], slam: bool, slam_flags: str, offline: bool = True
) -> dict:
    """SLAM's ``track_session`` options of ``--contacts slide|stick|auto`` (shared with ``vtrack reconstruct`` and,
    without ``auto`` (``offline`` False), ``vtrack live``): ``{}`` for slide,
    :data:`vtrack.tracking.slam.SLAM_STICKING_CONTACTS` for stick, ``select_contacts`` for auto; stick and auto need
    SLAM (``slam``; ``slam_flags``: the flags that select it, for the message) and touch among ``modalities`` (a
    comma list or a tuple); anything else is an InputError naming the flag."""
    from vtrack.errors import InputError

    if contacts == "slide":
        return {}
    modes = "slide|stick|auto" if offline else "slide|stick"
    if contacts not in modes.split("|"):
        raise InputError("unknown contact mode", field="--contacts", expected=modes, got=contacts)
    if not slam:
        raise InputError("the sticking-contact preset is for SLAM", field="--contacts", expected=slam_flags)
    mods = modalities.split(",") if isinstance(modalities, str) else modalities
    if "touch" not in [m.strip() for m in mods]:
        # without touch the preset would only re-weight the depth points of frames that see little
        raise InputError(
            "the sticking-contact preset needs touch", field="--contacts", expected="--modalities with touch"
        )
    if contacts == "auto":
        return {"select_contacts": True}
    from vtrack.tracking.slam import SLAM_STICKING_CONTACTS

    return dict(SLAM_STICKING_CONTACTS)


#: ``--prefetch`` of ``vtrack track`` and ``vtrack reconstruct`` (:mod:`vtrack.frames.prefetch`)
PREFETCH_HELP = (
    "build the frames ahead of the tracker in child processes (segmentation in one, the tactile pipelines in "
    "another): auto (sessions of >= 120 frames on >= 2 CPUs, not with --threads 1) | on | off | single (one child "
    "for both, an ablation); the same poses"
)


def prefetch_mode(value: str) -> str:
    """``--prefetch`` checked (shared with ``vtrack reconstruct``): an InputError naming the flag."""
    from vtrack.frames.prefetch import check_prefetch_mode

    return check_prefetch_mode(value, "--prefetch")


def register(app: typer.Typer) -> None:
    @app.command("track")
    def track(
        session: Path = typer.Argument(..., help="session directory (no ground truth needed)"),
        out: Path = typer.Option(..., "--out", help="result folder (poses.csv, metrics.json, ...)"),
        shape: str = typer.Option(
            "known_shape", "--shape", help="known_shape (mesh SDF) | slam (shape reconstructed online)"
        ),
        mesh: Path = typer.Option(None, "--mesh", help="known object shape (object frame, m); default: the scene's"),
        init_pose: str = typer.Option(
            None,
            "--init-pose",
            help="first-frame prior x,y,z,qx,qy,qz,qw or a poses.csv (default: global registration / SLAM's own frame)",
        ),
        modalities: str = typer.Option("vision,touch", "--modalities", help="vision, touch or vision,touch"),
        method: str = typer.Option("ours", "--method", help="ours | icp (Open3D point-to-plane, vision only)"),
        mapper: str = typer.Option("surfel", "--mapper", help="SLAM map: surfel (numpy) | neural (neural SDF)"),
        refine: bool = typer.Option(
            False,
            "--refine/--no-refine",
            help="SLAM: keyframe pose-graph refinement with loop closure after tracking (gtsam; off by default, "
            "it pays off when the object shows a face again)",
        ),
        loop_closure: bool = typer.Option(
            True, "--loop-closure/--no-loop-closure", help="SLAM: loop-closure edges in the pose graph"
        ),
        spin_search: bool = typer.Option(
            False,
            "--spin-search/--no-spin-search",
            help="SLAM back end: re-localise a spin lost by more than 1 rad (a search over the full turn with a "
            "symmetry test; needs --refine and loop closure; opt-in: it can close false turns, see docs/tracking.md)",
        ),
        colour: bool = typer.Option(
            True,
            "--colour/--no-colour",
            help="SLAM: colour term, KLT feature tracks on the object's pixels (observes a spin about a symmetry "
            "axis that depth and touch do not see; needs the camera's RGB and surface texture; about 3 % more CPU)",
        ),
        second_pass: float = typer.Option(
            None,
            "--second-pass",
            help="SLAM, offline: track the first SECONDS again, backwards, against the final map (default: the "
            "whole session; 0 = off; docs/benchmarks/slam_second_pass_default.md)",
        ),
        shape_prior: str = typer.Option(
            "sphere",
            "--shape-prior",
            help="SLAM: sphere (when the map is a ball, track against the first well-measured ball) | sphere-fill "
            "(ablation: fill the unobserved map only) | none (docs/benchmarks/sphere_prior.md)",
        ),
        few_touch: int | None = typer.Option(
            None,
            "--few-touch",
            help="contact points kept in frames that see fewer than 300 depth points (default: 12 for SLAM, all "
            "for a known shape; 0 = all 120; docs/benchmarks/few_touch.md)",
        ),
        colour_grow: int = typer.Option(
            0,
            "--colour-grow",
            help="heavy occlusion (opt-in): grow the colour tracks' mask by this many depth pixels into dropouts and "
            "along the fingers (1 is the measured setting; hurts a well-seen object; "
            "docs/benchmarks/heavy_mask_ablation.md)",
        ),
        contacts: str = typer.Option("slide", "--contacts", help=CONTACTS_HELP),
        select_run: bool = typer.Option(
            False,
            "--select-run",
            help="SLAM, offline (opt-in): track again with each alternative setting and keep the run whose map agrees "
            "best with its own depth points (3x the tracking CPU; docs/benchmarks/slam_select_run.md)",
        ),
        prefetch: str = typer.Option("auto", "--prefetch", help=PREFETCH_HELP),
        window: int = typer.Option(3, "--window", help="frames optimised jointly (sliding window)"),
        iterations: int = typer.Option(5, "--iterations", help="max LM iterations per frame"),
        gt: Path = typer.Option(None, "--gt", help="session with ground truth to score against (scoring only)"),
        init: str = typer.Option("auto", "--init", help="auto | gt (ORACLE: first ground-truth pose)"),
        tactile_source: str = typer.Option(
            "pipeline", "--tactile-source", help="pipeline (tactile images) | gt (ORACLE height maps)"
        ),
        segmentation: str = typer.Option(
            "pipeline",
            "--segmentation",
            help="pipeline (no GT) | gt (ORACLE masks) | none | gt_colour / gt_points (ORACLE mask for one use only)",
        ),
        init_perturb_mm: float = typer.Option(
            0.0, "--init-perturb-mm", help="with --init gt: start moved by this much (mm)"
        ),
        init_perturb_deg: float = typer.Option(0.0, "--init-perturb-deg", help="... and rotated by this (deg)"),
        max_frames: int = typer.Option(0, "--max-frames", help="track only the first N frames (0 = all)"),
        seed: int = typer.Option(0, "--seed", help="seed of the initial-pose perturbation"),
        json_out: Path = typer.Option(None, "--json", help="also write the metrics to this JSON file"),
    ) -> None:
        """Track the object pose from raw streams (segmentation and touch without ground truth)."""
        import math

        from vtrack.errors import InputError, require_range
        from vtrack.io.poses import parse_pose
        from vtrack.tracking.run import track_session
        from vtrack_apps.output import report, write_json

        mods = tuple(m.strip() for m in modalities.split(",") if m.strip())
        if not mods or set(mods) - {"vision", "touch"}:
            raise InputError(
                "unknown modality", field="--modalities", expected="vision, touch or vision,touch", got=modalities
            )
        perturb = None
        if init_perturb_mm > 0 or init_perturb_deg > 0:
            perturb = (init_perturb_mm / 1000.0, math.radians(init_perturb_deg))
        if select_run and (shape != "slam" or method != "ours"):
            raise InputError("run selection is for SLAM", field="--select-run", expected="--shape slam", got=shape)
        stick_opts = contacts_opts(contacts, mods, shape == "slam" and method == "ours", "--shape slam")
        if select_run and contacts == "auto":
            raise InputError("auto chooses between two runs itself", field="--contacts", expected="no --select-run")
        opts = {}
        if method == "ours":
            opts = {"window": window, "iterations": iterations}
            if few_touch is not None:  # a tracker option of both shapes (SLAM's default 12, known shape's 0)
                require_range("--few-touch", few_touch, "contact budget must be >= 0", ">= 0")
                opts["few_touch_points"] = few_touch
            if shape == "slam":
                opts.update(
                    mapper=mapper,
                    refine=refine,
                    loop_closure=loop_closure,
                    spin_search=spin_search,
                    shape_prior=shape_prior,
                )
                if second_pass is not None:
                    opts["second_pass_s"] = second_pass
                if select_run:
                    opts["select_runs"] = True
                opts.update(colour_grow_opts(colour_grow))
                opts.update(stick_opts)
                if not colour:
                    from vtrack.tracking.slam import SLAM_NO_COLOUR

                    opts.update(SLAM_NO_COLOUR)
        m = track_session(
            session,
            out,
            shape=shape,
            modalities=mods,
            method=method,
            mesh=mesh,
            init_pose=parse_pose(init_pose) if init_pose else None,
            init=init,
            init_perturb=perturb,
            gt=gt,
            tactile_source=tactile_source,
            segmentation=segmentation,
            max_frames=max_frames,
            seed=seed,
            prefetch=prefetch_mode(prefetch),
            **opts,
        )
        keys = (
            "mode",
            "modalities",
            "blind",
            "oracle",
            "frames",
            "init",
            "add_s_mm",
            "drift_mm",
            "motion_err_mm",
            "ms_per_frame_mean",
            "poses_per_s",
            "prefetch",
            "sticking_contacts",
            "contacts_choice",
            "status_counts",
            "backend_s",
            "keyframes",
            "loop_edges",
            "select_scores_mm",
            "selected_run",
        )
        report(f"track {session}", {k: m.get(k) for k in keys if k in m}, None)
        if json_out:
            write_json(json_out, m)
        typer.echo(f"wrote {out}/poses.csv, metrics.json, result.json")
