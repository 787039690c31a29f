"""Colour (feature-track) observations for SLAM: KLT tracks on the segmented object pixels.

Depth and touch do not see a body of revolution spin about its axis (a mug once its handle is hidden: see
docs/benchmarks/slam_medium.md); its surface colour does, when it has texture. This module turns a camera's
grey images into **feature tracks**: object pixels followed from frame to frame by pyramidal Lucas-Kanade
(OpenCV ``calcOpticalFlowPyrLK``), back-projected with the frame's depth to world points. Each track has an
integer id; the tracker (:class:`~vtrack.tracking.window.WindowTracker`, option ``sigma_colour``) anchors a
track in the object frame the first time it sees it and then asks every later observation of it to land on
that anchor (a robust 3D-3D term) - the object's motion between the frames, which a spin about a symmetry axis
leaves to colour alone.

Shading: the simulator's (and a real scene's) light is fixed in the world, so on a spinning cylinder the
shading stays put in the image while the texture moves; LK on raw intensities is pulled towards rest (the
5 s medium mug: 52 of 135 deg recovered). The image is divided by its local mean inside the object mask (a
masked Gaussian of ``blur_px``), which keeps the texture and removes most of the smooth shading (106 of 135 deg,
``data_tools``-style check in docs/benchmarks/slam_colour.md).

Alternative (opt-in, ``shading="sh"`` / ``"sh_local"``): an "intrinsic" image, the intensity divided by a
2nd-order spherical-harmonics lighting model fitted against the surface normals of the frame's own depth
(:func:`remove_shading_sh`; nothing of the simulator's lights is used). Measured on the 5 s sessions it is worse
than the local mean (docs/benchmarks/slam_5s_medium.md): the depth's normals do not resolve the scanned meshes'
fine relief, whose shading is what the tracks follow, and the model's residual (mask borders, a mug's rim)
is light-fixed texture of its own.

Graceful degradation: features are kept only where the normalised image has a corner whose minimum
eigenvalue is above ``min_eig`` (absolute, on the normalised image: a uniformly coloured object has none, its
shading divided out), away from the mask's border (occluding contours and fingers are not object-fixed);
tracks must pass a forward-backward check and stay on the mask with valid depth. No tracks: no term.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vtrack.errors import InputError

SHADING_MODES = ("local", "sh", "sh_local")


@dataclass
class ColourOptions:
    """KLT feature tracks on the object (pixels of the full-resolution image)."""

    max_features: int = 80  #: tracks kept at once
    min_distance: int = 4  #: px between features
    blur_px: float = 5.0  #: sigma of the masked local mean the image is divided by (shading removal), px
    #: minimum eigenvalue of the structure tensor (``cv2.cornerMinEigenVal``, 3x3 block, Sobel 3, OpenCV's scale)
    #: of the normalised image (mean 128 grey levels) for a new feature: on a uniform, shaded cylinder with the
    #: simulator's sensor noise (2 levels) the largest is 3.7e-4; the textured YCB mug's features reach 1e-3-7e-2
    min_eig: float = 5e-4
    erode_px: int = 5  #: features start at least this far inside the object mask, px ...
    keep_erode_px: int = 4  #: ... and tracks end when they come closer than this to its border, px
    win: int = 9  #: LK window, px (a small one: near the border a window sees the static background)
    levels: int = 2  #: LK pyramid levels above the base
    fb_max_px: float = 0.5  #: forward-backward disagreement above which a track is dropped, px
    roi_margin: int = 24  #: px around the mask's box the images are processed in
    #: look for new features only when fewer than this fraction of ``max_features`` tracks survive (detection costs
    #: as much as tracking)
    refill_frac: float = 0.5
    #: how the light-fixed shading is removed before tracking: ``"local"`` divides by the masked local mean
    #: (:func:`normalise_shading`); ``"sh"`` divides by a 2nd-order spherical-harmonics lighting model of the
    #: intensity against the surface normals estimated from the frame's depth (:func:`remove_shading_sh`, an
    #: "intrinsic" / albedo image; needs the full-resolution depth, else falls back to ``"local"``); ``"sh_local"``
    #: both, the SH division first
    shading: str = "local"
    #: per-frame weight kept of the earlier frames' lighting fit (0: each frame alone; 0.98: ~50 frames; the light
    #: is fixed relative to the camera, the albedo of a turning object averages out)
    sh_memory: float = 0.0
    sh_depth_blur_px: float = 3.0  #: sigma of the masked smoothing of the depth before its normals, px
    #: sigma of a Gaussian pre-blur of the shading-free image, px (0 = none): shading of surface relief finer
    #: than the depth resolves is not divided out and partly stays with the light; a blur weakens it
    pre_blur_px: float = 0.0

    @classmethod
    def from_dict(cls, opts: dict | None) -> ColourOptions:
        from vtrack.config import checked_fields

        o = cls(**checked_fields(cls, opts or {}, "colour"))
        if (
            o.max_features < 1
            or o.win < 3
            or o.blur_px <= 0
            or o.levels < 0
            or o.shading not in SHADING_MODES
            or o.sh_depth_blur_px < 0
            or not 0.0 <= o.sh_memory <= 1.0
            or o.pre_blur_px < 0
        ):
            raise InputError(
                "colour options out of range",
                field="colour",
                expected=f"max_features >= 1, win >= 3, blur_px > 0, levels >= 0, shading in {SHADING_MODES}, "
                "sh_depth_blur_px >= 0, pre_blur_px >= 0, 0 <= sh_memory <= 1",
                got=(o.max_features, o.win, o.blur_px, o.levels, o.shading, o.sh_depth_blur_px, o.pre_blur_px),
            )
        return o


def to_grey(rgb: np.ndarray) -> np.ndarray:
    """uint8 grey (H, W) of an RGB (H, W, 3) or grey (H, W) image."""
    import cv2

    a = np.asarray(rgb)
    if a.ndim == 3 and a.shape[2] >= 3:
        return cv2.cvtColor(np.ascontiguousarray(a[..., :3]).astype(np.uint8), cv2.COLOR_RGB2GRAY)
    if a.ndim == 2:
        return a.astype(np.uint8)
    raise InputError("colour image must be (H, W) or (H, W, 3)", field="rgb", got=a.shape)


def normalise_shading(grey: np.ndarray, mask: np.ndarray, blur_px: float) -> np.ndarray:
    """float32 image: ``grey`` divided by its masked local mean (Gaussian ``blur_px``) x 128 inside ``mask``,
    128 outside (texture kept, smooth light-fixed shading removed; a uniform surface becomes flat)."""
    import cv2

    g = grey.astype(np.float32)
    m = mask.astype(np.float32)
    # numerator and denominator as the two channels of one image: one filter call, the same values per channel
    nd = cv2.GaussianBlur(np.dstack([g * m, m]), (0, 0), blur_px)
    if nd.ndim == 2:  # a one-pixel-wide crop comes back without its channel axis
        nd = nd.reshape(g.shape + (2,))
    mean = nd[..., 0] / np.maximum(nd[..., 1], 1e-3)
    out = np.full(g.shape, 128.0, np.float32)
    # (= ``out[ok] = 128.0 * g[ok] / mean[ok]``: the same float32 operations per pixel, without three
    # boolean gathers and a scatter)
    np.divide(np.multiply(g, np.float32(128.0)), mean, out=out, where=mask & (mean > 1.0))
    return out


def normals_from_depth(
    depth_m: np.ndarray, mask: np.ndarray, K: np.ndarray, blur_px: float = 3.0, offset: tuple[int, int] = (0, 0)
) -> tuple[np.ndarray, np.ndarray]:
    """Camera-frame unit surface normals (H, W, 3), pointing towards the camera, of a depth image (metres, 0 /
    non-finite = no depth) on ``mask``, and where they are valid. The depth is first smoothed by a masked Gaussian
    (``blur_px``; sensor noise, ~1 mm, would dominate a 1-px difference), then the normal is the cross product of
    the back-projected points' image derivatives. ``offset`` (row, col): where the crop starts in the full image
    (the principal point of ``K`` is in full-image pixels). Invalid: no depth at the pixel or a neighbour, or a
    degenerate cross product (e.g. a surface seen edge-on)."""
    import cv2

    z = np.asarray(depth_m, np.float32)
    ok = np.asarray(mask, bool) & np.isfinite(z) & (z > 0)
    zc = np.where(ok, z, 0.0).astype(np.float32)
    if blur_px > 0:
        nd = cv2.GaussianBlur(np.dstack([zc, ok.astype(np.float32)]), (0, 0), blur_px)
        if nd.ndim == 2:
            nd = nd.reshape(zc.shape + (2,))
        # holes of the depth (dropouts) inside the mask are filled from their neighbours: a hole must not become
        # a patch without a normal (an artificial, world-fixed corner in the shading-free image)
        ok = np.asarray(mask, bool) & (nd[..., 1] > 0.25)
        zc = np.where(ok, nd[..., 0] / np.maximum(nd[..., 1], 1e-6), 0.0).astype(np.float32)
    H, W = z.shape
    r0, c0 = offset
    u = (np.arange(W, dtype=np.float32) + c0 - K[0, 2]) / K[0, 0]
    v = (np.arange(H, dtype=np.float32) + r0 - K[1, 2]) / K[1, 1]
    X = np.stack([u[None, :] * zc, v[:, None] * zc, zc], -1)
    dXu = np.zeros_like(X)
    dXv = np.zeros_like(X)
    dXu[:, 1:-1] = X[:, 2:] - X[:, :-2]
    dXv[1:-1] = X[2:] - X[:-2]
    n = np.cross(dXu, dXv)
    nn = np.linalg.norm(n, axis=-1)
    # the central differences need both neighbours on the surface
    okn = ok.copy()
    okn[:, 1:-1] &= ok[:, 2:] & ok[:, :-2]
    okn[1:-1] &= ok[2:] & ok[:-2]
    okn[:, [0, -1]] = False
    okn[[0, -1]] = False
    okn &= np.isfinite(nn) & (nn > 1e-12)
    n = np.where(okn[..., None], n / np.maximum(nn, 1e-12)[..., None], 0.0)
    # towards the camera (the point's ray is +z away from it)
    flip = (n * X).sum(-1) > 0
    n[flip] *= -1
    return n.astype(np.float32), okn


def sh_basis(n: np.ndarray) -> np.ndarray:
    """The 9 real 2nd-order spherical-harmonics functions (constants dropped: they are absorbed by the fitted
    coefficients) of unit normals ``n`` (..., 3): (..., 9)."""
    x, y, z = n[..., 0], n[..., 1], n[..., 2]
    return np.stack([np.ones_like(x), x, y, z, x * y, x * z, y * z, x * x - y * y, 3 * z * z - 1], -1)


def fit_sh_lighting(
    intensity: np.ndarray,
    normals: np.ndarray,
    iters: int = 3,
    ridge: float = 1e-3,
    huber_k: float = 1.345,
    state: dict | None = None,
    memory: float = 0.0,
) -> np.ndarray:
    """Coefficients (9,) of the lighting model ``intensity ~ sh_basis(normals) @ c`` (Lambertian shading of a
    uniform albedo under distant light: the 2nd-order SH capture ~98 % of it; the albedo's variation is the
    residual, down-weighted by Huber IRLS, ``huber_k`` robust sigmas). ``ridge`` (relative to the mean diagonal
    of the normal matrix) keeps the solve finite when the normals do not span the basis (a flat surface: every
    normal the same): the prediction is then the mean intensity. Empty input: zeros (or the state's model).

    ``state`` (a dict kept by the caller) with ``memory`` in (0, 1]: the normal equations of earlier frames,
    scaled by ``memory`` per frame, are added to this frame's (each frame weighted as one): a light fixed in the
    camera frame over many frames, so the albedo of a turning object averages out of it. A per-frame fit cannot
    tell an albedo pattern around a body of revolution from shading (both are functions of the normal there)."""
    I = np.asarray(intensity, np.float64).ravel()
    B = sh_basis(np.asarray(normals, np.float64).reshape(-1, 3))
    A0 = np.zeros((9, 9))
    b0 = np.zeros(9)
    if state is not None and memory > 0 and "A" in state:
        A0, b0 = memory * state["A"], memory * state["b"]
    if not len(I):
        if not np.any(A0):
            return np.zeros(9)
        c = np.linalg.solve(A0 + np.eye(9) * ridge * max(np.trace(A0) / 9.0, 1e-12), b0)
        return c if np.all(np.isfinite(c)) else np.zeros(9)
    w = np.ones(len(I))
    c = np.zeros(9)
    inv_n = 1.0 / len(I)
    for _ in range(max(1, iters)):
        Bw = B * (w * inv_n)[:, None]
        A = Bw.T @ B + A0
        A += np.eye(9) * ridge * max(np.trace(A) / 9.0, 1e-12)
        c = np.linalg.solve(A, Bw.T @ I + b0)
        r = I - B @ c
        s = 1.4826 * np.median(np.abs(r)) + 1e-6
        a = np.abs(r) / (huber_k * s)
        w = np.where(a <= 1.0, 1.0, 1.0 / np.maximum(a, 1e-12))
    if state is not None and memory > 0:
        Bw = B * (w * inv_n)[:, None]
        state["A"], state["b"] = Bw.T @ B + A0, Bw.T @ I + b0
    return c if np.all(np.isfinite(c)) else np.zeros(9)


def remove_shading_sh(
    grey: np.ndarray,
    mask: np.ndarray,
    depth_m: np.ndarray,
    K: np.ndarray,
    depth_blur_px: float = 3.0,
    offset: tuple[int, int] = (0, 0),
    max_fit_px: int = 4000,
    state: dict | None = None,
    memory: float = 0.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Albedo ("intrinsic") image of the object: ``grey`` divided by a 2nd-order spherical-harmonics lighting
    model fitted (robust least squares, :func:`fit_sh_lighting`) to the intensity against the normals of the
    depth (:func:`normals_from_depth`) over the object pixels of this frame; scaled to mean 128 on the object,
    128 elsewhere. Returns the float32 image and where it is valid (mask, a normal, a positive predicted shading);
    pixels without a valid normal keep 128. Everything is estimated from the frame (no light or albedo known).
    ``max_fit_px``: a regular subsample of at most this many pixels fits the model (the whole image is divided).
    ``state`` / ``memory``: the lighting model accumulated over frames (:func:`fit_sh_lighting`)."""
    g = np.asarray(grey, np.float32)
    n, ok = normals_from_depth(depth_m, mask, K, depth_blur_px, offset)
    out = np.full(g.shape, 128.0, np.float32)
    idx = np.flatnonzero(ok.ravel())
    if len(idx) < 20:
        return out, np.zeros(g.shape, bool)
    fit = idx[:: max(1, len(idx) // max_fit_px)]
    c = fit_sh_lighting(g.ravel()[fit], n.reshape(-1, 3)[fit], state=state, memory=memory)
    shade = np.zeros(g.size, np.float32)
    shade[idx] = sh_basis(n.reshape(-1, 3)[idx]) @ c.astype(np.float32)
    # a predicted shading below a tenth of the object's median: a normal far outside the fitted range, no division
    floor = 0.1 * max(float(np.median(g.ravel()[idx])), 1.0)
    have = ok.ravel() & (shade > floor)
    if not have.any():
        return out, np.zeros(g.shape, bool)
    # mask pixels without a usable normal take the shading of their neighbours (normalised convolution; the
    # shading is smooth), so the albedo image has no edge where the depth has none
    import cv2

    m = np.asarray(mask, bool).ravel()
    fill = m & ~have
    if fill.any():
        sw = cv2.GaussianBlur(
            np.dstack([np.where(have, shade, 0.0).reshape(g.shape), have.reshape(g.shape).astype(np.float32)]),
            (0, 0),
            max(depth_blur_px, 2.0),
        ).reshape(-1, 2)
        shade[fill] = np.where(sw[fill, 1] > 1e-3, sw[fill, 0] / np.maximum(sw[fill, 1], 1e-6), np.median(shade[have]))
        have = m & (shade > floor)
    alb = g.ravel()[have] / shade[have]
    flat = out.ravel()
    flat[have] = 128.0 * alb / max(float(np.mean(alb)), 1e-6)
    valid = have
    return out, valid.reshape(g.shape)


def _box(mask: np.ndarray, margin: int) -> tuple[int, int, int, int] | None:
    rows = np.flatnonzero(mask.any(1))
    if not len(rows):
        return None
    cols = np.flatnonzero(mask.any(0))
    h, w = mask.shape
    return (
        max(0, rows[0] - margin),
        min(h, rows[-1] + margin + 1),
        max(0, cols[0] - margin),
        min(w, cols[-1] + margin + 1),
    )


class FeatureTracks:
    """KLT tracks of one camera (image-space state; no pose). ``update`` per frame, in time order.

    Args:
        options: :class:`ColourOptions` or a dict of overrides.
    """

    def __init__(self, options: ColourOptions | dict | None = None) -> None:
        self.opts = options if isinstance(options, ColourOptions) else ColourOptions.from_dict(options)
        self.reset()

    def reset(self) -> None:
        """Forget every track (e.g. before re-running from the first frame); ids restart at 0."""
        self._end_tracks()
        self._next_id = 0
        self._sh_state: dict = {}  # the lighting model's normal equations over frames (``sh_memory``)

    def _end_tracks(self) -> None:
        """End every track (ids are not reused: a later track never takes an ended one's anchor)."""
        self._prev: np.ndarray | None = None  # normalised image inside _prev_box (uint8)
        self._prev_box: tuple[int, int, int, int] | None = None
        self._pts = np.zeros((0, 2), np.float32)  # full-image pixel positions (x, y) in the previous frame
        self._ids = np.zeros(0, np.int64)

    def update(
        self,
        grey: np.ndarray,
        mask: np.ndarray,
        depth: np.ndarray | None = None,
        K: np.ndarray | None = None,
        depth_scale: float = 1.0,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Track the features into this frame and add new ones; returns ``(ids (N,), uv (N, 2) float px)`` of the
        tracks seen in this frame (continuing ones keep their id). An empty / missing mask ends every track.
        ``grey``: the uint8 grey image (H, W), or the RGB image (H, W, 3), converted (:func:`to_grey`) only inside
        the box the tracks are processed in (the same values, without converting the whole frame).
        ``depth`` (H, W; times ``depth_scale`` = metres) and the intrinsics ``K``: for the ``"sh"`` shading modes
        (the normals of the lighting model); without them those modes fall back to ``"local"``."""
        import cv2

        o = self.opts
        mask = np.asarray(mask, bool)
        grey = np.asarray(grey)
        if grey.shape[:2] != mask.shape or grey.ndim not in (2, 3):
            raise InputError("colour image and mask differ in size", field="rgb", expected=mask.shape, got=grey.shape)
        box = _box(mask, o.roi_margin)
        if box is None or np.count_nonzero(mask) < 16:
            self._end_tracks()
            return np.zeros(0, np.int64), np.zeros((0, 2))
        cur_full_box = box
        if self._prev_box is not None and len(self._pts):
            pb = self._prev_box
            box = (min(box[0], pb[0]), max(box[1], pb[1]), min(box[2], pb[2]), max(box[3], pb[3]))
        r0, r1, c0, c1 = box
        sub_mask = mask[r0:r1, c0:c1]
        g_box = to_grey(grey[r0:r1, c0:c1])
        if o.shading != "local" and depth is not None and K is not None and np.shape(depth)[:2] == mask.shape:
            d = np.asarray(depth[r0:r1, c0:c1], np.float32) * np.float32(depth_scale)
            norm, _ = remove_shading_sh(
                g_box,
                sub_mask,
                d,
                np.asarray(K, np.float64),
                o.sh_depth_blur_px,
                (r0, c0),
                state=self._sh_state,
                memory=o.sh_memory,
            )
            if o.shading == "sh_local":
                norm = normalise_shading(norm, sub_mask, o.blur_px)
        else:
            norm = normalise_shading(g_box, sub_mask, o.blur_px)
        if o.pre_blur_px > 0:
            norm = cv2.GaussianBlur(norm, (0, 0), o.pre_blur_px)
        img = np.clip(norm, 0, 255).astype(np.uint8)
        ids = np.zeros(0, np.int64)
        uv = np.zeros((0, 2), np.float32)
        if self._prev is not None and len(self._pts):
            # the previous image in the union box (it was stored in its own box)
            pr0, pr1, pc0, pc1 = self._prev_box  # type: ignore[misc]
            prev = np.full(img.shape, 128, np.uint8)
            prev[pr0 - r0 : pr1 - r0, pc0 - c0 : pc1 - c0] = self._prev
            p0 = (self._pts - np.array([c0, r0], np.float32)).reshape(-1, 1, 2)
            lk = dict(winSize=(o.win, o.win), maxLevel=o.levels)
            p1, st, _ = cv2.calcOpticalFlowPyrLK(prev, img, p0, None, **lk)
            pb, stb, _ = cv2.calcOpticalFlowPyrLK(img, prev, p1, None, **lk)
            ok = (st.ravel() == 1) & (stb.ravel() == 1) & np.isfinite(p1.reshape(-1, 2)).all(1)
            fb = np.linalg.norm((pb - p0).reshape(-1, 2), axis=1)
            ok &= fb < o.fb_max_px
            q = p1.reshape(-1, 2) + np.array([c0, r0], np.float32)
            xi = np.round(q[:, 0]).astype(int)
            yi = np.round(q[:, 1]).astype(int)
            inside = (xi >= 0) & (yi >= 0) & (xi < mask.shape[1]) & (yi < mask.shape[0])
            ok &= inside
            keep = mask
            if o.keep_erode_px > 0:
                # a window that straddles the border sees the static background / occluder and is held back
                kk = 2 * o.keep_erode_px + 1
                keep = np.zeros_like(mask)
                keep[r0:r1, c0:c1] = cv2.erode(mask[r0:r1, c0:c1].astype(np.uint8), np.ones((kk, kk), np.uint8)) > 0
            ok[ok] &= keep[yi[ok], xi[ok]]
            ids, uv = self._ids[ok], q[ok]
        # new features where the tracks are thin
        need = o.max_features - len(ids)
        if len(ids) < o.refill_frac * o.max_features:
            sub = mask[r0:r1, c0:c1].astype(np.uint8)
            k = 2 * o.erode_px + 1
            allow = cv2.erode(sub, np.ones((k, k), np.uint8))
            for x, y in uv - np.array([c0, r0], np.float32):
                cv2.circle(allow, (int(round(x)), int(round(y))), o.min_distance, 0, -1)
            if allow.any():
                eig = cv2.cornerMinEigenVal(img, 3, 3)
                cand = cv2.goodFeaturesToTrack(
                    img, need, 1e-3, o.min_distance, mask=allow, blockSize=3, useHarrisDetector=False
                )
                if cand is not None:
                    c = cand.reshape(-1, 2)
                    strong = eig[c[:, 1].astype(int), c[:, 0].astype(int)] > o.min_eig
                    c = c[strong]
                    new_ids = np.arange(self._next_id, self._next_id + len(c))
                    self._next_id += len(c)
                    ids = np.concatenate([ids, new_ids])
                    uv = np.concatenate([uv, c + np.array([c0, r0], np.float32)])
        # keep this frame's image in its own box for the next frame
        cr0, cr1, cc0, cc1 = cur_full_box
        self._prev = img[cr0 - r0 : cr1 - r0, cc0 - c0 : cc1 - c0].copy()
        self._prev_box = cur_full_box
        self._pts = uv.astype(np.float32)
        self._ids = ids.astype(np.int64)
        return self._ids.copy(), self._pts.astype(np.float64)


def backproject(
    uv: np.ndarray, z: np.ndarray, stride: int, K: np.ndarray, scale: float = 1.0, patch: int = 0
) -> tuple[np.ndarray, np.ndarray]:
    """Camera-frame points (N, 3) of full-resolution pixels ``uv`` (x, y) with depth read from ``z`` (the image
    subsampled by ``stride``, nearest sample, times ``scale`` to metres; 0 / non-finite = no depth); and which of
    them have a valid depth. ``patch`` > 0: the mean of the valid depths in the (2 patch + 1)^2 samples around
    (within 5 mm of the centre sample) replaces the centre sample: per-pixel sensor noise, ~1 mm on the simulated
    camera, averages down (a track's anchor keeps its depth)."""
    uv = np.asarray(uv, np.float64).reshape(-1, 2)
    if not len(uv):
        return np.zeros((0, 3)), np.zeros(0, bool)
    xi = np.clip(np.round(uv[:, 0] / stride).astype(int), 0, z.shape[1] - 1)
    yi = np.clip(np.round(uv[:, 1] / stride).astype(int), 0, z.shape[0] - 1)
    zf = np.asarray(z).reshape(-1)  # (flat indices: numpy's 2-D fancy indexing is several times slower)
    d = zf[yi * z.shape[1] + xi].astype(np.float64) * scale
    ok = np.isfinite(d) & (d > 0)
    if patch > 0 and ok.any():
        o = np.arange(-patch, patch + 1)
        ys = np.clip(yi[:, None, None] + o[None, :, None], 0, z.shape[0] - 1)
        xs = np.clip(xi[:, None, None] + o[None, None, :], 0, z.shape[1] - 1)
        zz = zf[ys * z.shape[1] + xs].reshape(len(uv), -1).astype(np.float64) * scale
        # the mean of the samples within 5 mm of the centre's depth (not across an occluding edge)
        near = np.isfinite(zz) & (zz > 0) & (np.abs(zz - d[:, None]) < 0.005)
        n = near.sum(1)
        d = np.where(ok & (n > 0), np.where(near, zz, 0.0).sum(1) / np.maximum(n, 1), d)
    d = np.where(ok, d, 0.0)
    X = np.stack([(uv[:, 0] - K[0, 2]) * d / K[0, 0], (uv[:, 1] - K[1, 2]) * d / K[1, 1], d], 1)
    return X, ok
