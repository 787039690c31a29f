"""``vtrack dome``: dome-sensor simulator, training, evaluation and single-image reconstruction."""

from __future__ import annotations

from pathlib import Path

import typer

from vtrack.io.jsonio import write_json


def _write_json_out(json_out: Path | None, data: object) -> None:
    """``--json OUT`` of the dome commands: write ``data`` there (if given) and say so."""
    if json_out:
        write_json(json_out, data, indent=1)
        typer.echo(f"wrote {json_out}")


def register(app: typer.Typer) -> None:
    dome_app = typer.Typer(
        help="Dome (TacTip/FusionTouch-style) marker sensor: simulate, train, eval, reconstruct.", no_args_is_help=True
    )
    app.add_typer(dome_app, name="dome")

    @dome_app.command("simulate")
    def simulate(
        out: Path = typer.Option(..., "--out", help="output folder (images + gt.npz)"),
        n: int = typer.Option(20, "--n", min=1, help="number of samples"),
        seed: int = typer.Option(0, "--seed"),
    ) -> None:
        """Simulate dome presses: PNG images, their no-contact reference frames (at each press's operating
        pressure: dome_XXXXX_ref.png) and ground truth (markers, templates, contact, force, pressure) in gt.npz."""
        import cv2
        import numpy as np

        from vtrack.dome.simulate import make_dataset

        data = make_dataset(n, seed, cache=False)
        out.mkdir(parents=True, exist_ok=True)
        for i, img in enumerate(data["image"]):
            cv2.imwrite(str(out / f"dome_{i:05d}.png"), img)
        refs = data["reference_image"]
        if refs.ndim == 3:
            for i, ref in enumerate(refs):
                cv2.imwrite(str(out / f"dome_{i:05d}_ref.png"), ref)
        else:
            cv2.imwrite(str(out / "reference.png"), refs)
        np.savez_compressed(out / "gt.npz", **{k: v for k, v in data.items() if k not in ("image", "reference_image")})
        typer.echo(f"wrote {n} images, their reference frames and gt.npz to {out}")

    @dome_app.command("train")
    def train(
        out: Path = typer.Option(None, "--out", help="weights folder (default: the shipped vtrack/dome/weights)"),
        n_train: int = typer.Option(2000, "--n-train", min=16),
        n_test: int = typer.Option(300, "--n-test", min=8),
        epochs_coarse: int = typer.Option(8, "--epochs-coarse", min=1),
        epochs_fine: int = typer.Option(6, "--epochs-fine", min=1),
        epochs_force: int = typer.Option(20, "--epochs-force", min=1),
        seed: int = typer.Option(0, "--seed"),
        methods: str = typer.Option("gnn,cnn", "--methods", help="comma list of gnn, cnn"),
        jobs: int = typer.Option(2, "--jobs", min=1, help="methods trained in parallel, 1 thread each"),
        quick: bool = typer.Option(False, "--quick", help="tiny run (smoke test, not for shipping)"),
        recon_loss: str = typer.Option(
            "mix", "--recon-loss", help="mix (shipped: L2 + L1 on still points) | paper (FusionTouch S9, S14-S17, L1)"
        ),
    ) -> None:
        """Simulate (cached) and train GNN and CNN with the same budget; writes <method>.pt bundles."""
        import json
        from concurrent.futures import ProcessPoolExecutor
        from multiprocessing import get_context

        from vtrack.dome.model import DomeConfig
        from vtrack.dome.train import TrainConfig, load_sets, train_all, weights_dir

        epochs_force_net = TrainConfig().epochs_force_net
        if quick:
            n_train, n_test, epochs_coarse, epochs_fine, epochs_force, epochs_force_net = 128, 32, 1, 1, 1, 1
        tc = TrainConfig(
            n_train=n_train,
            n_test=n_test,
            seed=seed,
            epochs_coarse=epochs_coarse,
            epochs_fine=epochs_fine,
            epochs_force=epochs_force,
            epochs_force_net=epochs_force_net,
            recon_loss=recon_loss,
        )
        if recon_loss not in ("mix", "paper"):
            from vtrack.errors import InputError

            raise InputError(
                "unknown reconstruction loss", field="--recon-loss", expected="mix or paper", got=recon_loss
            )
        out = out or weights_dir()
        kinds = tuple(m.strip() for m in methods.split(",") if m.strip())
        load_sets(tc, DomeConfig(), progress=True)  # simulate once, before the workers read the cache
        res: dict = {}
        if jobs > 1 and len(kinds) > 1:
            with ProcessPoolExecutor(min(jobs, len(kinds)), mp_context=get_context("spawn")) as ex:
                futs = {k: ex.submit(train_all, tc, None, out, (k,)) for k in kinds}
                for _k, f in futs.items():
                    res.update(f.result())
        else:
            res = train_all(tc, None, out, kinds)
        typer.echo(json.dumps(res, indent=1))

    @dome_app.command("retarget")
    def retarget(
        kind: str = typer.Option(..., "--kind", help="gnn or cnn"),
        out: Path = typer.Option(..., "--out", help="bundle to write (merge parts with `vtrack dome merge`)"),
        src: Path = typer.Option(None, "--from", help="bundle whose reconstruction net is kept (default: shipped)"),
        keys: str = typer.Option("p,nop", "--keys", help="force nets: p, nop, legacy, plain_p, plain_nop"),
        epochs: int = typer.Option(12, "--epochs", min=1, help="epochs of the S18-S23 force nets"),
        n_train: int = typer.Option(2000, "--n-train", min=32),
    ) -> None:
        """Move a bundle to today's sensor config (``DomeConfig()``: confined inflation) keeping its reconstruction
        net: retrain the listed force nets and the contact calibration on that config's simulated presses."""
        import dataclasses

        from vtrack.dome.bundle import bundle_train_config, read_bundle
        from vtrack.dome.reconstruct import default_weights
        from vtrack.dome.train import retarget_bundle
        from vtrack.errors import InputError

        if kind not in ("gnn", "cnn"):
            raise InputError("unknown model kind", field="--kind", expected="gnn or cnn", got=kind)
        ks = tuple(k.strip() for k in keys.split(",") if k.strip())
        bad = [k for k in ks if k not in ("p", "nop", "legacy", "plain_p", "plain_nop")]
        if bad or not ks:
            raise InputError(
                "unknown force net key", field="--keys", expected="p, nop, legacy, plain_p, plain_nop", got=keys
            )
        src = src or default_weights(kind)
        tc = dataclasses.replace(
            bundle_train_config(read_bundle(src)), epochs_force_net=epochs, n_train=n_train, threads=1
        )
        info = retarget_bundle(src, out, None, tc, ks)
        typer.echo(f"wrote {out} ({info['retargeted_from']['changed']})")

    @dome_app.command("merge")
    def merge(
        parts: list[Path] = typer.Argument(..., help="bundles with the same reconstruction net, different force nets"),
        out: Path = typer.Option(..., "--out", help="merged bundle"),
        test: bool = typer.Option(True, "--test/--no-test", help="store the held-out metrics in the bundle"),
    ) -> None:
        """Merge the force nets of several bundles (e.g. parallel `vtrack dome retarget` runs) into one bundle and
        store its held-out metrics."""
        import json

        from vtrack.dome.train import merge_bundles

        info = merge_bundles(list(parts), out, evaluate_test=test)
        typer.echo(json.dumps(info.get("test", {}), indent=1))

    @dome_app.command("eval")
    def eval_(
        json_out: Path = typer.Option(None, "--json", help="write {gnn: {...}, cnn: {...}}"),
        weights: Path = typer.Option(None, "--weights", help="weights folder (default: shipped)"),
        n_test: int = typer.Option(300, "--n-test", min=4),
        seed: int = typer.Option(12345, "--seed", help="test-set seed (12345 = the held-out set)"),
        markers: bool = typer.Option(True, "--markers/--no-markers", help="marker detection: U-Net vs classic"),
        n_markers: int = typer.Option(100, "--n-markers", min=4, help="held-out simulated frames for markers"),
        handpose: bool = typer.Option(True, "--handpose/--no-handpose", help="hand-pose nets (S24-S27), 500 grasps"),
        methods: str = typer.Option("gnn,cnn", "--methods", help="comma list of gnn, cnn"),
    ) -> None:
        """Metrics of GNN and CNN on the held-out simulated test set (mm, N, ms); ``force``: the Table S6
        ablation (with / without pressure, per axis; ``oracle_no_p`` = the floor of any estimator blind to P);
        ``markers``: U-Net vs classic marker detection; ``handpose``: the S24-S27 nets on held-out grasps."""

        from vtrack.dome.evaluate import EVAL_KEYS, evaluate, force_table, marker_eval
        from vtrack_apps.output import print_table

        kinds = tuple(m.strip() for m in methods.split(",") if m.strip())
        if not kinds or any(k not in ("gnn", "cnn") for k in kinds):
            from vtrack.errors import InputError

            raise InputError("unknown method", field="--methods", expected="gnn and/or cnn", got=methods)
        res: dict = evaluate(weights, n_test, seed, kinds)
        print_table("dome eval", [{"method": m, **{k: round(r[k], 4) for k in EVAL_KEYS}} for m, r in res.items()])
        res["force"] = force_table(res)
        if seed == 12345 and n_test == 300:  # floor of any no-pressure estimator blind to P (vtrack.dome.pressure)
            from vtrack.dome.pressure import oracle_force_floor

            res["force"]["oracle_no_p"] = oracle_force_floor(n_test, seed)["oracle_no_p"]
        print_table(
            "dome force (N)",
            [{"setting": k, **{m: round(v, 4) for m, v in r.items()}} for k, r in res["force"].items()],
        )
        if markers:
            res["markers"] = marker_eval(n_markers)
            rows = [
                {"frames": f"simulated held-out ({n_markers})", "method": m, **res["markers"][m]}
                for m in ("unet", "classic")
            ]
            rows += [{"frames": k, **v} for k, v in res["markers"].get("tactip", {}).items()]
            print_table("dome markers", rows)
        if handpose:
            from vtrack.dome.handpose import evaluate_handpose_sets

            res["handpose"] = evaluate_handpose_sets()
            print_table(
                "dome hand pose, varied grasps (simulated, deg)",
                [
                    {
                        "modality": m,
                        **{k: round(res["handpose"][m][k], 3) for k in ("mae_deg", "rmse_deg", "acc1", "acc5")},
                    }
                    for m in ("rgb", "ir", "dual")
                ],
            )
        _write_json_out(json_out, res)

    @dome_app.command("segment")
    def segment(
        train: bool = typer.Option(False, "--train", help="train the marker U-Net first (writes --weights)"),
        weights: Path = typer.Option(None, "--weights", help="U-Net file (default: shipped marker_unet.pt)"),
        n_train: int = typer.Option(1200, "--n-train", min=16),
        epochs: int = typer.Option(12, "--epochs", min=1),
        n_test: int = typer.Option(100, "--n-test", min=2, help="held-out simulated frames"),
        json_out: Path = typer.Option(None, "--json", help="write the detection results as JSON"),
    ) -> None:
        """Marker segmentation (FusionTouch S4): U-Net vs classic Otsu + k-means extractor, detection rate and
        position error on held-out simulated frames, pin counts and track continuity on the real TacTip frames."""
        import torch

        from vtrack.dome.segment import MarkerSegmenter, evaluate_simulated, evaluate_tactip, train_unet
        from vtrack.paths import shared_data_dir
        from vtrack_apps.output import print_table

        torch.set_num_threads(1)
        if train:
            weights = train_unet(n_train, epochs, out=weights)
        seg = MarkerSegmenter(weights)
        res: dict = {}
        for hard in (True, False):
            r = evaluate_simulated(seg, n_test, 777 if hard else 778, hard=hard)
            res["simulated_hard" if hard else "simulated_plain"] = r
            print_table(
                f"markers, simulated ({'hard' if hard else 'plain'})", [{"method": k, **v} for k, v in r.items()]
            )
        if (shared_data_dir() / "tactip_frames").exists():
            res["tactip"] = evaluate_tactip(seg)
            print_table("markers, real TacTip", list(res["tactip"].values()))
        _write_json_out(json_out, res)

    @dome_app.command("reconstruct")
    def reconstruct(
        image: Path = typer.Argument(..., help="dome-sensor image (grey or colour)"),
        pressure: float = typer.Option(0.0, "--pressure", help="internal (operating) pressure, kPa"),
        method: str = typer.Option("gnn", "--method", help="gnn | cnn"),
        weights: Path = typer.Option(None, "--weights", help="bundle .pt (default: shipped)"),
        reference: Path = typer.Option(
            None, "--reference", help="no-contact image of the same sensor at the same pressure"
        ),
        resize: bool = typer.Option(False, "--resize", help="rescale the image to the model's input size"),
        out: Path = typer.Option(None, "--out", help="write mesh.ply, coarse.ply, result.json here"),
    ) -> None:
        """One image (+ pressure) -> dense dome surface (mm), contact mask and force (N)."""
        import json

        from vtrack.dome.reconstruct import DomeReconstructor

        rec = DomeReconstructor(method, weights, reference)
        res = rec.reconstruct(image, pressure, resize=resize)
        if not res.valid:  # refuse rather than print a confident force for an unreadable image
            from vtrack.errors import InputError

            raise InputError(
                res.info["invalid_reason"],
                path=image,
                field="image",
                expected="a marker image of this dome sensor (same size, pressure, lighting)",
            )
        typer.echo(json.dumps(res.summary(), indent=1))
        if out:
            paths = res.save(out)
            typer.echo(f"wrote {', '.join(str(p) for p in paths.values())}")

    @dome_app.command("pressure-ablation")
    def pressure_ablation_cmd(
        inflation: float = typer.Option(0.0, "--inflation", min=0.0, help="shell inflation, mm per kPa (shipped 0.03)"),
        n_train: int = typer.Option(2000, "--n-train", min=32),
        epochs: int = typer.Option(12, "--epochs", min=1),
        json_out: Path = typer.Option(None, "--json", help="write the with / without pressure rows + oracle floor"),
    ) -> None:
        """Is the pressure observable from the image? Retrain the GNN + patch force nets with and without P on
        data simulated with the given inflation (0 = a double shell that confines it) and compare with the
        oracle floor of any estimator that cannot see P (``vtrack.dome.pressure``)."""
        from vtrack.dome.pressure import pressure_ablation
        from vtrack_apps.output import print_table

        res = pressure_ablation(inflation, n_train=n_train, epochs=epochs)
        keys = ("gnn_patch_with_p", "gnn_patch_no_p", "oracle_no_p", "zero_force")
        print_table(
            f"dome force, inflation {inflation} mm/kPa (N)",
            [{"setting": k, **{m: round(v, 4) for m, v in res[k].items()}} for k in keys],
        )
        typer.echo(f"with pressure {100 * res['gain_with_p']:.0f} % lower MAE than without")
        _write_json_out(json_out, res)

    handpose_app = typer.Typer(
        help="Hand pose (FusionTouch S24-S27): 12 joint angles from the 70 mm dome's RGB and/or IR frame.",
        no_args_is_help=True,
    )
    dome_app.add_typer(handpose_app, name="handpose")

    @handpose_app.command("train")
    def handpose_train(
        out: Path = typer.Option(
            None, "--out", help="weights file (default: the shipped one of the grasp set, weights/handpose_varied.pt)"
        ),
        grasp_set: str = typer.Option(
            "varied", "--grasp-set", help="training / held-out grasps: varied (default), mixed or contact"
        ),
        n_train: int = typer.Option(
            6000, "--n-train", min=32, help="simulated training grasps (cached chunks of 3000)"
        ),
        steps: int = typer.Option(6000, "--steps", min=1, help="optimizer steps per single net"),
        fusion_steps: int = typer.Option(3000, "--fusion-steps", min=1, help="optimizer steps of the dual fusion head"),
        ir_encoder: str = typer.Option("markers", "--ir-encoder", help="markers (marker-centred patches) or cnn"),
        modalities: str = typer.Option("rgb,ir,dual", "--modalities", help="comma list of rgb, ir, dual"),
        seed: int = typer.Option(0, "--seed"),
        model_seed: int = typer.Option(
            0, "--model-seed", min=0, help="init / batch-order seed offset (seed ensembles; data and split stay)"
        ),
        n_contact: int = typer.Option(
            0, "--n-contact", min=0, help="extra training grasps with every fingertip on the shell (contact set)"
        ),
        init: Path = typer.Option(None, "--init", help="fine-tune the single nets from this weights file"),
        lr: float = typer.Option(2e-3, "--lr", min=1e-6, help="peak learning rate (one-cycle)"),
        time_budget_min: float = typer.Option(
            0.0, "--time-budget-min", min=0.0, help="stop a net at the first validation past this (min; 0 = none)"
        ),
        joint_weights: str = typer.Option(
            "", "--joint-weights", help="training-loss weights per joint, e.g. thumb_mcp=2,thumb_ip=3 (others 1)"
        ),
        select_weighted: bool = typer.Option(
            False, "--select-weighted", help="checkpoint on the --joint-weights-weighted validation loss (specialists)"
        ),
        width: int = typer.Option(16, "--width", min=4, max=64, help="base width of the RGB image encoder"),
        rgb_crop: str = typer.Option(
            "", "--rgb-crop", help="RGB net reads only row,col,side,upsampling of the frame (e.g. thumb: 26,0,32,2)"
        ),
        rotate_deg: float = typer.Option(
            0.0, "--rotate-deg", min=0.0, max=180.0, help="augment RGB frames: turn about the centre by +- this (deg)"
        ),
        val_base: int = typer.Option(
            0,
            "--val-base",
            min=0,
            help="nested split: the first N grasps keep the validation grasps of a run on N (0 = one split of all)",
        ),
        json_out: Path = typer.Option(None, "--json", help="write the training summary + held-out metrics"),
    ) -> None:
        """Simulate grasps (cached), train the single- and dual-modality regressors (loss S25-S27, best
        validation checkpoint, fixed step budgets), report held-out metrics, save all settings in one weights file
        (settings not listed in --modalities are kept from that file; the dual net fuses the two single nets)."""
        import json

        from vtrack.dome.handpose import (
            MODALITIES,
            HandPoseTrainConfig,
            joint_weight_vector,
            parse_rgb_crop,
            train_all,
        )
        from vtrack.dome.handsim import GRASP_SETS
        from vtrack.errors import InputError

        if grasp_set not in GRASP_SETS:
            raise InputError("unknown grasp set", field="--grasp-set", expected=", ".join(GRASP_SETS), got=grasp_set)
        mods = tuple(m.strip() for m in modalities.split(",") if m.strip())
        bad = [m for m in mods if m not in MODALITIES]
        if bad or not mods:
            raise InputError("unknown modality", field="--modalities", expected="rgb, ir, dual", got=modalities)
        if ir_encoder not in ("markers", "cnn"):
            raise InputError("unknown IR encoder", field="--ir-encoder", expected="markers or cnn", got=ir_encoder)
        if init is not None and not init.is_file():
            raise InputError("weights to fine-tune from not found", path=init, field="--init")
        jw: dict[str, float] = {}
        for item in (x.strip() for x in joint_weights.split(",") if x.strip()):
            name, _, val = item.partition("=")
            try:
                jw[name.strip()] = float(val)
            except ValueError:
                raise InputError(
                    "bad joint weight", field="--joint-weights", expected="name=number", got=item
                ) from None
        try:
            joint_weight_vector(jw)
        except ValueError as e:
            raise InputError(str(e), field="--joint-weights", got=joint_weights) from None
        try:
            parse_rgb_crop(rgb_crop)
        except ValueError as e:
            raise InputError(str(e), field="--rgb-crop", got=rgb_crop) from None
        tc = HandPoseTrainConfig(
            rgb_crop=rgb_crop,
            rotate_deg=rotate_deg,
            joint_weights=jw,
            n_train=n_train,
            steps=steps,
            fusion_steps=fusion_steps,
            seed=seed,
            ir_encoder=ir_encoder,
            n_contact=n_contact,
            init=str(init) if init else "",
            lr=lr,
            grasp_set=grasp_set,
            time_budget_s=60.0 * time_budget_min,
            model_seed=model_seed,
            select_weighted=select_weighted,
            width=width,
            val_base=val_base,
        )
        info = train_all(tc, out, mods, progress=True)
        typer.echo(json.dumps(info["test"], indent=1))
        _write_json_out(json_out, info)

    @handpose_app.command("eval")
    def handpose_eval(
        json_out: Path = typer.Option(None, "--json", help="write {rgb, ir, dual: {mae_deg, rmse_deg, acc1, acc5}}"),
        weights: Path = typer.Option(None, "--weights", help="weights file, varied set (default: shipped)"),
        mixed_weights: Path = typer.Option(
            None, "--mixed-weights", help="weights file for the mixed and contact sets (default: shipped handpose.pt)"
        ),
        n_test: int = typer.Option(500, "--n-test", min=4, help="held-out simulated grasps"),
        seed: int = typer.Option(4242, "--seed", help="test-set seed (4242 = the held-out set)"),
    ) -> None:
        """Overall MAE / RMSE (deg) and Acc@1 / Acc@5 (% of joint angles within 1 / 5 deg) per modality on
        held-out simulated grasps (Table S7): top level = the varied set (hand placed at random, every fingertip on
        or just over the visible shell, joints by IK; ``mean_pose_baseline`` = no image), ``mixed`` = grasp types
        with lifted digits (``information_bound`` is its ceiling), ``contact`` = every fingertip pressed with a
        +- 5 deg joint spread (``nominal_pose_baseline``: Acc@5 is uninformative there)."""
        from vtrack.dome.handpose import evaluate_handpose_sets
        from vtrack_apps.output import print_table

        res = evaluate_handpose_sets(weights, n_test, seed, mixed_weights)
        cols = ("mae_deg", "rmse_deg", "acc1", "acc5", "max_deg")
        for title, r in (
            ("varied set: hand placed at random, fingertips on / over the shell", res),
            ("mixed set: lifted digits", res["mixed"]),
            ("contact set: every fingertip on the shell, +- 5 deg", res["contact"]),
        ):
            rows = [{"modality": m, **{k: round(r[m][k], 3) for k in cols}} for m in ("rgb", "ir", "dual") if m in r]
            for name, key in (
                ("information bound", "information_bound"),
                ("mean pose (no image)", "mean_pose_baseline"),
                ("nominal wrap (no image)", "nominal_pose_baseline"),
            ):
                rows.append({"modality": name, **{k: round(r[key][k], 3) for k in cols}})
            print_table(f"dome hand pose, {title} (simulated, deg)", rows)
        _write_json_out(json_out, res)

    @handpose_app.command("predict")
    def handpose_predict(
        rgb: Path = typer.Option(None, "--rgb", help="visible-light frame (64 x 64 colour)"),
        ir: Path = typer.Option(None, "--ir", help="infrared marker frame (128 x 128 grey)"),
        reference: Path = typer.Option(None, "--reference", help="no-contact IR frame (default: the simulated one)"),
        weights: Path = typer.Option(None, "--weights", help="weights file (default: shipped)"),
        json_out: Path = typer.Option(None, "--json", help="write the angles as JSON"),
    ) -> None:
        """12 joint angles (deg) from an RGB and/or IR frame (both: the dual-modality net). Frames that do not
        look like this sensor's are refused."""
        import json

        from vtrack.dome.handpose import HandPosePredictor
        from vtrack.errors import InputError
        from vtrack.io.images import read_image

        def load(path: Path | None, grey: bool):
            if path is None:
                return None
            if grey:
                return read_image(path, "gray")
            return read_image(path, "color")[..., ::-1]  # file BGR -> RGB

        ref = load(reference, True)
        pred = HandPosePredictor(weights, ref)
        res = pred.predict(load(rgb, False), load(ir, True))
        if not res.valid:
            raise InputError(res.reason, path=ir or rgb, field="image", expected="a frame of the 70 mm hand-pose dome")
        typer.echo(json.dumps(res.summary(), indent=1))
        if json_out:
            write_json(json_out, res.summary(), indent=1)

    @dome_app.command("tactip")
    def tactip(
        json_out: Path = typer.Option(None, "--json", help="write the per-set results as JSON"),
        epochs: int = typer.Option(60, "--epochs", min=1, help="GNN pose-regressor epochs"),
        root: Path = typer.Option(None, "--root", help="tactip_frames folder (default: shared data)"),
    ) -> None:
        """Real TacTip frames: marker-count stability, track continuity, depth/roll regression (80/20 split)."""

        import torch

        from vtrack.dome.tactip import analyse_all
        from vtrack_apps.output import print_table

        torch.set_num_threads(1)
        res = analyse_all(root, epochs=epochs)
        print_table("dome tactip", res)
        _write_json_out(json_out, res)
