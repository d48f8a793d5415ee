"""Float64 NumPy reference of the Better Dipole (d'Eon 2012) and its inversion (Hery TM 12-11).

This module is the single source of truth for every test and every host-side table. It is
vectorized (NumPy broadcasting on all arguments) and written for accuracy, not speed. The
Fresnel moments and the eta ranges are in ``physics.fresnel``, the models' names in
``physics.models``; both are re-exported here.

Notation (as in docs/model.md and the memo)
-------------------------------------------
``alpha``  reduced albedo alpha' = sigma_s' / sigma_t'            [1]
``rho``    1 - alpha' = sigma_a / sigma_t' (the well-conditioned unknown near alpha' = 1) [1]
``q``      sqrt(rho)                                               [1]
``sigma_t`` reduced extinction sigma_t'                            [1/length]
``eta``    relative index of refraction, medium over outside       [1]
``rd``     diffuse reflectance (the painted "albedo"), memo eq. 3  [1]

Two models share the inversion machinery (``model=``, ``physics.models.MODEL``):

* ``"better"``: the Better Dipole, memo eqs. 1-4, Fresnel moments from d'Eon & Irving's fits
  (or exact quadrature).
* ``"dipole"``: Jensen et al. 2001's classical dipole with the Egan-Hilgeman ``Fdr`` fit,
  ``Rd = a/2 (1 + exp(-4/3 A sqrt(3 rho))) exp(-sqrt(3 rho))`` (Jensen & Buhler 2002 eq. 5).

Both have the form ``Rd = a**n * exp(K(q))`` with ``n = 2`` (better) or ``1`` (dipole), where
``K`` is analytic in ``q = sqrt(1 - a)``. The inversion splits at ``a = 1/2``:

* lower half, ``a in [0, 1/2]``: unknown ``a``, residual ``F(a) = Rd**(1/n)``, nearly linear;
* upper half, ``q in [0, sqrt(1/2)]``: unknown ``q``, residual ``G(q) = -log Rd``, a sum of
  one-signed terms, nearly linear (``-log Rd ~ 1 - Rd ~ c q``). Unlike ``1 - Rd`` it keeps
  the relative precision of a small Rd just above the split (where Rd is ~0.007 at eta 2.5).

Both residuals are increasing in their unknown and analytic on their interval, which makes
bisection, secant iterations and interpolation tables well conditioned at both stiff ends.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .fresnel import (ETA_EXACT_RANGE, ETA_FIT_RANGE, check_eta, fresnel_moments,  # noqa: F401
                      fresnel_moments_exact, fresnel_moments_fit, fresnel_reflectance)
from .models import BETTER, DIPOLE, MODEL, MODELS  # noqa: F401  (MODELS re-exported)

#: alpha' where the inversion switches from the lower to the upper half.
ALPHA_SPLIT = 0.5

_SQRT3 = np.sqrt(3.0)


class DipoleConstants(NamedTuple):
    """Boundary constants of one eta, memo eq. 1 (``cphi``, ``ce``, ``a_coef`` = A)."""

    cphi: np.ndarray
    ce: np.ndarray
    a_coef: np.ndarray


# {{{ boundary constants (the Fresnel moments: physics.fresnel)

def _poly(x, coefs):
    return np.polynomial.polynomial.polyval(x, coefs)


def dipole_constants(eta, exact=False, model="better"):
    """``(Cphi, Ce, A)`` of memo eq. 1 for the Better Dipole; for ``model="dipole"`` Jensen's
    ``A = (1 + Fdr)/(1 - Fdr)`` (``cphi``, ``ce`` are then unused and set to 1/4, 1/2)."""
    if MODEL[model] is DIPOLE:
        check_eta(eta, False, model)
        e = np.asarray(eta, dtype=np.float64)
        fdr = np.where(e < 1.0,
                       -0.4399 + 0.7099 / e - 0.3319 / e**2 + 0.0636 / e**3,
                       -1.440 / e**2 + 0.710 / e + 0.668 + 0.0636 * e)
        a_coef = (1.0 + fdr) / (1.0 - fdr)
        return DipoleConstants(np.full_like(a_coef, 0.25), np.full_like(a_coef, 0.5), a_coef)
    c1, c2 = fresnel_moments(eta, exact)
    cphi = 0.25 * (1.0 - 2.0 * c1)
    ce = 0.5 * (1.0 - 3.0 * c2)
    return DipoleConstants(cphi, ce, (1.0 + 3.0 * c2) / (1.0 - 2.0 * c1))

# }}}


# {{{ stable helper functions

def phi1(x):
    """``(1 - exp(-x))/x``, 1 at x = 0."""
    x = np.asarray(x, dtype=np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(x == 0.0, 1.0, -np.expm1(-x) / np.where(x == 0.0, 1.0, x))


def _series(x, coefs):
    return _poly(x, coefs)


_PHI2_COEFS = [(-1.0) ** k / np.prod(np.arange(1.0, k + 3.0)) for k in range(18)]
_PSI_COEFS = [(-1.0) ** k * (k + 1) / np.prod(np.arange(1.0, k + 3.0)) for k in range(18)]


def phi2(x):
    """``(exp(-x) - 1 + x)/x^2``, 1/2 at x = 0 (series below 0.5: no cancellation)."""
    x = np.asarray(x, dtype=np.float64)
    small = x < 0.5
    xs = np.where(small, 1.0, x)
    return np.where(small, _series(x, _PHI2_COEFS), (np.expm1(-xs) + xs) / xs**2)


def psi(x):
    """``(1 - exp(-x)(1 + x))/x^2 = -d phi1/dx``, 1/2 at x = 0."""
    x = np.asarray(x, dtype=np.float64)
    small = x < 0.5
    xs = np.where(small, 1.0, x)
    return np.where(small, _series(x, _PSI_COEFS), (-np.expm1(-xs) - xs * np.exp(-xs)) / xs**2)

# }}}


# {{{ Rd(alpha') in the split variables

def _power(model):
    return MODEL[model].power


def _k_terms(q, c: DipoleConstants, model):
    """``K(q)``, ``K'(q)`` and ``b(q) = 1 - exp(K + s)``: Rd = a^n exp(K), K = -s + log(1 - b).

    ``log(1 - b)`` is taken as log1p(-b) while b < 1/2 and from 1 - b summed directly above, so
    it keeps full relative accuracy at both ends.

    Better Dipole: s = sqrt(3 rho/(1+rho)), x = 4 A sqrt(rho (1+rho)/3),
    1 - b = B/2 = [Ce (1 + e^-x) + 4 A Cphi phi1(x)]/2, using Ce + 2 A Cphi = 1 so that
    b = Ce (1 - e^-x)/2 + 2 A Cphi x phi2(x) is a sum of positive terms.
    Dipole: s = sqrt(3 rho), x = 4/3 A s, 1 - b = (1 + e^-x)/2.
    """
    q = np.asarray(q, dtype=np.float64)
    q2 = q * q
    if MODEL[model] is BETTER:
        s = _SQRT3 * q / np.sqrt(1.0 + q2)
        ds = _SQRT3 / (1.0 + q2) ** 1.5
        x = 4.0 * c.a_coef * q * np.sqrt((1.0 + q2) / 3.0)
        dx = 4.0 * c.a_coef / _SQRT3 * (1.0 + 2.0 * q2) / np.sqrt(1.0 + q2)
        b = 0.5 * c.ce * -np.expm1(-x) + 2.0 * c.a_coef * c.cphi * x * phi2(x)
        db = 0.5 * c.ce * np.exp(-x) + 2.0 * c.a_coef * c.cphi * psi(x)
        one_minus_b = 0.5 * c.ce * (1.0 + np.exp(-x)) + 2.0 * c.a_coef * c.cphi * phi1(x)
    else:
        s = _SQRT3 * q
        ds = _SQRT3 + 0.0 * q
        x = 4.0 / 3.0 * c.a_coef * s
        dx = 4.0 / 3.0 * c.a_coef * ds
        b = 0.5 * -np.expm1(-x)
        db = 0.5 * np.exp(-x)
        one_minus_b = 0.5 * (1.0 + np.exp(-x))
    # log(1 - b): log1p where b is small (q -> 0), the directly summed 1 - b where b -> 1
    k = -s + np.where(b < 0.5, np.log1p(-np.minimum(b, 0.5)), np.log(one_minus_b))
    dk = -ds - db * dx / one_minus_b
    return k, dk, b


def log_rd_of_q(q, c, model="better", alpha=None):
    """``log Rd`` as a function of q = sqrt(1 - alpha'), and its q-derivative.

    Pass ``alpha`` too where it is known exactly: 1 - q^2 loses relative accuracy of alpha'
    as alpha' -> 0.
    """
    q = np.asarray(q, dtype=np.float64)
    q2 = q * q
    n = _power(model)
    k, dk, _ = _k_terms(q, c, model)
    with np.errstate(divide="ignore", invalid="ignore"):
        # log a: from alpha' where it is small and given exactly, else log1p(-q^2) (which keeps
        # the -2 rho term that 1 - q^2 would round away as rho -> 0)
        log_a = np.log1p(-q2)
        if alpha is not None:
            alpha = np.asarray(alpha, dtype=np.float64)
            log_a = np.where(alpha < 0.5, np.log(alpha), log_a)
        dlog_a = -2.0 * q / np.exp(log_a)
    return n * log_a + k, n * dlog_a + dk


def _rd(q, alpha, c, model):
    """Rd from q and alpha' (both exact): a^n exp(K) for small alpha' (exp(n log a + K) would
    turn log a's absolute rounding into relative error), exp(log Rd) otherwise."""
    log_rd, _ = log_rd_of_q(q, c, model, alpha=alpha)
    k = _k_terms(q, c, model)[0]
    return np.where(alpha < 0.5, alpha ** _power(model) * np.exp(k), np.exp(log_rd))


def rd_of_rho(rho, eta, exact=False, model="better"):
    """Rd as a function of rho = 1 - alpha' (accurate as rho -> 0 and rho -> 1)."""
    c = dipole_constants(eta, exact, model)
    rho = np.asarray(rho, dtype=np.float64)
    return _rd(np.sqrt(rho), 1.0 - rho, c, model)


def one_minus_rd_of_rho(rho, eta, exact=False, model="better"):
    """1 - Rd without cancellation (relative accuracy as rho -> 0)."""
    c = dipole_constants(eta, exact, model)
    log_rd, _ = log_rd_of_q(np.sqrt(np.asarray(rho, dtype=np.float64)), c, model)
    return -np.expm1(log_rd)


def rd(alpha, eta, exact=False, model="better"):
    """Memo eq. 3: diffuse reflectance of reduced albedo ``alpha`` (stable at alpha = 1)."""
    c = dipole_constants(eta, exact, model)
    alpha = np.asarray(alpha, dtype=np.float64)
    return _rd(np.sqrt(1.0 - alpha), alpha, c, model)


def rd_closed_form(alpha, eta, exact=False):
    """Memo eq. 3 written literally (with the 0/0 at alpha = 1 removed); a cross-check of ``rd``."""
    c = dipole_constants(eta, exact)
    a = np.asarray(alpha, dtype=np.float64)
    m = np.sqrt((1.0 - a) * (2.0 - a) / 3.0)
    x = 4.0 * c.a_coef * m
    return (0.5 * a * a * np.exp(-np.sqrt(3.0 * (1.0 - a) / (2.0 - a)))
            * (c.ce * (1.0 + np.exp(-x)) + c.cphi * 4.0 * c.a_coef * phi1(x)))


def lower_residual(a, c, model="better"):
    """``F(a) = Rd^(1/n)`` and ``dF/da`` on the lower half (a <= 1/2)."""
    a = np.asarray(a, dtype=np.float64)
    n = _power(model)
    q = np.sqrt(1.0 - a)
    k, dk, _ = _k_terms(q, c, model)
    ek = np.exp(k / n)
    return a * ek, ek * (1.0 - a * dk / (2.0 * n * q))


def upper_residual(q, c, model="better"):
    """``G(q) = -log Rd`` and ``dG/dq`` on the upper half (q <= sqrt(1/2))."""
    log_rd, dlog_rd = log_rd_of_q(q, c, model)
    return -log_rd, -dlog_rd


def rd_split(c, model="better"):
    """Rd at the split alpha' = 1/2, where the inversion changes variable."""
    return np.exp(log_rd_of_q(np.sqrt(1.0 - ALPHA_SPLIT), c, model)[0])


def rd_derivative(alpha, eta, exact=False, model="better"):
    """dRd/dalpha' (infinite at alpha' = 1, where 1 - Rd ~ sqrt(1 - alpha'))."""
    c = dipole_constants(eta, exact, model)
    a = np.asarray(alpha, dtype=np.float64)
    q = np.sqrt(1.0 - a)
    log_rd, dlog_rd_dq = log_rd_of_q(q, c, model, alpha=a)
    with np.errstate(divide="ignore"):
        return np.exp(log_rd) * dlog_rd_dq * (-0.5 / q)

# }}}


# {{{ inversion

def solve_increasing(f, target, lo, hi, iters=100):
    """Vectorized safeguarded Newton for increasing ``f`` on [lo, hi]: ``f(v) = target``.

    ``f`` returns (value, derivative) and must accept a subset of the elements through its
    ``index`` argument. Starts from the chord through (lo, f(lo)) and (hi, f(hi)); a step that
    leaves the bracket falls back to bisection, so it always converges. Elements leave the
    active set once a step is below 2 ulps (or the residual is exactly 0): with analytic
    derivatives that takes ~5 steps.
    """
    target = np.asarray(target, dtype=np.float64).reshape(-1)
    lo = np.broadcast_to(np.asarray(lo, np.float64), target.shape).copy()
    hi = np.broadcast_to(np.asarray(hi, np.float64), target.shape).copy()
    idx = np.arange(target.size)
    f_lo, f_hi = f(lo, idx)[0], f(hi, idx)[0]
    with np.errstate(invalid="ignore", divide="ignore"):
        v = lo + (target - f_lo) * (hi - lo) / (f_hi - f_lo)
    v = np.where(np.isfinite(v), np.clip(v, lo, hi), 0.5 * (lo + hi))
    out = v.copy()
    active = np.arange(target.size)
    for _ in range(iters):
        if active.size == 0:
            break
        va, la, ha = v[active], lo[active], hi[active]
        fv, dfv = f(va, active)
        r = fv - target[active]
        la = np.where(r < 0.0, va, la)
        ha = np.where(r > 0.0, va, ha)
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            nv = va - r / dfv       # a step past float64 is out of the bracket: bisected
        nv = np.where((nv >= la) & (nv <= ha) & np.isfinite(nv), nv, 0.5 * (la + ha))
        done = (r == 0.0) | (np.abs(nv - va) <= 4.5e-16 * np.abs(va)) | (ha - la <= 4.5e-16 * ha)
        nv = np.where(r == 0.0, va, nv)
        out[active] = nv
        v[active], lo[active], hi[active] = nv, la, ha
        active = active[~done]
    return out


def invert_rd_rho(rd_value, eta, exact=False, model="better"):
    """Inverse of memo eq. 3 to float64 accuracy: returns ``(alpha, rho)``.

    Rd <= 0 gives alpha' = 0; Rd >= 1 gives alpha' = 1 (rho = 0); NaN propagates. Each value
    is solved on its own half: alpha' from F = Rd^(1/n) below Rd(1/2), q from -log Rd above.
    """
    rdv = np.asarray(rd_value, dtype=np.float64)
    shape = rdv.shape
    c = dipole_constants(eta, exact, model)
    c = DipoleConstants(*(np.broadcast_to(x, shape).reshape(-1) for x in c))
    rdv = rdv.reshape(-1)
    n = _power(model)
    split = rd_split(c, model)
    inside = (rdv > 0.0) & (rdv < 1.0)
    lower = np.flatnonzero(inside & (rdv < split))
    upper = np.flatnonzero(inside & (rdv >= split))
    alpha = np.where(rdv >= 1.0, 1.0, 0.0)
    rho = 1.0 - alpha
    sub = lambda idx: DipoleConstants(*(x[idx] for x in c))  # noqa: E731
    a_lo = solve_increasing(lambda a, i: lower_residual(a, sub(lower[i]), model),
                             rdv[lower] ** (1.0 / n), 0.0, ALPHA_SPLIT)
    q_hi = solve_increasing(lambda q, i: upper_residual(q, sub(upper[i]), model),
                             -np.log(rdv[upper]), 0.0, np.sqrt(1.0 - ALPHA_SPLIT))
    alpha[lower], rho[lower] = a_lo, 1.0 - a_lo
    alpha[upper], rho[upper] = 1.0 - q_hi * q_hi, q_hi * q_hi
    nan = np.isnan(rdv)
    alpha[nan], rho[nan] = np.nan, np.nan
    return alpha.reshape(shape), rho.reshape(shape)


def invert_rd(rd_value, eta, exact=False, model="better"):
    """alpha' with Rd(alpha') = rd_value (float64; see ``invert_rd_rho`` for rho)."""
    return invert_rd_rho(rd_value, eta, exact, model)[0]


def mu_tr_over_sigma_t(rho, model="better"):
    """``mu_tr / sigma_t'``: sqrt(3 rho/(1 + rho)) (better; D = (1+rho)/(3 sigma_t'))
    or sqrt(3 rho) (dipole; D = 1/(3 sigma_t'))."""
    rho = np.asarray(rho, dtype=np.float64)
    return np.sqrt(3.0 * rho / (1.0 + rho)) if MODEL[model] is BETTER else np.sqrt(3.0 * rho)


def albedo_to_coefficients(rd_value, mfp, eta, exact=False, model="better"):
    """Reference of the memo's drop-in mapping: (Rd, ld = 1/mu_tr, eta) -> (sigma_a, sigma_s')."""
    alpha, rho = invert_rd_rho(rd_value, eta, exact, model)
    with np.errstate(divide="ignore"):
        sigma_t = 1.0 / (np.asarray(mfp, dtype=np.float64) * mu_tr_over_sigma_t(rho, model))
    return sigma_t * rho, sigma_t * alpha

# }}}


# {{{ radial profile R(r) and its energy

class _Geometry(NamedTuple):
    alpha: np.ndarray
    d_coef: np.ndarray
    mu_tr: np.ndarray
    z_r: np.ndarray
    z_v: np.ndarray
    c: DipoleConstants


def _geometry(alpha, sigma_t, eta, exact):
    c = dipole_constants(eta, exact)
    a = np.asarray(alpha, dtype=np.float64)
    st = np.asarray(sigma_t, dtype=np.float64)
    rho = 1.0 - a
    d_coef = (1.0 + rho) / (3.0 * st)       # D = (2 sigma_a + sigma_s')/(3 sigma_t'^2)
    mu_tr = st * mu_tr_over_sigma_t(rho)     # sqrt(sigma_a / D)
    z_r = 1.0 / st
    z_v = -z_r - 4.0 * c.a_coef * d_coef
    return _Geometry(a, d_coef, mu_tr, z_r, z_v, c)


def profile(r, alpha, sigma_t, eta, exact=False):
    """Memo eq. 1: the Better Dipole profile R(r) [1/length^2].

    The Cphi/D terms of the two sources cancel at large r; their difference is written as
    ``e^{-mu d_r}/d_r [ (d_v - d_r)/d_v + (d_r/d_v)(1 - e^{-mu (d_v - d_r)}) ]`` with
    ``d_v - d_r = (z_v^2 - z_r^2)/(d_v + d_r)``, a sum of positive terms.
    """
    g = _geometry(alpha, sigma_t, eta, exact)
    r = np.asarray(r, dtype=np.float64)
    d_r = np.sqrt(r * r + g.z_r**2)
    d_v = np.sqrt(r * r + g.z_v**2)
    e_r = np.exp(-g.mu_tr * d_r)
    e_v = np.exp(-g.mu_tr * d_v)
    ce_part = (g.z_r * (g.mu_tr * d_r + 1.0) * e_r / d_r**3
               - g.z_v * (g.mu_tr * d_v + 1.0) * e_v / d_v**3)
    gap = (g.z_v**2 - g.z_r**2) / (d_v + d_r)
    phi_part = e_r / d_r * (gap / d_v + (d_r / d_v) * -np.expm1(-g.mu_tr * gap))
    return g.alpha**2 / (4.0 * np.pi) * (g.c.ce * ce_part + g.c.cphi / g.d_coef * phi_part)


def profile_literal(r, alpha, sigma_t, eta, exact=False):
    """Memo eq. 1 exactly as printed (cancels at large r); a cross-check of ``profile``."""
    g = _geometry(alpha, sigma_t, eta, exact)
    r = np.asarray(r, dtype=np.float64)

    def source(z):
        d = np.sqrt(r * r + z * z)
        return ((g.c.ce * z * (g.mu_tr * d + 1.0) / (d * d) + g.c.cphi / g.d_coef)
                * np.exp(-g.mu_tr * d) / d)

    return g.alpha**2 / (4.0 * np.pi) * (source(g.z_r) - source(g.z_v))


def _energy_terms(r, g, z):
    """``2 pi Int_0^r`` of one source's two terms, divided by alpha'^2/2 (docs/model.md
    "Radial energy", d dd = r dr).

    Ce term: z (e^{-mu|z|}/|z| - e^{-mu d}/d); Cphi/D term: (e^{-mu|z|} - e^{-mu d})/mu,
    both rewritten with ``d - |z| = r^2/(d + |z|)`` and expm1 so they are exact as r -> 0
    and as mu -> 0 (alpha' -> 1).
    """
    az = np.abs(z)
    d = np.hypot(r, z)
    dz = r * (r / (d + az))
    e0 = np.exp(-g.mu_tr * az)
    t = g.mu_tr * dz
    ce_term = np.sign(z) * e0 * (dz / d + (az / d) * -np.expm1(-t))
    phi_term = e0 * dz * phi1(t)
    return g.c.ce * ce_term + g.c.cphi / g.d_coef * phi_term


def profile_cdf(r, alpha, sigma_t, eta, exact=False):
    """Energy within radius r: ``2 pi Int_0^r R(s) s ds`` (closed form); ``profile_cdf(inf) = rd``.

    Summed directly while the tail holds at least half the energy, else as ``total - tail``."""
    g = _geometry(alpha, sigma_t, eta, exact)
    r = np.asarray(r, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        inside = 0.5 * g.alpha**2 * (_energy_terms(r, g, g.z_r) - _energy_terms(r, g, g.z_v))
        # past the median, total - tail: the sources' Cphi terms cancel at large r as mu -> 0;
        # the switch is decided on tail and total, which never cancel
        tail = profile_tail(r, alpha, sigma_t, eta, exact)
        total = profile_tail(0.0, alpha, sigma_t, eta, exact)
    return np.where(np.isposinf(r) | (tail < 0.5 * total), total - tail, inside)


def profile_tail(r, alpha, sigma_t, eta, exact=False):
    """Energy beyond radius r: ``2 pi Int_r^inf R(s) s ds`` = rd - profile_cdf, without
    cancellation.

    Ce term: z e^{-mu d}/d per source; Cphi/D term: e^{-mu d}/mu per source, the difference of
    the two sources' Cphi terms written as e^{-mu d_r} (d_v - d_r) phi1(mu (d_v - d_r)).
    """
    g = _geometry(alpha, sigma_t, eta, exact)
    r = np.asarray(r, dtype=np.float64)
    d_r = np.hypot(r, g.z_r)
    d_v = np.hypot(r, g.z_v)
    e_r = np.exp(-g.mu_tr * d_r)
    e_v = np.exp(-g.mu_tr * d_v)
    ce_term = g.z_r * e_r / d_r - g.z_v * e_v / d_v
    gap = (g.z_v**2 - g.z_r**2) / (d_v + d_r)  # d_v - d_r > 0 since |z_v| > z_r
    phi_term = e_r * gap * phi1(g.mu_tr * gap)
    return 0.5 * g.alpha**2 * (g.c.ce * ce_term + g.c.cphi / g.d_coef * phi_term)

# }}}
