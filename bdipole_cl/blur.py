"""Radial-profile blur of irradiance maps with the Better Dipole profile R(r), per channel.

Definition
----------
Irradiance is constant over each texel (side ``texel_size``). The exitance at the centre x of
a texel is ``M(x) = sum_cells E(cell) * Integral_cell R(|x - y|) dy``: a discrete convolution
with texel-integrated weights ``W(i, j)``. The weights are exact (float64, host): the integral
of R over a rectangle [0, a] x [0, b] is ``(1/2 pi) Int CDF(rho(theta)) dtheta`` along its two
far edges (``rho`` the distance to the edge, CDF the closed-form radial energy), a smooth 1D
Gauss-Legendre integral, and cells follow by inclusion-exclusion on the corner grid. A point
sample at the centre would be badly wrong (albedo 0.8, mfp 1.5 texels, eta 1.4: centre weight
0.497, point sample 3.64).

The kernel is truncated at the radius where the energy left out, ``profile_tail``, is
``tol * Rd``, then scaled so that its weights sum to Rd exactly: a constant irradiance E
returns E * Rd in the interior, and no energy is lost or made (energy-conserving).

Methods (``method=``)
---------------------
``direct``     2D gather of the exact weights (kernels/blur_direct.cl), local-memory tiles.
``gaussians``  the weights fitted (non-negative least squares) by a sum of separable
               texel-integrated Gaussians (d'Eon et al. 2007's texture-space diffusion);
               the fit's L1 error, a bound on the output error relative to max(E) * Rd, is
               reported and kept <= tol where the basis allows (kernels/blur_separable.cl).
``fft``        the exact weights by FFT convolution on the host (scipy.fft, all cores).
``auto``       the cheapest configuration (method, truncation tol) that ``bdipole-cl report``
               measured to meet ``tol`` on the workload of the nearest kernel radius
               (bdipole_cl/data/inversion_auto.json); BlurInfo says which and why. With
               ``auto``, ``tol`` is the error target relative to max(E) * Rd; with an
               explicit method it is the truncation tolerance (which bounds that error).

Parameters are scalars, per-channel tuples or HxW / HxWxC textures. With textures each texel
uses its own (the exit texel's) profile, through per-texel weights over a shared basis
(bdipole_cl/varying.py; methods fft, gaussians, auto).

NaN/Inf irradiance: ``on_invalid="raise"`` (default) reports them (count, first texel);
``"zero"`` treats them as unlit texels. HDR values are fine: weights sum to Rd <= 1.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
import pyopencl as cl

from . import reference as ref
from .device import build_options, get_program, get_runtime

BORDERS = ("clamp", "zero", "wrap")
BLUR_METHODS = ("auto", "direct", "gaussians", "fft")
#: kernels up to this radius (texels) use ``direct`` under ``auto``
AUTO_DIRECT_MAX_RADIUS = 4
MAX_GAUSSIANS = 16


# {{{ exact texel-integrated weights

def quadrant_integral(a, b, alpha, sigma_t, eta, exact=False, nodes=48):
    """``Int_[0,a]x[0,b] R(|y|) dy`` (a, b >= 0, broadcast) through the radial CDF.

    48 Gauss-Legendre nodes per edge: the integrands are smooth (no kink inside an edge), and
    the result is converged to < 1e-14 relative (checked against scipy dblquad in the tests).
    """
    x, w = np.polynomial.legendre.leggauss(nodes)
    a = np.asarray(a, np.float64)[..., None]
    b = np.asarray(b, np.float64)[..., None]
    th = np.arctan2(b, a)
    t1, w1 = 0.5 * th * (x + 1.0), 0.5 * th * w
    t2 = th + 0.5 * (0.5 * np.pi - th) * (x + 1.0)
    w2 = 0.5 * (0.5 * np.pi - th) * w
    with np.errstate(divide="ignore", invalid="ignore"):
        c1 = ref.profile_cdf(a / np.cos(t1), alpha, sigma_t, eta, exact)
        c2 = ref.profile_cdf(b / np.sin(t2), alpha, sigma_t, eta, exact)
        out = (np.sum(w1 * c1, -1) + np.sum(w2 * c2, -1)) / (2.0 * np.pi)
    return np.where((a[..., 0] == 0) | (b[..., 0] == 0), 0.0, out)


def truncation_radius(alpha, sigma_t, eta, tol, exact=False):
    """Smallest r (world units) with ``profile_tail(r) <= tol * Rd`` (bisection on the tail)."""
    total = ref.profile_tail(0.0, alpha, sigma_t, eta, exact)
    if not total > 0:
        return 0.0
    hi = 1.0 / sigma_t
    while ref.profile_tail(hi, alpha, sigma_t, eta, exact) > tol * total:
        hi *= 2.0
        if hi > 1e12 / sigma_t:
            raise ValueError(f"the profile (alpha'={alpha}, sigma_t'={sigma_t}) does not decay "
                             f"to tol={tol} of its energy: alpha' too close to 1")
    lo = 0.0
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if ref.profile_tail(mid, alpha, sigma_t, eta, exact) > tol * total:
            lo = mid
        else:
            hi = mid
    return hi


def unfold_quadrant(q):
    """The (2K+1)^2 radially symmetric kernel from its quadrant q[i, j], i, j = 0..K
    (offsets >= 0), mirrored in x and y."""
    k = q.shape[0] - 1
    w = np.zeros((2 * k + 1, 2 * k + 1))
    w[k:, k:] = q
    w[k:, :k + 1] = q[:, ::-1]
    w[:k + 1, :] = w[::-1, :][:k + 1, :]
    return w


@dataclass(frozen=True)
class ChannelKernel:
    """One channel's blur: the exact normalized weights and their provenance."""

    weights: np.ndarray      # (2K+1, 2K+1) float64, sums to rd
    radius: int              # K, texels
    rd: float                # total energy (memo eq. 3)
    alpha: float
    sigma_t: float           # per texel
    truncated: float         # energy beyond the truncation radius, before renormalizing, / rd
    tol: float               # the truncation tolerance it was built for


#: cells within this Chebyshev distance (texels) of the centre take the exact corner integrals;
#: farther cells a GL_NODES^2 Gauss-Legendre product rule of R itself. Far out the corner
#: integrals' inclusion-exclusion cancels (relative error 7e-4 at 90 texels for mfp 16), while
#: the product rule is within 2e-9 relative beyond 3 texels (measured over albedo 0.05..0.97,
#: mfp 0.5..16 texels; the profile is smooth on the texel scale there).
EXACT_CELLS, GL_NODES = 3, 5


def quadrant_weights(alpha, sigma_t_texels, eta, k, exact=False):
    """Texel-integrated weights ``q[i, j] = Int_cell(i, j) R(|y|) dy``, i, j = 0..k, of the
    whole cells centred at (i, j) texels (float64)."""
    n = min(k, EXACT_CELLS)
    # corners c_-1 = 0, c_i = i + 1/2; cell i spans [c_{i-1}, c_i] (cell 0 only its half)
    c = np.concatenate([[0.0], np.arange(n + 1) + 0.5])
    f = quadrant_integral(c[:, None], c[None, :], alpha, sigma_t_texels, eta, exact)
    near = f[1:, 1:] - f[:-1, 1:] - f[1:, :-1] + f[:-1, :-1]
    m = np.ones(n + 1)
    m[0] = 2.0
    q = np.zeros((k + 1, k + 1))
    if k > n:
        x, w = np.polynomial.legendre.leggauss(GL_NODES)
        x, w = 0.5 * x, 0.5 * w
        pos = np.arange(k + 1)[:, None] + x[None, :]          # (k+1, GL) sample coordinates
        ww = w[:, None] * w[None, :]
        for i0 in range(0, k + 1, 64):                           # rows in chunks: bounded memory
            rows = pos[i0:i0 + 64]
            r = np.hypot(rows[:, None, :, None], pos[None, :, None, :])
            q[i0:i0 + 64] = np.einsum("ijab,ab->ij", ref.profile(r, alpha, sigma_t_texels,
                                                                  eta, exact), ww)
    q[:n + 1, :n + 1] = near * m[:, None] * m[None, :]
    return q


@lru_cache(maxsize=64)
def channel_kernel(alpha, sigma_t_texels, eta, tol, exact=False, max_radius=2048):
    """The texel-integrated weights of one channel; ``sigma_t_texels`` = sigma_t' * texel."""
    alpha, st = float(alpha), float(sigma_t_texels)
    rd = float(ref.rd(alpha, eta, exact))
    r_t = truncation_radius(alpha, st, eta, tol, exact)
    k = int(min(np.ceil(r_t - 0.5), max_radius)) if r_t > 0.5 else 0
    if r_t - 0.5 > max_radius:
        raise ValueError(f"truncation radius {r_t:.0f} texels exceeds max_radius={max_radius}: "
                         f"raise tol or the texel size")
    w = unfold_quadrant(quadrant_weights(alpha, st, eta, k, exact))
    kept = w.sum()
    w *= rd / kept
    w.setflags(write=False)
    return ChannelKernel(w, k, rd, alpha, st, 1.0 - kept / rd, tol)

# }}}


# {{{ sum of separable Gaussians

def gaussian_1d(sigma, radius):
    """Texel-integrated normalized Gaussian on [-radius, radius] (erf differences)."""
    from math import erf, sqrt
    edges = np.arange(-radius, radius + 2) - 0.5
    cdf = np.array([0.5 * (1.0 + erf(e / (sqrt(2.0) * sigma))) for e in edges])
    g = np.diff(cdf)
    return g / g.sum()


@dataclass(frozen=True)
class GaussianFit:
    sigmas: tuple
    weights: tuple
    radii: tuple
    l1_error: float          # sum |W_fit - W| / Rd: bounds |error| / (max E * Rd)
    near_rel_error: float    # max relative error of the cells within NEAR_CELLS of the centre


#: near cells (within this many texels of the centre) must fit to NEAR_REL_TOL relative
NEAR_CELLS, NEAR_REL_TOL = 2, 1e-3


@lru_cache(maxsize=64)
def fit_gaussians(alpha, sigma_t_texels, eta, tol, exact=False):
    """Non-negative least-squares fit of the exact weights by separable Gaussians.

    The residual is weighted relatively (absolute below 1e-4 of the peak), so the peak and the
    near cells fit as well as the tail. The basis (geometric sigmas from 0.2 texel to the
    truncation radius) grows until the L1 error is <= tol and the near cells are within
    NEAR_REL_TOL, or MAX_GAUSSIANS is reached; the best fit found is returned.
    """
    from scipy.optimize import nnls
    ck = channel_kernel(alpha, sigma_t_texels, eta, tol, exact)
    k = ck.radius
    target = ck.weights[k:, k:] / ck.rd                      # one quadrant, symmetric
    mult = np.ones(k + 1)
    mult[0] = 0.5                                            # the axis is shared by 2 quadrants
    count_w = np.sqrt(mult[:, None] * mult[None, :] * 4.0)   # cells each quadrant cell stands for
    row_w = count_w / np.maximum(target, 1e-4 * target.max())
    near = slice(0, min(k, NEAR_CELLS) + 1)
    best, best_key = None, None
    for count in range(2, MAX_GAUSSIANS + 1):
        sigmas = np.geomspace(0.15, max(1.0, k / 2.0), count)
        radii = [int(min(k, np.ceil(4.0 * s))) for s in sigmas]
        cols = []
        for s, r in zip(sigmas, radii):
            g = np.zeros(2 * k + 1)
            g[k - r:k + r + 1] = gaussian_1d(s, r)
            cols.append(np.outer(g, g)[k:, k:])
        a_mat = np.stack([(c * row_w).ravel() for c in cols], axis=1)
        coef, _ = nnls(a_mat, (target * row_w).ravel())
        fitted = sum(cw * c for cw, c in zip(coef, cols))
        l1 = float(np.abs(unfold_quadrant(fitted) - ck.weights / ck.rd).sum())
        near_rel = float(np.abs(fitted[near, near] / target[near, near] - 1).max())
        keep = coef > 0
        fit = GaussianFit(tuple(sigmas[keep]), tuple(coef[keep] * ck.rd),
                          tuple(np.array(radii)[keep]), l1, near_rel)
        key = max(l1 / tol, near_rel / NEAR_REL_TOL)
        if best is None or key < best_key:
            best, best_key = fit, key
        if key <= 1.0:
            break
    return best

# }}}


def _channel_values(value, nchan, name):
    v = np.atleast_1d(np.asarray(value, np.float64))
    if v.ndim > 1 or (v.size not in (1, nchan)):
        if v.ndim > 1:
            raise ValueError(f"{name}: one value or one per channel here; texture-varying "
                             f"parameters go to blur() (bdipole_cl.varying)")
        raise ValueError(f"{name} has {v.size} values for {nchan} channels")
    return np.broadcast_to(v, (nchan,))


def channel_parameters(nchan, *, albedo=None, mfp=None, eta=1.4, texel_size=1.0, alpha=None,
                       sigma_t=None, exact=False):
    """Per-channel (alpha', sigma_t' per texel, eta) from albedo + mfp (memo's mapping, float64)
    or directly from alpha' + sigma_t' (per world unit)."""
    etas = _channel_values(eta, nchan, "eta")
    if alpha is not None or sigma_t is not None:
        if alpha is None or sigma_t is None or albedo is not None or mfp is not None:
            raise ValueError("give either albedo and mfp, or alpha and sigma_t")
        a = _channel_values(alpha, nchan, "alpha")
        st = _channel_values(sigma_t, nchan, "sigma_t")
    else:
        if albedo is None or mfp is None:
            raise ValueError("give albedo and mfp (or alpha and sigma_t)")
        rd = _channel_values(albedo, nchan, "albedo")
        ld = _channel_values(mfp, nchan, "mfp")
        if np.any(~((rd > 0) & (rd < 1))) or np.any(~((ld > 0) & np.isfinite(ld))):
            raise ValueError(f"albedo must be in (0, 1) and mfp positive and finite; got "
                             f"albedo={rd.tolist()}, mfp={ld.tolist()}")
        sa = np.empty(nchan)
        ss = np.empty(nchan)
        for c in range(nchan):
            sa[c], ss[c] = ref.albedo_to_coefficients(rd[c], ld[c], etas[c], exact)
        st = sa + ss
        a = ss / st
    if not np.all(texel_size > 0):
        raise ValueError(f"texel_size={texel_size!r} must be > 0")
    return [(float(a[c]), float(st[c] * texel_size), float(etas[c])) for c in range(nchan)]


def _check_irradiance(irradiance, on_invalid):
    e = np.asarray(irradiance)
    if e.ndim == 2:
        e = e[..., None]
    if e.ndim != 3:
        raise ValueError(f"irradiance must be HxW or HxWxC, got shape {e.shape}")
    e = np.ascontiguousarray(e, dtype=np.float32)
    bad = ~np.isfinite(e)
    if np.any(bad):
        n = int(bad.sum())
        y, x, c = (int(i) for i in np.argwhere(bad)[0])
        if on_invalid == "raise":
            raise ValueError(f"{n} NaN/Inf irradiance texel(s); first at x={x}, y={y}, "
                             f"channel {c}: {e[y, x, c]!r} (on_invalid='zero' treats them as 0)")
        if on_invalid != "zero":
            raise ValueError(f"on_invalid={on_invalid!r}: expected 'raise' or 'zero'")
        e = np.where(bad, np.float32(0), e)
    return e


class _Blur:
    """Device buffers and programs for one image."""

    def __init__(self, e, border, rt):
        self.rt = rt
        self.h, self.w, self.c = e.shape
        opts = build_options({f"BORDER_{border.upper()}": None})
        self.direct = cl.Kernel(get_program(rt, "blur_direct", opts), "blur_direct")
        sep = get_program(rt, "blur_separable", opts)
        self.rows, self.cols = cl.Kernel(sep, "blur_rows"), cl.Kernel(sep, "blur_cols_add")
        self.cols_varying = cl.Kernel(get_program(
            rt, "blur_separable", opts + ("-DPER_TEXEL_WEIGHT",)), "blur_cols_add")
        mf = cl.mem_flags
        self.src = cl.Buffer(rt.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=e)
        self.dst = cl.Buffer(rt.context, mf.READ_WRITE, max(e.nbytes, 4))
        self.tmp = cl.Buffer(rt.context, mf.READ_WRITE, max(self.h * self.w * 4, 4))
        cl.enqueue_fill_buffer(rt.queue, self.dst, np.float32(0), 0, max(e.nbytes, 4))

    def _buf(self, array):
        return cl.Buffer(self.rt.context, cl.mem_flags.READ_ONLY | cl.mem_flags.COPY_HOST_PTR,
                         hostbuf=np.ascontiguousarray(array, np.float32))

    def run_direct(self, c, ck: ChannelKernel):
        tile = 16
        gx = -(-self.w // tile) * tile
        gy = -(-self.h // tile) * tile
        self.direct(self.rt.queue, (gx, gy), (tile, tile), self.src, self.dst,
                    self._buf(ck.weights), np.int32(self.w), np.int32(self.h),
                    np.int32(self.c), np.int32(c), np.int32(ck.radius))

    def run_gaussians(self, c, fit: GaussianFit):
        for sigma, weight, radius in zip(fit.sigmas, fit.weights, fit.radii):
            g = self._buf(gaussian_1d(sigma, radius))
            args = (np.int32(self.w), np.int32(self.h), np.int32(self.c), np.int32(c),
                    np.int32(radius))
            self.rows(self.rt.queue, (self.w, self.h), None, self.src, self.tmp, g, *args)
            self.cols(self.rt.queue, (self.w, self.h), None, self.tmp, self.dst, g, *args,
                      np.float32(weight))

    def run_varying(self, c, plan, weights):
        """Texture-varying parameters: each basis Gaussian of the VaryingPlan blurred by the
        separable kernels and added with its per-texel weight plane (w_j(x) * Rd(x))."""
        for g, plane in zip(plan.kernels, weights):
            radius = (len(g) - 1) // 2
            args = (np.int32(self.w), np.int32(self.h), np.int32(self.c), np.int32(c),
                    np.int32(radius))
            self.rows(self.rt.queue, (self.w, self.h), None, self.src, self.tmp, self._buf(g),
                      *args)
            self.cols_varying(self.rt.queue, (self.w, self.h), None, self.tmp, self.dst,
                              self._buf(g), *args, self._buf(plane))

    def result(self):
        out = np.empty((self.h, self.w, self.c), np.float32)
        cl.enqueue_copy(self.rt.queue, out, self.dst)
        self.rt.queue.finish()
        return out


def fft_shape(shape, k):
    """The fast even FFT shape (>= the image padded by k) for the circular convolution of the
    padded image with a (2k+1)^2 kernel: the wrap-around reaches only the first 2k rows and
    columns of the result, which are the padding (the image is at [2k, 2k + n) with the kernel
    at [0, 2k], at [k, k + n) with it centred on 0)."""
    import scipy.fft as sfft

    def even_fast(n):          # even, so that an even kernel's spectrum is a DCT-I
        n = sfft.next_fast_len(n, real=True)
        return n if n % 2 == 0 else even_fast(n + 1)
    return [even_fast(n + 2 * k) for n in shape]


def fft_padded(e2d, k, border):
    """The image padded by k texels by the border rule, and its ``fft_shape``."""
    mode = {"clamp": "edge", "zero": "constant", "wrap": "wrap"}[border]
    return np.pad(e2d, k, mode=mode), fft_shape(e2d.shape, k)


def fft_blur_channel(e2d, weights, border):
    """Exact-weights convolution of one channel by FFT (scipy.fft, all cores), with the same
    border rule as the kernels (the image padded by the kernel radius)."""
    import scipy.fft as sfft
    k = (weights.shape[0] - 1) // 2
    pad, shape = fft_padded(e2d.astype(np.float64), k, border)
    spec = sfft.rfft2(pad, shape, workers=-1) * sfft.rfft2(weights, shape, workers=-1)
    full = sfft.irfft2(spec, shape, workers=-1)
    h, w = e2d.shape
    return full[2 * k:2 * k + h, 2 * k:2 * k + w]


@dataclass
class BlurInfo:
    """What ``blur`` did per channel: method, radius, and its error bound relative to
    max(E) * Rd (truncation tol for exact weights; the fit's L1 error for gaussians)."""

    channels: list


def _halo_rows(y0, y1, k, height, border):
    """Row indices of band [y0, y1) with k halo rows each side, by the border rule
    (-1: a zero row)."""
    rows = np.arange(y0 - k, y1 + k)
    if border == "clamp":
        return np.clip(rows, 0, height - 1)
    if border == "wrap":
        return rows % height
    return np.where((rows >= 0) & (rows < height), rows, -1)


def blur(irradiance, *, albedo=None, mfp=None, eta=1.4, texel_size=1.0, alpha=None,
         sigma_t=None, tol=1e-3, method="auto", border="clamp", exact=False,
         on_invalid="raise", return_info=False, max_memory=None, device=None):
    """Texture-space subsurface scattering: ``irradiance`` (HxW or HxWxC) blurred by R(r).

    ``albedo`` (Rd) and ``mfp`` (ld = 1/mu_tr, same unit as ``texel_size``), or ``alpha``
    (alpha') and ``sigma_t`` (sigma_t', 1/unit): scalars, per channel, or HxW(xC) textures
    (texture-varying: the exit texel's profile, see bdipole_cl/varying.py); ``eta`` per
    channel. Returns the exitance, HxWxC float32 (and a BlurInfo with ``return_info``). See the
    module docstring.

    ``max_memory`` (bytes): blur in bands of rows, each with a halo of the truncation radius
    taken by the border rule, so the working set stays bounded; the result is the same as in
    one piece (the halo holds every texel an interior kernel reaches).

    ``device``: where to run (None, a string such as ``"intel"``, a pyopencl Device or a
    Runtime; see ``bdipole_cl.device``).
    """
    if method not in BLUR_METHODS:
        raise ValueError(f"method={method!r}: expected one of {BLUR_METHODS}")
    if not 0 < tol < 1:
        raise ValueError(f"tol={tol!r}: expected 0 < tol < 1")
    if border not in BORDERS:
        raise ValueError(f"border={border!r}: expected one of {BORDERS}")
    e = _check_irradiance(irradiance, on_invalid)
    if e.shape[0] == 0 or e.shape[1] == 0:
        raise ValueError(f"irradiance is empty (shape {np.shape(irradiance)}): nothing to blur")
    rt = get_runtime(device)
    if any(np.ndim(v) >= 2 for v in (albedo, mfp, alpha, sigma_t, eta)):
        from .varying import blur_textured
        return blur_textured(e, method=method, tol=tol, border=border, exact=exact,
                             return_info=return_info, max_memory=max_memory, albedo=albedo,
                             mfp=mfp, eta=eta, texel_size=texel_size, alpha=alpha,
                             sigma_t=sigma_t, rt=rt)
    params, plans = _channel_plans(e.shape[2], method=method, tol=tol, exact=exact,
                                   albedo=albedo, mfp=mfp, eta=eta, texel_size=texel_size,
                                   alpha=alpha, sigma_t=sigma_t)
    h, w, nch = e.shape
    k = max(ck.radius for _, ck, _ in plans)
    # working set per band row: input, output, a temporary and the FFT's float64 copies
    per_row = w * nch * 4 * 8
    rows = h if max_memory is None else max(1, int(max_memory // per_row) - 2 * k)
    if rows >= h:
        return _blur_whole(e, params, plans, border, exact, return_info, rt)
    out = np.empty_like(e)
    info = None
    for y0 in range(0, h, rows):
        y1 = min(y0 + rows, h)
        idx = _halo_rows(y0, y1, k, h, border)
        band = np.where((idx >= 0)[:, None, None], e[np.maximum(idx, 0)], np.float32(0))
        res, info = _blur_whole(band, params, plans, border, exact, True, rt)
        out[y0:y1] = res[k:k + (y1 - y0)]
    return (out, info) if return_info else out


def _auto_choice(ck, alpha, sigma_t, eta, tol, exact):
    """``method="auto"``: the cheapest configuration measured by ``bdipole-cl report`` whose
    max error (relative to max(E) * Rd) is <= tol, on the workload of the nearest radius; without
    data, ``direct`` up to AUTO_DIRECT_MAX_RADIUS and ``fft`` above, at truncation tol."""
    from .report import auto_blur_config
    choice = auto_blur_config(ck.radius, tol)
    if choice is None:
        m = "direct" if ck.radius <= AUTO_DIRECT_MAX_RADIUS else "fft"
        return m, ck, {"rule": "no measured configuration meets tol: radius rule"}
    method, trunc_tol, entry = choice
    if trunc_tol != tol:
        ck = channel_kernel(alpha, sigma_t, eta, trunc_tol, exact)
    return method, ck, {"measured_error": entry["max_error"], "truncation_tol": trunc_tol,
                        "measured_ms": entry["median_s"] * 1e3,
                        "workload_radius": entry["radius"]}


#: the physical parameters of ``blur`` (passed on to ``channel_parameters``)
PARAM_KEYS = ("albedo", "mfp", "eta", "texel_size", "alpha", "sigma_t")


def _channel_plans(nchan, *, method, tol, exact, **physical):
    """Per-channel parameters and plans (method, ChannelKernel, auto record): the one place
    that decides each channel's kernel, and so the halo of banded blurs."""
    params = channel_parameters(nchan, exact=exact, **physical)
    return params, [_plan(method, a, st, et, tol, exact) for a, st, et in params]


def _plan(method, alpha, sigma_t, eta, tol, exact):
    """(method, ChannelKernel, auto record or None) of one channel."""
    ck = channel_kernel(alpha, sigma_t, eta, tol, exact)
    if method == "auto":
        return _auto_choice(ck, alpha, sigma_t, eta, tol, exact)
    return method, ck, None


def _blur_whole(e, params, plans, border, exact, return_info, rt):
    """``blur`` on one in-memory image (or band with its halo), channel plans resolved."""
    ctx = None
    fft_out = {}
    info = []
    for c, ((a, st, et), (m, ck, picked)) in enumerate(zip(params, plans)):
        tol = ck.tol
        if m in ("direct", "gaussians") and ctx is None:
            ctx = _Blur(e, border, rt)
        if m == "direct":
            ctx.run_direct(c, ck)
            bound = tol
        elif m == "gaussians":
            fit = fit_gaussians(a, st, et, tol, exact)
            ctx.run_gaussians(c, fit)
            bound = tol + fit.l1_error
        else:
            fft_out[c] = fft_blur_channel(e[..., c], ck.weights, border)
            bound = tol
        entry = {"channel": c, "method": m, "radius": ck.radius, "rd": ck.rd,
                 "error_bound": bound}
        if picked is not None:
            entry["auto"] = picked
            entry["error_bound"] = max(bound, picked.get("measured_error", 0.0))
        info.append(entry)
    out = ctx.result() if ctx is not None else np.empty_like(e)
    for c, v in fft_out.items():
        out[..., c] = v
    return (out, BlurInfo(info)) if return_info else out


def _read_rows(reader, idx):
    """Rows ``idx`` (-1: zeros) of an open image, reading each contiguous run once."""
    spec = reader.spec
    out = np.zeros((len(idx), spec.width, spec.nchannels), np.float32)
    valid = np.flatnonzero(idx >= 0)
    if valid.size:
        lo, hi = int(idx[valid].min()), int(idx[valid].max()) + 1
        if hi - lo <= 2 * len(idx):
            block = reader.read_band(lo, hi)
            out[valid] = block[idx[valid] - lo]
        else:                                   # wrap halos: the two ends separately
            for j in valid:
                out[j] = reader.read_band(int(idx[j]), int(idx[j]) + 1)[0]
    return out


def read_parameter_texture(path, what, colour=False, colorspace="auto"):
    """A parameter texture (albedo, mfp, alpha', sigma_t') as HxWxC float32, alpha dropped;
    ``colour``: integer-encoded files are decoded to linear (albedo), else read as data."""
    from .textures import _Reader, source_colorspace, to_linear
    reader = _Reader(path, what)
    try:
        cols, _ = reader.channels()
        px = reader.read_band(0, reader.spec.height)[..., cols]
        space = source_colorspace(reader.spec, colorspace) if colour else None
        return to_linear(px, space) if space is not None else px
    finally:
        reader.close()


def blur_file(path, output, *, colorspace="auto", half=False, max_memory=256 << 20,
              sources=None, cancel=None, **kwargs):
    """``bdipole-cl blur``: blur an irradiance image file into an EXR, streamed in bands of
    rows with a halo of the truncation radius (memory bounded by ``max_memory``). Integer
    files are decoded to linear as in ``process_textures``; alpha is copied through.

    ``sources``: {parameter name: file} of parameter textures given as arrays, so that errors
    name the file they come from and ``output`` never overwrites one of them. ``cancel`` (threading.Event): when set, the next band raises Cancelled
    and the temporary output is removed."""
    import os
    from pathlib import Path

    from .textures import (Cancelled, TextureError, _output_spec, _Reader, _Writer,
                           check_output_format, source_colorspace, to_linear)
    check_output_format(output)
    sources = dict(sources or {})
    for src in (path, *sources.values()):
        if os.path.exists(output) and os.path.exists(src) and os.path.samefile(output, src):
            raise ValueError(f"{output}: the output would overwrite the input {src}")
    reader = _Reader(path, "irradiance")
    writer = None
    try:
        spec = reader.spec
        colour, alpha_ch = reader.channels()
        space = source_colorspace(spec, colorspace)
        border = kwargs.get("border", "clamp")
        kwargs["device"] = get_runtime(kwargs.get("device"))   # resolved once for all bands
        varying = any(np.ndim(kwargs.get(key)) >= 2 for key in PARAM_KEYS)
        if varying:
            # parameter textures: one global plan, so the whole image is read and ``blur``
            # bands it internally (its halo follows that plan)
            k, rows = 0, spec.height
            kwargs["max_memory"] = max_memory
        else:
            # the halo follows each channel's plan (auto may pick a tighter truncation than tol)
            _, plans = _channel_plans(
                len(colour), method=kwargs.get("method", "auto"), tol=kwargs.get("tol", 1e-3),
                exact=kwargs.get("exact", False),
                **{key: kwargs[key] for key in PARAM_KEYS if key in kwargs})
            k = max(ck.radius for _, ck, _ in plans)
            per_row = spec.width * spec.nchannels * 4 * 10
            rows = max(1, int(max_memory // per_row) - 2 * k)
        if spec.tile_height and not varying:
            rows = max(spec.tile_height, rows - rows % spec.tile_height)
        names = [spec.channelnames[c] for c in colour]
        if alpha_ch >= 0:
            names.append(spec.channelnames[alpha_ch])
        info = None
        for y0 in range(0, spec.height, rows):
            if cancel is not None and cancel.is_set():
                raise Cancelled(f"{path}: interrupted; nothing written")
            y1 = min(y0 + rows, spec.height)
            px = _read_rows(reader, _halo_rows(y0, y1, k, spec.height, border))
            e = px[..., colour]
            if space is not None:
                e = to_linear(e, space)
            out, info = blur(e, return_info=True, **kwargs)
            parts = [out[k:k + y1 - y0]]
            if alpha_ch >= 0:
                parts.append(px[k:k + y1 - y0, :, alpha_ch:alpha_ch + 1])
            if writer is None:
                meta = {key: (v if np.ndim(v) < 2 else "texture") for key, v in kwargs.items()
                        if key in PARAM_KEYS + ("tol", "border")}
                meta["methods"] = ",".join(f"{c['method']}(r={c['radius']})"
                                           for c in info.channels)
                meta["source"] = str(path)
                Path(output).parent.mkdir(parents=True, exist_ok=True)
                writer = _Writer(output, _output_spec(
                    spec, names, len(names) - 1 if alpha_ch >= 0 else -1, half, meta))
            writer.write_band(y0, y1, np.concatenate(parts, axis=-1))
        writer.commit()
        writer = None
        return info
    except (OSError, ValueError) as exc:
        where = sources.get(getattr(exc, "parameter", None), path)
        raise TextureError(f"{where}: {exc}") from exc
    finally:
        if writer is not None:
            writer.abort()
        reader.close()
