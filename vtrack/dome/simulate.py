"""Dome simulator: indenters pressed into a hemispherical shell, marker images with exact ground truth.

Deformation model (why: fast, smooth, and it respects the rigid-contact constraint):
1. *Rigid interpenetration.* The indenter approaches along the inward normal ``-n_c`` of a contact point
   ``c`` on the outer surface. Its lower surface is a height profile ``h(u, v) >= 0`` in the tangent plane
   at ``c`` (sphere, flat cylinder punch, rounded edge, textured mold). The undeformed outer surface lies
   ``g(p) = R - p . n_c`` behind the tangent plane, so a press of depth ``D`` gives the penetration
   ``delta(p) = max(0, D - g(p) - h(u, v))`` (mm); the contact mask is ``delta > 0``.
2. *Elastic spread.* Outside contact, the shell is dragged along by a superposition of regularised
   Boussinesq kernels ``K(d) = (1 + d^2 / l^2)^{-3/2} / (2 pi l^2)`` (a point load on an elastic layer
   of thickness ~l decays like 1/d^3 far away): ``w = max(delta, sum_q K(|p - q|) delta_q A_q)``, with
   ``l = 1.5 * thickness``. The max keeps contact points on the indenter surface (thin-shell
   approximation: inner and outer surface move together, no through-thickness compression).
3. *Shear and pressure.* Friction adds a tangential displacement ``s * w / max(w)``; internal pressure
   ``P`` (kPa) inflates the shell radially by ``alpha * P`` (``DomeConfig.inflation_mm_per_kpa``) and
   stiffens it. The reference (no-contact) frame is rendered at the operating pressure when
   ``DomeConfig.reference_at_pressure`` (one reference per sample), else at P = 0.
4. *Force* (N): ``F = -n_c (k_n(P) sum delta A + P A_contact) + k_t s A_contact`` with
   ``k_n(P) = k0 (1 + 4 P / P_max)`` (Winkler-foundation estimate). Why this form (FusionTouch S3/S6: the
   internal air pressure sets the stiffness of the shell, so the same deformation comes with a different force):
   an inflated shell carries the membrane tension ``T = P R / 2`` (Laplace), and the restoring force of a
   tensioned membrane against an indentation grows linearly with ``T``; the material's own bending stiffness
   is the P-independent part (``k0``; at ``P_max`` the tension part is 4x it - FusionTouch Fig. S5 shows the
   pressurised double shell several times stiffer than the unpressurised one). The internal pressure also
   pushes back on the contact patch directly, ``P A_contact`` (1 kPa = 1e-3 N/mm^2). The deformation itself is
   displacement-controlled (the indenter goes to a given depth), so it does not depend on P: the image shows
   the same pattern and only the pressure input can resolve the force.

Markers (inner surface) are rendered as filled ellipses from 8 projected rim points each (so
foreshortening and fisheye distortion are exact per marker), then blur, vignetting, gain and noise.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vtrack.dome.model import DomeConfig, DomeGeometry

INDENTERS = ("sphere", "cylinder", "edge", "textured")

#: area per template point (mm^2) is computed from the cap area; stiffness constants below.
K0_N_PER_MM3 = 0.02
#: tension part of the indentation stiffness at P_max, in units of K0 (k_n(P) = K0 (1 + TENSION_GAIN P / P_max))
TENSION_GAIN = 4.0
KT_N_PER_MM3 = 0.05


@dataclass
class Press:
    """One indentation: shape, contact direction (unit, dome frame), depth mm, in-plane angle rad."""

    shape: str
    direction: np.ndarray
    depth_mm: float
    size_mm: float
    angle_rad: float
    shear_mm: np.ndarray  # tangential (2,) in the local (e1, e2) basis
    pressure_kpa: float


def _tangent_basis(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    a = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(n, a)
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(n, e1)


def _profile(shape: str, u: np.ndarray, v: np.ndarray, size: float, angle: float) -> np.ndarray:
    """Indenter height profile h(u, v) >= 0 (mm) above its lowest point; inf where it has no material."""
    ca, sa = np.cos(angle), np.sin(angle)
    ur, vr = ca * u + sa * v, -sa * u + ca * v
    r2 = u * u + v * v
    if shape == "sphere":
        h = np.where(r2 < size**2, size - np.sqrt(np.clip(size**2 - r2, 0, None)), np.inf)
    elif shape == "cylinder":  # flat punch with a 0.3 mm rounded edge
        r = np.sqrt(r2)
        h = np.where(r < size, np.clip(r - (size - 0.3), 0, None) ** 2 / 0.6, np.inf)
    elif shape == "edge":  # rounded ridge (cylinder lying in the tangent plane), length 4*size
        h = np.where(np.abs(vr) < 2 * size, ur * ur / (2 * 1.5), np.inf)
    elif shape == "textured":  # broad dome with a sinusoidal texture (mold)
        h = r2 / (2 * 3 * size) + 0.25 * (1 - np.cos(2 * np.pi * ur / 2.0)) * (1 - np.cos(2 * np.pi * vr / 2.0))
        h = np.where(r2 < (2 * size) ** 2, h, np.inf)
    else:
        raise ValueError(f"unknown indenter {shape}")
    return h


def sample_press(rng: np.random.Generator, cfg: DomeConfig, *, contact_prob: float = 0.9) -> Press | None:
    """A random press (None = no contact, with probability ``1 - contact_prob``)."""
    pressure = float(rng.uniform(0.0, cfg.pressure_max_kpa))
    if rng.random() > contact_prob:
        return Press("none", np.array([0.0, 0.0, 1.0]), 0.0, 0.0, 0.0, np.zeros(2), pressure)
    polar = np.deg2rad(rng.uniform(0.0, cfg.cap_deg - 15.0)) * np.sqrt(rng.random()) ** 0.5
    az = rng.uniform(0, 2 * np.pi)
    d = np.array([np.sin(polar) * np.cos(az), np.sin(polar) * np.sin(az), np.cos(polar)])
    shape = str(rng.choice(INDENTERS))
    size = {
        "sphere": rng.uniform(2.0, 6.0),
        "cylinder": rng.uniform(1.5, 3.5),
        "edge": rng.uniform(1.5, 3.0),
        "textured": rng.uniform(2.0, 3.5),
    }[shape]
    depth = float(rng.uniform(0.3, 3.0))
    shear = rng.normal(0.0, 0.25, 2)
    return Press(shape, d, depth, float(size), float(rng.uniform(0, np.pi)), shear, pressure)


class DomeSimulator:
    """Deform the dome for a :class:`Press` and render the marker image."""

    def __init__(self, cfg: DomeConfig | None = None) -> None:
        self.geo = DomeGeometry(cfg)
        self.cfg = self.geo.cfg
        c = self.cfg
        cap_area = 2 * np.pi * c.radius_mm**2 * (1 - np.cos(np.deg2rad(c.cap_deg)))
        self.area_per_src = cap_area / c.n_dense
        self.ell = 1.5 * c.thickness_mm
        # all evaluation points: dense, coarse, markers (directions)
        self._eval_dirs = np.vstack([self.geo.dense_dirs, self.geo.coarse_dirs, self.geo.marker_dirs])
        self._rim = np.stack([np.cos(np.arange(8) * np.pi / 4), np.sin(np.arange(8) * np.pi / 4)], 1)

    def deform(self, press: Press) -> dict[str, np.ndarray]:
        """Displacements (mm) at dense, coarse and marker directions, contact masks and force (N)."""
        c = self.cfg
        dirs = self._eval_dirs
        P = press.pressure_kpa
        disp = dirs * (c.inflation_mm_per_kpa * P)  # radial inflation
        delta = np.zeros(len(dirs))
        force = np.zeros(3)
        if press.shape != "none":
            n = press.direction
            e1, e2 = _tangent_basis(n)
            p = dirs * c.radius_mm
            rel = p - n * c.radius_mm
            u, v = rel @ e1, rel @ e2
            gap = c.radius_mm - p @ n
            h = _profile(press.shape, u, v, press.size_mm, press.angle_rad)
            delta = np.clip(press.depth_mm - gap - h, 0.0, None)
            delta[dirs[:, 2] < np.cos(np.deg2rad(c.cap_deg)) - 1e-9] = 0.0
            nd = c.n_dense
            src = np.nonzero(delta[:nd] > 0)[0]
            w = delta.copy()
            if len(src):
                d2 = ((p[:, None, :] - p[None, src, :]) ** 2).sum(-1)
                K = (1.0 + d2 / self.ell**2) ** -1.5 / (2 * np.pi * self.ell**2)
                w = np.maximum(delta, K @ (delta[src] * self.area_per_src))
            shear = press.shear_mm[0] * e1 + press.shear_mm[1] * e2
            wmax = max(float(w.max()), 1e-9)
            disp = disp - w[:, None] * n[None, :] + (w / wmax)[:, None] * shear[None, :]
            k_n = K0_N_PER_MM3 * (1.0 + TENSION_GAIN * P / c.pressure_max_kpa)
            vol = float(delta[:nd].sum() * self.area_per_src)
            area = float((delta[:nd] > 0).sum() * self.area_per_src)
            force = -n * (k_n * vol + 1e-3 * P * area) + KT_N_PER_MM3 * area * shear
        nd, nc = c.n_dense, c.n_coarse
        return {
            "disp_dense": disp[:nd],
            "disp_coarse": disp[nd : nd + nc],
            "disp_markers": disp[nd + nc :],
            "contact_dense": delta[:nd] > 0,
            "contact_coarse": delta[nd : nd + nc] > 0,
            "depth_coarse": delta[nd : nd + nc],
            "force": force,
        }

    def draw_markers(self, marker_pos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Anti-aliased marker coverage (S, S) float32 in [0, 1] (before blur, lighting and noise) of markers at
        dome-frame positions (n, 3) mm, and their image centres (n, 2) px (mean of the 8 projected rim points =
        the drawn ellipse centre). Exact masks for the marker-segmentation training: ``coverage > 0.5``."""
        import cv2

        c = self.cfg
        S = c.image_size
        n = marker_pos / np.linalg.norm(marker_pos, axis=1, keepdims=True)
        e1 = np.cross(n, np.array([1.0, 0.0, 0.0]))
        bad = np.linalg.norm(e1, axis=1) < 1e-6
        e1[bad] = np.cross(n[bad], np.array([0.0, 1.0, 0.0]))
        e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
        e2 = np.cross(n, e1)
        rim = marker_pos[:, None, :] + c.marker_radius_mm * (
            self._rim[None, :, 0:1] * e1[:, None, :] + self._rim[None, :, 1:2] * e2[:, None, :]
        )
        uv = self.geo.project(rim.reshape(-1, 3)).reshape(len(marker_pos), 8, 2)
        ctr = uv.mean(1)
        dev = uv - ctr[:, None, :]
        cov = np.einsum("nki,nkj->nij", dev, dev) / 8.0
        evals, evecs = np.linalg.eigh(cov)
        axes = np.sqrt(2.0 * np.clip(evals, 1e-6, None))  # circle points: var = a^2 / 2
        ang = np.degrees(np.arctan2(evecs[:, 1, 1], evecs[:, 0, 1]))
        img = np.zeros((S, S), np.float32)
        sh = 4  # sub-pixel precision of cv2.ellipse (2^4)
        for (x, y), (a0, a1), an in zip(ctr, axes, ang, strict=True):
            cv2.ellipse(
                img,
                (int(round(x * 16)), int(round(y * 16))),
                (max(1, int(round(a1 * 16))), max(1, int(round(a0 * 16)))),
                float(an),
                0,
                360,
                1.0,
                -1,
                cv2.LINE_AA,
                sh,
            )
        return img, ctr

    def render(self, marker_pos: np.ndarray, rng: np.random.Generator | None, *, noise: float = 1.0) -> np.ndarray:
        """Grey uint8 image (S, S) of markers at dome-frame positions (n, 3) mm (bright pins on dark)."""
        import cv2

        S = self.cfg.image_size
        rng = rng or np.random.default_rng(0)
        img, _ = self.draw_markers(marker_pos)
        gain = rng.uniform(0.75, 1.0) if noise > 0 else 0.9
        img = cv2.GaussianBlur(img, (0, 0), 0.7) * gain
        yy, xx = np.mgrid[0:S, 0:S]
        rr = np.hypot(xx - (S - 1) / 2, yy - (S - 1) / 2) / (S / 2)
        vign = 1.0 - 0.35 * rr**2
        bg = 0.08 + (0.04 * rng.random() if noise > 0 else 0.0)
        img = img * vign + bg * vign
        if noise > 0:
            img = img + rng.normal(0, 0.02 * noise, img.shape)
        return np.clip(img * 255, 0, 255).astype(np.uint8)

    def sample(self, rng: np.random.Generator, press: Press | None = None, *, noise: float = 1.0) -> dict:
        """One training sample: image, GT markers/templates/contact/force and the press parameters."""
        press = press or sample_press(rng, self.cfg)
        d = self.deform(press)
        g = self.geo
        markers = g.marker_rest + d["disp_markers"]
        img = self.render(markers, rng, noise=noise)
        return {
            "image": img,
            "markers_mm": markers.astype(np.float32),
            "markers_px": g.project(markers).astype(np.float32),
            "dense_mm": (g.dense_rest + d["disp_dense"]).astype(np.float32),
            "coarse_mm": (g.coarse_rest + d["disp_coarse"]).astype(np.float32),
            "contact_coarse": d["contact_coarse"],
            "contact_dense": d["contact_dense"],
            "force_n": d["force"].astype(np.float32),
            "pressure_kpa": np.float32(press.pressure_kpa),
            "shape": press.shape,
        }

    def reference_image(self, pressure_kpa: float = 0.0) -> np.ndarray:
        """No-contact, noise-free image at internal pressure ``pressure_kpa`` (the sensor's reference frame)."""
        p = float(pressure_kpa)
        if not np.isfinite(p) or p < 0:
            raise ValueError(f"reference pressure must be finite and >= 0 kPa, got {pressure_kpa}")
        g = self.geo
        return self.render(g.marker_rest + g.marker_dirs * (self.cfg.inflation_mm_per_kpa * p), None, noise=0.0)


def dataset_path(n: int, seed: int, cfg: DomeConfig) -> Path:
    from vtrack.paths import cache_dir

    key = hashlib.sha1(json.dumps({"n": n, "seed": seed, "cfg": cfg.to_dict(), "v": 5}, sort_keys=True).encode())
    return cache_dir() / "dome" / f"sim_{n}_{seed}_{key.hexdigest()[:10]}.npz"


def make_dataset(
    n: int, seed: int, cfg: DomeConfig | None = None, *, cache: bool = True, progress: bool = False
) -> dict[str, np.ndarray]:
    """``n`` simulated samples stacked into arrays (cached as .npz in ``vtrack.paths.cache_dir()``).

    ``reference_image`` is (S, S) (one reference at P = 0) or, when ``cfg.reference_at_pressure``, (n, S, S):
    each sample's reference frame at its own operating pressure."""
    cfg = cfg or DomeConfig()
    path = dataset_path(n, seed, cfg)
    if cache and path.exists():
        with np.load(path) as z:
            return {k: z[k] for k in z.files}
    sim = DomeSimulator(cfg)
    rng = np.random.default_rng(seed)
    out: dict[str, list] = {}
    for i in range(n):
        s = sim.sample(rng)
        for k, v in s.items():
            out.setdefault(k, []).append(v)
        if progress and (i + 1) % 500 == 0:
            print(f"[dome simulate] {i + 1}/{n}", flush=True)
    arrs = {k: np.stack(v) if k != "shape" else np.array(v) for k, v in out.items()}
    if cfg.reference_at_pressure:
        arrs["reference_image"] = np.stack([sim.reference_image(p) for p in arrs["pressure_kpa"]])
    else:
        arrs["reference_image"] = sim.reference_image()
    if cache:
        from vtrack.io.jsonio import atomic_savez

        atomic_savez(path, **arrs)
    return arrs
