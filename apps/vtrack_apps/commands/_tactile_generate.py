"""``vtrack tactile generate | generate-train | generate-eval``: controllable tactile generation (issue #24).

Registered on the ``tactile`` group by :mod:`vtrack_apps.commands.tactile`; heavy imports (torch, OpenCV)
stay inside the commands.
"""

from __future__ import annotations

from pathlib import Path

import typer


def _parse_position(text: str, option: str = "--position"):
    from vtrack.errors import InputError
    from vtrack.tactile.generate.data import Pose

    try:
        parts = [float(v) for v in text.split(",")]
    except ValueError:
        parts = []
    if len(parts) not in (2, 3):
        raise InputError(f"bad {option}", field=option, expected="x,y[,theta] (px, px, deg)", got=text)
    return Pose(parts[0], parts[1], parts[2] if len(parts) == 3 else 0.0)


def register_generate(tac: typer.Typer) -> None:
    @tac.command("generate")
    def generate_cmd(
        reference: Path = typer.Argument(..., help="reference tactile image of one contact (BGR PNG/JPEG)"),
        out: Path = typer.Option(..., "--out", help="generated image to write (PNG)"),
        force: float = typer.Option(
            None, "--force", help="target normal force, N (Hertz proxy, sphere of --ball-radius-mm)"
        ),
        depth: float = typer.Option(None, "--depth", help="target indentation depth, mm"),
        mask: Path = typer.Option(None, "--mask", help="target contact mask (PNG, white = contact; sets the pose)"),
        position: str = typer.Option(
            None, "--position", help="target contact centroid and rotation: x,y[,theta] (px, px, deg vs the reference)"
        ),
        ref_pose: str = typer.Option(
            None,
            "--ref-pose",
            help="the reference contact's labelled pose x,y[,theta] (px, px, deg): the target is placed relative to "
            "it, not to the detected footprint's centroid (which a dim or unevenly lit contact pulls off centre)",
        ),
        background: Path = typer.Option(
            None, "--background", help="no-contact frame (default: background.png beside the reference)"
        ),
        ref_depth: float = typer.Option(None, "--ref-depth", help="reference indentation, mm (default: estimated)"),
        ref_force: float = typer.Option(None, "--ref-force", help="reference normal force, N (instead of --ref-depth)"),
        ball_radius_mm: float = typer.Option(2.0, "--ball-radius-mm", help="indenter radius for force <-> depth, mm"),
        mm_per_px: float = typer.Option(
            None, "--mm-per-px", help="pixel pitch, mm (default: GelSight 0.0295 at 640 px wide, scaled)"
        ),
        mode: str = typer.Option(
            "two_stage", "--mode", help="two_stage | stage1 | hybrid | separate | flow1|2|4|8 | flowx1|2|4|8 | shift"
        ),
        weights: Path = typer.Option(None, "--weights", help="generator weights .pt (default: shipped)"),
    ) -> None:
        """Generate the tactile image of the reference contact at another force/depth and pose."""
        import cv2

        from vtrack.errors import InputError
        from vtrack.sim.presses import press_depth_mm
        from vtrack.tactile.generate import data as gd
        from vtrack.tactile.generate.generator import TactileGenerator
        from vtrack.tactile.pressset import read_bgr
        from vtrack_apps.output import report

        if (force is None) == (depth is None):
            raise InputError("give exactly one of --force and --depth", field="--force/--depth")
        if mask is not None and position is not None:
            raise InputError("give at most one of --mask and --position", field="--mask/--position")
        if force is not None and not force >= 0:
            raise InputError("force must be non-negative", field="--force", expected=">= 0 N", got=force)
        if depth is not None and not depth >= 0:
            raise InputError("depth must be non-negative", field="--depth", expected=">= 0 mm", got=depth)
        ref = read_bgr(reference)
        bg_path = background if background is not None else reference.parent / "background.png"
        if not bg_path.is_file():
            raise InputError("no background frame", path=bg_path, field="--background", expected="a no-contact image")
        bg = read_bgr(bg_path)
        H, W = ref.shape[:2]
        pitch = mm_per_px if mm_per_px is not None else 0.0295 * 640.0 / W
        ref_mask = gd.detect_contact(ref, bg, path=reference)
        if ref_force is not None:
            ref_d = gd.hertz_depth_mm(ref_force, ball_radius_mm)
        elif ref_depth is not None:
            ref_d = ref_depth
        else:  # the contact circle of a sphere: a = sqrt(area / pi)
            ref_d = press_depth_mm(ball_radius_mm, (float(ref_mask.sum()) / 3.141592653589793) ** 0.5 * pitch)
        tgt_d = gd.hertz_depth_mm(force, ball_radius_mm) if force is not None else depth
        tmask = None
        if mask is not None:
            m = cv2.imread(str(mask), cv2.IMREAD_GRAYSCALE)
            if m is None:
                raise InputError("cannot read mask image", path=mask, field="--mask")
            tmask = gd.check_mask(m > 127, (H, W), path=mask)
        pose = _parse_position(position) if position is not None else None
        labelled = _parse_position(ref_pose, "--ref-pose") if ref_pose is not None else None
        if pose is not None:
            rp = labelled if labelled is not None else gd.mask_pose(ref_mask)
            pose = gd.Pose(pose.x, pose.y, rp.theta_deg + pose.theta_deg)
        gen = TactileGenerator(weights, mode=mode)
        img = gen.generate(
            ref,
            bg,
            ref_depth_mm=ref_d,
            target_depth_mm=tgt_d,
            target_pose=pose,
            target_mask=tmask,
            ref_mask=ref_mask,
            ref_pose=labelled,
        )
        out.parent.mkdir(parents=True, exist_ok=True)
        cv2.imwrite(str(out), img)
        report(
            "tactile generate",
            {
                "out": str(out),
                "mode": mode,
                "ref_depth_mm": ref_d,
                "target_depth_mm": tgt_d,
                "target_force_n": gd.hertz_force_n(tgt_d, ball_radius_mm),
            },
            None,
        )

    @tac.command("generate-train")
    def generate_train_cmd(
        out: Path = typer.Option(None, "--out", help="weights to write (default: the shipped file in the package)"),
        pressset: Path = typer.Option(
            None, "--pressset", help="real labelled GelSight press set (default: shared gelsight_ball_presses)"
        ),
        minutes: float = typer.Option(13.0, "--minutes", help="total training budget (stages split 9:5:5)"),
        no_hybrid: bool = typer.Option(False, "--no-hybrid", help="skip the hybrid baseline"),
        threads: int = typer.Option(2, "--train-threads", help="torch threads for training"),
        seed: int = typer.Option(0, "--seed"),
        extras: str = typer.Option(
            "",
            "--extras",
            help="extra baselines, comma-separated: separate (position-only model after stage 1), flow "
            "(few-step rectified-flow stage 1), flowx (the same, predicting the clean target); "
            "each adds 3-6 min to a full run; with --update also stage2 (retrain the control branch on the "
            "file's frozen stage 1, --stage2-steps steps)",
        ),
        stage2_steps: int = typer.Option(
            0, "--stage2-steps", help="--extras stage2: optimiser steps (0 = the file's hybrid steps)"
        ),
        update: Path = typer.Option(
            None,
            "--update",
            help="existing weights: train only --extras (step counts matched to its stage 1 / hybrid) and add "
            "them to a copy of it (written to --out, default the same file)",
        ),
    ) -> None:
        """Train the generator: stage 1 (depth/force), stage 2 (position ControlNet), hybrid baseline."""
        import math

        from vtrack.errors import InputError
        from vtrack.tactile.generate.train import TrainConfig, train
        from vtrack_apps.output import print_table

        if not (math.isfinite(minutes) and minutes > 0):
            raise InputError("training budget must be a positive number of minutes", field="--minutes", got=minutes)
        total = minutes * 60.0
        ex = tuple(e.strip() for e in extras.split(",") if e.strip())
        if update is not None and not ex:
            raise InputError("--update needs --extras", field="--extras", expected="separate,flow")
        if update is not None and not update.is_file():
            raise InputError("weights to update not found", path=update, field="--update")
        parts = (9, 5, 0 if no_hybrid else 5)
        s = total / sum(parts)
        cfg = TrainConfig(
            stage1_seconds=parts[0] * s,
            stage2_seconds=parts[1] * s,
            hybrid_seconds=parts[2] * s,
            train_hybrid=not no_hybrid,
            threads=threads,
            seed=seed,
            extras=ex,
            stage2_max_steps=max(0, stage2_steps),
        )
        if update is not None:  # the step counts decide; the minutes only cap each extra
            cfg.position_seconds = cfg.flow_seconds = cfg.stage2_seconds = total / len(ex)
        path = train(cfg, out if out is not None or update is None else update, pressset, update=update)
        print_table("generate-train", cfg.log)
        typer.echo(f"wrote {path}")

    @tac.command("generate-eval")
    def generate_eval_cmd(
        pressset: Path = typer.Argument(..., help="labelled real press set"),
        json_out: Path = typer.Option(None, "--json", help="write the scores (JSON)"),
        weights: Path = typer.Option(None, "--weights", help="generator weights .pt (default: shipped)"),
        holdout: str = typer.Option(
            None, "--holdout", help="presses to score (default: the weights' real hold-out; 'all' = every press)"
        ),
        reference: str = typer.Option(None, "--reference", help="reference press file (default: first scored press)"),
        max_presses: int = typer.Option(0, "--max-presses", help="> 0: score only that many targets"),
        modes: str = typer.Option(
            "",
            "--modes",
            help="generator modes, comma-separated (default: two_stage, stage1 and every baseline in the weights)",
        ),
    ) -> None:
        """Generate every held-out press from one reference; crop/full MSE, SSIM, PSNR vs three baselines."""
        from vtrack.tactile.generate.evaluate import METRICS, generate_eval
        from vtrack_apps.output import print_table, write_json

        md = tuple(m.strip() for m in modes.split(",") if m.strip()) or None
        res = generate_eval(
            pressset, weights=weights, holdout=holdout, reference=reference, max_presses=max_presses, modes=md
        )
        names = ["generator", *res["modes"][1:], "shift", "copy", "background"]
        print_table(
            f"generate-eval {Path(pressset).name}: {res['n']} presses from {res['reference']} "
            f"(generator {res['ms_per_image']:.1f} ms/image)",
            [{"method": n} | {m: res[n][m] for m in METRICS} for n in names],
        )
        if res["trained_on_targets"]:
            print(
                f"warning: {res['trained_on_targets']} of the {res['n']} scored presses were used to train these "
                "weights: these are not held-out numbers (omit --holdout to score the held-out presses)"
            )
        if json_out:
            write_json(json_out, res)
