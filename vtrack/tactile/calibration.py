"""Calibration: tactile image colour (+ pixel position) -> surface normal / gradient.

Methods (all learn from ball presses with known radius, see :mod:`vtrack.tactile.pressset`):
- ``lut``: binned lookup table on the colour change against the background (GelSight classic; the
  classic variant bins the raw colour, ``lut_raw``);
- ``mlp``: a small per-pixel MLP (trained with torch on CPU, evaluated with numpy) on colour change,
  raw colour and normalised pixel position;
- ``ps``: least-squares photometric stereo: one light per colour channel (K >= 3 channels), light
  matrix estimated from the presses by linear least squares, normal and albedo solved per pixel.

All methods predict the in-plane components (nx, ny) of the outward unit normal (sensor frame:
x = columns, y = rows); slopes are ``g = n_xy / n_z`` (mm/mm). Predicting bounded normals rather than
unbounded slopes keeps averaging (LUT bins) and regression well-behaved near the steep contact edge.

A :class:`Calibration` also stores the background frame and a gradient -> colour table (inverse model for
:func:`vtrack.tactile.render.render_tactile_image`). Saved as one ``.npz`` (arrays + JSON header).
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field, replace
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np

from vtrack.errors import InputError
from vtrack.geometry.pixels import mask_pixels
from vtrack.tactile.pressset import Press, PressSet, sphere_truth

METHODS = ("lut", "lut_raw", "mlp", "ps")
#: Largest slope angle the calibration predicts (deg): bounds n_z away from 0 (slope <= tan(80 deg) = 5.7).
MAX_TILT_DEG = 80.0
FORMAT_VERSION = 1


@dataclass
class TrainOptions:
    """Options of :func:`calibrate` (defaults are the ones reported in docs/tactile.md)."""

    lut_bins: int = 32
    lut_range: float = 96.0  # grey levels of colour change covered by the LUT (+-)
    mlp_hidden: int = 64  # 64 is on the Pareto front of `vtrack bench tactile` (3.0 vs 3.3 deg at h32)
    mlp_layers: int = 2
    mlp_epochs: int = 12
    mlp_lr: float = 3e-3
    #: MLPs trained from different random starts whose predictions are averaged (1 = one net). Averaging
    #: lowers the variance of a net fitted to few presses (the gel's border, docs/benchmarks/calib_border.md)
    mlp_ensemble: int = 1
    #: draw the training pixels from the presses downscaled to the pipeline's default working resolution
    #: (``auto_downsample``: 2 at 320x240, 4 at 640x480) instead of the full-resolution images
    train_work_res: bool = False
    #: MLP colour features besides the change: "raw" = the raw colour (the original model), "rel" = the change
    #: relative to the sensor's own background at that pixel, dI / (bg + 16): an LED's fall-off across the
    #: gel scales bg and dI alike, so "rel" needs fewer presses to learn it; "poly" / "relpoly": the change
    #: (and for relpoly its relative form) times quadratic monomials of the position, no free position term
    #: (see ``_mlp_features``). `--method auto` tries raw, rel and relpoly
    mlp_features: str = "raw"
    inside_frac: float = 0.95  # use the labelled disc shrunk by this factor as gradient truth
    outside_frac: float = 1.15  # and pixels beyond this factor x radius as flat gel
    flat_per_press: int = 3000
    inside_per_press: int = 4000  # 0 = every contact pixel; else a random subset (faster MLP training)
    # grey levels: |colour change| (sum of channels, 5x5 mean) below this -> flat gel. 12 cuts the flagged
    # area of the real GelSight frames from 46 % to 25 % (JPEG noise, uneven drift) at no accuracy cost.
    gate: float = 12.0
    seed: int = 0


#: Options added after calibrations were first cached, with the value that reproduces the older behaviour:
#: left out of cache keys at that value, so the calibrations cached before (and the sessions built on them)
#: keep their keys.
_KEY_NEUTRAL_OPTIONS = {"mlp_ensemble": 1, "train_work_res": False}


def options_key(opts: TrainOptions) -> dict[str, Any]:
    """``opts`` as a dict for cache keys (fields at their :data:`_KEY_NEUTRAL_OPTIONS` value left out)."""
    return {k: v for k, v in opts.__dict__.items() if _KEY_NEUTRAL_OPTIONS.get(k, object()) != v}


def normals_to_slopes(nx: np.ndarray, ny: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Slopes (dh/dx, dh/dy) of unit normals with in-plane part (nx, ny); tilt clipped at MAX_TILT_DEG."""
    s2 = nx * nx + ny * ny
    smax = np.sin(np.deg2rad(MAX_TILT_DEG))
    scale = np.where(s2 > smax * smax, smax / np.sqrt(np.maximum(s2, 1e-12)), 1.0)
    nx, ny = nx * scale, ny * scale
    nz = np.sqrt(np.maximum(1.0 - (nx * nx + ny * ny), 1e-6))
    return nx / nz, ny / nz


def slopes_to_normals(gx: np.ndarray, gy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    inv = 1.0 / np.sqrt(gx * gx + gy * gy + 1.0)
    return gx * inv, gy * inv


def colour_change(image: np.ndarray, background: np.ndarray) -> np.ndarray:
    """(H, W, 3) float32 image minus background (grey levels); NaN/Inf -> 0 change."""
    d = np.asarray(image, np.float32) - np.asarray(background, np.float32)
    if d.dtype.kind == "f" and not np.isfinite(d).all():
        d = np.nan_to_num(d, nan=0.0, posinf=0.0, neginf=0.0)
    return d


def gate_mask(dI: np.ndarray, gate: float) -> np.ndarray:
    """Pixels whose (box-smoothed) total colour change exceeds ``gate`` grey levels: candidates for contact."""
    import cv2

    a = np.abs(np.asarray(dI, np.float32)).sum(axis=2)
    a = cv2.blur(a, (5, 5))
    return a > gate


_ONES3 = np.ones((1, 3), np.float32)


def drift_offset(
    image: np.ndarray, background: np.ndarray, max_spread: float = 6.0, step: int = 0
) -> tuple[np.ndarray, float]:
    """Global colour drift of a frame against the background, and the frame's typical colour change.

    Returns ``(offset, level)``: ``offset`` (3,) is the per-channel MODE of the colour change on a sparse
    grid: the flat gel is the one tight cluster of the distribution, whereas a contact spreads its pixels
    over a wide range. (The median, used before, is pulled by a contact covering a large part of the gel: a
    large object pressed on a DIGIT lost up to half its depth to the "compensation".) ``offset`` is zeros
    when fewer than a third of the samples lie within ``max_spread`` grey levels of the mode in every channel
    (most of the gel is deformed: there is no flat reference to measure drift on). ``level`` is the
    expected total |change| of pure sensor noise, ``sum_c 0.8 sigma_c`` with ``sigma_c`` from the median
    absolute difference of horizontally adjacent pixels (shading is smooth, noise is not, so contact does
    not inflate it). ``step`` = sampling stride (0: about 1200 samples).
    """
    if step <= 0:
        step = max(1, int(np.sqrt(np.asarray(image).shape[0] * np.asarray(image).shape[1] / 1200.0)))
    a = np.asarray(image)[::step, ::step].reshape(-1, 3).astype(np.int16)
    b = np.asarray(background)[::step, ::step].reshape(-1, 3)
    if a.size == 0:
        return np.zeros(3), 0.0
    d = a - b
    off = np.zeros(3)
    if max_spread >= 0:
        # the three channels' histograms in one bincount (channel c at bins c * nb ...); integer counts, so the
        # smoothing and the means below are exact whatever the summation order (= the per-channel loop's values)
        nb = 2 * _MODE_RANGE + 1
        counts = np.bincount(
            (np.clip(d, -_MODE_RANGE, _MODE_RANGE) + (_MODE_RANGE + nb * np.arange(3, dtype=np.int16))).ravel(),
            minlength=3 * nb,
        ).reshape(3, nb)
        cp = np.pad(counts, ((0, 0), (2, 2)))
        # = np.convolve(counts, _MODE_KERNEL, "same") per channel: noise spreads the peak over a few levels
        counts = cp[:, :-4] + 2 * cp[:, 1:-3] + 3 * cp[:, 2:-2] + 2 * cp[:, 3:-1] + cp[:, 4:]
        m = (np.argmax(counts, axis=1) - _MODE_RANGE).astype(np.float64)
        near = np.abs(d - m) <= 2.0
        cnt = near.sum(axis=0)
        off = np.where(cnt > 0, np.where(near, d, 0).sum(axis=0) / np.maximum(cnt, 1), m)
        flat = (np.abs(d - off) <= max(max_spread, 1.0)).all(axis=1)
        if np.abs(off).max() < 1.0 or flat.mean() < 1.0 / 3.0:
            off = np.zeros(3)
    row = np.asarray(image)[::step].astype(np.int16) - np.asarray(background)[::step]
    adj = np.abs(np.diff(row, axis=1)).reshape(-1, 3)
    sigma = 1.4826 * np.median(adj, axis=0) / np.sqrt(2.0) if adj.size else np.zeros(3)
    return off, float(0.8 * sigma.sum())


def drift_offsets(
    images: np.ndarray, backgrounds: np.ndarray, max_spread: float = 6.0
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`drift_offset` of ``images[j]`` against ``backgrounds[j]`` for a stack of frames of one size (e.g. the
    four DIGIT of a hand at one time step): the same values, ``(offsets (B, 3), levels (B,))``, with one numpy
    call per step for the whole stack instead of one per frame (the per-call overhead is most of the cost of a
    1200-sample frame). The samples are laid out channel-first (numpy's loops over a last axis of 3 cost several
    times the arithmetic) and the noise median comes from a histogram of the integer differences (the same value
    as ``np.median``: the mean of the two middle order statistics): 0.73 instead of 2.4 ms for four DIGIT frames at
    80 x 60."""
    images = np.asarray(images)
    backgrounds = np.asarray(backgrounds)
    B = images.shape[0]
    step = max(1, int(np.sqrt(images.shape[1] * images.shape[2] / 1200.0)))
    a = np.moveaxis(images[:, ::step, ::step], 3, 1).astype(np.int16, order="C").reshape(B, 3, -1)
    if a.shape[2] == 0:
        return np.zeros((B, 3)), np.zeros(B)
    d = a - np.moveaxis(backgrounds[:, ::step, ::step], 3, 1).reshape(B, 3, -1)  # (B, 3, N) int16
    off = np.zeros((B, 3))
    if max_spread >= 0:
        nb = 2 * _MODE_RANGE + 1
        base = _MODE_RANGE + nb * np.arange(3 * B, dtype=_index_dtype(3 * B * nb)).reshape(B, 3, 1)
        counts = np.bincount((np.clip(d, -_MODE_RANGE, _MODE_RANGE) + base).ravel(), minlength=3 * B * nb)
        cp = np.zeros((B, 3, nb + 4), counts.dtype)
        cp[..., 2:-2] = counts.reshape(B, 3, nb)
        counts = cp[..., :-4] + 2 * cp[..., 1:-3] + 3 * cp[..., 2:-2] + 2 * cp[..., 3:-1] + cp[..., 4:]
        m = (np.argmax(counts, axis=2) - _MODE_RANGE).astype(np.float64)  # (B, 3)
        near = np.abs(d - m[..., None]) <= 2.0
        cnt = np.count_nonzero(near, axis=2)
        off = np.where(cnt > 0, np.where(near, d, 0).sum(axis=2) / np.maximum(cnt, 1), m)
        dev = np.abs(d - off[..., None]) <= max(max_spread, 1.0)
        flat = dev[:, 0] & dev[:, 1] & dev[:, 2]
        off[(np.abs(off).max(axis=1) < 1.0) | (flat.mean(axis=1) < 1.0 / 3.0)] = 0.0
    row = images[:, ::step].astype(np.int16) - backgrounds[:, ::step]
    adj = np.abs(np.diff(row, axis=2))  # (B, rows, W - 1, 3): 0 ... 510
    n = adj.shape[1] * adj.shape[2]
    if n == 0:
        return off, np.zeros(B)
    nv = 511
    cum = np.bincount((adj + _channel_bins(adj.shape, nv)).ravel(), minlength=3 * B * nv).reshape(B, 3, nv)
    cum = cum.cumsum(axis=2)
    med = (np.count_nonzero(cum <= (n - 1) // 2, axis=2) + np.count_nonzero(cum <= n // 2, axis=2)) / 2.0
    sigma = 1.4826 * med / np.sqrt(2.0)
    return off, 0.8 * sigma.sum(axis=1)


def _index_dtype(n: int) -> type:
    """The smallest of int16 / int64 holding bin indices below ``n`` (int16 arithmetic is the fast path)."""
    return np.int16 if n < 2**15 else np.int64


@lru_cache(maxsize=8)
def _channel_bins(shape: tuple[int, ...], nb: int) -> np.ndarray:
    """Read-only array of ``shape`` (B, ..., 3): ``nb * (3 b + c)`` at frame b, channel c, i.e. the offsets that put
    every (frame, channel) in its own ``nb`` bins of one bincount (built once per shape: broadcasting a last axis
    of 3 is slow)."""
    B = shape[0]
    base = (nb * np.arange(3 * B, dtype=_index_dtype(3 * B * nb))).reshape((B,) + (1,) * (len(shape) - 2) + (3,))
    out = np.ascontiguousarray(np.broadcast_to(base, shape))
    out.flags.writeable = False
    return out


_MODE_RANGE = 64  # grey levels of drift searched (+-)
_MODE_KERNEL = np.array([1.0, 2.0, 3.0, 2.0, 1.0])


def shift_background(background: np.ndarray, offset: np.ndarray) -> np.ndarray:
    """Background plus a per-channel offset (grey levels), saturated to uint8."""
    import cv2

    o = np.rint(np.asarray(offset, np.float64))
    bg = np.asarray(background, np.uint8)
    pos, neg = np.clip(o, 0, None), np.clip(-o, 0, None)
    if pos.any():
        bg = cv2.add(bg, (*pos.tolist(), 0.0))
    if neg.any():
        bg = cv2.subtract(bg, (*neg.tolist(), 0.0))
    return bg


def gate_mask_images(image: np.ndarray, background: np.ndarray, gate: float) -> np.ndarray:
    """:func:`gate_mask` from two uint8 images (OpenCV only: ~10x faster than through float dI)."""
    import cv2

    a = cv2.transform(cv2.absdiff(image, background).astype(np.float32), _ONES3)
    a = cv2.blur(a, (5, 5))
    return a > gate


@dataclass
class Calibration:
    """A trained colour -> normal model of one sensor (image size fixed by the training background)."""

    method: str
    sensor: str
    mm_per_px: float
    background: np.ndarray  # (H, W, 3) uint8 BGR
    params: dict[str, np.ndarray] = field(default_factory=dict)
    info: dict[str, Any] = field(default_factory=dict)

    @property
    def shape(self) -> tuple[int, int]:
        return tuple(self.background.shape[:2])  # type: ignore[return-value]

    # ------------------------------------------------------------------ prediction
    def check_image(self, image: np.ndarray, name: str = "image") -> np.ndarray:
        img = np.asarray(image)
        if img.ndim != 3 or img.shape[2] != 3:
            raise InputError("tactile image must be (H, W, 3) BGR", field=name, expected="(H, W, 3)", got=img.shape)
        if img.shape[:2] != self.shape:
            raise InputError(
                "image size differs from the calibration",
                field=name,
                expected=f"{self.shape[0]}x{self.shape[1]} (HxW) as calibrated",
                got=img.shape[:2],
            )
        return img

    def normals(
        self, image: np.ndarray, background: np.ndarray | None = None, mask: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """In-plane normal components (nx, ny), each (H, W) float32, for a BGR image.

        ``background`` defaults to the calibration's; ``mask`` (optional) limits the evaluation (others 0);
        by default pixels whose colour barely changed (``gate_mask``) are flat.
        """
        img = self.check_image(image)
        bg = self.background if background is None else self.check_image(background, "background")
        dI = colour_change(img, bg)
        gate = float(self.info.get("gate", 6.0))
        m = gate_mask_images(img, bg, gate) if mask is None else np.asarray(mask, bool)
        return self.normals_from_change(dI, img, m)

    def normals_from_change(self, dI: np.ndarray, img: np.ndarray, mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(nx, ny) from a precomputed colour change ``dI`` (float32 (H, W, 3)); zero outside ``mask``."""
        H, W = img.shape[:2]
        nx = np.zeros((H, W), np.float32)
        ny = np.zeros((H, W), np.float32)
        if self.method in ("lut", "lut_raw"):
            src = dI if self.method == "lut" else np.asarray(img, np.float32)
            out = self._lut_lookup(src)
            nx[:], ny[:] = out[..., 0], out[..., 1]
            nx[~mask] = 0.0
            ny[~mask] = 0.0
            return nx, ny
        rows, cols = mask_pixels(mask)
        if len(rows) == 0:
            return nx, ny
        out = self._predict_pixels(dI[rows, cols], np.asarray(img)[rows, cols], rows, cols, (H, W))
        nx[rows, cols] = out[:, 0]
        ny[rows, cols] = out[:, 1]
        return nx, ny

    def slopes_from_images(
        self, image: np.ndarray, background: np.ndarray, mask: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Slopes (dh/dx, dh/dy, mm/mm, float32) from a uint8 image and background of this model's size;
        zero outside ``mask``. The fast path of the real-time pipeline (LUT: one gather from a slope table)."""
        import cv2

        if self.method == "lut":
            qtab, table = self._fast_lut()
            B = int(round(len(table) ** (1 / 3)))
            # colour change + 128 saturated to uint8, then one 256-entry table per channel -> bin index
            d8 = cv2.addWeighted(image, 1.0, background, -1.0, 128.0, dtype=cv2.CV_8U)
            q = cv2.LUT(d8, qtab)
            flat = cv2.transform(q, np.array([[B * B, B, 1]], np.float64))
            if flat.dtype.kind == "f":  # B^3 > 65535: float path of cv2.LUT/transform
                flat = flat.astype(np.int32)
            flat = np.where(mask, flat, len(table) - 1)  # last entry: exact zero slope (flat gel)
            out = np.take(table, flat)
            return out.real, out.imag
        H, W = image.shape[:2]
        if self.method == "lut_raw":
            nx, ny = self.normals_from_change(None, image, mask)
        else:
            # zero normals have zero slopes: only the masked pixels go through the model and the conversion
            # (flat indices: numpy's 2-D fancy indexing costs several times the 1-D gather of the same pixels)
            idx = np.flatnonzero(mask)
            gx = np.zeros(H * W, np.float32)
            gy = np.zeros(H * W, np.float32)
            if len(idx):
                rows, cols = np.divmod(idx, W)
                im = image.reshape(-1, 3)[idx]
                d = im.astype(np.float32) - background.reshape(-1, 3)[idx]
                out = self._predict_pixels(d, im, rows, cols, (H, W)).astype(np.float32, copy=False)
                gx[idx], gy[idx] = normals_to_slopes(out[:, 0], out[:, 1])
            return gx.reshape(H, W), gy.reshape(H, W)
        gx, gy = normals_to_slopes(nx, ny)
        return gx.astype(np.float32, copy=False), gy.astype(np.float32, copy=False)

    def _fast_lut(self) -> tuple[np.ndarray, np.ndarray]:
        """(256-entry per-channel bin table for colour change + 128, flat complex64 slope table + zero entry)."""
        t = self.params.get("_fast")
        if t is None:
            slopes = self._slope_table()
            B = slopes.shape[0]
            lo, step = float(self.params["lut_lo"]), float(self.params["lut_step"])
            d = np.arange(256) - 128.0
            bins = np.clip(np.floor((d - lo) / step), 0, B - 1)
            depth = np.uint16 if B**3 < 65535 else np.int32
            # OpenCV LUT output depth = table depth; uint16 keeps cv2.transform in range for B <= 40
            qtab = bins.astype(depth if depth is np.uint16 else np.float32).reshape(1, 256)
            flat = np.concatenate([slopes.reshape(-1, 2), np.zeros((1, 2), np.float32)])
            table = np.ascontiguousarray(flat).view(np.complex64).ravel()
            t = (qtab, table)
            self.params["_fast"] = t  # type: ignore[assignment]
        return t

    def _slope_table(self) -> np.ndarray:
        t = self.params.get("_slopes")
        if t is None:
            lut = self.params["lut"]
            gx, gy = normals_to_slopes(lut[..., 0].astype(np.float64), lut[..., 1].astype(np.float64))
            t = np.stack([gx, gy], -1).astype(np.float32)
            self.params["_slopes"] = t
        return t

    def _predict_pixels(
        self, d: np.ndarray, raw: np.ndarray, rows: np.ndarray, cols: np.ndarray, shape: tuple[int, int]
    ) -> np.ndarray:
        if self.method == "mlp":
            kind = MLP_FEATURES[int(self.params.get("mlp_features", 0))]
            return _mlp_forward(self.params, _mlp_features(d, raw, rows, cols, shape, kind))
        if self.method == "ps":
            return _ps_solve(self.params, d)
        raise InputError("unknown calibration method", field="method", expected="|".join(METHODS), got=self.method)

    def resized(self, background: np.ndarray) -> Calibration:
        """The same model on a resized background (working resolution); colour/position features are
        resolution-independent (positions are normalised to [-1, 1])."""
        return Calibration(
            self.method,
            self.sensor,
            self.mm_per_px * self.shape[1] / background.shape[1],
            np.asarray(background),
            self.params,
            self.info,
        )

    def slopes(
        self, image: np.ndarray, background: np.ndarray | None = None, mask: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Surface slopes (dh/dx, dh/dy) in mm/mm, each (H, W) float32."""
        nx, ny = self.normals(image, background, mask)
        return normals_to_slopes(nx, ny)

    def _lut_lookup(self, src: np.ndarray) -> np.ndarray:
        table = self.params["lut"]
        B = table.shape[0]
        lo, step = float(self.params["lut_lo"]), float(self.params["lut_step"])
        q = ((src - lo) * (1.0 / step)).astype(np.int32)
        np.clip(q, 0, B - 1, out=q)
        flat = (q[..., 0] * B + q[..., 1]) * B + q[..., 2]
        return table.reshape(-1, 2)[flat]

    # ------------------------------------------------------------------ inverse model (rendering)
    def colour_delta(self, gx: np.ndarray, gy: np.ndarray) -> np.ndarray:
        """(H, W, 3) colour change for slopes (gx, gy) (mm/mm), from the press-learned inverse table."""
        from scipy.ndimage import map_coordinates

        table = self.params["inverse"]  # (B, B, 3) mean colour change over (ny, nx) bins in [-1, 1]
        B = table.shape[0]
        nx, ny = slopes_to_normals(np.asarray(gx, np.float64), np.asarray(gy, np.float64))
        u = (nx + 1.0) * 0.5 * (B - 1)
        v = (ny + 1.0) * 0.5 * (B - 1)
        out = np.stack([map_coordinates(table[..., c], [v, u], order=1, mode="nearest") for c in range(3)], -1)
        return out

    # ------------------------------------------------------------------ I/O
    def save(self, path: str | Path) -> Path:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        header = {
            "format": FORMAT_VERSION,
            "method": self.method,
            "sensor": self.sensor,
            "mm_per_px": self.mm_per_px,
            "info": self.info,
        }
        arrays = {f"p_{k}": v for k, v in self.params.items() if not k.startswith("_")}
        with open(path, "wb") as f:
            np.savez_compressed(f, header=np.array(json.dumps(header)), background=self.background, **arrays)
        return path

    @classmethod
    def load(cls, path: str | Path) -> Calibration:
        path = Path(path)
        if not path.is_file():
            raise InputError("calibration file not found", path=path, expected="an .npz from `vtrack calibrate`")
        try:
            with np.load(path, allow_pickle=False) as z:
                header = json.loads(str(z["header"]))
                params = {k[2:]: z[k] for k in z.files if k.startswith("p_")}
                bg = z["background"]
        except (OSError, ValueError, KeyError) as e:
            raise InputError(f"not a vtrack calibration ({e})", path=path) from None
        if header.get("format") != FORMAT_VERSION or header.get("method") not in METHODS:
            raise InputError(
                "unsupported calibration file",
                path=path,
                field="header",
                expected=f"format {FORMAT_VERSION}, method in {METHODS}",
                got=header.get("method"),
            )
        return cls(header["method"], header["sensor"], float(header["mm_per_px"]), bg, params, header["info"])


# ---------------------------------------------------------------------- training data
def training_samples(ps: PressSet, presses: list[Press], opts: TrainOptions) -> dict[str, np.ndarray]:
    """Pixels with known normals: inside each (shrunk) contact disc from the analytic sphere, plus flat gel
    sampled well outside the disc. Returns dI (N,3), raw colour (N,3), rows, cols, target (nx, ny)."""
    rng = np.random.default_rng(opts.seed)
    bg = ps.background()
    H, W = ps.shape
    out: dict[str, list] = {"dI": [], "raw": [], "rows": [], "cols": [], "n": [], "w": []}
    for p in presses:
        img = ps.image(p)
        _, gx, gy, _ = sphere_truth(p, (H, W), ps.ball_radius_px)
        yy, xx = np.mgrid[0:H, 0:W]
        rho = np.hypot(xx - p.center_xy_px[0], yy - p.center_xy_px[1])
        inside = rho < opts.inside_frac * p.contact_radius_px
        flat = rho > opts.outside_frac * p.contact_radius_px
        fr, fc = np.nonzero(flat)
        pick = rng.choice(len(fr), size=min(opts.flat_per_press, len(fr)), replace=False)
        ir, ic = np.nonzero(inside)
        if 0 < opts.inside_per_press < len(ir):
            sel = rng.choice(len(ir), size=opts.inside_per_press, replace=False)
            ir, ic = ir[sel], ic[sel]
        rows = np.concatenate([ir, fr[pick]])
        cols = np.concatenate([ic, fc[pick]])
        nx, ny = slopes_to_normals(gx[rows, cols], gy[rows, cols])
        # same drift compensation as the pipeline, so training and use see the same colour changes
        d = colour_change(img, shift_background(bg, drift_offset(img, bg)[0]))
        out["dI"].append(d[rows, cols])
        out["raw"].append(img[rows, cols].astype(np.float32))
        out["rows"].append(rows)
        out["cols"].append(cols)
        out["n"].append(np.stack([nx, ny], 1).astype(np.float32))
    return {k: np.concatenate(v) for k, v in out.items() if v}


# ---------------------------------------------------------------------- LUT
def _fill_empty(table: np.ndarray, filled: np.ndarray) -> np.ndarray:
    """Fill empty bins with the value of the nearest filled bin (Euclidean in bin space)."""
    from scipy.ndimage import distance_transform_edt

    if filled.all() or not filled.any():
        return table
    _, idx = distance_transform_edt(~filled, return_indices=True)
    return table[tuple(idx)]


def fit_lut(src: np.ndarray, target: np.ndarray, bins: int, lo: float, hi: float) -> dict[str, np.ndarray]:
    """Mean target per colour bin (B^3 bins over [lo, hi) per channel); empty bins take the nearest value."""
    step = (hi - lo) / bins
    q = np.clip(((src - lo) / step).astype(np.int64), 0, bins - 1)
    flat = (q[:, 0] * bins + q[:, 1]) * bins + q[:, 2]
    n = np.bincount(flat, minlength=bins**3).astype(np.float64)
    table = np.zeros((bins**3, 2))
    for c in range(2):
        table[:, c] = np.bincount(flat, weights=target[:, c], minlength=bins**3)
    filled = n > 0
    table[filled] /= n[filled, None]
    table = _fill_empty(table.reshape(bins, bins, bins, 2), filled.reshape(bins, bins, bins))
    return {"lut": table.astype(np.float32), "lut_lo": np.float64(lo), "lut_step": np.float64(step)}


# ---------------------------------------------------------------------- MLP
#: Feature sets of the MLP (stored in a calibration as their index, ``params["mlp_features"]``; absent = 0).
MLP_FEATURES = ("raw", "rel", "poly", "relpoly")


def _monomials(rows: np.ndarray, cols: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """(N, 6) float32 monomials 1, x, y, x^2, xy, y^2 of the pixel position normalised to [-1, 1]."""
    H, W = shape
    x = np.asarray(cols, np.float32) * (2.0 / W) - 1.0
    y = np.asarray(rows, np.float32) * (2.0 / H) - 1.0
    return np.column_stack([np.ones_like(x), x, y, x * x, x * y, y * y])


def _mlp_features(
    dI: np.ndarray,
    raw: np.ndarray,
    rows: np.ndarray,
    cols: np.ndarray,
    shape: tuple[int, int],
    kind: str = "raw",
) -> np.ndarray:
    """MLP inputs (float32). ``raw`` / ``rel`` (N, 8): colour change / 64, then the raw colour (``raw``:
    / 255 - 0.5) or the change relative to the background colour (``rel``: 2 dI / (bg + 16), bg = raw - dI,
    grey levels), then the pixel position normalised to [-1, 1] (x = column, y = row).

    ``poly`` (N, 18) / ``relpoly`` (N, 36): the colour change (and for ``relpoly`` also its relative form)
    multiplied by the quadratic monomials of the position (:func:`_monomials`), and no position term of its
    own. The first layer then computes ``sum_k m_k(x, y) W_k dI``: a linear map of the colour change that
    varies smoothly (quadratically) over the gel, as an LED's direction and fall-off do. The model cannot
    memorise "a normal at a place" (no colour, no activation beyond the bias), only how colour maps to slope
    there, which carries over to places between and beyond the training presses."""
    if kind in ("poly", "relpoly"):
        m = _monomials(rows, cols, shape)
        parts = [np.asarray(dI, np.float32) * (1.0 / 64.0)]
        if kind == "relpoly":
            parts.append(2.0 * dI / (np.asarray(raw, np.float32) - dI + 16.0))
        return np.concatenate([(c[:, :, None] * m[:, None, :]).reshape(len(m), -1) for c in parts], 1)
    H, W = shape
    f = np.empty((len(rows), 8), np.float32)
    f[:, 0:3] = dI * (1.0 / 64.0)
    if kind == "rel":
        f[:, 3:6] = 2.0 * dI / (np.asarray(raw, np.float32) - dI + 16.0)
    else:
        f[:, 3:6] = raw * (1.0 / 255.0) - 0.5
    f[:, 6] = cols * (2.0 / W) - 1.0
    f[:, 7] = rows * (2.0 / H) - 1.0
    return f


def _mlp_forward(params: dict[str, np.ndarray], x: np.ndarray) -> np.ndarray:
    """numpy forward pass (no torch at inference): Linear-ReLU ... Linear, tanh -> (nx, ny) in (-1, 1).

    An ensemble (``params["n_members"]`` = E > 1, members' weights ``m{e}_W{i}`` / ``m{e}_b{i}`` for e >= 1 beside
    member 0's ``W{i}`` / ``b{i}``) predicts the mean of its members' (nx, ny)."""
    n_layers = int(params["n_layers"])
    n_members = int(params.get("n_members", 1))
    out = None
    for e in range(n_members):
        pre = "" if e == 0 else f"m{e}_"
        h = x
        for i in range(n_layers):
            h = h @ params[f"{pre}W{i}"] + params[f"{pre}b{i}"]
            if i < n_layers - 1:
                np.maximum(h, 0.0, out=h)
        h = np.tanh(h)
        out = h if out is None else out + h
    if n_members > 1:
        out *= np.float32(1.0 / n_members)
    return out


def fit_mlp(feats: np.ndarray, target: np.ndarray, opts: TrainOptions) -> dict[str, np.ndarray]:
    """Train the per-pixel MLP with torch (CPU, current thread setting); returns numpy weights."""
    import torch

    torch.manual_seed(opts.seed)
    dims = [feats.shape[1]] + [opts.mlp_hidden] * opts.mlp_layers + [2]
    layers: list[torch.nn.Module] = []
    for i in range(len(dims) - 1):
        layers.append(torch.nn.Linear(dims[i], dims[i + 1]))
        if i < len(dims) - 2:
            layers.append(torch.nn.ReLU())
    net = torch.nn.Sequential(*layers)
    X = torch.from_numpy(np.ascontiguousarray(feats, np.float32))
    Y = torch.from_numpy(np.ascontiguousarray(target, np.float32))
    opt = torch.optim.Adam(net.parameters(), lr=opts.mlp_lr)
    n = len(X)
    batch = 1024
    steps = opts.mlp_epochs * ((n + batch - 1) // batch)
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=opts.mlp_lr, total_steps=max(steps, 1))
    g = torch.Generator().manual_seed(opts.seed)
    for _ in range(opts.mlp_epochs):
        perm = torch.randperm(n, generator=g)
        for s in range(0, n, batch):
            b = perm[s : s + batch]
            loss = torch.nn.functional.smooth_l1_loss(torch.tanh(net(X[b])), Y[b], beta=0.05)
            opt.zero_grad()
            loss.backward()
            opt.step()
            sched.step()
    params: dict[str, np.ndarray] = {"n_layers": np.int64(len(dims) - 1)}
    lin = [m for m in net if isinstance(m, torch.nn.Linear)]
    for i, m in enumerate(lin):
        params[f"W{i}"] = m.weight.detach().numpy().T.astype(np.float32).copy()
        params[f"b{i}"] = m.bias.detach().numpy().astype(np.float32).copy()
    return params


# ---------------------------------------------------------------------- photometric stereo
def fit_ps(dI: np.ndarray, n_xy: np.ndarray) -> dict[str, np.ndarray]:
    """Estimate the light matrix of K colour channels from pixels of known normal.

    Model: ``I_k - bg_k = l_k . (n - n0)`` with ``n0 = (0, 0, 1)`` (per-pixel background as ambient +
    flat shading). ``L`` (K, 3) by linear least squares over all training pixels.
    """
    nz = np.sqrt(np.clip(1.0 - (n_xy**2).sum(1), 0.0, 1.0))
    A = np.column_stack([n_xy, nz - 1.0])
    L, *_ = np.linalg.lstsq(A, dI.astype(np.float64), rcond=None)  # (3, K): dI = A @ L
    Lt = L.T  # (K, 3) light vectors (scaled by intensity x albedo)
    cond = np.linalg.cond(Lt)
    if not np.isfinite(cond) or cond > 1e6:
        raise InputError(
            "photometric stereo: light directions are degenerate",
            field="lights",
            expected="K >= 3 non-coplanar lights",
            got=f"condition number {cond:.3g}",
        )
    return {"lights": Lt.astype(np.float64), "lights_pinv": np.linalg.pinv(Lt).astype(np.float64)}


def _ps_solve(params: dict[str, np.ndarray], dI: np.ndarray) -> np.ndarray:
    """Per-pixel least squares: ``m = pinv(L) dI = n - n0``; n = (m + n0) / |m + n0| (albedo = |m + n0|)."""
    m = dI.astype(np.float64) @ params["lights_pinv"].T
    m[:, 2] += 1.0
    m[:, 2] = np.maximum(m[:, 2], 1e-3)  # normals never point into the sensor
    n = m / np.linalg.norm(m, axis=1, keepdims=True)
    return n[:, :2].astype(np.float32)


def ps_albedo(calib: Calibration, image: np.ndarray) -> np.ndarray:
    """(H, W) relative albedo |n0 + pinv(L) dI| of a photometric-stereo calibration (1 = background)."""
    dI = colour_change(calib.check_image(image), calib.background).reshape(-1, 3)
    m = dI.astype(np.float64) @ calib.params["lights_pinv"].T
    m[:, 2] += 1.0
    return np.linalg.norm(m, axis=1).reshape(calib.shape)


# ---------------------------------------------------------------------- inverse table
def fit_inverse(dI: np.ndarray, n_xy: np.ndarray, bins: int = 33) -> np.ndarray:
    """(B, B, 3) mean colour change over normal bins (rows = ny, cols = nx, both in [-1, 1])."""
    q = np.clip(np.rint((n_xy + 1.0) * 0.5 * (bins - 1)).astype(np.int64), 0, bins - 1)
    flat = q[:, 1] * bins + q[:, 0]
    cnt = np.bincount(flat, minlength=bins * bins).astype(np.float64)
    table = np.zeros((bins * bins, 3))
    for c in range(3):
        table[:, c] = np.bincount(flat, weights=dI[:, c], minlength=bins * bins)
    filled = cnt > 0
    table[filled] /= cnt[filled, None]
    table = table.reshape(bins, bins, 3)
    # the centre bin is the flat gel: exactly no colour change
    table[bins // 2, bins // 2] = 0.0
    filled = filled.reshape(bins, bins)
    filled[bins // 2, bins // 2] = True
    return _fill_empty(table, filled).astype(np.float32)


def lambertian_calibration(
    background: np.ndarray,
    mm_per_px: float,
    gain: float = 110.0,
    elevation_deg: float = 35.0,
    sensor: str = "lambertian",
) -> Calibration:
    """Uncalibrated fallback: photometric stereo with the known lights of the Lambertian render model
    (:func:`vtrack.tactile.render.lambert_colour_delta`), so simulated images invert exactly."""
    from vtrack.tactile.render import lambert_light_dirs

    L = gain * lambert_light_dirs(elevation_deg)
    grid = np.linspace(-0.95, 0.95, 33)
    nxg, nyg = np.meshgrid(grid, grid)
    inside = nxg**2 + nyg**2 < 0.95**2
    nxy = np.column_stack([nxg[inside], nyg[inside]])
    nz = np.sqrt(1 - (nxy**2).sum(1))
    dI = np.column_stack([nxy, nz - 1.0]) @ L.T
    params = {"lights": L, "lights_pinv": np.linalg.pinv(L), "inverse": fit_inverse(dI, nxy)}
    return Calibration(
        "ps",
        sensor,
        float(mm_per_px),
        np.asarray(background),
        params,
        {"gate": 6.0, "model": "lambertian", "gain": gain, "elevation_deg": elevation_deg},
    )


def height_noise(calib: Calibration, ps: PressSet, presses: list[Press], max_presses: int = 6) -> float:
    """Robust std (1.4826 MAD, mm) of the reconstructed height on flat gel (beyond 1.3 x contact radius)."""
    from vtrack.tactile.pipeline import TactilePipeline

    pipe = TactilePipeline(calib)
    vals = []
    H, W = ps.shape
    yy, xx = np.mgrid[0:H, 0:W]
    for p in presses[:max_presses]:
        h = pipe.height(ps.image(p))
        far = np.hypot(xx - p.center_xy_px[0], yy - p.center_xy_px[1]) > 1.3 * p.contact_radius_px
        v = h[far]
        vals.append(1.4826 * np.median(np.abs(v - np.median(v))))
    return float(np.median(vals)) if vals else 0.0


def _training_set(ps: PressSet, train: list[Press], opts: TrainOptions) -> tuple[PressSet, list[Press]]:
    """The press set and presses the samples are drawn from: ``ps`` itself, or (``opts.train_work_res``) its
    ``train`` presses downscaled to the tactile pipeline's default working resolution
    (:func:`vtrack.tactile.pipeline.auto_downsample`), so the model learns from the colour changes, camera
    noise and pixel positions it is later applied to (a 2 x 2 area average halves the noise: a net trained on
    full-resolution pixels shrinks its slopes for noise the working image no longer has)."""
    if not opts.train_work_res:
        return ps, train
    from dataclasses import replace as dc_replace

    from vtrack.tactile.pipeline import auto_downsample
    from vtrack.tactile.pressset import scaled_press_set

    f = auto_downsample(ps.shape)
    if f == 1:
        return ps, train
    small = scaled_press_set(dc_replace(ps, presses=list(train)), f)
    return small, small.presses


def calibrate(
    ps: PressSet, method: str = "lut", train: list[Press] | None = None, opts: TrainOptions | None = None
) -> Calibration:
    """Train a calibration of ``method`` on the ``train`` presses (default all) of a press set."""
    opts = opts or TrainOptions()
    if method not in METHODS:
        raise InputError("unknown calibration method", field="method", expected=" | ".join(METHODS), got=method)
    if opts.mlp_features not in MLP_FEATURES:
        raise InputError(
            "unknown MLP feature set", field="mlp_features", expected=" | ".join(MLP_FEATURES), got=opts.mlp_features
        )
    train = ps.presses if train is None else train
    if not train:
        raise InputError("no training presses left after the hold-out split", field="holdout")
    t0 = time.perf_counter()
    tps, ttrain = _training_set(ps, train, opts)
    data = training_samples(tps, ttrain, opts)
    info: dict[str, Any] = {
        "gate": opts.gate,
        "train_files": [p.file for p in train],
        "n_train_pixels": int(len(data["n"])),
        "options": opts.__dict__.copy(),
    }
    if method == "lut":
        # bin edges on half-integers: integer colour changes never sit on an edge (float-rounding safe)
        params = fit_lut(data["dI"], data["n"], opts.lut_bins, -opts.lut_range - 0.5, opts.lut_range - 0.5)
    elif method == "lut_raw":
        params = fit_lut(data["raw"], data["n"], opts.lut_bins, -0.5, 255.5)
    elif method == "mlp":
        feats = _mlp_features(data["dI"], data["raw"], data["rows"], data["cols"], tps.shape, opts.mlp_features)
        params = fit_mlp(feats, data["n"], opts)
        for e in range(1, max(1, opts.mlp_ensemble)):  # more members: the same data, other initial weights/batches
            member = fit_mlp(feats, data["n"], replace(opts, seed=opts.seed + 1000 * e))
            params.update({f"m{e}_{k}": v for k, v in member.items() if k != "n_layers"})
        if opts.mlp_ensemble > 1:
            params["n_members"] = np.int64(opts.mlp_ensemble)
        if opts.mlp_features != "raw":  # absent = raw: calibrations written before the option load unchanged
            params["mlp_features"] = np.int64(MLP_FEATURES.index(opts.mlp_features))
    else:
        params = fit_ps(data["dI"], data["n"])
    params["inverse"] = fit_inverse(data["dI"], data["n"])
    info["train_seconds"] = time.perf_counter() - t0
    info.update({"ball_radius_mm": ps.ball_radius_mm, "press_set": str(ps.root)})
    calib = Calibration(method, ps.sensor, ps.mm_per_px, ps.background().copy(), params, info)
    calib.info["height_noise_mm"] = height_noise(calib, ps, train)
    return calib


def cached_calibration(
    ps: PressSet, method: str, holdout: str | None = None, opts: TrainOptions | None = None
) -> Calibration:
    """Train (or load from ``cache_dir()/tactile``) a calibration on the non-held-out presses of a press set."""
    import hashlib

    from vtrack.paths import cache_dir

    opts = opts or TrainOptions()
    train, _ = ps.split(holdout)
    key = json.dumps(
        {
            "root": str(ps.root.resolve()),
            "meta": ps.meta(),
            "method": method,
            "train": [p.file for p in train],
            "opts": options_key(opts),
            "v": FORMAT_VERSION,
        },
        sort_keys=True,
    )
    digest = hashlib.sha1(key.encode()).hexdigest()[:16]
    path = cache_dir() / "tactile" / f"calib_{method}_{digest}.npz"
    if path.is_file():
        try:
            return Calibration.load(path)
        except InputError:
            pass  # stale/corrupt cache entry: retrain
    calib = calibrate(ps, method, train, opts)
    calib.info["holdout"] = holdout
    calib.save(path)
    return calib


def held_out_presses(calib: Calibration, ps: PressSet) -> list[Press]:
    """Presses of ``ps`` not used to train ``calib`` (all of them for a calibration from another set)."""
    same = str(Path(calib.info.get("press_set", "")).resolve()) == str(ps.root.resolve())
    used = set(calib.info.get("train_files", [])) if same else set()
    return [p for p in ps.presses if p.file not in used]
