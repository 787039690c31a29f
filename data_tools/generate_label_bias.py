"""Do the pose study's generated training images carry their labels? (issue #24 diagnosis)

Reruns `vtrack.bench.generate.pose_study` for one seed without training (the CNN trainer is replaced by a stub),
captures the generated images, their position labels and requested depths, and compares each label with the
contact centre measured on the generated image by `weighted_moments_pose` (the same measure is within ~1 px of the
truth on the simulated test presses: its test-set row gives the bias). With ``--truth N`` it also renders the first
N generated poses with the study's own "real" sensor unit (the simulator, i.e. what a real press at that label
looks like; evaluation only) and reports the generated minus the true press's measured centre (which cancels the
measure's own bias, but still mixes in shading differences) and the shape displacement between the two (phase
correlation of the colour-change magnitudes): the generator's position error.

Defaults = the pose study's (label frame, every labelled press a reference, the nearest one per target); the runs
before 2026-11-26 late morning are ``--ref-frame detected --refs 1 --choice cycle``. Results:
docs/benchmarks/generate_pose_exact.md.

Usage: python data_tools/generate_label_bias.py SEED [--ref-frame label|detected] [--refs K --choice cycle|nearest]
[--truth N]
"""

import argparse

import numpy as np
import torch

import vtrack.bench.generate as G
from vtrack.tactile.generate import data as gd
from vtrack.tactile.generate.generator import TactileGenerator

ap = argparse.ArgumentParser()
ap.add_argument("seed", type=int)
ap.add_argument("--ref-frame", default="label", choices=("label", "detected"))
ap.add_argument("--refs", type=int, default=24, help="gen_refs of the pose study")
ap.add_argument("--choice", default="nearest", choices=("cycle", "nearest"), help="ref_choice of the pose study")
ap.add_argument("--truth", type=int, default=0, help="render this many generated poses with the simulator")
args = ap.parse_args()
torch.set_num_threads(1)
seed = args.seed
cap: dict = {"depth": []}
_generate_many = TactileGenerator.generate_many
_prepare = TactileGenerator.prepare


def _capture(self, reqs, bg):
    out = _generate_many(self, reqs, bg)
    cap["gen"], cap["bg"] = np.stack(out), bg
    return out


def _capture_prepare(self, *a, **kw):
    cap["depth"].append(kw["target_depth_mm"])
    return _prepare(self, *a, **kw)


def _displacement(a: np.ndarray, b: np.ndarray, bg: np.ndarray) -> tuple[float, float]:
    """(dx, dy) px that moves image b's contact onto image a's (phase correlation of the colour-change
    magnitudes, Hann-windowed): a shape-based displacement, insensitive to how the shading is distributed."""
    import cv2

    A, B = (np.abs(x.astype(np.float32) - bg.astype(np.float32)).sum(2) for x in (a, b))
    (dx, dy), _ = cv2.phaseCorrelate(B, A, cv2.createHanningWindow(A.shape[::-1], cv2.CV_32F))
    return dx, dy


class _Zero(torch.nn.Module):
    def forward(self, x):
        return torch.zeros(len(x), 4)


calls = []


def _no_training(X, T, seconds, **kw):
    calls.append(T)
    return _Zero(), 0


TactileGenerator.generate_many = _capture
TactileGenerator.prepare = _capture_prepare
G._train_pose_cnn = _no_training
rows = G.pose_study(
    seed=seed,
    steps=1,
    heads=("softargmax",),
    sets=("real-only", "generated"),
    moments_row=True,
    ref_frame=args.ref_frame,
    gen_refs=args.refs,
    ref_choice=args.choice,
)
tag = f"{args.ref_frame}, {args.refs} ref{'s' * (args.refs > 1)}" + (", nearest" if args.choice == "nearest" else "")
T, gen, bg = calls[-1], cap["gen"], cap["bg"]
H, W = bg.shape[:2]
Tg = T[-len(gen) :]
lab = np.stack([(Tg[:, 0] + 1) / 2 * W, (Tg[:, 1] + 1) / 2 * H], 1)
meas = np.array([G.weighted_moments_pose(im, bg, 4)[:2] for im in gen])
d = meas - lab
wm = rows[1]
print(
    f"seed {seed} ({tag}): weighted moments on the real test presses, bias x / y "
    f"{wm['x_bias_px']:.2f} / {wm['y_bias_px']:.2f} px"
)
print(
    f"seed {seed} ({tag}): generated images, measured centre - label: mean {d.mean(0).round(2)}, median "
    f"{np.median(d, 0).round(2)}, sd {d.std(0).round(2)} px ({len(gen)} images)"
)
if args.truth > 0:
    from vtrack.sim.tactile_optics import OpticalModel

    model = OpticalModel.for_sensor("gelsight", seed=4242)
    rng = np.random.default_rng(99)
    n = min(args.truth, len(gen))
    th = np.degrees(np.arctan2(Tg[:n, 3], Tg[:n, 2])) / 4
    true, shift = [], []
    for k in range(n):
        h = gd.indenter_height("cross", (H, W), gd.Pose(*lab[k], float(th[k])), float(cap["depth"][k]), 0.059)
        im = model.render(h, 0.059, bg, rng)
        true.append(G.weighted_moments_pose(im, bg, 4)[:2])
        shift.append(_displacement(gen[k], im, bg))
    dt = meas[:n] - np.array(true)
    shift = np.array(shift)
    print(
        f"seed {seed} ({tag}): generated - true press (same pose, depth), measured centres: mean "
        f"{dt.mean(0).round(2)}, median {np.median(dt, 0).round(2)}, sd {dt.std(0).round(2)}, mean |.| "
        f"{np.abs(dt).mean(0).round(2)} px ({n} images)"
    )
    print(
        f"seed {seed} ({tag}): generated vs true press, phase-correlation displacement of the colour-change "
        f"magnitude: mean {shift.mean(0).round(2)}, median {np.median(shift, 0).round(2)}, mean |.| "
        f"{np.abs(shift).mean(0).round(2)} px ({n} images)"
    )
