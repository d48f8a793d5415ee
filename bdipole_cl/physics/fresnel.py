"""The Fresnel moments of a dielectric boundary and the eta range each model is defined on
(docs/model.md "Fresnel moments"): d'Eon & Irving's fits, the exact moments by quadrature,
and the check of eta. Float64 reference, vectorised like ``physics.reference`` (which
re-exports these names)."""
from __future__ import annotations

from functools import lru_cache

import numpy as np

from . import fresnel_fit
from .models import MODEL

#: eta interval where the d'Eon fits keep Rd(alpha') monotone (docs/model.md "Fresnel moments":
#: invalid from ~2.9 up).
ETA_FIT_RANGE = (0.5, 2.8)
#: eta interval accepted with exact (quadrature) Fresnel moments.
ETA_EXACT_RANGE = (0.2, 5.0)


def fresnel_moments_fit(eta):
    """d'Eon & Irving 2011 fits of the first two Fresnel moments (pbrt-v3 FresnelMoment1/2),
    evaluated exactly and rounded once (``fresnel_fit``: the float64 sums cancel)."""
    return fresnel_fit.fresnel_moments_fit(eta)


def fresnel_reflectance(mu, eta):
    """Unpolarized dielectric Fresnel reflectance for light inside a medium of index ``eta``
    meeting a boundary to index 1 at cosine ``mu``; 1 past the critical angle."""
    mu = np.asarray(mu, dtype=np.float64)
    eta = np.asarray(eta, dtype=np.float64)
    sin2_t = eta**2 * (1.0 - mu**2)
    cos_t = np.sqrt(np.maximum(1.0 - sin2_t, 0.0))
    with np.errstate(invalid="ignore", divide="ignore"):
        r_par = (mu - eta * cos_t) / (mu + eta * cos_t)
        r_perp = (eta * mu - cos_t) / (eta * mu + cos_t)
        f = 0.5 * (r_par**2 + r_perp**2)
    return np.where(sin2_t >= 1.0, 1.0, f)


def fresnel_moments_exact(eta, nodes=256):
    """``C_i(eta) = Int_0^1 mu^i F_r(mu; eta -> 1) dmu`` for i = 1, 2, by Gauss-Legendre.

    Past the critical cosine ``mu_c`` F_r = 1 and the integral is closed-form; on [mu_c, 1] the
    substitution ``mu = mu_c + (1 - mu_c) t^2`` removes the square-root kink at mu_c, so the
    rule converges spectrally (checked against scipy.quad to 1e-13 in the tests). A single eta's
    are remembered (a plan's kernels ask for one eta's hundreds of times, 5 ms each).
    """
    if np.ndim(eta) == 0:
        return _moments_exact_at(float(eta), nodes)
    return _moments_exact(eta, nodes)


@lru_cache(maxsize=256)
def _moments_exact_at(eta: float, nodes: int):
    return _moments_exact(eta, nodes)


def _moments_exact(eta, nodes):
    eta = np.asarray(eta, dtype=np.float64)
    mu_c = np.sqrt(np.maximum(1.0 - 1.0 / eta**2, 0.0))
    x, w = np.polynomial.legendre.leggauss(nodes)
    t = 0.5 * (x + 1.0)
    w = 0.5 * w
    mc = mu_c[..., None]
    mu = mc + (1.0 - mc) * t**2
    jac = 2.0 * (1.0 - mc) * t
    f = fresnel_reflectance(mu, eta[..., None]) * jac * w
    c1 = 0.5 * mu_c**2 + np.sum(f * mu, axis=-1)
    c2 = mu_c**3 / 3.0 + np.sum(f * mu**2, axis=-1)
    return c1, c2


def check_eta(eta, exact=False, model="better"):
    """Raise ValueError naming the offending eta if it is outside the model's valid range."""
    lo, hi = ETA_EXACT_RANGE if (exact and MODEL[model].fresnel_moments) else ETA_FIT_RANGE
    e = np.asarray(eta, dtype=np.float64)
    bad = ~((e >= lo) & (e <= hi))
    if np.any(bad):
        first = float(e.reshape(-1)[np.flatnonzero(bad.reshape(-1))[0]])
        how = ("exact Fresnel moments" if exact else
               "the d'Eon fits (exact=True / --exact reaches further)")
        raise ValueError(
            f"eta={first!r} is outside [{lo}, {hi}], the range where {how} keep Rd(alpha') "
            f"monotone and the inversion well defined")


def fresnel_moments(eta, exact=False):
    """First two Fresnel moments ``(C1, C2)`` of ``eta`` (memo: ``2C1``, ``3C2`` are 2x, 3x these).

    ``exact=False`` uses d'Eon & Irving's fits, valid for eta in ``ETA_FIT_RANGE``;
    ``exact=True`` integrates the Fresnel reflectance (valid in ``ETA_EXACT_RANGE``).
    """
    check_eta(eta, exact)
    return fresnel_moments_exact(eta) if exact else fresnel_moments_fit(eta)
