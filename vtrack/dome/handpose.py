"""Hand-pose network (FusionTouch supplementary S24-S27): 12 joint angles from the dome's inner camera.

Inputs (simulated by :mod:`vtrack.dome.handsim`): the visible-light image of the hand through the shell
(``rgb``, (64, 64, 3) uint8) and the infrared marker image (``ir``, (128, 128) uint8) with the sensor's
no-contact reference frame. Three settings share target, loss and model selection (S24-S27):

- ``rgb``: one image encoder on the visible-light image -> regression head;
- ``ir``: the same encoder architecture on the IR image (2 channels: the gain-matched frame and its
  difference to the reference frame) -> regression head;
- ``dual``: two independent encoders, features concatenated (late fusion) -> a shared regression head.

Loss (S25-S27): ``lambda_mae * MAE + lambda_rmse * (RMSE + eps)`` over the 12 angles in degrees; the
checkpoint with the lowest validation loss (10 % of the training grasps) is kept. Metrics: MAE, RMSE (deg)
and Acc@1 / Acc@5 = % of all predicted joint angles within 1 / 5 deg of the truth.

Shipped weights: ``vtrack/dome/weights/handpose.pt`` (all three settings, float16). Imports torch.
"""

from __future__ import annotations

import copy
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
from torch import nn

from vtrack.dome.handsim import HAND_DOME, JOINTS, RGB_SIZE

MODALITIES = ("rgb", "ir", "dual")
HANDPOSE_VERSION = 1
#: held-out test set (grasps, seed) used by ``vtrack dome handpose eval`` and ``vtrack dome eval``
TEST_N, TEST_SEED = 500, 4242
#: gate: an IR frame must correlate this much with the sensor's reference frame (markers where they should be)
IR_MIN_CORR = 0.5
#: gate: predicted angles further than this (deg) outside the training range are flagged
ANGLE_MARGIN_DEG = 10.0


@dataclass
class HandPoseTrainConfig:
    n_train: int = 3000
    seed: int = 0
    epochs: int = 30
    batch: int = 64
    lr: float = 2e-3
    lambda_mae: float = 1.0
    lambda_rmse: float = 1.0
    val_frac: float = 0.1
    feat: int = 128
    #: dual net: per-sample probability of dropping each modality's features in training (0 = off)
    modality_dropout: float = 0.0


def weights_path() -> Path:
    return Path(__file__).parent / "weights" / "handpose.pt"


class ImageEncoder(nn.Module):
    """Four stride-2 conv blocks (8-16-32-64 channels: sized for a 15-minute CPU training), 4 x 4 average
    pooling (keeps where on the dome things are), linear."""

    def __init__(self, in_ch: int, feat: int = 128) -> None:
        super().__init__()

        def block(i: int, o: int, k: int = 3) -> list[nn.Module]:
            return [nn.Conv2d(i, o, k, 2, k // 2, bias=False), nn.BatchNorm2d(o), nn.ReLU()]

        self.net = nn.Sequential(
            *block(in_ch, 8, 5),
            *block(8, 16),
            *block(16, 32),
            *block(32, 64),
            nn.AdaptiveAvgPool2d(4),
            nn.Flatten(),
            nn.Linear(64 * 16, feat),
            nn.ReLU(),
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.net(x)


class HandPoseNet(nn.Module):
    """Single- (``rgb`` | ``ir``) or dual-modality (late fusion) regressor of the 12 joint angles.

    ``forward`` returns standardised angles; :meth:`degrees` maps them to degrees with the training mean/std."""

    def __init__(self, modality: str, mean: np.ndarray, std: np.ndarray, feat: int = 128) -> None:
        super().__init__()
        if modality not in MODALITIES:
            raise ValueError(f"modality must be one of {MODALITIES}, got {modality}")
        self.modality = modality
        self.enc = nn.ModuleDict()
        if modality in ("rgb", "dual"):
            self.enc["rgb"] = ImageEncoder(3, feat)
        if modality in ("ir", "dual"):
            self.enc["ir"] = ImageEncoder(2, feat)
        self.head = nn.Sequential(nn.Linear(feat * len(self.enc), 128), nn.ReLU(), nn.Linear(128, len(JOINTS)))
        self.register_buffer("mean", torch.as_tensor(np.asarray(mean, np.float32)))
        self.register_buffer("std", torch.as_tensor(np.asarray(std, np.float32)))

    #: training only, dual net: probability of zeroing one modality's features per sample ("modality
    #: dropout"), so the shared head cannot lean on the IR features for digits the IR camera does not see
    modality_dropout: float = 0.0

    def forward(self, inputs: dict[str, torch.Tensor]) -> torch.Tensor:
        feats = [e(inputs[k]) for k, e in self.enc.items()]
        if self.training and len(feats) == 2 and self.modality_dropout > 0:
            B = feats[0].shape[0]
            r = torch.rand(B, 1)
            feats[0] = feats[0] * (r >= self.modality_dropout).float()  # drop RGB
            feats[1] = feats[1] * ((r < self.modality_dropout) | (r >= 2 * self.modality_dropout)).float()  # IR
        return self.head(torch.cat(feats, 1))

    def degrees(self, inputs: dict[str, torch.Tensor]) -> torch.Tensor:
        return self.mean + self.std * self(inputs)


def prep_rgb(rgb: np.ndarray) -> np.ndarray:
    """(n, S, S, 3) uint8 -> (n, 3, S, S) float32 centred on 0."""
    return np.ascontiguousarray(np.asarray(rgb, np.float32).transpose(0, 3, 1, 2) / 255.0 - 0.5)


def prep_ir(ir: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """(n, S, S) uint8 IR frames + (S, S) reference -> (n, 2, S, S): the frame with its brightness matched
    to the reference (a global gain: the illumination drifts, the pins do not), and its difference to the
    reference (x 4, so the sub-pixel pin shifts of the contacts are not lost in the scale)."""
    x = np.asarray(ir, np.float32)
    r = np.asarray(ref, np.float32)
    gain = r.mean() / np.maximum(x.mean(axis=(1, 2), keepdims=True), 1e-3)
    x = x * gain
    return np.ascontiguousarray(np.stack([x / 255.0 - 0.3, 4.0 * (x - r[None]) / 255.0], 1))


def model_inputs(modality: str, data: dict, idx: np.ndarray | slice) -> dict[str, torch.Tensor]:
    out = {}
    if modality in ("rgb", "dual"):
        out["rgb"] = torch.from_numpy(prep_rgb(data["rgb"][idx]))
    if modality in ("ir", "dual"):
        out["ir"] = torch.from_numpy(prep_ir(data["ir"][idx], data["ir_reference"]))
    return out


def pose_loss(pred_deg: torch.Tensor, gt_deg: torch.Tensor, lam_mae: float = 1.0, lam_rmse: float = 1.0):
    """S25-S27: ``lam_mae * mean|e| + lam_rmse * (sqrt(mean e^2) + eps)`` over batch and the 12 joints (deg)."""
    e = pred_deg - gt_deg
    return lam_mae * e.abs().mean() + lam_rmse * (torch.sqrt((e * e).mean() + 1e-12) + 1e-6)


def pose_metrics(pred_deg: np.ndarray, gt_deg: np.ndarray) -> dict:
    """Overall MAE / RMSE (deg), Acc@1 / Acc@5 (% of joint angles within 1 / 5 deg), per-joint MAE."""
    e = np.abs(np.asarray(pred_deg, np.float64) - np.asarray(gt_deg, np.float64))
    return {
        "mae_deg": float(e.mean()),
        "rmse_deg": float(np.sqrt((e**2).mean())),
        "acc1": float((e <= 1.0).mean() * 100),
        "acc5": float((e <= 5.0).mean() * 100),
        "max_deg": float(e.max()),
        "per_joint_mae_deg": {j: float(v) for j, v in zip(JOINTS, e.mean(0), strict=True)},
    }


@torch.no_grad()
def predict_deg(model: HandPoseNet, data: dict, batch: int = 128) -> np.ndarray:
    model.eval()
    n = len(data["angles_deg"]) if "angles_deg" in data else len(data.get("rgb", data.get("ir")))
    outs = [model.degrees(model_inputs(model.modality, data, slice(i, i + batch))).numpy() for i in range(0, n, batch)]
    return np.concatenate(outs).astype(np.float64)


def train_handpose(
    modality: str, data: dict, tc: HandPoseTrainConfig, log=print, init: dict[str, HandPoseNet] | None = None
) -> tuple[HandPoseNet, dict]:
    """Train one setting; returns the best-validation model and a training summary. ``init``: trained
    single-modality nets whose encoders start the dual net's encoders (then everything is trained)."""
    torch.manual_seed(tc.seed)
    rng = np.random.default_rng(tc.seed)
    n = len(data["angles_deg"])
    perm = rng.permutation(n)
    n_val = max(8, int(round(tc.val_frac * n)))
    val_idx, tr_idx = np.sort(perm[:n_val]), perm[n_val:]
    y = torch.from_numpy(np.asarray(data["angles_deg"], np.float32))
    mean, std = y[tr_idx].mean(0).numpy(), y[tr_idx].std(0).clamp_min(1e-3).numpy()
    model = HandPoseNet(modality, mean, std, tc.feat)
    model.modality_dropout = tc.modality_dropout if modality == "dual" else 0.0
    for k, enc in model.enc.items():
        if init and k in init and k in init[k].enc:
            enc.load_state_dict(init[k].enc[k].state_dict())
    opt = torch.optim.AdamW(model.parameters(), lr=tc.lr, weight_decay=1e-4)
    steps = tc.epochs * int(np.ceil(len(tr_idx) / tc.batch))
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=tc.lr, total_steps=steps, pct_start=0.15)
    val_in = model_inputs(modality, data, val_idx)
    best, best_state, best_epoch = np.inf, None, -1
    t0 = time.time()
    for ep in range(tc.epochs):
        model.train()
        order = rng.permutation(tr_idx)
        for i in range(0, len(order), tc.batch):
            idx = np.sort(order[i : i + tc.batch])
            if len(idx) < 2:
                continue
            loss = pose_loss(model.degrees(model_inputs(modality, data, idx)), y[idx], tc.lambda_mae, tc.lambda_rmse)
            opt.zero_grad()
            loss.backward()
            opt.step()
            sched.step()
        model.eval()
        with torch.no_grad():
            vl = float(pose_loss(model.degrees(val_in), y[val_idx], tc.lambda_mae, tc.lambda_rmse))
        if vl < best:
            best, best_state, best_epoch = vl, copy.deepcopy(model.state_dict()), ep
        log(f"[handpose {modality}] epoch {ep + 1}/{tc.epochs} val loss {vl:.3f} deg ({time.time() - t0:.0f} s)")
    model.load_state_dict(best_state)
    model.eval()
    return model, {"val_loss_deg": best, "best_epoch": best_epoch + 1, "train_s": time.time() - t0}


def save_models(path: Path, models: dict[str, HandPoseNet], tc: HandPoseTrainConfig, info: dict) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    blob = {
        "version": HANDPOSE_VERSION,
        "joints": list(JOINTS),
        "dome": HAND_DOME.to_dict(),
        "rgb_size": RGB_SIZE,
        "train": asdict(tc),
        "info": info,
        "models": {
            m: {
                k: v.half() if v.is_floating_point() and k not in ("mean", "std") else v
                for k, v in net.state_dict().items()
            }
            for m, net in models.items()
        },
    }
    tmp = path.with_suffix(".tmp")
    torch.save(blob, tmp)
    tmp.replace(path)


def load_models(path: Path | None = None) -> tuple[dict[str, HandPoseNet], dict]:
    """All settings stored in a hand-pose weights file (default: shipped) and the file's metadata."""
    from vtrack.errors import InputError

    path = Path(path) if path else weights_path()
    if not path.is_file():
        raise InputError(
            "hand-pose weights not found", path=path, expected="a file written by `vtrack dome handpose train`"
        )
    try:
        blob = torch.load(path, map_location="cpu", weights_only=False)
    except Exception as e:  # noqa: BLE001 - any unreadable file is the same user error
        raise InputError(f"cannot read hand-pose weights: {e}", path=path) from None
    if not isinstance(blob, dict) or blob.get("version") != HANDPOSE_VERSION or "models" not in blob:
        raise InputError("not a hand-pose weights file", path=path, expected=f"version {HANDPOSE_VERSION}")
    models = {}
    feat = int(blob["train"].get("feat", 128))
    for m, sd in blob["models"].items():
        net = HandPoseNet(m, sd["mean"].numpy(), sd["std"].numpy(), feat)
        net.load_state_dict({k: v.float() if v.is_floating_point() else v for k, v in sd.items()})
        net.eval()
        models[m] = net
    return models, blob


def touching_joints(grasps: np.ndarray) -> np.ndarray:
    """(n, 12) bool: joint of a digit that touches the shell in that grasp type (the others are lifted 20-30
    deg; their distal joints barely show in either image)."""
    from vtrack.dome.handsim import DIGITS, GRASPS

    out = np.zeros((len(grasps), len(JOINTS)), bool)
    for i, g in enumerate(np.asarray(grasps).astype(str)):
        for d in DIGITS:
            if d.name in GRASPS[g]:
                out[i, list(d.joints)] = True
                if d.name == "thumb":
                    out[i, 0] = True  # thumb abduction
    return out


def evaluate_handpose(path: Path | None = None, n_test: int = TEST_N, seed: int = TEST_SEED) -> dict:
    """Metrics of every stored setting on held-out simulated grasps (never seen in training: other seed)."""
    from vtrack.dome.handsim import make_handpose_dataset

    torch.set_num_threads(1)
    models, blob = load_models(path)
    te = make_handpose_dataset(n_test, seed)
    res: dict = {}
    touching = touching_joints(te["grasp"])
    for m in MODALITIES:
        if m not in models:
            continue
        t0 = time.perf_counter()
        pred = predict_deg(models[m], te)
        ms = (time.perf_counter() - t0) * 1e3 / len(pred)
        res[m] = {**pose_metrics(pred, te["angles_deg"]), "ms_per_frame_batched": ms}
        e = np.abs(pred - te["angles_deg"])
        for part, sel in (("touching", touching), ("lifted", ~touching)):
            res[m][f"{part}_mae_deg"] = float(e[sel].mean())
            res[m][f"{part}_acc5"] = float((e[sel] <= 5.0).mean() * 100)
    res["test_set"] = {
        "grasps": int(n_test),
        "seed": int(seed),
        "simulated": True,
        "angle_std_deg": float(te["angles_deg"].std(0).mean()),
        "touching_joint_frac": float(touching.mean()),
    }
    # predicting the training mean: what the image contributes beyond the prior
    mean = np.asarray(next(iter(models.values())).mean.numpy(), np.float64)
    res["mean_pose_baseline"] = {
        k: v
        for k, v in pose_metrics(np.broadcast_to(mean, te["angles_deg"].shape), te["angles_deg"]).items()
        if k != "per_joint_mae_deg"
    }
    return res


@dataclass
class HandPoseResult:
    angles_deg: np.ndarray
    modality: str
    valid: bool
    reason: str = ""

    def summary(self) -> dict:
        return {
            "modality": self.modality,
            "valid": self.valid,
            **({"invalid_reason": self.reason} if not self.valid else {}),
            "angles_deg": {j: round(float(a), 3) for j, a in zip(JOINTS, self.angles_deg, strict=True)},
        }


class HandPosePredictor:
    """Joint angles (deg) from one RGB and/or IR frame of the 70 mm dome, with plausibility gates."""

    def __init__(self, weights: Path | None = None, reference: np.ndarray | None = None) -> None:
        torch.set_num_threads(1)
        self.models, blob = load_models(weights)
        self.info = blob.get("info", {})
        lo, hi = self.info.get("angle_range_deg", (None, None))
        self.lo = np.asarray(lo, np.float64) if lo is not None else None
        self.hi = np.asarray(hi, np.float64) if hi is not None else None
        if reference is None:
            from vtrack.dome.handsim import HandDomeSimulator

            reference = HandDomeSimulator().ir_reference()
        self.reference = np.asarray(reference, np.uint8)

    def predict(self, rgb: np.ndarray | None = None, ir: np.ndarray | None = None) -> HandPoseResult:
        from vtrack.errors import InputError

        if rgb is None and ir is None:
            raise InputError("give an RGB and/or an IR frame", field="image")
        modality = "dual" if rgb is not None and ir is not None else ("rgb" if rgb is not None else "ir")
        if modality not in self.models:
            raise InputError("no model for this modality in the weights file", field="modality", got=modality)
        data: dict = {}
        reasons = []
        if rgb is not None:
            rgb = np.asarray(rgb)
            if rgb.shape != (RGB_SIZE, RGB_SIZE, 3):
                raise InputError(
                    "RGB frame has the wrong size",
                    field="rgb",
                    expected=f"({RGB_SIZE}, {RGB_SIZE}, 3)",
                    got=str(rgb.shape),
                )
            if float(rgb.std()) < 2.0:
                reasons.append("RGB frame is blank")
            data["rgb"] = rgb[None].astype(np.uint8)
        if ir is not None:
            ir = np.asarray(ir)
            S = HAND_DOME.image_size
            if ir.shape != (S, S):
                raise InputError(
                    "IR frame has the wrong size", field="ir", expected=f"({S}, {S}) grey", got=str(ir.shape)
                )
            a, b = ir.astype(np.float64).ravel(), self.reference.astype(np.float64).ravel()
            corr = float(np.corrcoef(a, b)[0, 1]) if a.std() > 1e-6 else 0.0
            if not np.isfinite(corr) or corr < IR_MIN_CORR:
                reasons.append(f"IR frame does not show this sensor's markers (correlation {corr:.2f} < {IR_MIN_CORR})")
            data["ir"] = ir[None].astype(np.uint8)
            data["ir_reference"] = self.reference
        q = predict_deg(self.models[modality], data)[0]
        if not np.all(np.isfinite(q)):
            reasons.append("non-finite angles")
            q = np.nan_to_num(q)
        elif self.lo is not None and (np.any(q < self.lo - ANGLE_MARGIN_DEG) or np.any(q > self.hi + ANGLE_MARGIN_DEG)):
            reasons.append(f"angles beyond the trained range +- {ANGLE_MARGIN_DEG} deg")
        return HandPoseResult(q, modality, not reasons, "; ".join(reasons))


def train_all(
    tc: HandPoseTrainConfig,
    out: Path | None = None,
    modalities: tuple[str, ...] = MODALITIES,
    log=print,
    progress: bool = False,
) -> dict:
    """Simulate (cached), train every setting with the same budget, evaluate on the held-out grasps, save."""
    from vtrack.dome.handsim import make_handpose_dataset

    torch.set_num_threads(1)
    tr = make_handpose_dataset(tc.n_train, tc.seed, progress=progress)
    te = make_handpose_dataset(TEST_N, TEST_SEED, progress=progress)
    models, info = {}, {"train": {}, "test": {}}
    path = Path(out) if out else weights_path()
    if set(modalities) != set(MODALITIES) and path.is_file():  # keep the settings not retrained in this run
        old, blob = load_models(path)
        models = {k: v for k, v in old.items() if k not in modalities}
        info = {**blob.get("info", {}), **info}
        info["train"] = {k: v for k, v in blob.get("info", {}).get("train", {}).items() if k not in modalities}
        info["test"] = {k: v for k, v in blob.get("info", {}).get("test", {}).items() if k not in modalities}
    for m in modalities:
        # the dual net's encoders start from the single-modality ones trained in this run (late fusion of
        # pretrained encoders, then trained end to end with the same loss and budget)
        init = {k: models[k] for k in ("rgb", "ir") if k in models} if m == "dual" else None
        net, summ = train_handpose(m, tr, tc, log, init)
        summ["encoders_from_single"] = sorted(init) if init else []
        models[m] = net
        info["train"][m] = summ
        info["test"][m] = {
            k: v for k, v in pose_metrics(predict_deg(net, te), te["angles_deg"]).items() if k != "per_joint_mae_deg"
        }
        log(f"[handpose {m}] held-out: {info['test'][m]}")
    info["angle_range_deg"] = (tr["angles_deg"].min(0).tolist(), tr["angles_deg"].max(0).tolist())
    save_models(path, {k: models[k] for k in MODALITIES if k in models}, tc, info)
    return info
