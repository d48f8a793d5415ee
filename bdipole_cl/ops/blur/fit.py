"""Sums of separable texel-integrated Gaussians: the fits of the ``gaussians`` blur and the
shared basis of the texture-varying blur (d'Eon et al. 2007's texture-space diffusion).

One basis rule (``basis_sigmas``: geometric sigmas from BASIS_MIN_SIGMA to half the radius), one
column layout (``basis_columns``: each separable kernel's quadrant) and one NNLS row weighting
(``row_weights``: relative, times the cells a quadrant cell stands for) serve both.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...caches import ByteCache
from ...signals import check_stop
from .weights import channel_kernel, multiplicity, unfold_quadrant

FIT_CACHE = ByteCache("gaussian fits", 16 << 20)
MAX_GAUSSIANS = 16
BASIS_MIN_SIGMA = 0.15      # texels: narrower texel-integrated Gaussians are ~ a delta
BASIS_RATIO = 1.5           # texture-varying basis: geometric ratio of the sigmas (densified if
                            # the fit needs)
MAX_BASIS = 24


def gaussian_1d(sigma, radius):
    """Texel-integrated normalized Gaussian on [-radius, radius] (erf differences)."""
    from math import erf, sqrt
    edges = np.arange(-radius, radius + 2) - 0.5
    cdf = np.array([0.5 * (1.0 + erf(e / (sqrt(2.0) * sigma))) for e in edges])
    g = np.diff(cdf)
    return g / g.sum()


def basis_sigmas(radius, count):
    """``count`` sigmas (texels), geometric from BASIS_MIN_SIGMA to half the kernel radius (at
    least 1): the one basis rule."""
    return np.geomspace(BASIS_MIN_SIGMA, max(1.0, radius / 2.0), count)


def basis_count(radius, ratio):
    """How many sigmas ``basis_sigmas`` needs for a geometric ratio of at most ``ratio``."""
    hi = max(1.0, radius / 2.0)
    return max(2, int(np.ceil(np.log(hi / BASIS_MIN_SIGMA) / np.log(ratio))) + 1)


def basis_kernels(sigmas, radius):
    """The 1D texel-integrated Gaussians of the basis, each on [-r_j, r_j], r_j <= radius."""
    return tuple(gaussian_1d(s, int(min(radius, np.ceil(4.0 * s)))) for s in sigmas)


def basis_columns(kernels, radius):
    """The quadrant (offsets 0..K) of each separable basis kernel, flattened as columns."""
    cols = []
    for taps in kernels:
        r = (len(taps) - 1) // 2
        half = np.zeros(radius + 1)
        half[:r + 1] = taps[r:]
        cols.append(np.outer(half, half).ravel())
    return np.stack(cols, axis=1)


def row_weights(target):
    """NNLS row weights of a kernel quadrant: relative (absolute below 1e-4 of the peak),
    times the square root of the kernel cells each quadrant cell stands for."""
    count_w = np.sqrt(multiplicity(target.shape[0] - 1))
    return (count_w / np.maximum(target, 1e-4 * target.max())).ravel()


@dataclass(frozen=True)
class GaussianFit:
    sigmas: tuple
    weights: tuple
    radii: tuple
    l1_error: float          # sum |W_fit - W| / Rd: bounds |error| / (max E * Rd)
    near_rel_error: float    # max relative error of the cells within NEAR_CELLS of the centre


#: near cells (within this many texels of the centre) must fit to NEAR_REL_TOL relative
NEAR_CELLS, NEAR_REL_TOL = 2, 1e-3


@FIT_CACHE.memoize
def fit_gaussians(alpha, sigma_t_texels, eta, tol, exact=False):
    """Non-negative least-squares fit of the exact weights by separable Gaussians.

    The residual is weighted relatively (``row_weights``), so the peak and the near cells fit
    as well as the tail. The weights are scaled to sum to Rd: the fitted kernel conserves
    energy exactly, as the exact one does; ``l1_error`` is the normalized fit's. The basis
    (``basis_sigmas``) grows until the L1 error is <= tol and the near cells are within
    NEAR_REL_TOL, or MAX_GAUSSIANS is reached; the best fit found is returned.
    """
    from scipy.optimize import nnls
    ck = channel_kernel(alpha, sigma_t_texels, eta, tol, exact)
    k = ck.radius
    target = ck.weights[k:, k:] / ck.rd                      # one quadrant, symmetric
    row_w = row_weights(target)
    near = slice(0, min(k, NEAR_CELLS) + 1)
    best, best_key = None, None
    for count in range(2, MAX_GAUSSIANS + 1):
        check_stop()
        sigmas = basis_sigmas(k, count)
        kernels = basis_kernels(sigmas, k)
        radii = [(len(taps) - 1) // 2 for taps in kernels]
        cols = basis_columns(kernels, k)
        try:
            coef, _ = nnls(cols * row_w[:, None], target.ravel() * row_w,
                           maxiter=100 * cols.shape[1])
        except RuntimeError:           # this basis did not converge (a very tight tol): the
            continue                   # next, wider one may
        # each separable Gaussian sums to 1, so the fitted kernel sums to sum(coef): scaled to
        # 1, it keeps the energy (M = E Rd for constant E) however poorly the shape fits
        coef /= coef.sum()
        fitted = (cols @ coef).reshape(target.shape)
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
    if best is None:
        raise ValueError(f"method='gaussians': no Gaussian basis of up to {MAX_GAUSSIANS} "
                         f"converged at tol={tol:g} (alpha' {alpha:.6g}, sigma_t' "
                         f"{sigma_t_texels:.6g} per texel): use method 'fft' or 'direct', or a "
                         f"larger tol")
    return best


def fit_node(target, columns):
    """Non-negative weights (summing to 1) of the basis columns for one node's kernel quadrant,
    and the L1 error of the fitted kernel (unfolded)."""
    from scipy.optimize import nnls
    check_stop()
    rw = row_weights(target)
    coef, _ = nnls(columns * rw[:, None], target.ravel() * rw, maxiter=100 * columns.shape[1])
    coef /= coef.sum()
    fitted = (columns @ coef).reshape(target.shape)
    return coef, float(np.abs(unfold_quadrant(fitted - target)).sum())
