"""Height from surface gradients: Poisson integration (DCT Neumann, FFT Frankot-Chellappa, masked sparse LSQ).

All solvers take gradients ``gx = dh/dx`` (along image columns) and ``gy = dh/dy`` (along rows) in units of
height per pixel (multiply mm/mm slopes by mm/px to get mm/px) and return the height in the same units as
``gx * px``. The integration constant is fixed so that the image border has zero median height (the gel
border is normally out of contact), or with ``zero_mask`` so that those pixels have zero median.

Why the results keep the peak height: the gradients are averaged onto the half-pixel grid on which the
forward-difference operator lives, and the right-hand side is built with the exact adjoint of that operator.
The normal equations are then the 5-point Neumann Laplacian, which DCT-II diagonalises exactly, so an exactly
integrable input is reproduced up to the half-pixel averaging (no 1/4 peak-height loss from mixing central
differences with the 5-point Laplacian's eigenvalues).
"""

from __future__ import annotations

import numpy as np

from vtrack.errors import InputError

_EIG_CACHE: dict[tuple[int, int, str], np.ndarray] = {}


def _check(gx: np.ndarray, gy: np.ndarray, dtype=np.float64) -> tuple[np.ndarray, np.ndarray]:
    gx = np.asarray(gx, dtype=dtype)
    gy = np.asarray(gy, dtype=dtype)
    if gx.ndim != 2 or gx.shape != gy.shape:
        raise InputError(
            "gradients must be two 2-D arrays of the same shape",
            field="gx/gy",
            expected="(H, W) and (H, W)",
            got=(gx.shape, gy.shape),
        )
    # Non-finite gradients carry no information: treat them as flat rather than letting NaN spread.
    if not (np.isfinite(gx).all() and np.isfinite(gy).all()):
        gx = np.where(np.isfinite(gx), gx, 0.0)
        gy = np.where(np.isfinite(gy), gy, 0.0)
    return gx, gy


def divergence_rhs(gx: np.ndarray, gy: np.ndarray) -> np.ndarray:
    """``Dx^T gx_half + Dy^T gy_half``: right-hand side of the LSQ normal equations (negated divergence)."""
    H, W = gx.shape[-2:]
    f = np.zeros(gx.shape, dtype=gx.dtype)  # (..., H, W): a stack of maps is done map by map, at once
    if W > 1:
        hx = 0.5 * (gx[..., 1:] + gx[..., :-1])  # forward difference z[:, j+1] - z[:, j] ~ hx[:, j]
        f[..., 1:] += hx
        f[..., :-1] -= hx
    if H > 1:
        hy = 0.5 * (gy[..., 1:, :] + gy[..., :-1, :])
        f[..., 1:, :] += hy
        f[..., :-1, :] -= hy
    return f


def _anchor(z: np.ndarray, zero_mask: np.ndarray | None) -> np.ndarray:
    if zero_mask is not None and zero_mask.any():
        ref = np.median(z[zero_mask])
    else:
        H, W = z.shape
        b = max(1, min(H, W) // 50)
        ring = np.concatenate([z[:b].ravel(), z[-b:].ravel(), z[:, :b].ravel(), z[:, -b:].ravel()])
        ref = np.median(ring)
    return z - ref


def poisson_dct(gx: np.ndarray, gy: np.ndarray, zero_mask: np.ndarray | None = None, dtype=np.float64) -> np.ndarray:
    """Least-squares integration with Neumann boundary, solved by DCT-II (O(HW log HW)).

    Exact for integrable gradients (up to half-pixel averaging); the LSQ solution for noisy ones.
    ``dtype=np.float32`` halves the time (used by the real-time pipeline; heights are far above float32 eps).
    """
    from scipy.fft import dctn, idctn

    gx, gy = _check(gx, gy, dtype)
    H, W = gx.shape
    if H * W == 0:
        return np.zeros((H, W), np.float64)
    f = divergence_rhs(gx, gy)
    key = (H, W, np.dtype(dtype).name)
    denom = _EIG_CACHE.get(key)
    if denom is None:
        ey = 2.0 - 2.0 * np.cos(np.pi * np.arange(H) / H)
        ex = 2.0 - 2.0 * np.cos(np.pi * np.arange(W) / W)
        denom = ey[:, None] + ex[None, :]
        denom[0, 0] = 1.0  # the constant mode is free: fixed by _anchor
        denom = (1.0 / denom).astype(dtype)
        _EIG_CACHE[key] = denom
    F = dctn(f, type=2, norm="ortho", workers=1)
    # Normal equations are (Dx^T Dx + Dy^T Dy) z = f; our f has the sign of -div, the Laplacian is -L.
    Z = F * denom
    Z[0, 0] = 0.0
    z = idctn(Z, type=2, norm="ortho", workers=1)
    return _anchor(z, zero_mask)


def poisson_dct_stack(gx: np.ndarray, gy: np.ndarray, dtype=np.float32) -> np.ndarray:
    """:func:`poisson_dct` (border anchoring) of each map of a stack ``gx``, ``gy`` (B, H, W) of one size: the
    transforms of all maps in one call each (the real-time tactile pipeline's four sensors of a time step)."""
    from scipy.fft import dctn, idctn

    gx = np.asarray(gx, dtype=dtype)
    gy = np.asarray(gy, dtype=dtype)
    if gx.ndim != 3 or gx.shape != gy.shape:
        raise InputError("gradient stacks must be (B, H, W) of one shape", field="gx/gy", got=(gx.shape, gy.shape))
    if not (np.isfinite(gx).all() and np.isfinite(gy).all()):
        return np.stack([poisson_dct(a, b, dtype=dtype) for a, b in zip(gx, gy, strict=True)])
    B, H, W = gx.shape
    if B * H * W == 0:
        return np.zeros((B, H, W), np.float64)
    f = divergence_rhs(gx, gy)
    key = (H, W, np.dtype(dtype).name)
    denom = _EIG_CACHE.get(key)
    if denom is None:
        poisson_dct(np.zeros((H, W), dtype), np.zeros((H, W), dtype), dtype=dtype)  # fills the cache
        denom = _EIG_CACHE[key]
    Z = dctn(f, type=2, norm="ortho", axes=(1, 2), workers=1) * denom
    Z[:, 0, 0] = 0.0
    z = idctn(Z, type=2, norm="ortho", axes=(1, 2), workers=1)
    b = max(1, min(H, W) // 50)
    ring = np.concatenate(
        [z[:, :b].reshape(B, -1), z[:, -b:].reshape(B, -1), z[:, :, :b].reshape(B, -1), z[:, :, -b:].reshape(B, -1)],
        axis=1,
    )
    return z - np.median(ring, axis=1)[:, None, None]


def poisson_fft(gx: np.ndarray, gy: np.ndarray, zero_mask: np.ndarray | None = None) -> np.ndarray:
    """Frankot-Chellappa projection onto integrable surfaces in the Fourier domain.

    The gradients are mirror-extended (gx odd in x / even in y, gy the reverse) so the periodic FFT sees no
    jump at the image border, and the discrete forward-difference spectrum (with half-pixel shift) is used
    instead of the continuous ``j*w`` so an exactly integrable input keeps its peak height.
    """
    gx, gy = _check(gx, gy)
    H, W = gx.shape
    if H * W == 0:
        return np.zeros((H, W), np.float64)
    # Half-pixel gradients on the forward-difference grid, then the symmetric extension that matches
    # Neumann boundaries (the Frankot-Chellappa solution on the extension equals the mirrored LSQ one).
    hx = np.zeros((H, W))
    hy = np.zeros((H, W))
    if W > 1:
        hx[:, :-1] = 0.5 * (gx[:, 1:] + gx[:, :-1])
    if H > 1:
        hy[:-1, :] = 0.5 * (gy[1:, :] + gy[:-1, :])
    # Mirror so that z_ext[k] = z[2W-1-k]; forward differences flip sign and shift by one in the mirror half.
    ex = np.concatenate([hx, -np.roll(hx[:, ::-1], -1, axis=1)], axis=1)
    ex = np.concatenate([ex, ex[::-1]], axis=0)
    ey = np.concatenate([hy, -np.roll(hy[::-1], -1, axis=0)], axis=0)
    ey = np.concatenate([ey, ey[:, ::-1]], axis=1)
    Gx = np.fft.rfft2(ex)
    Gy = np.fft.rfft2(ey)
    wy = 2 * np.pi * np.fft.fftfreq(2 * H)[:, None]
    wx = 2 * np.pi * np.fft.rfftfreq(2 * W)[None, :]
    dx = np.exp(1j * wx) - 1.0  # spectrum of the forward difference
    dy = np.exp(1j * wy) - 1.0
    denom = np.abs(dx) ** 2 + np.abs(dy) ** 2
    denom[0, 0] = 1.0
    Z = (np.conj(dx) * Gx + np.conj(dy) * Gy) / denom
    Z[0, 0] = 0.0
    z = np.fft.irfft2(Z, s=(2 * H, 2 * W))[:H, :W]
    return _anchor(z, zero_mask)


def poisson_masked_lsq(
    gx: np.ndarray, gy: np.ndarray, mask: np.ndarray, *, boundary_zero: bool = True, reg: float = 1e-8
) -> np.ndarray:
    """Sparse least-squares integration using only the gradients inside ``mask``.

    Unknown heights are the mask pixels; pixels outside the mask are fixed at zero (``boundary_zero``,
    the gel is flat out of contact) and differences that touch them become Dirichlet constraints. A tiny
    Tikhonov term ``reg`` keeps isolated components solvable; heights outside the mask are 0.
    """
    import scipy.sparse as sp
    from scipy.sparse.linalg import spsolve

    gx, gy = _check(gx, gy)
    m = np.asarray(mask, dtype=bool)
    if m.shape != gx.shape:
        raise InputError("mask size differs from the gradients", field="mask", expected=str(gx.shape), got=m.shape)
    H, W = gx.shape
    z = np.zeros((H, W))
    n = int(m.sum())
    if n == 0:
        return z
    idx = -np.ones((H, W), dtype=np.int64)
    idx[m] = np.arange(n)
    rows, cols, vals, rhs = [], [], [], []
    r = 0
    for axis, g in ((1, gx), (0, gy)):
        if g.shape[axis] < 2:
            continue
        a = (slice(None), slice(None, -1)) if axis == 1 else (slice(None, -1), slice(None))
        b = (slice(None), slice(1, None)) if axis == 1 else (slice(1, None), slice(None))
        ia, ib = idx[a], idx[b]
        half = 0.5 * (g[a] + g[b])
        ma, mb = m[a], m[b]
        use = (ma | mb) if boundary_zero else (ma & mb)
        if not boundary_zero:
            half = np.where(use, half, 0.0)
        ia, ib, half, ma, mb = ia[use], ib[use], half[use], ma[use], mb[use]
        k = len(half)
        eq = np.arange(r, r + k)
        # equation: z[b] - z[a] = half, with z = 0 for pixels outside the mask
        rows += [eq[mb], eq[ma]]
        cols += [ib[mb], ia[ma]]
        vals += [np.ones(mb.sum()), -np.ones(ma.sum())]
        rhs.append(half)
        r += k
    if r == 0:
        return z
    A = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(r, n))
    bvec = np.concatenate(rhs)
    N = (A.T @ A + reg * sp.identity(n)).tocsc()
    sol = spsolve(N, A.T @ bvec)
    if not np.all(np.isfinite(sol)):
        sol = np.nan_to_num(sol)
    z[m] = sol
    if not boundary_zero:
        z[m] -= np.median(sol)
    return z


SOLVERS = {"dct": poisson_dct, "fft": poisson_fft}


def integrate(gx: np.ndarray, gy: np.ndarray, method: str = "dct", mask: np.ndarray | None = None) -> np.ndarray:
    """Dispatch: ``dct`` | ``fft`` | ``lsq`` (``lsq`` needs ``mask``; without one it integrates everywhere)."""
    if method == "lsq":
        if mask is None:
            mask = np.ones(np.shape(gx), dtype=bool)
            return poisson_masked_lsq(gx, gy, mask, boundary_zero=False)
        return poisson_masked_lsq(gx, gy, mask)
    try:
        return SOLVERS[method](gx, gy)
    except KeyError:
        raise InputError("unknown Poisson solver", field="method", expected="dct | fft | lsq", got=method) from None
