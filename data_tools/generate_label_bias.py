"""Do the pose study's generated training images carry their labels? (issue #24 diagnosis)

Reruns `vtrack.bench.generate.pose_study` for one seed without training (the CNN trainer is replaced by a stub),
captures the generated images and their position labels, and compares each label with the contact centre measured
on the generated image by `weighted_moments_pose` (the same measure is within ~1 px of the truth on real presses:
its test-set row gives the bias). Prints the mean / median / sd of (measured - label) in px.

Usage: python data_tools/generate_label_bias.py SEED
"""

import sys

import numpy as np
import torch

import vtrack.bench.generate as G
from vtrack.tactile.generate.generator import TactileGenerator

torch.set_num_threads(1)
seed = int(sys.argv[1])
cap: dict = {}
_generate_many = TactileGenerator.generate_many


def _capture(self, reqs, bg):
    out = _generate_many(self, reqs, bg)
    cap["gen"], cap["bg"] = np.stack(out), bg
    return out


class _Zero(torch.nn.Module):
    def forward(self, x):
        return torch.zeros(len(x), 4)


calls = []


def _no_training(X, T, seconds, **kw):
    calls.append(T)
    return _Zero(), 0


TactileGenerator.generate_many = _capture
G._train_pose_cnn = _no_training
rows = G.pose_study(seed=seed, steps=1, heads=("softargmax",), sets=("real-only", "generated"), moments_row=True)
T, gen, bg = calls[-1], cap["gen"], cap["bg"]
H, W = bg.shape[:2]
lab = np.stack([(T[-len(gen) :, 0] + 1) / 2 * W, (T[-len(gen) :, 1] + 1) / 2 * H], 1)
meas = np.array([G.weighted_moments_pose(im, bg, 4)[:2] for im in gen])
d = meas - lab
wm = rows[1]
print(
    f"seed {seed}: weighted moments on the real test presses, bias x / y "
    f"{wm['x_bias_px']:.2f} / {wm['y_bias_px']:.2f} px"
)
print(
    f"seed {seed}: generated images, measured centre - label: mean {d.mean(0).round(2)}, median "
    f"{np.median(d, 0).round(2)}, sd {d.std(0).round(2)} px ({len(gen)} images)"
)
