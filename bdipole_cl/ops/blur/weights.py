"""Exact texel-integrated weights of the Better Dipole profile R(r) (docs/model.md "Texel-
integrated weights").

Irradiance is constant over each texel (side ``texel_size``). The exitance at the centre x of a
texel is ``M(x) = sum_cells E(cell) * Integral_cell R(|x - y|) dy``: a discrete convolution
with texel-integrated weights ``W(i, j)``. The weights are exact (float64, host): the integral
of R over a rectangle [0, a] x [0, b] is ``(1/2 pi) Int CDF(rho(theta)) dtheta`` along its two
far edges (``rho`` the distance to the edge, CDF the closed-form radial energy), a smooth 1D
Gauss-Legendre integral, and cells follow by inclusion-exclusion on the corner grid. A point
sample at the centre would be badly wrong (albedo 0.8, mfp 1.5 texels, eta 1.4: centre weight
0.497, point sample 3.64).

The kernel is truncated at the radius where the energy left out, ``profile_tail``, is
``tol * Rd``, then scaled so that its weights sum to Rd exactly: a constant irradiance E
returns E * Rd in the interior, and no energy is lost or made (energy-conserving).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...caches import ByteCache
from ...physics import reference as ref
from ...signals import check_stop

#: channel kernels kept across calls (a radius-2048 kernel is 134 MB: a few at most)
KERNEL_CACHE = ByteCache("channel kernels", 512 << 20)


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


def unfold_quadrant(quad):
    """The (2K+1)^2 radially symmetric kernel from its quadrant quad[i, j], i, j = 0..K
    (offsets >= 0), mirrored in x and y."""
    k = quad.shape[0] - 1
    w = np.zeros((2 * k + 1, 2 * k + 1))
    w[k:, k:] = quad
    w[k:, :k + 1] = quad[:, ::-1]
    w[:k + 1, :] = w[::-1, :][:k + 1, :]
    return w


def multiplicity(radius):
    """How many kernel cells each quadrant cell stands for (centre 1, axis 2, others 4)."""
    m = np.full(radius + 1, 2.0)
    m[0] = 1.0
    return m[:, None] * m[None, :]


def quadrant_sum(quad):
    """Sum of the unfolded kernel of quadrant quad (axis cells twice, the centre once)."""
    return float((quad * multiplicity(quad.shape[0] - 1)).sum())


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


def quadrant_weights(alpha, sigma_t_texels, eta, k, exact=False, su=1.0, sv=1.0):
    """Texel-integrated weights ``quad[i, j] = Int_cell(i, j) R(|y|) dy``, i, j = 0..k, of the
    whole cells centred at (i, j) texels (float64). ``su``, ``sv``: the lengths of a texel
    step along columns (u) and rows (v) in the unit of ``sigma_t_texels`` (a stretched
    texel's surface rectangle, docs/stretch.md; 1: square texels)."""
    n = min(k, EXACT_CELLS)
    # corners c_-1 = 0, c_i = i + 1/2; cell i spans [c_{i-1}, c_i] (cell 0 only its half)
    c = np.concatenate([[0.0], np.arange(n + 1) + 0.5])
    f = quadrant_integral(sv * c[:, None], su * c[None, :], alpha, sigma_t_texels, eta, exact)
    near = f[1:, 1:] - f[:-1, 1:] - f[1:, :-1] + f[:-1, :-1]
    m = np.ones(n + 1)
    m[0] = 2.0
    quad = np.zeros((k + 1, k + 1))
    if k > n:
        x, w = np.polynomial.legendre.leggauss(GL_NODES)
        x, w = 0.5 * x, 0.5 * w
        pos = np.arange(k + 1)[:, None] + x[None, :]          # (k+1, GL) sample coordinates
        ww = w[:, None] * w[None, :] * (su * sv)
        for i0 in range(0, k + 1, 64):           # rows in chunks: bounded memory, and a stop
            check_stop()                         # obeyed within one chunk (~0.1 s at K = 500)
            r = np.hypot(sv * pos[i0:i0 + 64, None, :, None], su * pos[None, :, None, :])
            quad[i0:i0 + 64] = np.einsum("ijab,ab->ij", ref.profile(r, alpha, sigma_t_texels,
                                                                  eta, exact), ww)
    quad[:n + 1, :n + 1] = near * m[:, None] * m[None, :]
    return quad


@KERNEL_CACHE.memoize
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
    if kept > 0:
        w *= rd / kept
    else:                     # alpha' = 0: Rd = 0, no light comes out (not 0 / 0)
        w[...] = 0.0
    w.setflags(write=False)
    return ChannelKernel(w, k, rd, alpha, st, 1.0 - kept / rd if kept > 0 else 0.0, tol)
