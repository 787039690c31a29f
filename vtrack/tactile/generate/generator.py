""":class:`TactileGenerator`: one reference tactile image + target depth/force + target pose/mask -> image.

Pipeline per request (full-resolution frame, any size; the network runs on a :data:`~.data.CROP_PX` square
crop around the target contact):
1. the reference's contact footprint (given, or detected against the background; no contact -> error)
   and its pose (centroid, orientation);
2. the target pose from ``target_pose`` or ``target_mask`` (else the reference's own pose);
3. the reference colour change inside its contact window is moved rigidly onto the target pose (this alone
   is the "shift" baseline of ``generate-eval``);
4. the network (stage 1 + control branch by default) predicts a colour-change correction in the target
   crop from the aligned reference, the target mask, the reference/target depths and the target pose; it
   is mapped back to the frame and added: ``out = background + aligned + correction``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vtrack.errors import InputError
from vtrack.tactile.generate import data as gd

_TAPER = gd.crop_taper()
#: ``flowK``: the few-step rectified-flow stage 1 sampled with K Euler steps.
FLOW_STEPS = (1, 2, 4, 8)
#: ``flowxK``: the same flow predicting the clean correction (x0 parametrisation).
MODES = (
    "two_stage",
    "stage1",
    "hybrid",
    "separate",
    *(f"flow{k}" for k in FLOW_STEPS),
    *(f"flowx{k}" for k in FLOW_STEPS),
    "shift",
    "shift_denoised",
)


@dataclass
class Request:
    """One generation request prepared at full and work resolution (internal)."""

    aligned_full: np.ndarray  # (H, W, 3) float32: the reference contact moved onto the target pose
    x: np.ndarray  # (6, CROP_PX, CROP_PX) float32 network crop input
    cond: np.ndarray  # (3,) depths
    pose: np.ndarray  # (5,) position condition
    crop: np.ndarray  # (2, 3) full-frame -> crop affine
    then: dict | None = None  # "separate" mode: the position step run on this request's output


class TactileGenerator:
    """Controllable tactile generator (see the module docstring).

    Args:
        weights: ``.pt`` from :func:`vtrack.tactile.generate.train.train` (default: the shipped weights).
        mode: ``two_stage`` (stage 1 + control branch), ``stage1`` (force control only), ``hybrid``
            (single-model baseline), ``separate`` (baseline: stage 1 at the reference's pose, then a separate
            position-only model moves its output), ``flow1|2|4|8`` (few-step rectified-flow stage 1 with that
            many sampling steps), ``shift`` (no network: the reference patch moved) or ``shift_denoised``
            (no network: the smoothed reference patch moved, i.e. what the network corrects).
        threads: torch threads (0 = leave as set, e.g. by `vtrack --threads`).
    """

    def __init__(self, weights: str | Path | None = None, mode: str = "two_stage", threads: int = 0) -> None:
        import torch

        from vtrack.tactile.generate import default_weights_path
        from vtrack.tactile.generate.model import ControlBranch, Flow, Hybrid, Position, Stage1, TwoStage, UNet

        if mode not in MODES:
            raise InputError("unknown generator mode", field="mode", expected=" | ".join(MODES), got=mode)
        if threads > 0:
            torch.set_num_threads(int(threads))
        self.mode = mode
        self.path = Path(weights) if weights is not None else default_weights_path()
        self.net = None
        self.net2 = None  # "separate": the position-only model
        self.meta: dict = {}
        self.available: set[str] = set()
        self._cache: tuple | None = None
        if mode in ("shift", "shift_denoised"):
            return
        if not self.path.is_file():
            raise InputError(
                "generator weights not found (run `vtrack tactile generate-train`)", path=self.path, field="weights"
            )
        try:
            # weights_only: a weights file is data; it must never be able to run code when unpickled
            state = torch.load(self.path, map_location="cpu", weights_only=True)
            self.meta = state["meta"]
            self.available = {k for k in state if k != "meta"}  # networks in this file
            ch = tuple(self.meta["channels"])
            f32 = {k: ({n: t.float() for n, t in v.items()} if k != "meta" else v) for k, v in state.items()}
            key = {"hybrid": "hybrid", "separate": "position"}.get(mode)
            if mode.startswith("flow"):
                key = "flowx" if mode.startswith("flowx") else "flow"
            if key is not None and key not in f32:
                raise InputError(
                    f"these weights have no {mode} baseline (train it: `vtrack tactile generate-train --extras`)",
                    path=self.path,
                    field="mode",
                )
            if mode == "hybrid":
                net = Hybrid(ch)
                net.load_state_dict(f32["hybrid"])
            elif mode.startswith("flow"):
                net = Flow(ch, steps=int(mode[len(key) :]), predict="target" if key == "flowx" else "velocity")
                net.load_state_dict(f32[key])
            else:
                base = UNet(ch=ch)
                base.load_state_dict(f32["base"])
                if mode in ("stage1", "separate"):
                    net = Stage1(base)
                    if mode == "separate":
                        pos = Position(ch)
                        pos.load_state_dict(f32["position"])
                        self.net2 = pos.eval().to(memory_format=torch.channels_last)
                else:
                    ctrl = ControlBranch(base)
                    ctrl.load_state_dict(f32["control"])
                    net = TwoStage(base, ctrl)
        except InputError:
            raise
        except Exception as e:  # corrupt / foreign file
            raise InputError(f"cannot load generator weights: {e}", path=self.path, field="weights") from e
        # channels-last convolutions run ~2x faster than NCHW for these small nets on CPU (measured)
        self.net = net.eval().to(memory_format=torch.channels_last)

    # ------------------------------------------------------------------ request preparation
    def _reference(
        self, ref: np.ndarray, bg: np.ndarray, ref_mask: np.ndarray | None, ref_pose: gd.Pose | None = None
    ) -> tuple[np.ndarray, gd.Pose, float, np.ndarray]:
        """(footprint, pose, footprint radius px, smoothed windowed colour change) of a reference.

        The pose is ``ref_pose`` when given (a labelled reference), else the footprint's centroid and principal
        axis. The generator was trained with the label's centre and angle as the reference pose, so moving the
        contact about its label puts it exactly where the target pose says; a footprint centroid can sit several
        px off the true centre (a shaded cross thresholded at half its peak loses its dim arms) and a symmetric
        footprint has no principal axis. The last reference is cached (keyed by a hash of every pixel and the
        pose: a subsampled hash would serve a different reference that differs only between the samples), so
        many targets from one reference cost one preparation."""
        import hashlib

        h = hashlib.blake2b(digest_size=16)
        for a in (ref, bg) + (() if ref_mask is None else (np.asarray(ref_mask),)):
            h.update(str(a.shape).encode())
            h.update(np.ascontiguousarray(a).tobytes())
        h.update(repr(ref_pose).encode())
        key = h.hexdigest()
        if self._cache is not None and self._cache[0] == key:
            return self._cache[1]
        H, W = ref.shape[:2]
        m = gd.detect_contact(ref, bg) if ref_mask is None else gd.check_mask(ref_mask, (H, W))
        rp = gd.mask_pose(m) if ref_pose is None else ref_pose
        radius = gd.footprint_radius(m, rp)
        delta = ref.astype(np.float32) - bg.astype(np.float32)
        out = (m, rp, radius, gd.reference_patch(delta, gd.contact_window(m, feather=gd.FEATHER), radius))
        self._cache = (key, out)
        return out

    def prepare(
        self,
        reference: np.ndarray,
        background: np.ndarray,
        *,
        ref_depth_mm: float,
        target_depth_mm: float,
        target_pose: gd.Pose | None = None,
        target_mask: np.ndarray | None = None,
        ref_mask: np.ndarray | None = None,
        ref_pose: gd.Pose | None = None,
        rotation_deg: float = 0.0,
        _second: bool = False,
    ) -> Request:
        """Validate and prepare one request (see :meth:`generate`; ``_second``: internal, the position step of
        the ``separate`` baseline)."""
        ref = np.asarray(reference)
        bg = np.asarray(background)
        for name, v in (("ref_depth_mm", ref_depth_mm), ("target_depth_mm", target_depth_mm)):
            if not (np.isfinite(v) and v >= 0):
                raise InputError("depth must be a finite non-negative number", field=name, expected=">= 0 mm", got=v)
        if ref.ndim != 3 or ref.shape[2] != 3 or bg.shape != ref.shape:
            raise InputError(
                "reference and background must be BGR images of the same size",
                field="background",
                expected=str(ref.shape),
                got=bg.shape,
            )
        H, W = ref.shape[:2]
        if ref_pose is not None:
            gd.check_pose_in_gel(ref_pose, (H, W), field="ref_pose")
        ref_mask, rp, radius, patch = self._reference(ref, bg, ref_mask, ref_pose)
        if target_mask is not None:
            tm = gd.check_mask(target_mask, (H, W))
            tp = gd.mask_pose(tm)
            tp = gd.Pose(tp.x, tp.y, rp.theta_deg + _axis_delta(tp.theta_deg - rp.theta_deg))
        elif target_pose is not None:
            tp = target_pose
        else:
            tp = gd.Pose(rp.x, rp.y, rp.theta_deg + rotation_deg)
        gd.check_pose_in_gel(tp, (H, W))
        _check_moved(ref_mask, gd.relative_transform(rp, tp))
        then = None
        if self.mode == "separate" and not _second:
            # step 1 = force only, at the reference's own pose; step 2 (in generate_many) moves its output
            then = {"target_pose": tp, "ref_mask": ref_mask, "ref_pose": rp, "depth": float(target_depth_mm)}
            tp = rp
        x, A, M = gd.crop_inputs(patch, ref_mask, rp, tp, radius)
        if self.mode == "shift":  # the baseline moves the patch as it is, noise included
            delta = ref.astype(np.float32) - bg.astype(np.float32)
            patch = gd.reference_patch(delta, gd.contact_window(ref_mask), radius, denoise=False)
        aligned = gd.warp(patch, M)
        cond = gd.cond_vector(float(ref_depth_mm), float(target_depth_mm))
        return Request(aligned, x, cond, gd.pose_vector(rp, tp, (H, W)), A, then)

    # ------------------------------------------------------------------ generation
    def corrections(self, requests: list[Request], net=None) -> np.ndarray:
        """(B, CROP_PX, CROP_PX, 3) float32 colour-change corrections (grey levels) in the target crops
        (``net``: another network than the generator's own, e.g. the separate position model)."""
        import torch

        net = net if net is not None else self.net
        if net is None:
            return np.zeros((len(requests), gd.CROP_PX, gd.CROP_PX, 3), np.float32)
        with torch.inference_mode():
            x = torch.from_numpy(np.stack([r.x for r in requests])).contiguous(memory_format=torch.channels_last)
            c = torch.from_numpy(np.stack([r.cond for r in requests]))
            p = torch.from_numpy(np.stack([r.pose for r in requests]))
            out = net(x, c, p).numpy().transpose(0, 2, 3, 1) * gd.DELTA_SCALE
        if not np.isfinite(out).all():
            raise InputError("generator produced non-finite values", path=self.path, field="weights")
        return out

    def compose(self, req: Request, background: np.ndarray, corr: np.ndarray) -> np.ndarray:
        """Full-resolution uint8 BGR image: background + aligned reference + upsampled correction."""
        import cv2

        H, W = background.shape[:2]
        # the correction lives in the target crop: map it back with the inverse crop affine (zero outside)
        up = cv2.warpAffine(corr * _TAPER, req.crop, (W, H), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP)
        img = background.astype(np.float32) + req.aligned_full + up
        return np.clip(np.rint(img), 0, 255).astype(np.uint8)

    def generate_many(self, requests: list[Request], background: np.ndarray, batch: int = 32) -> list[np.ndarray]:
        out = []
        for i in range(0, len(requests), batch):
            chunk = requests[i : i + batch]
            for r, c in zip(chunk, self.corrections(chunk), strict=True):
                out.append(self.compose(r, background, c))
        if self.net2 is not None:  # "separate": move each force-step output with the position model
            second = []
            for img, r in zip(out, requests, strict=True):
                t = r.then
                second.append(
                    self.prepare(
                        img,
                        background,
                        ref_depth_mm=t["depth"],
                        target_depth_mm=t["depth"],
                        target_pose=t["target_pose"],
                        ref_mask=t["ref_mask"],
                        ref_pose=t["ref_pose"],
                        _second=True,
                    )
                )
            out = []
            for i in range(0, len(second), batch):
                chunk = second[i : i + batch]
                for r, c in zip(chunk, self.corrections(chunk, self.net2), strict=True):
                    out.append(self.compose(r, background, c))
        return out

    def generate(self, reference: np.ndarray, background: np.ndarray, **kw) -> np.ndarray:
        """Generate one tactile image (uint8 BGR, the reference's size).

        Args:
            reference: the reference press (uint8 BGR).
            background: its no-contact frame (same size).
            ref_depth_mm: the reference's indentation (mm).
            target_depth_mm: the wanted indentation (mm); see :func:`~.data.hertz_depth_mm` for a force.
            target_pose: target contact centroid (px) and orientation (deg) (or ``target_mask``; neither =
                the reference's pose; ``rotation_deg`` then rotates in place).
            target_mask: a target footprint (the reference template moved; its centroid and axis set the pose).
            ref_mask: the reference footprint (default: detected).
            ref_pose: the reference contact's labelled pose (px, deg; default: the centroid and principal axis
                of ``ref_mask``). Give it when the reference is labelled: the target pose is then relative to
                the label, and the generated contact sits exactly at ``target_pose`` (see
                :func:`~.data.indenter_mask` for a footprint consistent with a label).
        """
        req = self.prepare(reference, background, **kw)
        if self.net2 is not None:
            return self.generate_many([req], np.asarray(background))[0]
        return self.compose(req, np.asarray(background), self.corrections([req])[0])


def _check_moved(ref_mask: np.ndarray, M: np.ndarray) -> None:
    """The reference footprint moved by ``M`` must keep at least a quarter of itself inside the image."""
    moved = gd.warp(ref_mask.astype(np.uint8), M)
    if moved.sum() < 0.25 * ref_mask.sum():
        raise InputError(
            "target contact lies (mostly) outside the gel",
            field="position",
            expected="at least a quarter of the footprint inside the image",
            got=f"{int(moved.sum())} of {int(ref_mask.sum())} px",
        )


def _axis_delta(d: float) -> float:
    """Orientation difference of two principal axes (defined mod 180 deg), wrapped to [-90, 90)."""
    return (d + 90.0) % 180.0 - 90.0
