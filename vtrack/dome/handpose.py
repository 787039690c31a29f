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

Shipped weights (all three settings, float16), one file per grasp set of :mod:`vtrack.dome.handsim`:
``vtrack/dome/weights/handpose_varied.pt`` (the default task, :data:`DEFAULT_GRASP_SET`) and
``vtrack/dome/weights/handpose.pt`` (trained on the ``mixed`` set, kept for its reported row). Imports torch.
"""

from __future__ import annotations

import copy
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch
from torch import nn

from vtrack.dome.handsim import HAND_DOME, JOINTS, RGB_SIZE, rgb_model, sensor_config
from vtrack.io.jsonio import atomic_torch_save

MODALITIES = ("rgb", "ir", "dual")
HANDPOSE_VERSION = 2
#: the task of ``vtrack dome handpose`` (train / eval / predict): hand placed at random, every fingertip on or
#: just over the visible shell, joints by inverse kinematics (see docs/dome.md for why it is the paper's task)
DEFAULT_GRASP_SET = "varied"
#: a joint counts as observable when a 5 deg change of it moves the noise-free RGB or IR image by at least this
#: matched-filter SNR (||image change|| / per-pixel noise sigma of that camera)
OBS_SNR_MIN = 2.0
#: held-out test set (grasps, seed) used by ``vtrack dome handpose eval`` and ``vtrack dome eval``
TEST_N, TEST_SEED = 500, 4242
#: training grasps are simulated in cached chunks of this many, chunk k with seed ``seed + k`` (a larger
#: training set reuses the simulations of a smaller one)
CHUNK = 3000
#: gate: an IR frame must correlate this much with the sensor's reference frame (markers where they should be)
IR_MIN_CORR = 0.5
#: gate: predicted angles further than this (deg) outside the training range are flagged
ANGLE_MARGIN_DEG = 10.0
#: RGB gate: principal components of the training frames (2 x 2-binned, 32 x 32 x 3) that span "a frame of this
#: sensor" (16 keep 96 % of the variance), and the factor on the training set's 99.9th percentile of each score
RGB_GATE_K = 16
RGB_GATE_MARGIN = 1.5


@dataclass
class HandPoseTrainConfig:
    """Training recipe. Budgets are optimizer steps (not wall time), the same for every run of a setting."""

    n_train: int = 6000
    seed: int = 0
    #: optimizer steps of each single-modality net (one-cycle schedule)
    steps: int = 6000
    #: optimizer steps of the dual net's fusion head (the encoders and branch heads are frozen)
    fusion_steps: int = 3000
    batch: int = 64
    lr: float = 2e-3
    lambda_mae: float = 1.0
    lambda_rmse: float = 1.0
    val_frac: float = 0.1
    feat: int = 128
    #: base width of the RGB image encoder (channels width, 2x, 4x, 8x)
    width: int = 16
    #: base width of the IR image encoder (``ir_encoder="cnn"``; the 128 px frame costs 4x the 64 px RGB one)
    ir_width: int = 8
    #: IR encoder: ``markers`` (marker-centred patches of the frame and its difference to the reference, per
    #: marker features in the reference's fixed marker order) or ``cnn`` (the image encoder on the IR frame)
    ir_encoder: str = "markers"
    #: half side (px) of the marker-centred IR patches (the rest-marker spacing is ~5.4 px)
    patch_half: int = 3
    #: validate (and maybe checkpoint) every this many steps
    eval_every: int = 250
    #: grasps of the ``contact`` set (:data:`vtrack.dome.handsim.GRASP_SETS`: every fingertip on the shell) added
    #: to the ``n_train`` grasps of the ``mixed`` set (cached chunks, seeds ``seed + k`` as for the mixed set)
    n_contact: int = 0
    #: start the single-modality nets from this weights file (fine-tuning; "" = from scratch). The dual net is
    #: always fused anew from the single nets of the run
    init: str = ""
    #: grasp set (:data:`vtrack.dome.handsim.GRASP_SETS`) of the ``n_train`` training grasps and of the held-out
    #: grasps reported after training
    grasp_set: str = DEFAULT_GRASP_SET
    #: wall-time guard per net (s, 0 = none): training stops at the first validation past it and keeps the best
    #: checkpoint so far (the step budget stays the recipe; the guard only protects a shared machine's schedule)
    time_budget_s: float = 0.0
    #: per-joint weights of the training loss (joint name -> weight, the others 1; normalised to mean 1), e.g. more
    #: weight on the thumb MCP / IP; validation and checkpointing stay on the unweighted S25-S27 loss
    joint_weights: dict[str, float] = field(default_factory=dict)
    #: offset of the initialisation and batch-order seeds (another member of a seed ensemble on the same data and
    #: split; ``seed`` picks the training grasps and the validation split)
    model_seed: int = 0
    #: checkpoint on the ``joint_weights``-weighted validation loss instead of the unweighted S25-S27 one (a joint
    #: specialist, e.g. a net trained for the thumb MCP / IP only, is selected on the joints it is trained for)
    select_weighted: bool = False
    #: RGB net reads only this window of the frame, magnified: "row,col,side,upsampling" ("" = the whole frame),
    #: e.g. "26,0,32,2" = the thumb's region (rows / cols 26-57 / 0-31 of the 64 px frame) at 2x
    rgb_crop: str = ""
    #: training augmentation of the RGB net: each frame turned about the image centre by an angle drawn in +-
    #: this (deg; 0 = off) plus fresh pixel noise. Exact for this sensor: the fisheye, shell, light and haze are
    #: symmetric about the dome axis, so a turned frame is the same grasp with the hand yawed (a nuisance) and
    #: the joint angles are unchanged
    rotate_deg: float = 0.0
    #: nested validation split: the first ``val_base`` grasps are split exactly as a run with ``n_train = val_base``
    #: splits them, the grasps beyond by a permutation of their own (0 = one permutation of all ``n_train``). A run
    #: on more grasps then keeps the smaller run's validation grasps out of training, so nets of both runs are
    #: compared and combined on validation grasps that none of them was trained on
    val_base: int = 0


def parse_rgb_crop(text: str) -> tuple[int, int, int, int] | None:
    """``"row,col,side,up"`` -> a window of the RGB frame (px) and its magnification; ``""`` -> None."""
    if not text:
        return None
    try:
        r, c, side, up = (int(v) for v in text.split(","))
    except ValueError:
        raise ValueError(f"RGB crop must be row,col,side,upsampling (integers), got {text!r}") from None
    if r < 0 or c < 0 or side < 8 or r + side > RGB_SIZE or c + side > RGB_SIZE or not 1 <= up <= 4:
        raise ValueError(f"RGB crop {text!r} must be a window of at least 8 px inside the {RGB_SIZE} px frame, 1-4x")
    return r, c, side, up


def weights_path(grasp_set: str = DEFAULT_GRASP_SET) -> Path:
    """Shipped weights of the nets trained on ``grasp_set`` (``mixed`` and ``contact`` share the mixed-set nets)."""
    name = "handpose_varied.pt" if grasp_set == "varied" else "handpose.pt"
    return Path(__file__).parent / "weights" / name


class ImageEncoder(nn.Module):
    """Four stride-2 conv blocks (``width``, 2x, 4x, 8x channels), 4 x 4 average pooling (keeps where on the
    dome things are), linear."""

    def __init__(self, in_ch: int, feat: int = 128, width: int = 8) -> None:
        super().__init__()

        def block(i: int, o: int, k: int = 3) -> list[nn.Module]:
            return [nn.Conv2d(i, o, k, 2, k // 2, bias=False), nn.BatchNorm2d(o), nn.ReLU()]

        w = width
        self.net = nn.Sequential(
            *block(in_ch, w, 5),
            *block(w, 2 * w),
            *block(2 * w, 4 * w),
            *block(4 * w, 8 * w),
            nn.AdaptiveAvgPool2d(4),
            nn.Flatten(),
            nn.Linear(8 * w * 16, feat),
            nn.ReLU(),
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.net(x)


class MarkerPatchEncoder(nn.Module):
    """IR encoder on the marker field: one (2 h + 1)^2 patch of the gain-matched frame and of its difference to
    the reference around every rest marker of the reference frame (px centres, fixed order), a per-marker MLP
    shared by all markers (-> ``node`` features: how that pin moved / dimmed), and an MLP over the
    concatenation in marker order (the order carries where on the dome each pin sits).

    Why: the contacts move pins by a pixel or two; a strided CNN on the whole 128 px frame spends its first
    layers finding the pins, while here each pin's neighbourhood is read at full resolution."""

    def __init__(self, centers: np.ndarray, image_size: int, feat: int = 128, half: int = 3, node: int = 4) -> None:
        super().__init__()
        c = np.asarray(centers, np.float32).reshape(-1, 2)
        self.register_buffer("centers", torch.from_numpy(c))
        self.half, self.size, self.node = int(half), int(image_size), int(node)
        d = np.arange(-self.half, self.half + 1)
        cx = np.clip(np.rint(c[:, 0]).astype(np.int64)[:, None, None] + d[None, None, :], 0, self.size - 1)
        cy = np.clip(np.rint(c[:, 1]).astype(np.int64)[:, None, None] + d[None, :, None], 0, self.size - 1)
        self.register_buffer("idx", torch.from_numpy((cy * self.size + cx).reshape(len(c), -1)), persistent=False)
        P = (2 * self.half + 1) ** 2
        self.local = nn.Sequential(nn.Linear(2 * P, 32), nn.ReLU(), nn.Linear(32, node), nn.ReLU())
        # small on purpose (a 331 x 8 -> 256 layer overfitted 3000 grasps within 750 steps)
        self.glob = nn.Sequential(
            nn.Dropout(0.1), nn.Linear(len(c) * node, 128), nn.ReLU(), nn.Linear(128, feat), nn.ReLU()
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        B, C = x.shape[:2]
        g = x.reshape(B, C, -1)[:, :, self.idx]  # (B, C, M, P)
        g = g.permute(0, 2, 1, 3).reshape(B, self.idx.shape[0], -1)
        return self.glob(self.local(g).reshape(B, -1))


def _head(feat: int) -> nn.Module:
    return nn.Sequential(nn.Linear(feat, 128), nn.ReLU(), nn.Linear(128, len(JOINTS)))


class HandPoseNet(nn.Module):
    """Single- (``rgb`` | ``ir``) or dual-modality regressor of the 12 joint angles.

    Dual (late fusion of features *and* predictions): both branches keep their own encoder and head (those of
    the trained single-modality nets); a fusion head reads the concatenated features and outputs a per-joint
    gate ``w`` and a residual ``r``: ``w * y_rgb + (1 - w) * y_ir + r``. The gate starts at the branch that is
    better on the validation grasps for that joint and ``r`` at 0, so the fused net starts at least as good as
    the better branch per joint, and training (with best-validation checkpointing, the start included) can
    only keep or improve that.

    ``forward`` returns standardised angles; :meth:`degrees` maps them to degrees with the training mean/std."""

    def __init__(
        self,
        modality: str,
        mean: np.ndarray,
        std: np.ndarray,
        feat: int = 128,
        width: int = 16,
        ir_centers: np.ndarray | None = None,
        patch_half: int = 3,
        ir_width: int | None = None,
        rgb_crop: tuple[int, int, int, int] | None = None,
    ) -> None:
        super().__init__()
        if modality not in MODALITIES:
            raise ValueError(f"modality must be one of {MODALITIES}, got {modality}")
        self.modality = modality
        # (row, col, side, upsampling) of a square window of the RGB frame read instead of the whole frame, e.g. the
        # thumb's region magnified 2x (a joint specialist); stored in the state so a weights file rebuilds it
        self.register_buffer("rgb_crop", torch.tensor(rgb_crop or (0, 0, 0, 1), dtype=torch.int64))
        self.enc = nn.ModuleDict()
        if modality in ("rgb", "dual"):
            self.enc["rgb"] = ImageEncoder(3, feat, width)
        if modality in ("ir", "dual"):
            self.enc["ir"] = (
                ImageEncoder(2, feat, ir_width or width)
                if ir_centers is None
                else MarkerPatchEncoder(ir_centers, HAND_DOME.image_size, feat, patch_half)
            )
        self.heads = nn.ModuleDict({k: _head(feat) for k in self.enc})
        if modality == "dual":
            self.gate = nn.Linear(2 * feat, len(JOINTS))
            self.resid = nn.Sequential(
                nn.Dropout(0.1), nn.Linear(2 * feat, 128), nn.ReLU(), nn.Linear(128, len(JOINTS))
            )
            nn.init.zeros_(self.gate.weight)
            nn.init.zeros_(self.resid[-1].weight)
            nn.init.zeros_(self.resid[-1].bias)
        self.register_buffer("mean", torch.as_tensor(np.asarray(mean, np.float32)))
        self.register_buffer("std", torch.as_tensor(np.asarray(std, np.float32)))

    def features(self, inputs: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        return {k: e(self._crop(inputs[k]) if k == "rgb" else inputs[k]) for k, e in self.enc.items()}

    def _crop(self, x: torch.Tensor) -> torch.Tensor:
        r, c, side, up = (int(v) for v in self.rgb_crop)
        if side <= 0:
            return x
        x = x[:, :, r : r + side, c : c + side]
        return nn.functional.interpolate(x, scale_factor=up, mode="bilinear", align_corners=False) if up > 1 else x

    def fuse(self, feats: dict[str, torch.Tensor]) -> torch.Tensor:
        y = {k: self.heads[k](f) for k, f in feats.items()}
        if self.modality != "dual":
            return y[self.modality]
        f = torch.cat([feats["rgb"], feats["ir"]], 1)
        w = torch.sigmoid(self.gate(f))
        return w * y["rgb"] + (1.0 - w) * y["ir"] + self.resid(f)

    def forward(self, inputs: dict[str, torch.Tensor]) -> torch.Tensor:
        return self.fuse(self.features(inputs))

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


def rotate_frames(
    x: torch.Tensor,
    max_deg: float,
    gen: torch.Generator | None,
    noise: float = 0.01,
    angles_deg: torch.Tensor | None = None,
) -> torch.Tensor:
    """Training augmentation: (n, C, S, S) prepared frames each turned about the image centre by an angle drawn
    uniformly in +-``max_deg`` (or by ``angles_deg``; bilinear; the corners outside the shell's disc repeat the
    border, which lies outside it too), plus Gaussian noise of ``noise`` (full scale 1) to restore the pixel noise
    the interpolation smooths. A turn by -a matches the hand yawed by +a (:class:`HandPlace`) to the interpolation
    error (docs/dome.md)."""
    n = x.shape[0]
    a = (torch.rand(n, generator=gen) * 2 - 1) * max_deg if angles_deg is None else angles_deg.float()
    a = torch.deg2rad(a)
    c, s = torch.cos(a), torch.sin(a)
    theta = torch.stack([torch.stack([c, -s, torch.zeros(n)], 1), torch.stack([s, c, torch.zeros(n)], 1)], 1)
    grid = nn.functional.affine_grid(theta, list(x.shape), align_corners=False)
    out = nn.functional.grid_sample(x, grid, mode="bilinear", padding_mode="border", align_corners=False)
    return out if noise == 0 else out + noise * torch.randn(out.shape, generator=gen)


def model_inputs(modality: str, data: dict, idx: np.ndarray | slice) -> dict[str, torch.Tensor]:
    out = {}
    if modality in ("rgb", "dual"):
        out["rgb"] = torch.from_numpy(prep_rgb(data["rgb"][idx]))
    if modality in ("ir", "dual"):
        out["ir"] = torch.from_numpy(prep_ir(data["ir"][idx], data["ir_reference"]))
    return out


def pose_loss(
    pred_deg: torch.Tensor,
    gt_deg: torch.Tensor,
    lam_mae: float = 1.0,
    lam_rmse: float = 1.0,
    weights: torch.Tensor | None = None,
):
    """S25-S27: ``lam_mae * mean|e| + lam_rmse * (sqrt(mean e^2) + eps)`` over batch and the 12 joints (deg).
    ``weights`` (12,): optional per-joint weights (mean 1) inside both means."""
    e = pred_deg - gt_deg
    w = torch.ones(e.shape[-1]) if weights is None else weights
    return lam_mae * (w * e.abs()).mean() + lam_rmse * (torch.sqrt((w * e * e).mean() + 1e-12) + 1e-6)


def joint_weight_vector(weights: dict[str, float]) -> torch.Tensor | None:
    """(12,) per-joint loss weights normalised to mean 1 from ``{joint name: weight}`` (others 1); None if empty."""
    if not weights:
        return None
    bad = [k for k in weights if k not in JOINTS]
    if bad or any(not np.isfinite(v) or v <= 0 for v in weights.values()):
        raise ValueError(f"joint weights must be positive and name joints of {JOINTS}, got {weights}")
    w = torch.tensor([float(weights.get(j, 1.0)) for j in JOINTS])
    return w / w.mean()


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


def _rgb_gate_features(rgb: np.ndarray) -> np.ndarray:
    """(n, S, S, 3) uint8 -> (n, 3 S^2 / 4) float64 in [0, 1], 2 x 2-binned (the pixel noise averages down)."""
    x = np.asarray(rgb, np.float64) / 255.0
    n, S = x.shape[0], x.shape[1]
    return x.reshape(n, S // 2, 2, S // 2, 2, 3).mean((2, 4)).reshape(n, -1)


def fit_rgb_gate(
    rgb: np.ndarray, k: int = RGB_GATE_K, margin: float = RGB_GATE_MARGIN, n_fit: int = 2000
) -> dict[str, torch.Tensor]:
    """Plausibility model of this sensor's visible-light frames, learnt from training frames ``rgb``
    ((n, S, S, 3) uint8): the mean frame and the ``k`` leading principal components. A frame is scored by its
    distance from that subspace (``spe``: RMS residual per binned pixel, [0, 1] intensity units) and by its
    position inside it (``t2``: Hotelling's T^2, sum of squared coefficients over the component variances). The
    thresholds are ``margin`` x the 99.9th percentile of each score on the training frames. Every frame of the
    dome shows the same shell, vignetting and room light with a hand blurred by the haze in front, so noise, a
    checkerboard, a gradient or another camera's picture leave the subspace by far (see docs/dome.md). The
    components come from ``n_fit`` evenly spaced frames (16 components are stable and the SVD stays a few
    seconds); the thresholds from all frames."""
    x = _rgb_gate_features(rgb[np.linspace(0, len(rgb) - 1, min(n_fit, len(rgb))).astype(int)])
    mu = x.mean(0)
    _, sv, vt = np.linalg.svd(x - mu, full_matrices=False)
    gate = {
        "mean": torch.from_numpy(mu.astype(np.float32)),
        "components": torch.from_numpy(vt[:k].astype(np.float32)),
        "var": torch.from_numpy((sv[:k] ** 2 / max(len(x) - 1, 1)).astype(np.float32)),
    }
    spe, t2 = rgb_gate_scores(gate, rgb)
    gate["spe_max"] = torch.tensor(float(margin * np.quantile(spe, 0.999)))
    gate["t2_max"] = torch.tensor(float(margin * np.quantile(t2, 0.999)))
    return gate


def rgb_gate_scores(gate: dict[str, torch.Tensor], rgb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(spe, t2) of (n, S, S, 3) uint8 frames under :func:`fit_rgb_gate`'s model (see there)."""
    v = gate["components"].double().numpy()
    d = _rgb_gate_features(rgb) - gate["mean"].double().numpy()
    c = d @ v.T
    spe = np.sqrt(np.mean((d - c @ v) ** 2, axis=1))
    t2 = np.sum(c**2 / gate["var"].double().numpy(), axis=1)
    return spe, t2


def split_train_val(n: int, tc: HandPoseTrainConfig) -> tuple[np.ndarray, np.ndarray]:
    """(train, val) indices: a fixed ``val_frac`` of the grasps (same split for every setting of a run). With
    ``tc.val_base`` in (0, n) the split is nested: the first ``val_base`` grasps as in a run on ``val_base`` grasps,
    plus ``val_frac`` of the rest by its own permutation (see :class:`HandPoseTrainConfig`)."""
    base = tc.val_base if 0 < tc.val_base < n else n
    perm = np.random.default_rng(tc.seed).permutation(base)
    n_val = max(8, int(round(tc.val_frac * base)))
    tr, val = perm[n_val:], perm[:n_val]
    if base < n:  # the extra grasps: their own permutation, seeded by (seed, base) so it does not depend on n
        extra = base + np.random.default_rng([tc.seed, base]).permutation(n - base)
        n_extra = int(round(tc.val_frac * (n - base)))
        tr, val = np.concatenate([tr, extra[n_extra:]]), np.concatenate([val, extra[:n_extra]])
    return tr, np.sort(val)


def trained_within(sub: dict, main: dict) -> bool:
    """True when nets trained with the config ``sub`` (:func:`dataclasses.asdict` of a
    :class:`HandPoseTrainConfig`, as stored in a weights file) saw no grasp that is a validation grasp of ``main``:
    the same grasp set and seed, and either the same training set and split, or ``sub``'s set is ``main``'s nested
    base (``main["val_base"] == sub["n_train"]``). Files from before ``val_base`` count as 0."""
    same = all(sub.get(k) == main.get(k) for k in ("seed", "grasp_set"))
    same_split = sub.get("n_train") == main.get("n_train") and sub.get("val_base", 0) == main.get("val_base", 0)
    nested = main.get("val_base", 0) == sub.get("n_train") and sub.get("val_base", 0) in (0, sub.get("n_train"))
    return same and (same_split or nested)


def _fit(model: nn.Module, params, loss_on, val_loss, n_steps: int, n_train: int, tc, log, tag: str) -> dict:
    """Fixed-budget AdamW + one-cycle loop: ``loss_on(idx)`` is the training loss of a batch of training
    positions, ``val_loss()`` the validation loss; keeps the best-validation state (the start included)."""
    rng = np.random.default_rng(tc.seed + 1 + 1000 * tc.model_seed)
    opt = torch.optim.AdamW(params, lr=tc.lr, weight_decay=1e-4)
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=tc.lr, total_steps=n_steps, pct_start=0.15)
    model.eval()
    best, best_state, best_step = val_loss(), copy.deepcopy(model.state_dict()), 0
    log(f"[handpose {tag}] step 0 val loss {best:.3f} deg")
    t0 = time.time()
    order, pos = rng.permutation(n_train), 0
    for step in range(1, n_steps + 1):
        if pos + tc.batch > n_train:
            order, pos = rng.permutation(n_train), 0
        idx = np.sort(order[pos : pos + tc.batch])
        pos += tc.batch
        model.train()
        loss = loss_on(idx)
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
        if step % tc.eval_every == 0 or step == n_steps:
            model.eval()
            vl = val_loss()
            if vl < best:
                best, best_state, best_step = vl, copy.deepcopy(model.state_dict()), step
            log(f"[handpose {tag}] step {step}/{n_steps} val loss {vl:.3f} deg ({time.time() - t0:.0f} s)")
            if tc.time_budget_s and time.time() - t0 > tc.time_budget_s and step < n_steps:
                log(f"[handpose {tag}] time budget {tc.time_budget_s:.0f} s reached at step {step}: stopping")
                n_steps = step
                break
    model.load_state_dict(best_state)
    model.eval()
    return {"val_loss_deg": float(best), "best_step": best_step, "steps": n_steps, "train_s": time.time() - t0}


def ir_reference_centers(ref: np.ndarray) -> np.ndarray:
    """Rest-marker centres (px) of the IR reference frame (the pipeline's marker extractor, no simulator state)."""
    from vtrack.dome.markers import extract_markers

    return extract_markers(np.asarray(ref, np.uint8)).centers


def train_handpose(modality: str, data: dict, tc: HandPoseTrainConfig, log=print) -> tuple[HandPoseNet, dict]:
    """Train one single-modality setting (``rgb`` | ``ir``) for ``tc.steps``; best-validation model + summary."""
    if modality not in ("rgb", "ir"):
        raise ValueError("train_handpose trains the single-modality nets; the dual net is fuse_dual")
    torch.manual_seed(tc.seed + 1000 * tc.model_seed)
    tr_idx, val_idx = split_train_val(len(data["angles_deg"]), tc)
    y = torch.from_numpy(np.asarray(data["angles_deg"], np.float32))
    mean, std = y[tr_idx].mean(0).numpy(), y[tr_idx].std(0).clamp_min(1e-3).numpy()
    centers = ir_reference_centers(data["ir_reference"]) if modality == "ir" and tc.ir_encoder == "markers" else None
    crop = parse_rgb_crop(tc.rgb_crop) if modality == "rgb" else None
    model = HandPoseNet(modality, mean, std, tc.feat, tc.width, centers, tc.patch_half, tc.ir_width, crop)
    if tc.init:  # fine-tuning: architecture and angle normalisation of the starting weights
        model = load_models(Path(tc.init))[0][modality]
        model = model.nets[0] if isinstance(model, HandPoseEnsemble) else model  # fine-tune the main net
        log(f"[handpose {modality}] fine-tuning from {tc.init} ({len(tr_idx)} training grasps)")
    val_in = model_inputs(modality, data, val_idx)
    w = joint_weight_vector(tc.joint_weights)

    gen = torch.Generator().manual_seed(tc.seed + 7 + 1000 * tc.model_seed)

    def loss_on(pos: np.ndarray) -> torch.Tensor:
        idx = np.sort(tr_idx[pos])
        inputs = model_inputs(modality, data, idx)
        if tc.rotate_deg > 0 and "rgb" in inputs:
            inputs["rgb"] = rotate_frames(inputs["rgb"], tc.rotate_deg, gen)
        return pose_loss(model.degrees(inputs), y[idx], tc.lambda_mae, tc.lambda_rmse, w)

    wv = w if tc.select_weighted else None

    @torch.no_grad()
    def val_loss() -> float:
        return float(pose_loss(model.degrees(val_in), y[val_idx], tc.lambda_mae, tc.lambda_rmse, wv))

    summ = _fit(model, model.parameters(), loss_on, val_loss, tc.steps, len(tr_idx), tc, log, modality)
    return model, summ


@torch.no_grad()
def _features(model: HandPoseNet, data: dict, idx: np.ndarray, batch: int = 256) -> dict[str, torch.Tensor]:
    model.eval()
    parts = [model.features(model_inputs("dual", data, idx[i : i + batch])) for i in range(0, len(idx), batch)]
    return {k: torch.cat([p[k] for p in parts]) for k in parts[0]}


def fuse_dual(
    rgb: HandPoseNet, ir: HandPoseNet, data: dict, tc: HandPoseTrainConfig, log=print
) -> tuple[HandPoseNet, dict]:
    """The dual net from two trained single-modality nets: their encoders and heads are copied and frozen, the
    fusion head (gate + residual, :class:`HandPoseNet`) is trained for ``tc.fusion_steps`` on the cached
    branch features with the same loss, split and best-validation checkpointing."""
    torch.manual_seed(tc.seed)
    tr_idx, val_idx = split_train_val(len(data["angles_deg"]), tc)
    if not torch.equal(rgb.mean, ir.mean) or not torch.equal(rgb.std, ir.std):
        raise ValueError("the two branches were trained on different splits (mean/std differ)")
    centers = ir.enc["ir"].centers.numpy() if isinstance(ir.enc["ir"], MarkerPatchEncoder) else None
    half = ir.enc["ir"].half if centers is not None else tc.patch_half
    width = rgb.enc["rgb"].net[0].out_channels
    ir_width = None if centers is not None else ir.enc["ir"].net[0].out_channels
    feat = rgb.heads["rgb"][0].in_features
    model = HandPoseNet("dual", rgb.mean.numpy(), rgb.std.numpy(), feat, width, centers, half, ir_width)
    model.rgb_crop.copy_(rgb.rgb_crop)
    for k, src in (("rgb", rgb), ("ir", ir)):
        model.enc[k].load_state_dict(src.enc[k].state_dict())
        model.heads[k].load_state_dict(src.heads[k].state_dict())
    for p in [*model.enc.parameters(), *model.heads.parameters()]:
        p.requires_grad_(False)
    y = torch.from_numpy(np.asarray(data["angles_deg"], np.float32))
    f_tr, f_val = _features(model, data, tr_idx), _features(model, data, val_idx)
    # gate start: per joint, the branch with the lower validation MAE (sigmoid(+-4) = 0.98 / 0.02)
    with torch.no_grad():
        e = {k: (model.mean + model.std * model.heads[k](f_val[k]) - y[val_idx]).abs().mean(0) for k in ("rgb", "ir")}
        model.gate.bias.copy_(torch.where(e["rgb"] <= e["ir"], 4.0, -4.0))

    def loss_on(pos: np.ndarray) -> torch.Tensor:
        pred = model.mean + model.std * model.fuse({k: v[pos] for k, v in f_tr.items()})
        return pose_loss(pred, y[tr_idx[pos]], tc.lambda_mae, tc.lambda_rmse)

    @torch.no_grad()
    def val_loss() -> float:
        pred = model.mean + model.std * model.fuse(f_val)
        return float(pose_loss(pred, y[val_idx], tc.lambda_mae, tc.lambda_rmse))

    params = [*model.gate.parameters(), *model.resid.parameters()]
    summ = _fit(model, params, loss_on, val_loss, tc.fusion_steps, len(tr_idx), tc, log, "dual")
    summ["gate_start_rgb_joints"] = [j for j, v in zip(JOINTS, (e["rgb"] <= e["ir"]).tolist(), strict=True) if v]
    return model, summ


def _dual_shared_keys(models: dict[str, HandPoseNet]) -> set[str]:
    """State keys of the dual net that are copies of a single-modality net's (its frozen branches)."""
    if not {"rgb", "ir", "dual"} <= set(models):
        return set()
    dual = models["dual"].state_dict()
    out = set()
    for m in ("rgb", "ir"):
        single = models[m].state_dict()
        for k, v in dual.items():
            if k.startswith((f"enc.{m}.", f"heads.{m}.")) and k in single and torch.equal(single[k], v):
                out.add(k)
    return out


def save_models(
    path: Path,
    models: dict[str, HandPoseNet],
    tc: HandPoseTrainConfig,
    info: dict,
    rgb_gate: dict[str, torch.Tensor] | None = None,
) -> None:
    """One weights file for all settings (float16 except normalisation and marker centres). The dual net's
    frozen branches are stored once, in the single-modality nets (``dual_shared``), which halves the file.
    ``rgb_gate``: the RGB plausibility model of :func:`fit_rgb_gate` (float32, ~0.2 MB)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    shared = _dual_shared_keys(models)
    blob = {
        "dual_shared": sorted(shared),
        "version": HANDPOSE_VERSION,
        "joints": list(JOINTS),
        "dome": sensor_config(tc.grasp_set).to_dict(),  # the sensor whose IR reference the net was trained on
        "rgb_size": RGB_SIZE,
        "train": asdict(tc),
        "info": info,
        **({"rgb_gate": rgb_gate} if rgb_gate is not None else {}),
        "models": {
            m: {
                k: v.half() if v.is_floating_point() and k not in ("mean", "std") and not k.endswith("centers") else v
                for k, v in net.state_dict().items()
                if not (m == "dual" and k in shared)
            }
            for m, net in models.items()
        },
    }
    atomic_torch_save(path, blob)


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
    models = _build_nets(blob["models"], blob.get("dual_shared", []))
    main = blob["models"]  # a member stores only the tensors that differ from the main nets' (e.g. not the IR net)
    members = [
        _build_nets({m: {**main[m], **sd} for m, sd in mb["models"].items()}, mb.get("dual_shared", []))
        for mb in blob.get("members", [])
    ]
    if members:  # a seed ensemble: every setting predicts the mean of its members' angles
        models = {m: HandPoseEnsemble([net, *(mb[m] for mb in members)]) for m, net in models.items()}
    sp = blob.get("specialists")
    if sp:  # joint specialists (RGB nets): they give their joints in every setting that sees the RGB frame
        spec = [_build_nets({"rgb": sd}, [])["rgb"] for sd in sp["nets"]]
        idx = [JOINTS.index(j) for j in sp["joints"]]
        for m in [m for m in models if m in ("rgb", "dual")]:
            base = models[m] if isinstance(models[m], HandPoseEnsemble) else HandPoseEnsemble([models[m]])
            tta = tuple(sp.get("tta_deg", (0.0,)))
            models[m] = HandPoseEnsemble(list(base.nets), spec, idx, float(sp.get("mix", 1.0)), tta)
    return models, blob


class HandPoseEnsemble(nn.Module):
    """Independently seeded nets of one setting (same data, split and recipe, ``--model-seed``); predicts the mean
    of their angles (deg). ``nets[0]`` is the file's main net (the one partial retraining starts from).

    ``specialists``: RGB nets trained for a few joints (``joints``, indices into :data:`JOINTS`; e.g. the thumb
    MCP / IP, :func:`add_joint_specialists`). Those joints become ``(1 - mix) x`` the members' mean ``+ mix x``
    the specialists' mean; the other joints stay the members' mean. ``tta_deg``: the specialists' angles are
    averaged over the RGB frame turned about the image centre by each of these angles (deg; test-time rotation
    averaging, exact for this axially symmetric sensor up to interpolation, see :func:`rotate_frames`)."""

    def __init__(
        self,
        nets: list[HandPoseNet],
        specialists: list[HandPoseNet] | None = None,
        joints: list[int] | None = None,
        mix: float = 1.0,
        tta_deg: tuple[float, ...] = (0.0,),
    ) -> None:
        super().__init__()
        self.nets = nn.ModuleList(nets)
        self.tta_deg = tuple(float(a) for a in tta_deg) or (0.0,)
        self.specialists = nn.ModuleList(specialists or [])
        self.joints = list(joints or [])
        self.mix = float(mix)
        self.modality = nets[0].modality
        self.mean, self.std = nets[0].mean, nets[0].std

    def degrees(self, inputs: dict[str, torch.Tensor]) -> torch.Tensor:
        y = torch.stack([n.degrees(inputs) for n in self.nets]).mean(0)
        if len(self.specialists) and self.joints:
            x = inputs["rgb"]
            turned = [x if a == 0 else rotate_frames(x, 0.0, None, 0.0, torch.full((len(x),), a)) for a in self.tta_deg]
            ys = torch.stack([n.degrees({"rgb": xa}) for xa in turned for n in self.specialists]).mean(0)
            y = y.clone()
            y[:, self.joints] = (1.0 - self.mix) * y[:, self.joints] + self.mix * ys[:, self.joints]
        return y


def add_ensemble_members(path: Path, member_paths: list[Path]) -> None:
    """Append the nets of other weights files (same training set and split or the file's nested base,
    :func:`trained_within`; other ``--model-seed``) to the
    hand-pose weights file ``path`` as ensemble members (their RGB gate and info are not used)."""
    blob = torch.load(path, map_location="cpu", weights_only=False)
    for mp in member_paths:
        mb = torch.load(mp, map_location="cpu", weights_only=False)
        if set(mb["models"]) != set(blob["models"]) or not trained_within(mb.get("train", {}), blob["train"]):
            raise ValueError(f"{mp}: not a member of the same recipe as {path}")
        main = blob["models"]
        diff = {
            m: {k: v for k, v in sd.items() if not (k in main[m] and torch.equal(main[m][k], v))}
            for m, sd in mb["models"].items()
        }
        blob.setdefault("members", []).append({"models": diff, "dual_shared": mb.get("dual_shared", [])})
    atomic_torch_save(path, blob)


def add_joint_specialists(
    path: Path, specialist_paths: list[Path], joints: list[str], mix: float = 1.0, tta_deg: tuple[float, ...] = (0.0,)
) -> None:
    """Store the RGB nets of ``specialist_paths`` (trained on the same grasps and split or on the file's nested
    base, :func:`trained_within`; e.g. with the thumb MCP /
    IP weighted, ``--select-weighted``, maybe ``--rgb-crop``) in the hand-pose weights file ``path`` as joint
    specialists: in the ``rgb`` and ``dual`` settings the listed ``joints`` become ``(1 - mix) x`` the setting's
    prediction ``+ mix x`` the specialists' mean (:class:`HandPoseEnsemble`), each averaged over the RGB frame
    turned by the angles ``tta_deg`` (deg; ``(0,)``: no turn). Replaces earlier specialists."""
    blob = torch.load(path, map_location="cpu", weights_only=False)
    bad = [j for j in joints if j not in JOINTS]
    if bad or not joints or not 0.0 <= mix <= 1.0:
        raise ValueError(f"specialist joints must name joints of {JOINTS} and mix lie in [0, 1], got {joints}, {mix}")
    if not tta_deg or not all(np.isfinite(a) and abs(a) <= 45.0 for a in tta_deg):
        raise ValueError(f"test-time turns must be finite angles within +-45 deg, got {tta_deg}")
    nets = []
    for sp in specialist_paths:
        sb = torch.load(sp, map_location="cpu", weights_only=False)
        if "rgb" not in sb.get("models", {}) or not trained_within(sb.get("train", {}), blob["train"]):
            raise ValueError(f"{sp}: not an RGB net of the same training set as {path}")
        nets.append(sb["models"]["rgb"])
    blob["specialists"] = {
        "joints": list(joints),
        "mix": float(mix),
        "nets": nets,
        "tta_deg": [float(a) for a in tta_deg],
    }
    atomic_torch_save(path, blob)


def _build_nets(models_blob: dict, dual_shared: list[str]) -> dict[str, HandPoseNet]:
    """The nets of one stored set of settings (see :func:`save_models`)."""
    models = {}
    for m in sorted(models_blob, key=lambda k: k == "dual"):  # singles first: the dual net may share their weights
        sd = dict(models_blob[m])
        for k in dual_shared if m == "dual" else []:
            sd[k] = models_blob["rgb" if k.split(".")[1] == "rgb" else "ir"][k]
        centers = sd.get("enc.ir.centers")
        widths = {k: int(sd[f"enc.{k}.net.0.weight"].shape[0]) for k in ("rgb", "ir") if f"enc.{k}.net.0.weight" in sd}
        net = HandPoseNet(
            m,
            sd["mean"].numpy(),
            sd["std"].numpy(),
            int(sd[f"heads.{next(iter(['rgb', 'ir'] if m == 'dual' else [m]))}.0.weight"].shape[1]),
            widths.get("rgb", widths.get("ir", 16)),
            None if centers is None else centers.float().numpy(),
            int(round((np.sqrt(sd["enc.ir.local.0.weight"].shape[1] / 2) - 1) / 2)) if centers is not None else 3,
            widths.get("ir"),
            tuple(int(v) for v in sd["rgb_crop"]) if "rgb_crop" in sd else None,
        )
        sd.setdefault("rgb_crop", net.rgb_crop)  # files from before the crop option read the whole frame
        net.load_state_dict({k: v.float() if v.is_floating_point() else v for k, v in sd.items()})
        net.eval()
        models[m] = net
    return models


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


def unobservable_joints(grasps: np.ndarray) -> np.ndarray:
    """(n, 12) bool: distal joints of the lifted digits (finger PIP, thumb MCP and IP). A lifted digit does
    not touch the shell, so the IR image shows nothing of it, and its distal segments are 15-30 mm off the
    shell: a 5 deg change of such a joint moves the simulated RGB image by ~1 grey level (matched-filter SNR
    0-1.6 against the sensor noise, noise-free renders), against 7-65 for the MCP / CMC joints."""
    from vtrack.dome.handsim import DIGITS, GRASPS

    out = np.zeros((len(grasps), len(JOINTS)), bool)
    for i, g in enumerate(np.asarray(grasps).astype(str)):
        for d in DIGITS:
            if d.name not in GRASPS[g]:
                out[i, list(d.joints[1:])] = True
    return out


def rgb_joint_sensitivity(n_grasps: int = 40, step_deg: float = 5.0, seed: int = 7) -> dict:
    """Evaluation-only: how much the simulated RGB image changes when one joint moves by ``step_deg``.

    Noise-free renders of ``n_grasps`` random grasps, each joint moved in turn. For each joint and contact
    state (``touch`` / ``lifted``) the median over grasps of the largest pixel change (grey levels) and of the
    matched-filter SNR ``||diff|| / sigma``, with sigma the simulator's per-pixel noise (0.015 x 255). SNR around
    1 or below means the change is lost in the noise of one frame."""
    from vtrack.dome.handsim import DIGITS, GRASPS, HandDomeSimulator

    sim = HandDomeSimulator()
    rng = np.random.default_rng(seed)
    rows: dict[tuple[str, str], list] = {}
    for _ in range(n_grasps):
        q, yaw, grasp = sim.hand.sample(rng)
        base = sim.render_rgb(sim.hand.capsules(q, yaw), np.random.default_rng(0), noise=0.0).astype(np.float64)
        for d in DIGITS:
            state = "touch" if d.name in GRASPS[grasp] else "lifted"
            for j in d.joints:
                qq = q.copy()
                qq[j] += step_deg
                img = sim.render_rgb(sim.hand.capsules(qq, yaw), np.random.default_rng(0), noise=0.0)
                diff = img.astype(np.float64) - base
                rows.setdefault((JOINTS[j], state), []).append((np.abs(diff).max(), _snr(img, base, RGB_NOISE_GREY)))
    return {
        f"{j}/{st}": {
            "max_grey": float(np.median([r[0] for r in v])),
            "snr": float(np.median([r[1] for r in v])),
            "n": len(v),
        }
        for (j, st), v in sorted(rows.items())
    }


def digit_joint_mask(touch: np.ndarray) -> np.ndarray:
    """(n, 5) per-digit flags (:data:`vtrack.dome.handsim.DIGITS` order) -> (n, 12) per-joint flags (the thumb's
    flag also covers its abduction)."""
    from vtrack.dome.handsim import DIGITS

    touch = np.asarray(touch, bool)
    out = np.zeros((len(touch), len(JOINTS)), bool)
    for i, d in enumerate(DIGITS):
        out[:, list(d.joints)] = touch[:, i : i + 1]
        if d.name == "thumb":
            out[:, 0] = touch[:, i]
    return out


#: per-pixel noise sigma of the simulated cameras in grey levels (RGB 0.015, IR 0.02 of full scale): the unit of
#: the matched-filter SNR ``||image change|| / sigma`` of the observability diagnostics below
RGB_NOISE_GREY, IR_NOISE_GREY = 0.015 * 255, 0.02 * 255


def _snr(a: np.ndarray, b: np.ndarray, sigma: float) -> float:
    """Matched-filter SNR of the change between two images: ``||a - b|| / sigma``."""
    return float(np.sqrt(((np.asarray(a, np.float64) - b) ** 2).sum()) / sigma)


def _noise_free_images(sim, q: np.ndarray, place) -> tuple[np.ndarray, np.ndarray]:
    """(RGB, IR) float64 noise-free renders of hand pose ``q`` (deg) at ``place`` by ``sim``."""
    caps = sim.hand.capsules(q, place=place)
    return (
        sim.render_rgb(caps, np.random.default_rng(0), noise=0.0).astype(np.float64),
        sim.render_ir(caps, np.random.default_rng(0), noise=0.0).astype(np.float64),
    )


def joint_observability(data: dict, step_deg: float = 5.0, cache: bool = True) -> dict[str, np.ndarray]:
    """Evaluation-only (reads the simulated hand state ``angles_deg`` + ``place`` of a ``varied`` set): for every
    grasp and joint, how much a ``step_deg`` change of that joint alone changes the noise-free images.

    Returns ``rgb_snr`` and ``ir_snr`` (n, 12): matched-filter SNR ``||image change|| / sigma`` with sigma the
    simulator's per-pixel noise (RGB 0.015 x 255, IR 0.02 x 255 grey levels), and ``observable`` = either SNR
    >= :data:`OBS_SNR_MIN` (a change of a few deg is then visible in one frame). Cached next to the data set
    (``vtrack.paths.cache_dir()``), ~0.3 s per grasp."""
    import hashlib

    from vtrack.dome.handsim import HandDomeSimulator, HandPlace
    from vtrack.paths import cache_dir

    q_all = np.asarray(data["angles_deg"], np.float64)
    place_all = np.asarray(data["place"], np.float64)
    sensor = sensor_config("varied").to_dict()  # the IR image (and so its SNR) depends on the marker layout
    salt = str(sorted(sensor.items())).encode() + rgb_model("varied").encode()  # and the RGB one on its model
    key = hashlib.sha1(q_all.tobytes() + place_all.tobytes() + str(step_deg).encode() + salt).hexdigest()[:12]
    path = cache_dir() / "dome" / f"handpose_obs_{key}.npz"
    if cache and path.exists():
        with np.load(path) as z:
            return {k: z[k] for k in z.files}
    sim = HandDomeSimulator(grasp_set="varied")
    rgb_snr = np.zeros(q_all.shape)
    ir_snr = np.zeros(q_all.shape)
    for i, (q, pa) in enumerate(zip(q_all, place_all, strict=True)):
        place = HandPlace.from_array(pa)
        rgb0, ir0 = _noise_free_images(sim, q, place)
        for j in range(len(JOINTS)):
            qq = q.copy()
            qq[j] += step_deg
            rgb1, ir1 = _noise_free_images(sim, qq, place)
            rgb_snr[i, j] = _snr(rgb1, rgb0, RGB_NOISE_GREY)
            ir_snr[i, j] = _snr(ir1, ir0, IR_NOISE_GREY)
    out = {"rgb_snr": rgb_snr, "ir_snr": ir_snr, "observable": (rgb_snr >= OBS_SNR_MIN) | (ir_snr >= OBS_SNR_MIN)}
    if cache:
        from vtrack.io.jsonio import atomic_savez

        atomic_savez(path, **out)
    return out


def thumb_redundancy_snr(n_grasps: int = 60, seed: int = TEST_SEED, scale: float = 0.25) -> dict:
    """Evaluation-only: how visible the thumb's redundant degree of freedom is on held-out ``varied`` grasps.

    For each grasp the thumb tip is held fixed and the IP / MCP ratio is changed by ``-scale`` (or ``+scale`` when
    that is out of reach); the thumb is re-solved by :meth:`HandModel.digit_ik`. Returns the medians of the
    largest thumb-joint change (deg) and of the noise-free image change as matched-filter SNR (RGB and IR, as in
    :func:`joint_observability`), per grasp that could be re-solved, and per grasp (``grasp_index`` into the
    held-out set, ``snr_rgb``)."""
    from vtrack.dome.handsim import DIGITS, HandDomeSimulator, HandPlace, make_handpose_dataset

    te = make_handpose_dataset(TEST_N, seed, grasp_set="varied")
    sim = HandDomeSimulator(grasp_set="varied")
    hand, thumb = sim.hand, DIGITS[0]

    dq, snr_rgb, snr_ir, index = [], [], [], []
    for i, (q, pa) in enumerate(
        zip(te["angles_deg"][:n_grasps].astype(np.float64), te["place"][:n_grasps], strict=True)
    ):
        place = HandPlace.from_array(pa)
        tip = hand._chain(thumb, q, 0.0, place)[-1]
        ratio = q[thumb.joints[2]] / max(q[thumb.joints[1]], 1e-6)
        for r in (ratio * (1 - scale), ratio * (1 + scale)):
            qq = hand.digit_ik(thumb, tip, q, place, r)
            if qq is None:
                continue
            (a0, b0), (a1, b1) = _noise_free_images(sim, q, place), _noise_free_images(sim, qq, place)
            dq.append(float(np.abs(qq - q)[list(thumb.joints)].max()))
            snr_rgb.append(_snr(a1, a0, RGB_NOISE_GREY))
            snr_ir.append(_snr(b1, b0, IR_NOISE_GREY))
            index.append(i)
            break
    return {
        "grasp_index": index,
        "snr_rgb": snr_rgb,
        "grasps": len(dq),
        "median_joint_change_deg": float(np.median(dq)),
        "median_snr_rgb": float(np.median(snr_rgb)),
        "median_snr_rgb_per_deg": float(np.median(np.asarray(snr_rgb) / np.asarray(dq))),
        "median_snr_ir": float(np.median(snr_ir)),
    }


#: nuisance parameters of :func:`pose_crb` besides the 12 joints: the hand placement (:class:`HandPlace`: yaw, tilts,
#: knuckle lift, four finger abductions), the RGB camera's room-light and skin gains and the IR camera's gain
CRB_NUISANCE = (
    "yaw",
    "tilt_x",
    "tilt_y",
    "lift",
    "abd_index",
    "abd_middle",
    "abd_ring",
    "abd_little",
    "rgb_bg_gain",
    "rgb_skin_gain",
    "ir_gain",
)


def _ir_float(sim, caps: list, gain: float = 0.9) -> np.ndarray:
    """(S, S) float64 noise-free IR frame (full scale 1, no 8-bit quantisation) of the hand-pose sensor: the
    renderer of :meth:`DomeSimulator.render` with ``noise=0`` (gain 0.9, no background jitter) before rounding."""
    import cv2

    rng = np.random.default_rng(0)  # the presses' drag jitter: the same draw for every render of a grasp
    disp = np.zeros_like(sim.sim.geo.marker_rest)
    for pr in sim.presses(caps, rng):
        disp += sim.sim.deform(pr)["disp_markers"]
    img, _ = sim.sim.draw_markers(sim.sim.geo.marker_rest + disp)
    S = img.shape[0]
    img = cv2.GaussianBlur(img, (0, 0), 0.7).astype(np.float64) * gain
    yy, xx = np.mgrid[0:S, 0:S]
    vign = 1.0 - 0.35 * (np.hypot(xx - (S - 1) / 2, yy - (S - 1) / 2) / (S / 2)) ** 2
    return img * vign + 0.08 * vign


def pose_crb(n_grasps: int = 100, seed: int = TEST_SEED, step_deg: float = 1.0) -> dict:
    """Evaluation-only (reads the simulated hand state of held-out ``varied`` grasps): the Cramer-Rao bound of the
    12 joint angles given one noisy RGB and / or IR frame, with every other unknown of a frame free.

    Per grasp, the Jacobian of the noise-free images (RGB :meth:`HandDomeSimulator.rgb_float`, IR
    :func:`_ir_float`, both before 8-bit rounding) with respect to the 12 joints and the :data:`CRB_NUISANCE`
    parameters is taken by central differences (``step_deg`` deg / 0.25 mm / 0.02 gain). The Fisher information
    is ``J^T J / sigma^2`` with the simulator's pixel noise (RGB 0.015, IR 0.02 of full scale); its inverse bounds
    the covariance of any unbiased estimator. The thumb's redundant degree of freedom (IP / MCP ratio at a fixed
    tip) is not removed by hand: it is one direction of the joint space, and the bound of the thumb MCP / IP
    says how well the images pin it down once the placement and the gains may absorb what they can.

    Returns per grasp and joint ``sigma_rgb``, ``sigma_ir``, ``sigma_dual`` (deg, (n, 12)) and ``p5_dual``: the
    probability that an unbiased Gaussian estimator at the bound lands within 5 deg (so its mean over joints and
    grasps is an Acc@5 an efficient estimator would reach, locally). The prior (r drawn in 0.5-1.5, the joint
    ranges) is not used: a net that knows it can do better where the images are weak."""
    from math import erf, sqrt

    from vtrack.dome.handsim import HandDomeSimulator, HandPlace, make_handpose_dataset

    te = make_handpose_dataset(TEST_N, seed, grasp_set="varied")
    sim = HandDomeSimulator(grasp_set="varied")
    out = {k: np.zeros((n_grasps, len(JOINTS))) for k in ("sigma_rgb", "sigma_ir", "sigma_dual")}
    for i in range(n_grasps):
        one = grasp_crb(sim, te["angles_deg"][i], HandPlace.from_array(te["place"][i]), step_deg)
        for k, v in one.items():
            out[k][i] = v
    out["p5_dual"] = np.vectorize(lambda s: erf(5.0 / (sqrt(2.0) * max(s, 1e-9))))(out["sigma_dual"])
    return out


def grasp_crb(sim, q: np.ndarray, place, step_deg: float = 1.0) -> dict[str, np.ndarray]:
    """Cramer-Rao bound (deg, (12,) per camera: ``sigma_rgb``, ``sigma_ir``, ``sigma_dual``) of the joints of one
    grasp (joints ``q`` deg, :class:`HandPlace` ``place``) rendered by ``sim``; see :func:`pose_crb`."""
    nj, nn_ = len(JOINTS), len(CRB_NUISANCE)
    steps = np.r_[np.full(nj, step_deg), step_deg, step_deg, step_deg, 0.25, np.full(4, step_deg), 0.02, 0.02, 0.02]
    s_rgb, s_ir = 0.015, 0.02

    def render(theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        from vtrack.dome.handsim import HandPlace

        qq, pl, g = theta[:nj], theta[nj : nj + 8], theta[nj + 8 :]
        caps = sim.hand.capsules(qq, place=HandPlace.from_array(pl))
        return sim.rgb_float(caps, g[0], g[1]).astype(np.float64).ravel(), _ir_float(sim, caps, g[2]).ravel()

    theta0 = np.r_[np.asarray(q, np.float64), place.to_array().astype(np.float64), 1.0, 1.0, 0.9]
    cols_rgb, cols_ir = [], []
    for k in range(nj + nn_):
        tp, tm = theta0.copy(), theta0.copy()
        tp[k] += steps[k]
        tm[k] -= steps[k]
        (rp, ip), (rm, im) = render(tp), render(tm)
        cols_rgb.append((rp - rm) / (2 * steps[k]) / s_rgb)
        cols_ir.append((ip - im) / (2 * steps[k]) / s_ir)
    j_rgb, j_ir = np.stack(cols_rgb, 1), np.stack(cols_ir, 1)
    f_rgb, f_ir = j_rgb.T @ j_rgb, j_ir.T @ j_ir
    out = {}
    for key, f in (("sigma_rgb", f_rgb), ("sigma_ir", f_ir), ("sigma_dual", f_rgb + f_ir)):
        cov = np.linalg.inv(f + 1e-6 * np.eye(len(f)))  # an unseen direction gets sigma ~1000 deg, not 0
        out[key] = np.sqrt(np.clip(np.diag(cov)[:nj], 0.0, None))
    return out


def ir_content_ablation(steps: int = 3000, n_train: int = 6000, seed: int = 0) -> dict:
    """Evaluation-only (reads the simulated hand of the ``varied`` set): what the fingertip contacts can tell about
    the pose at best. An MLP (2 x 256, AdamW, one-cycle 2e-3, L1, batch 128) maps the *exact* fingertip positions of
    the pressing digits (x, y, z / R and a press flag per digit, zeros for a hovering digit: no more than a perfect
    IR front end could read off the tips) to the 12 joints; trained on the ``n_train`` training grasps, scored on
    the held-out grasps. ``tips_and_placement`` adds the hand placement (yaw, tilts, knuckle lift), which neither
    the IR image nor the tips show. Returns both metric dicts (deg, %)."""
    from vtrack.dome.handsim import DIGITS, HandModel, HandPlace, make_handpose_dataset

    hand = HandModel()

    def feats(d: dict) -> tuple[np.ndarray, np.ndarray]:
        f_all, p_all = [], []
        for q, pa in zip(np.asarray(d["angles_deg"], np.float64), d["place"], strict=True):
            place, f = HandPlace.from_array(pa), []
            for dg in DIGITS:
                press = hand.digit_penetration_mm(dg, q, place) > 0
                f += [*(hand._chain(dg, q, 0.0, place)[-1] / hand.R * press), float(press)]
            f_all.append(f)
            p_all.append(np.asarray(pa[:4], np.float64) / np.array([20.0, 8.0, 12.0, 8.0]))
        return np.array(f_all), np.array(p_all)

    torch.set_num_threads(1)
    tr = load_train_set(n_train, seed, grasp_set="varied")
    te = make_handpose_dataset(TEST_N, TEST_SEED, grasp_set="varied")
    (f_tr, p_tr), (f_te, p_te) = feats(tr), feats(te)
    y = np.asarray(tr["angles_deg"], np.float64)
    ym, ys = y.mean(0), y.std(0) + 1e-6

    def fit_predict(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        torch.manual_seed(seed)
        mu, sd = a.mean(0), a.std(0) + 1e-6
        x = torch.tensor((a - mu) / sd, dtype=torch.float32)
        t = torch.tensor((y - ym) / ys, dtype=torch.float32)
        net = nn.Sequential(nn.Linear(a.shape[1], 256), nn.ReLU(), nn.Linear(256, 256), nn.ReLU(), nn.Linear(256, 12))
        opt = torch.optim.AdamW(net.parameters(), 2e-3)
        sch = torch.optim.lr_scheduler.OneCycleLR(opt, 2e-3, total_steps=steps)
        for _ in range(steps):
            i = torch.randint(0, len(x), (128,))
            loss = (net(x[i]) - t[i]).abs().mean()
            opt.zero_grad()
            loss.backward()
            opt.step()
            sch.step()
        with torch.no_grad():
            return net(torch.tensor((b - mu) / sd, dtype=torch.float32)).numpy() * ys + ym

    gt = np.asarray(te["angles_deg"], np.float64)
    keep = ("mae_deg", "rmse_deg", "acc1", "acc5")
    out = {}
    for name, a, b in (("tips", f_tr, f_te), ("tips_and_placement", np.hstack([f_tr, p_tr]), np.hstack([f_te, p_te]))):
        m = pose_metrics(fit_predict(a, b), gt)
        out[name] = {k: m[k] for k in keep}
    return out


def information_bound(angles_deg: np.ndarray, grasps: np.ndarray, unobservable: np.ndarray | None = None) -> dict:
    """Evaluation-only bound (reads the truth): the metrics of an estimator that is exact on every joint
    except the unobservable ones, where it predicts the centre of their prior. ``mixed`` set
    (``unobservable=None``): :func:`unobservable_joints`, prior centre = the nominal wrap minus the 25 deg lift
    (the MAE- and Acc@5-optimal guess when the image carries no information). Otherwise ``unobservable``
    (n, 12) (e.g. ``~joint_observability(...)["observable"]``) and the per-joint median of the set."""
    from vtrack.dome.handsim import HandModel

    q = np.asarray(angles_deg, np.float64)
    if unobservable is None:
        un = unobservable_joints(grasps)
        centre = np.broadcast_to(HandModel().nominal() - 25.0, q.shape)
    else:
        un = np.asarray(unobservable, bool)
        centre = np.broadcast_to(np.median(q, 0), q.shape)
    pred = np.where(un, centre, q)
    return {
        **{k: v for k, v in pose_metrics(pred, q).items() if k != "per_joint_mae_deg"},
        "unobservable_joint_frac": float(un.mean()),
    }


def evaluate_handpose(
    path: Path | None = None, n_test: int = TEST_N, seed: int = TEST_SEED, grasp_set: str = "mixed"
) -> dict:
    """Metrics of every stored setting on held-out simulated grasps of ``grasp_set`` (never seen in training:
    other seed). ``path``: weights file (default: the shipped nets of that grasp set, :func:`weights_path`)."""
    from vtrack.dome.handsim import make_handpose_dataset

    torch.set_num_threads(1)
    models, blob = load_models(path or weights_path(grasp_set))
    te = make_handpose_dataset(n_test, seed, grasp_set=grasp_set)
    res: dict = {}
    obs = None
    if "touch" in te:  # varied set: contact flags per digit, observability measured on the images
        touching = digit_joint_mask(te["touch"])
        obs = joint_observability(te)
        unobs = ~obs["observable"]
    else:
        touching = touching_joints(te["grasp"])
        unobs = unobservable_joints(te["grasp"])
    for m in MODALITIES:
        if m not in models:
            continue
        t0 = time.perf_counter()
        pred = predict_deg(models[m], te)
        ms = (time.perf_counter() - t0) * 1e3 / len(pred)
        res[m] = {**pose_metrics(pred, te["angles_deg"]), "ms_per_frame_batched": ms}
        e = np.abs(pred - te["angles_deg"])
        parts = (("touching", touching), ("lifted", ~touching), ("observable", ~unobs), ("unobservable", unobs))
        for part, sel in parts:
            if sel.any():  # the contact set has no lifted digits: those keys are left out, never NaN
                res[m][f"{part}_mae_deg"] = float(e[sel].mean())
                res[m][f"{part}_acc5"] = float((e[sel] <= 5.0).mean() * 100)
    res["information_bound"] = information_bound(te["angles_deg"], te["grasp"], None if obs is None else unobs)
    if obs is not None:
        res["information_bound"]["obs_snr_min"] = OBS_SNR_MIN
        res["information_bound"]["median_snr_rgb"] = float(np.median(obs["rgb_snr"]))
    res["test_set"] = {
        "grasps": int(n_test),
        "seed": int(seed),
        "grasp_set": grasp_set,
        "simulated": True,
        "angle_std_deg": float(te["angles_deg"].std(0).mean()),
        "touching_joint_frac": float(touching.mean()),
    }
    res["weights"] = str(Path(path or weights_path(grasp_set)).name)
    # predicting the training mean: what the image contributes beyond the prior
    mean = np.asarray(next(iter(models.values())).mean.numpy(), np.float64)
    res["mean_pose_baseline"] = {
        k: v
        for k, v in pose_metrics(np.broadcast_to(mean, te["angles_deg"].shape), te["angles_deg"]).items()
        if k != "per_joint_mae_deg"
    }
    # predicting the nominal wrap (no image): every touching joint is drawn within +- JOINT_VAR_DEG (5 deg) of it,
    # so on the contact set this prior alone is within 5 deg of every joint - Acc@5 cannot rank nets there
    from vtrack.dome.handsim import HandModel

    nominal = np.broadcast_to(HandModel().nominal(), te["angles_deg"].shape)
    res["nominal_pose_baseline"] = {
        k: v for k, v in pose_metrics(nominal, te["angles_deg"]).items() if k != "per_joint_mae_deg"
    }
    return res


def evaluate_handpose_sets(
    path: Path | None = None, n_test: int = TEST_N, seed: int = TEST_SEED, mixed_path: Path | None = None
) -> dict:
    """All held-out sets. Top level (``rgb``, ``ir``, ``dual``, ``information_bound``, ``mean_pose_baseline``, ...):
    the default ``varied`` set (every fingertip on or just over the visible shell, hand placed at random, joints by
    IK) with the nets of ``path`` (default: shipped ``handpose_varied.pt``). ``mixed``: grasp types with lifted
    digits, whose distal joints neither camera sees (harder, partly unobservable), and ``contact``: every
    fingertip pressed, joints +- 5 deg around the nominal wrap (a no-image guess has Acc@5 = 100 % there), both
    with the nets of ``mixed_path`` (default: shipped ``handpose.pt``, trained on the mixed set)."""
    return {
        **evaluate_handpose(path, n_test, seed, "varied"),
        "mixed": evaluate_handpose(mixed_path, n_test, seed, "mixed"),
        "contact": evaluate_handpose(mixed_path, n_test, seed, "contact"),
    }


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
        #: RGB plausibility model (:func:`fit_rgb_gate`); files written before it have only the blank check
        self.rgb_gate = blob.get("rgb_gate")
        lo, hi = self.info.get("angle_range_deg", (None, None))
        self.lo = np.asarray(lo, np.float64) if lo is not None else None
        self.hi = np.asarray(hi, np.float64) if hi is not None else None
        if reference is None:  # the simulated no-contact frame of the sensor the nets were trained on
            from vtrack.dome.model import DomeConfig
            from vtrack.dome.simulate import DomeSimulator

            cfg = DomeConfig.from_dict(blob["dome"]) if "dome" in blob else HAND_DOME
            reference = DomeSimulator(cfg).reference_image(0.0)
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
            elif self.rgb_gate is not None:
                spe, t2 = (float(v[0]) for v in rgb_gate_scores(self.rgb_gate, rgb[None]))
                spe_max, t2_max = float(self.rgb_gate["spe_max"]), float(self.rgb_gate["t2_max"])
                if not (spe <= spe_max and t2 <= t2_max):  # NaN-safe: a NaN score fails
                    reasons.append(
                        f"RGB frame does not look like this sensor's (off the frames' subspace {spe:.3f} / max "
                        f"{spe_max:.3f}, inside it {t2:.0f} / max {t2_max:.0f})"
                    )
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


def load_train_set(
    n: int, seed: int, progress: bool = False, grasp_set: str = "mixed", n_contact: int = 0
) -> dict[str, np.ndarray]:
    """``n`` training grasps of ``grasp_set`` from cached chunks of :data:`CHUNK` (chunk k simulated with seed
    ``seed + k``), plus ``n_contact`` grasps of the ``contact`` set (same chunking)."""
    from vtrack.dome.handsim import make_handpose_dataset

    sets = [(n, grasp_set), (n_contact, "contact")]
    parts = [
        make_handpose_dataset(min(CHUNK, m - s), seed + k, progress=progress, grasp_set=g)
        for m, g in sets
        for k, s in enumerate(range(0, m, CHUNK))
    ]
    keys = set.intersection(*(set(p) for p in parts)) - {"ir_reference"}  # ``place`` / ``touch``: varied set only
    out = {k: np.concatenate([p[k] for p in parts]) for k in sorted(keys)}
    out["ir_reference"] = parts[0]["ir_reference"]
    return out


def train_all(
    tc: HandPoseTrainConfig,
    out: Path | None = None,
    modalities: tuple[str, ...] = MODALITIES,
    log=print,
    progress: bool = False,
) -> dict:
    """Simulate (cached), train the listed settings with their fixed budgets, evaluate on the held-out grasps,
    save. The dual net is fused from the single-modality nets of this run (or, when they are not retrained,
    of the weights file ``out``; they must come from the same training set and split)."""
    from vtrack.dome.handsim import make_handpose_dataset

    torch.set_num_threads(1)
    tr = load_train_set(tc.n_train, tc.seed, progress, grasp_set=tc.grasp_set, n_contact=tc.n_contact)
    te = make_handpose_dataset(TEST_N, TEST_SEED, progress=progress, grasp_set=tc.grasp_set)
    models, info = {}, {"train": {}, "test": {}}
    path = Path(out) if out else weights_path(tc.grasp_set)
    if set(modalities) != set(MODALITIES) and path.is_file():  # keep the settings not retrained in this run
        old, blob = load_models(path)
        if "members" in blob:
            log(f"[handpose] {path}: retraining keeps only the main net of each setting, not the ensemble members")
        old = {k: v.nets[0] if isinstance(v, HandPoseEnsemble) else v for k, v in old.items()}
        models = {k: v for k, v in old.items() if k not in modalities}
        info = {**blob.get("info", {}), **info}
        info["train"] = {k: v for k, v in blob.get("info", {}).get("train", {}).items() if k not in modalities}
        info["test"] = {k: v for k, v in blob.get("info", {}).get("test", {}).items() if k not in modalities}
    for m in [m for m in MODALITIES if m in modalities]:  # singles first: the dual net is fused from them
        if m == "dual":
            from vtrack.errors import InputError

            if not {"rgb", "ir"} <= set(models):
                raise InputError("the dual net needs trained rgb and ir nets", field="--modalities", got=modalities)
            net, summ = fuse_dual(models["rgb"], models["ir"], tr, tc, log)
        else:
            net, summ = train_handpose(m, tr, tc, log)
        models[m] = net
        info["train"][m] = summ
        info["test"][m] = {
            k: v for k, v in pose_metrics(predict_deg(net, te), te["angles_deg"]).items() if k != "per_joint_mae_deg"
        }
        log(f"[handpose {m}] held-out: {info['test'][m]}")
    info["angle_range_deg"] = (tr["angles_deg"].min(0).tolist(), tr["angles_deg"].max(0).tolist())
    gate = fit_rgb_gate(tr["rgb"])
    spe, t2 = rgb_gate_scores(gate, te["rgb"])
    info["rgb_gate_heldout_pass"] = float(np.mean((spe <= float(gate["spe_max"])) & (t2 <= float(gate["t2_max"]))))
    save_models(path, {k: models[k] for k in MODALITIES if k in models}, tc, info, gate)
    return info
