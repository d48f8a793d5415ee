"""Exact reflectance of an isotropically scattering, index-matched half-space (Chandrasekhar's
H-function), and what a walk renders when it is refracted in through a dielectric but leaves
the medium at its first surface crossing (Cycles' random walks: docs/conventions.md
"Boundaries"). Float64, vectorised over the single-scattering albedo ``alpha``.

H by its integral representation (Chandrasekhar 1950, ch. V; isotropic scattering):
    ln H(mu) = -(mu/pi) Int_0^{pi/2} ln(1 - alpha t cot t) / (cos^2 t + mu^2 sin^2 t) dt,
the directional albedo for incidence cosine mu: A(mu) = 1 - H(mu) sqrt(1 - alpha).
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np

from .fresnel import fresnel_reflectance

#: Gauss-Legendre nodes in t on [0, pi/2], refined towards t = 0 (t = (pi/2) u^2: the
#: integrand's log(1 - alpha t cot t) ~ log(1 - alpha) + alpha t^2/3 is steep there as
#: alpha -> 1)
_U, _WU = np.polynomial.legendre.leggauss(256)
_U, _WU = 0.5 * (_U + 1.0), 0.5 * _WU
_T = 0.5 * np.pi * _U**2
_WT = np.pi * _U * _WU
#: cosines of the outer (diffuse incidence) integral
_MU, _WMU = np.polynomial.legendre.leggauss(96)
_MU, _WMU = 0.5 * (_MU + 1.0), 0.5 * _WMU


def h_function(mu, alpha):
    """Chandrasekhar's H(mu) for single-scattering albedo ``alpha`` < 1 (broadcast)."""
    mu = np.asarray(mu, np.float64)[..., None]
    alpha = np.asarray(alpha, np.float64)[..., None]
    t = _T
    with np.errstate(divide="ignore", invalid="ignore"):
        tcot = np.where(t > 0, t / np.tan(t), 1.0)
    log_term = np.log1p(-alpha * tcot)
    integrand = log_term / (np.cos(t) ** 2 + mu**2 * np.sin(t) ** 2)
    return np.exp(-mu[..., 0] / np.pi * np.sum(_WT * integrand, axis=-1))


def directional_albedo(mu, alpha):
    """Reflectance of the index-matched half-space for light arriving at cosine ``mu``."""
    alpha = np.asarray(alpha, np.float64)
    return 1.0 - h_function(mu, alpha) * np.sqrt(1.0 - alpha)


def matched_reflectance(alpha):
    """White-sky (diffuse incidence) reflectance of the index-matched half-space:
    2 Int A(mu) mu dmu."""
    a = np.asarray(alpha, np.float64)[..., None]
    return np.sum(2.0 * _WMU * _MU * directional_albedo(_MU, a), axis=-1)


def entry_reflectance(alpha, eta):
    """White-sky reflectance of a walk refracted in through a smooth dielectric of relative
    index ``eta`` (the Fresnel-reflected part excluded: it is the specular lobe's) that leaves
    at its first surface crossing: 2 Int (1 - F(mu)) A(mu_t) mu dmu, mu_t the refracted
    cosine. Isotropic scattering."""
    a = np.asarray(alpha, np.float64)[..., None]
    eta = float(eta)
    transmitted = 1.0 - fresnel_reflectance(_MU, 1.0 / eta)   # from outside, index eta inside
    mu_t = np.sqrt(1.0 - (1.0 - _MU**2) / eta**2)
    return np.sum(2.0 * _WMU * _MU * transmitted * directional_albedo(mu_t, a), axis=-1)


@lru_cache(maxsize=32)
def _entry_table(eta):
    """entry_reflectance on a grid in q = sqrt(1 - alpha) (the smooth variable), read-only."""
    q = np.linspace(0.0, 1.0, 1025)
    r = np.empty_like(q)
    r[1:] = entry_reflectance(1.0 - q[1:] ** 2, eta)
    # alpha = 1: every path leaves, so all that was let in: 1 - the diffuse Fresnel
    r[0] = np.sum(2.0 * _WMU * _MU * (1.0 - fresnel_reflectance(_MU, 1.0 / eta)))
    q.setflags(write=False)
    r.setflags(write=False)
    return q, r


def entry_reflectance_fast(alpha, eta):
    """``entry_reflectance`` interpolated (cubic in q) from a 1025-point table per eta:
    within 4e-12 of the direct sum (measured), for texture-sized arrays."""
    from scipy.interpolate import CubicSpline
    q, r = _entry_table(float(eta))
    spline = CubicSpline(q, r)
    return spline(np.sqrt(np.clip(1.0 - np.asarray(alpha, np.float64), 0.0, 1.0)))


def diffuse_fresnel(eta):
    """The surface's white-sky Fresnel reflectance for light from outside:
    2 Int F(mu) mu dmu (index ``eta`` inside)."""
    return float(np.sum(2.0 * _WMU * _MU * fresnel_reflectance(_MU, 1.0 / float(eta))))


def cosine_entry_reflectance_fast(alpha, eta):
    """A walk let in through 1 - F (white sky) as a cosine-distributed (diffuse) bounce,
    index-matched inside, leaving at its first crossing: (1 - F_dr) times the matched
    half-space's white-sky reflectance (at alpha = 1: all of 1 - F_dr). From a table in q as
    ``entry_reflectance_fast``; isotropic scattering."""
    from scipy.interpolate import CubicSpline
    q, r = _matched_table()
    spline = CubicSpline(q, r)
    matched = spline(np.sqrt(np.clip(1.0 - np.asarray(alpha, np.float64), 0.0, 1.0)))
    return (1.0 - diffuse_fresnel(eta)) * matched


@lru_cache(maxsize=1)
def _matched_table():
    q = np.linspace(0.0, 1.0, 1025)
    r = np.empty_like(q)
    r[1:] = matched_reflectance(1.0 - q[1:] ** 2)
    r[0] = 1.0
    q.setflags(write=False)
    r.setflags(write=False)
    return q, r
