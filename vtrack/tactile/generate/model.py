"""Networks of the tactile generator (torch; imported only by :mod:`vtrack.tactile.generate`).

- :class:`UNet`: a small conditional U-Net (3 levels) with FiLM conditioning on a vector at every level.
  Stage 1 (force/depth control) is one: inputs = the aligned reference colour change (3 ch) + the target
  mask (1 ch), condition = (reference depth, target depth, difference); output = a colour-change
  *correction* added to the aligned reference (last layer zero-initialised, so an untrained net returns
  the reference unchanged).
- :class:`ControlBranch`: the stage-2 position control, ControlNet-style: a trainable copy of the stage-1
  encoder fed the stage-1 input plus a hint (target mask, target-centroid coordinates, displacement and
  rotation maps) through a zero-initialised conv, whose features reach the frozen stage-1 decoder through
  zero-initialised 1x1 convs (so at the start of fine-tuning the two-stage model equals stage 1).
- ``hybrid`` baseline: one :class:`UNet` with all inputs (reference, mask, position maps), from scratch.
"""

from __future__ import annotations

import copy

import torch
from torch import nn

N_IMG = 4  # aligned reference delta (3) + target mask (1); the crop input has 2 more: coordinates x, y
N_COND = 3  # ref depth, target depth, difference (mm)
N_POSE = 5  # target x, y in [-1, 1], displacement dx, dy, rotation / 180


def _block(cin: int, cout: int) -> nn.Sequential:
    return nn.Sequential(
        nn.Conv2d(cin, cout, 3, padding=1),
        nn.ReLU(inplace=True),
        nn.Conv2d(cout, cout, 3, padding=1),
        nn.ReLU(inplace=True),
    )


def _zero(m: nn.Module) -> nn.Module:
    for p in m.parameters():
        nn.init.zeros_(p)
    return m


class Encoder(nn.Module):
    def __init__(self, cin: int, ch: tuple[int, int, int], n_cond: int) -> None:
        super().__init__()
        c1, c2, c3 = ch
        self.b1, self.b2, self.b3 = _block(cin, c1), _block(c1, c2), _block(c2, c3)
        self.pool = nn.AvgPool2d(2)
        self.film = nn.Linear(n_cond, 2 * (c1 + c2 + c3))
        self.ch = ch

    def forward(self, x: torch.Tensor, cond: torch.Tensor, hint: torch.Tensor | None = None) -> list[torch.Tensor]:
        c1, c2, c3 = self.ch
        f = self.film(cond)
        g1, b1, g2, b2, g3, b3 = torch.split(f, [c1, c1, c2, c2, c3, c3], 1)

        def mod(h: torch.Tensor, g: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
            return h * (1 + g[:, :, None, None]) + b[:, :, None, None]

        h1 = self.b1[0](x)
        if hint is not None:
            h1 = h1 + hint
        h1 = mod(self.b1[3](self.b1[2](self.b1[1](h1))), g1, b1)
        h2 = mod(self.b2(self.pool(h1)), g2, b2)
        h3 = mod(self.b3(self.pool(h2)), g3, b3)
        return [h1, h2, h3]


class UNet(nn.Module):
    """Conditional U-Net: ``(image channels, condition vector) -> 3-channel correction`` at input size."""

    def __init__(self, cin: int = N_IMG, n_cond: int = N_COND, ch: tuple[int, int, int] = (12, 24, 32)) -> None:
        super().__init__()
        c1, c2, c3 = ch
        self.enc = Encoder(cin, ch, n_cond)
        self.up = nn.Upsample(scale_factor=2, mode="bilinear", align_corners=False)
        self.d2 = _block(c3 + c2, c2)
        self.d1 = _block(c2 + c1, c1)
        self.out = _zero(nn.Conv2d(c1, 3, 3, padding=1))
        self.cin, self.n_cond, self.ch = cin, n_cond, ch

    def decode(self, feats: list[torch.Tensor]) -> torch.Tensor:
        h1, h2, h3 = feats
        d2 = self.d2(torch.cat([self.up(h3), h2], 1))
        d1 = self.d1(torch.cat([self.up(d2), h1], 1))
        return self.out(d1)

    def forward(self, x: torch.Tensor, cond: torch.Tensor) -> torch.Tensor:
        return self.decode(self.enc(x, cond))


def pose_maps(x: torch.Tensor, pose: torch.Tensor) -> torch.Tensor:
    """Hint maps (B, 1 + 2 + N_POSE, H, W): target mask, the crop pixels' full-frame coordinates in [-1, 1]
    (channels 3..5 of the crop input ``x``), and the pose vector broadcast as constant maps."""
    B, _, H, W = x.shape
    return torch.cat([x[:, 3:6], pose[:, :, None, None].expand(B, pose.shape[1], H, W)], 1)


N_HINT = 1 + 2 + N_POSE


class ControlBranch(nn.Module):
    """Zero-initialised ControlNet branch on a frozen stage-1 :class:`UNet` (see the module docstring)."""

    def __init__(self, base: UNet) -> None:
        super().__init__()
        c1, c2, c3 = base.ch
        self.copy = copy.deepcopy(base.enc)
        self.hint = nn.Sequential(
            nn.Conv2d(N_HINT, c1, 3, padding=1), nn.ReLU(inplace=True), _zero(nn.Conv2d(c1, c1, 3, padding=1))
        )
        self.cond = nn.Linear(N_POSE, N_COND)  # the copy's FiLM also sees the pose (added to the depth condition)
        nn.init.zeros_(self.cond.weight)
        nn.init.zeros_(self.cond.bias)
        self.zero = nn.ModuleList([_zero(nn.Conv2d(c, c, 1)) for c in (c1, c2, c3)])

    def forward(self, x: torch.Tensor, cond: torch.Tensor, pose: torch.Tensor) -> list[torch.Tensor]:
        hint = self.hint(pose_maps(x, pose))
        feats = self.copy(x[:, :N_IMG], cond + self.cond(pose), hint)
        return [z(f) for z, f in zip(self.zero, feats, strict=True)]


class TwoStage(nn.Module):
    """Frozen stage-1 U-Net + control branch: the branch's features are added to stage 1's encoder features."""

    def __init__(self, base: UNet, control: ControlBranch | None = None) -> None:
        super().__init__()
        self.base = base
        self.control = control if control is not None else ControlBranch(base)

    def forward(self, x: torch.Tensor, cond: torch.Tensor, pose: torch.Tensor) -> torch.Tensor:
        feats = self.base.enc(x[:, :N_IMG], cond)
        ctrl = self.control(x, cond, pose)
        return self.base.decode([f + c for f, c in zip(feats, ctrl, strict=True)])


class Hybrid(nn.Module):
    """Single model with force and position inputs together (the paper's hybrid baseline)."""

    def __init__(self, ch: tuple[int, int, int] = (12, 24, 32)) -> None:
        super().__init__()
        self.net = UNet(N_IMG + N_HINT - 1, N_COND + N_POSE, ch)

    def forward(self, x: torch.Tensor, cond: torch.Tensor, pose: torch.Tensor) -> torch.Tensor:
        return self.net(torch.cat([x[:, :N_IMG], pose_maps(x, pose)[:, 1:]], 1), torch.cat([cond, pose], 1))


class Stage1(nn.Module):
    """Stage 1 alone behind the common ``(x, cond, pose)`` signature (ignores the pose)."""

    def __init__(self, base: UNet) -> None:
        super().__init__()
        self.base = base

    def forward(self, x: torch.Tensor, cond: torch.Tensor, pose: torch.Tensor) -> torch.Tensor:
        return self.base(x[:, :N_IMG], cond)


class Position(nn.Module):
    """Separate position generator (the paper's "separate force-then-position" baseline, second model): one
    :class:`UNet` with the reference, mask and position maps but NO force/depth input, trained from scratch on
    pairs at (nearly) the same depth across poses. At inference it moves the output of stage 1 (run at the
    reference's own pose) to the target pose; the two models share nothing."""

    def __init__(self, ch: tuple[int, int, int] = (12, 24, 32)) -> None:
        super().__init__()
        self.net = UNet(N_IMG + N_HINT - 1, N_POSE, ch)

    def forward(self, x: torch.Tensor, cond: torch.Tensor, pose: torch.Tensor) -> torch.Tensor:
        return self.net(torch.cat([x[:, :N_IMG], pose_maps(x, pose)[:, 1:]], 1), pose)


class Flow(nn.Module):
    """Few-step rectified-flow variant of stage 1 (same U-Net size): the net sees the stage-1 input plus the
    noisy correction ``z_t = t y + (1 - t) sigma eps`` and predicts the velocity ``y - sigma eps``; ``t`` joins
    the depth condition. Sampling: ``steps`` Euler steps from ``z_0 = sigma eps`` (noise from a fixed seed, so
    a batch's output is reproducible). ``sigma`` is the correction's training std (in DELTA_SCALE units).

    ``predict="target"`` is the x0 (DDIM-style) parametrisation: the net predicts the clean correction ``y``
    and the velocity is ``(y_hat - z) / (1 - t)``; its loss is the plain MSE of ``y_hat``, and the last Euler
    step lands exactly on ``y_hat`` (no leftover noise)."""

    def __init__(
        self, ch: tuple[int, int, int] = (12, 24, 32), sigma: float = 0.1, steps: int = 4, predict: str = "velocity"
    ) -> None:
        super().__init__()
        self.net = UNet(N_IMG + 3, N_COND + 1, ch)
        self.register_buffer("sigma", torch.tensor(float(sigma)))
        self.steps = steps
        self.predict = predict

    def _out(self, x: torch.Tensor, cond: torch.Tensor, z: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        return self.net(torch.cat([x[:, :N_IMG], z], 1), torch.cat([cond, t[:, None]], 1))

    def velocity(self, x: torch.Tensor, cond: torch.Tensor, z: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        out = self._out(x, cond, z, t)
        if self.predict == "target":
            return (out - z) / (1 - t)[:, None, None, None].clamp_min(1e-3)
        return out

    def loss(self, x: torch.Tensor, cond: torch.Tensor, y: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
        """Weighted flow-matching loss on a batch (``w``: the crop's loss weights, broadcast)."""
        B = x.shape[0]
        t = torch.rand(B)
        eps = torch.randn_like(y) * self.sigma
        z = t[:, None, None, None] * y + (1 - t[:, None, None, None]) * eps
        z = z.contiguous(memory_format=torch.channels_last)
        if self.predict == "target":
            return (w * (self._out(x, cond, z, t) - y) ** 2).mean()
        return (w * (self.velocity(x, cond, z, t) - (y - eps)) ** 2).mean()

    def forward(self, x: torch.Tensor, cond: torch.Tensor, pose: torch.Tensor) -> torch.Tensor:
        B, _, H, W = x.shape
        g = torch.Generator().manual_seed(0)
        z = (torch.randn((B, 3, H, W), generator=g) * self.sigma).contiguous(memory_format=torch.channels_last)
        dt = 1.0 / self.steps
        for k in range(self.steps):
            z = z + dt * self.velocity(x, cond, z, torch.full((B,), k * dt))
        return z
