"""``vtrack calibrate`` and ``vtrack tactile ...``: tactile calibration, press evaluation, single images.

Heavy imports (torch via the MLP calibration, OpenCV, scipy) happen inside the command functions.
"""

from __future__ import annotations

from pathlib import Path

import typer

_PRESS_HELP = "press-set folder (labels.csv, background.png, press images; meta.json or a preset)"


def _load_set(
    pressset: Path, meta: Path | None, sensor: str | None, mm_per_px: float | None, ball_radius_mm: float | None
):
    from vtrack.tactile.pressset import load_press_set

    return load_press_set(pressset, meta, sensor=sensor, mm_per_px=mm_per_px, ball_radius_mm=ball_radius_mm)


def _eval(ps, calib, presses, solver: str, downsample: int) -> dict:
    from vtrack.tactile.evaluation import evaluate_calibration

    label = {"press_set": str(ps.root), "method": calib.method, "solver": solver, "downsample": downsample}
    return evaluate_calibration(ps, calib, presses, solver=solver, downsample=downsample, label=label)


def register(app: typer.Typer) -> None:
    @app.command("calibrate")
    def calibrate_cmd(
        pressset: Path = typer.Argument(..., help=_PRESS_HELP),
        out: Path = typer.Option(..., "--out", help="calibration file to write (.npz)"),
        json_out: Path = typer.Option(None, "--json", help="write the calibration report (JSON)"),
        method: str = typer.Option(
            "auto",
            "--method",
            help="auto (the model with the lowest cross-validated error on your training presses: MLP of "
            "width 64/32/16, LUT or photometric stereo) | lut | lut_raw | mlp | ps",
        ),
        holdout: str = typer.Option(
            "every:4:3", "--holdout", help="every:K[:OFF] | idx:1,5 | files:a.png,b.png | last:N | none"
        ),
        compare: bool = typer.Option(False, "--compare", help="also train and evaluate every other method"),
        meta: Path = typer.Option(None, "--meta", help="press-set meta JSON (sensor, mm_per_px, ball_radius_mm)"),
        sensor: str = typer.Option(None, "--sensor", help="override meta: sensor name"),
        mm_per_px: float = typer.Option(None, "--mm-per-px", help="override meta: pixel pitch, mm"),
        ball_radius_mm: float = typer.Option(None, "--ball-radius-mm", help="override meta: ball radius, mm"),
        lut_bins: int = typer.Option(None, "--lut-bins", help="LUT bins per colour channel (default: TrainOptions)"),
        mlp_hidden: int = typer.Option(None, "--mlp-hidden", help="MLP hidden width (default: TrainOptions)"),
        mlp_epochs: int = typer.Option(None, "--mlp-epochs", help="MLP training epochs (default: TrainOptions)"),
        downsample: str = typer.Option(
            "auto",
            "--downsample",
            help="working-resolution factor of the held-out / cross-validated evaluation: auto (the tactile "
            "pipeline's default, what the calibration is used at) or an integer >= 1",
        ),
        train_res: str = typer.Option(
            "cv",
            "--train-res",
            help="resolution of the training pixels: cv (--method auto: the chosen model at full and at the "
            "pipeline's working resolution, the better by cross-validation) | full | work",
        ),
        labels: str = typer.Option(
            "hand_or_auto", "--labels", help="hand (labels.csv) | auto (detect contacts) | hand_or_auto"
        ),
        review: Path = typer.Option(None, "--review", help="auto labels: draw every detected circle into this PNG"),
        edge_choice: str = typer.Option(
            "cv",
            "--edge-choice",
            help="auto labels + --method auto: choose the edge placement again with the chosen model: off | "
            "heldout (on the held-out presses) | cv (cross-validated over the training presses)",
        ),
        refit_all: bool = typer.Option(
            False,
            "--refit-all",
            help="after the held-out check, train the written calibration on every usable press (held-out too)",
        ),
    ) -> None:
        """Learn colour(+position) -> surface normal from ball presses; report held-out errors.

        Without labels.csv the contact circles are detected automatically (labels.auto.csv is written beside
        --out, with the reason for every dropped press). A calibration whose held-out normal error exceeds
        15 deg is not written (exit 2).
        """
        from vtrack.errors import InputError
        from vtrack.tactile.autolabel import write_auto_labels
        from vtrack.tactile.calibrate_set import MAX_NORMAL_ERR_DEG, calibrate_press_set
        from vtrack.tactile.calibration import METHODS, TrainOptions, calibrate
        from vtrack_apps.output import print_table, write_json

        if method not in METHODS + ("auto",):
            raise InputError(
                "unknown calibration method", field="--method", expected=" | ".join(METHODS + ("auto",)), got=method
            )
        # defaults live in TrainOptions only (the CLI used to train a 32-wide MLP while the library's is 64)
        reselect = {"off": False, "heldout": True, "cv": "cv"}
        if edge_choice not in reselect:
            raise InputError(
                "unknown edge choice", field="--edge-choice", expected=" | ".join(reselect), got=edge_choice
            )
        given = {"lut_bins": lut_bins, "mlp_hidden": mlp_hidden, "mlp_epochs": mlp_epochs}
        opts = TrainOptions(**{k: v for k, v in given.items() if v is not None})
        if downsample != "auto":
            try:
                downsample = int(downsample)
            except ValueError:
                raise InputError(
                    "bad working-resolution factor",
                    field="--downsample",
                    expected="auto | integer >= 1",
                    got=downsample,
                ) from None
        run = calibrate_press_set(
            pressset,
            method=method,
            holdout=holdout,
            opts=opts,
            labels=labels,
            meta_file=meta,
            sensor=sensor,
            mm_per_px=mm_per_px,
            ball_radius_mm=ball_radius_mm,
            downsample=downsample,
            reselect_edge=reselect[edge_choice],
            refit_all=refit_all,
            train_res=train_res,
        )
        ps, train, test = run.press_set, run.train, run.test
        from vtrack.tactile.sensors import orientation_warning, press_count_warning

        turned = orientation_warning(ps.sensor, ps.shape[1], ps.shape[0])
        if turned:
            typer.echo(f"warning: {turned}")
        few = press_count_warning(ps.sensor, len(ps.presses))
        if few:
            typer.echo(f"warning: {few}")
        if ps.mm_per_px_source == "preset":
            typer.echo(
                f"warning: mm_per_px not given: using the {ps.sensor} preset's nominal {ps.mm_per_px:.4f} mm/px "
                f"at {ps.shape[1]}x{ps.shape[0]} px (unverified; pass --mm-per-px or add it to meta.json)"
            )
        auto_csv = None
        if ps.labels_source == "auto":
            auto_csv = write_auto_labels(out.parent / "labels.auto.csv", ps.detections)
            dropped = [d for d in ps.detections if not d.ok]
            typer.echo(f"auto labels: {len(ps.presses)} presses used, {len(dropped)} dropped -> {auto_csv}")
            for d in dropped:
                typer.echo(f"  dropped {d.file}: {d.reason}")
            if run.edge_trials:
                print_table(
                    "edge placement (held-out presses, all scored on the middle placement's circles; "
                    "chosen by fitted ball radius)",
                    run.edge_trials,
                )
            if review is not None:
                from vtrack.tactile.autolabel import review_sheet

                typer.echo(f"wrote {review_sheet(ps.root, ps.detections, review)}")
        elif review is not None:
            typer.echo("--review: hand labels used (labels.csv), nothing detected to review")
        expected = None
        if run.cv:
            print_table(
                f"model choice ({run.cv[0]['folds']}-fold cross-validation over the {len(train)} training "
                "presses, whole presses per fold)",
                run.cv,
            )
            best = next(r for r in run.cv if r["chosen"])
            expected = {
                "model": best["model"],
                "folds": best["folds"],
                "radius_abs_err_pct_median": best["radius_abs_err_pct_median"],
                "normal_err_deg_median": best["normal_err_deg_median"],
            }
            edge_cv = run.calib.info.get("cv_expected")
            if edge_cv:  # the chosen model at the chosen placement, cross-validated (--edge-choice cv)
                expected.update(
                    folds=edge_cv["folds"],
                    radius_abs_err_pct_median=edge_cv["radius_abs_err_pct_median"],
                    normal_err_deg_median=edge_cv["normal_err_deg_median"],
                )
            typer.echo(
                f"chosen: {best['model']}; expected on new presses of this sensor (cross-validated): radius "
                f"{expected['radius_abs_err_pct_median']:.2f} %, normals {expected['normal_err_deg_median']:.2f} deg"
            )
        method = run.calib.method
        results = []
        for m in [method] + ([m for m in METHODS if m != method] if compare else []):
            calib = run.calib if m == method else calibrate(ps, m, train, opts)
            calib.info["holdout"] = holdout
            calib.info["labels"] = ps.labels_source
            calib.info["mm_per_px_source"] = ps.mm_per_px_source
            row = {
                "method": m,
                "model": run.calib.info.get("model", m) if m == method else m,
                "train_seconds": calib.info["train_seconds"],
                "height_noise_mm": calib.info["height_noise_mm"],
            }
            if test:
                row.update(run.held_out if m == method else _eval(ps, calib, test, "dct", downsample)["summary"])
            results.append(row)
        report = {
            "press_set": str(ps.root),
            **ps.meta(),
            "mm_per_px_source": ps.mm_per_px_source,
            "out": str(out),
            "method": method,
            "model": run.calib.info.get("model", method),
            "cv_expected": expected,
            "holdout": holdout,
            "labels": ps.labels_source,
            "labels_auto_csv": str(auto_csv) if auto_csv else None,
            "edge_trials": run.edge_trials,
            "cv": run.cv,
            "train_files": [p.file for p in train],
            "test_files": [p.file for p in test],
            "results": results,
        }
        print_table(
            f"calibrate {ps.root.name} ({len(train)} train / {len(test)} held out, {ps.labels_source} labels)", results
        )
        if json_out:
            write_json(json_out, report)
        if not run.plausible:
            bad_held = run.held_out is not None and run.held_out["normal_err_deg_median"] > MAX_NORMAL_ERR_DEG
            h = run.held_out if bad_held else expected
            raise InputError(
                f"calibration not written: {'held-out' if bad_held else 'cross-validated'} normal error "
                f"{h['normal_err_deg_median']:.1f} deg (radius error {h['radius_abs_err_pct_median']:.1f} %) "
                "is implausible",
                path=out,
                expected=f"<= {MAX_NORMAL_ERR_DEG:g} deg: check the presses, labels and meta",
            )
        if not test:
            typer.echo("warning: nothing held out (--holdout none): the calibration's accuracy is unchecked")
        if run.calib.info.get("refit_all"):
            typer.echo(
                f"refitted on all {len(ps.presses)} presses (the held-out errors above are of the model trained "
                f"on the {len(train)} training presses)"
            )
        run.calib.save(out)  # its info (holdout, labels) was set in the results loop above
        typer.echo(f"wrote {out}")

    tac = typer.Typer(help="Tactile pipeline: press evaluation, single images.", no_args_is_help=True)
    app.add_typer(tac, name="tactile")

    @tac.command("eval-presses")
    def eval_presses(
        pressset: Path = typer.Argument(..., help=_PRESS_HELP),
        calib: Path = typer.Option(..., "--calib", help="calibration .npz from `vtrack calibrate`"),
        json_out: Path = typer.Option(None, "--json", help="write per-press results + summary (JSON)"),
        holdout: str = typer.Option(
            None, "--holdout", help="presses to evaluate (default: those the calibration did not train on)"
        ),
        solver: str = typer.Option("dct", "--solver", help="Poisson solver: dct | fft | lsq"),
        downsample: int = typer.Option(1, "--downsample", help="working-resolution factor"),
        meta: Path = typer.Option(None, "--meta", help="press-set meta JSON"),
        sensor: str = typer.Option(None, "--sensor"),
        mm_per_px: float = typer.Option(None, "--mm-per-px"),
        ball_radius_mm: float = typer.Option(None, "--ball-radius-mm"),
    ) -> None:
        """Reconstruct held-out ball presses; fitted radius, normal error, shape RMSE, ms per frame."""
        from vtrack.tactile.calibration import Calibration, held_out_presses
        from vtrack_apps.output import print_table, write_json

        ps = _load_set(pressset, meta, sensor, mm_per_px, ball_radius_mm)
        cal = Calibration.load(calib)
        presses = held_out_presses(cal, ps) if holdout is None else ps.split(holdout)[1]
        res = _eval(ps, cal, presses, solver, downsample)
        res["calib"] = str(calib)
        print_table(
            f"eval-presses {ps.root.name} ({cal.method}, {solver}, downsample {downsample})",
            [{k: v for k, v in r.items() if k != "index"} for r in res["presses"]],
        )
        print_table("summary", res["summary"])
        if json_out:
            write_json(json_out, res)

    @tac.command("height")
    def height_cmd(
        image: Path = typer.Argument(..., help="tactile image (BGR PNG/JPEG)"),
        calib: Path = typer.Option(..., "--calib", help="calibration .npz"),
        out: Path = typer.Option(..., "--out", help="output folder: height_mm.npy, contact.png, points.ply"),
        background: Path = typer.Option(None, "--background", help="no-contact frame (default: the calibration's)"),
        solver: str = typer.Option("dct", "--solver", help="dct | fft | lsq"),
        downsample: int = typer.Option(1, "--downsample"),
    ) -> None:
        """Run the pipeline on one image; write the height map, contact mask and contact points."""
        import cv2
        import numpy as np

        from vtrack.tactile.pipeline import TactilePipeline
        from vtrack.tactile.pressset import read_bgr
        from vtrack_apps.output import report

        bg = read_bgr(background) if background else None
        pipe = TactilePipeline(calib, background=bg, solver=solver, downsample=downsample)
        f = pipe.process(read_bgr(image))
        out.mkdir(parents=True, exist_ok=True)
        np.save(out / "height_mm.npy", f.height_mm)
        cv2.imwrite(str(out / "contact.png"), f.contact.astype(np.uint8) * 255)
        hv = f.height_mm / max(float(f.height_mm.max()), 1e-6)
        cv2.imwrite(
            str(out / "height.png"), cv2.applyColorMap(np.clip(hv * 255, 0, 255).astype(np.uint8), cv2.COLORMAP_VIRIDIS)
        )
        _write_ply(out / "points.ply", f.points, f.normals)
        s = f.stats
        report(
            "tactile height",
            {
                "in_contact": f.in_contact,
                "area_mm2": s.area_mm2,
                "max_depth_mm": s.max_depth_mm,
                "centroid_px": s.centroid_px,
                "n_points": len(f.points),
                **f.timings_ms,
            },
            out / "summary.json",
        )

    from vtrack_apps.commands._tactile_generate import register_generate

    register_generate(tac)


def _write_ply(path: Path, pts, nrm) -> None:
    """ASCII PLY with normals (sensor frame, m)."""
    with open(path, "w") as fh:
        fh.write(
            "ply\nformat ascii 1.0\n"
            f"element vertex {len(pts)}\nproperty float x\nproperty float y\nproperty float z\n"
            "property float nx\nproperty float ny\nproperty float nz\nend_header\n"
        )
        for p, n in zip(pts, nrm, strict=True):
            fh.write(f"{p[0]:.7g} {p[1]:.7g} {p[2]:.7g} {n[0]:.5g} {n[1]:.5g} {n[2]:.5g}\n")
