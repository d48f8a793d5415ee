"""The closed-form maps renderers use to turn a painted colour and radius into a medium or a
profile (docs/conventions.md "Formulas and sources"): float64, vectorised, each named after
its source. What each convention does with them is ``physics.conventions``.

Names: ``colour`` is the painted colour A (a multiple-scattering albedo) [1], ``alpha`` a
single-scattering albedo sigma_s/sigma_t [1], ``g`` the Henyey-Greenstein mean cosine [1],
``s`` a dimensionless scaling factor of a radius.
"""
from __future__ import annotations

import numpy as np


def _f64(x):
    return np.asarray(x, dtype=np.float64)


# {{{ van de Hulst (OpenPBR; Cycles Random Walk; d'Eon's Hitchhiker's Guide eq. 53.7)

def van_de_hulst_colour(alpha, g=0.0):
    """The multiple-scattering albedo C of single-scattering albedo ``alpha`` with HG ``g``:
    s = sqrt((1 - alpha)/(1 - alpha g)), C = (1 - s)(1 - 0.139 s)/(1 + 1.17 s)."""
    alpha, g = _f64(alpha), _f64(g)
    s = np.sqrt((1.0 - alpha) / (1.0 - alpha * g))
    return (1.0 - s) * (1.0 - 0.139 * s) / (1.0 + 1.17 * s)


def van_de_hulst_alpha(colour, g=0.0):
    """The fitted inverse: s = 4.09712 + 4.20863 C - sqrt(9.59217 + 41.6808 C + 17.7126 C^2),
    alpha = (1 - s^2)/(1 - g s^2). (Not the exact inverse of ``van_de_hulst_colour``: the
    two differ by the fit's error, up to ~2e-3 in C.)"""
    c, g = _f64(colour), _f64(g)
    s = 4.09712 + 4.20863 * c - np.sqrt(9.59217 + 41.6808 * c + 17.7126 * c * c)
    s2 = s * s
    return (1.0 - s2) / (1.0 - g * s2)

# }}}


# {{{ Wrenninge, Villemin & Hery 2017 (Cycles "Random Walk (Legacy)" and "Skin")

def _wvh_coefficients(g):
    g = _f64(g)
    p = lambda *c: np.polynomial.polynomial.polyval(g, c)  # noqa: E731
    a = p(1.8260523782, -1.28451056436, -1.79904629312, 9.19393289202, -22.8215585862,
          32.0234874259, -23.6264803333, 7.21067002658)
    b = 4.98511194385 + 0.127355959438 * np.exp(p(0.0, 31.1491581433, -201.847017512,
                                                   841.576016723, -2018.09288505, 2731.71560286,
                                                   -1935.41424244, 559.009054474))
    c = p(1.09686102424, -0.394704063468, 1.05258115941, -8.83963712726, 28.8643230661,
          -46.8802913581, 38.5402837518, -12.7181042538)
    d = p(0.496310210422, 0.360146581622, -2.15139309747, 17.8896899217, -55.2984010333,
          82.065982243, -58.5106008578, 15.8478295021)
    e = 4.23190299701 + 0.00310603949088 * np.exp(p(0.0, 76.7316253952, -594.356773233,
                                                     2448.8834203, -5576.68528998,
                                                     7116.60171912, -4763.54467887,
                                                     1303.5318055))
    f = p(2.40602999408, -2.51814844609, 9.18494908356, -79.2191708682, 259.082868209,
          -403.613804597, 302.85712436, -87.4370473567)
    return a, b, c, d, e, f


def wvh_alpha(colour, g=0.0):
    """Single-scattering albedo of colour A: (1 - A^(1/4)) a atan(b A)^c + A^(1/4) d
    atan(e A)^f, the coefficients polynomials in g (the fit is for an index-matched walk).
    Not clamped (Cycles clamps to [0, 0.999999]: ``physics.conventions``)."""
    c = _f64(colour)
    a, b, cc, d, e, f = _wvh_coefficients(g)
    blend = c ** 0.25
    return (1.0 - blend) * a * np.arctan(b * c) ** cc + blend * d * np.arctan(e * c) ** f

# }}}


# {{{ Chiang, Kutz & Burley 2016; MoonRay; Hyperion 2018

def chiang_alpha(colour):
    """Chiang et al. 2016 eq. 1: alpha = 1 - exp(-5.09406 A + 2.61188 A^2 - 4.31805 A^3)."""
    a = _f64(colour)
    return -np.expm1(a * (-5.09406 + a * (2.61188 - 4.31805 * a)))


def moonray_alpha(colour):
    """MoonRay VolumeSubsurface's refit: alpha = 1 - exp(-4.75914 A + 1.2166 A^2 - 3.25172 A^3)."""
    a = _f64(colour)
    return -np.expm1(a * (-4.75914 + a * (1.2166 - 3.25172 * a)))


def hyperion_alpha(colour):
    """Burley et al. 2018 (Hyperion, IOR 1.4 boundary):
    alpha = 1 - exp(-11.43 A + 15.38 A^2 - 13.91 A^3)."""
    a = _f64(colour)
    return -np.expm1(a * (-11.43 + a * (15.38 - 13.91 * a)))


def hyperion_s(colour):
    """Burley et al. 2018: s = 4.012 - 15.21 A + 32.34 A^2 - 34.68 A^3 + 13.91 A^4."""
    return np.polynomial.polynomial.polyval(_f64(colour), (4.012, -15.21, 32.34, -34.68, 13.91))

# }}}


# {{{ Christensen & Burley 2015 normalized diffusion

def burley_s_searchlight(colour):
    """s for the diffuse mean free path (searchlight configuration, eq. 8):
    3.5 + 100 (A - 0.33)^4."""
    return 3.5 + 100.0 * (_f64(colour) - 0.33) ** 4


def burley_s_perpendicular(colour):
    """s for the volume mean free path, perpendicular configuration (eq. 5):
    1.85 - A + 7 |A - 0.8|^3."""
    a = _f64(colour)
    return 1.85 - a + 7.0 * np.abs(a - 0.8) ** 3


def burley_s_transmission(colour):
    """s for the volume mean free path, diffuse surface transmission (eq. 6; also Chiang et
    al. 2016 eq. 2): 1.9 - A + 3.5 (A - 0.8)^2."""
    a = _f64(colour)
    return 1.9 - a + 3.5 * (a - 0.8) ** 2


#: x = r/d where the normalized diffusion's energy 1 - e^-x/4 - 3/4 e^(-x/3) is 1/2: with
#: y = e^(-x/3), y^3 + 3 y = 2 (a cubic with one real root, Cardano: y = u - 1/u,
#: u = cbrt(1 + sqrt(2)))
_U = np.cbrt(1.0 + np.sqrt(2.0))
BURLEY_MEDIAN_X = -3.0 * np.log(_U - 1.0 / _U)


def burley_energy(x):
    """Energy of the normalized diffusion profile within r = x d (eq. 11):
    1 - e^-x/4 - 3/4 e^(-x/3)."""
    y = np.exp(-_f64(x) / 3.0)
    return 1.0 - 0.25 * y ** 3 - 0.75 * y

# }}}


# {{{ Jensen 2001 (Cycles "Random Walk (Skin)")

def jensen_fdr(eta):
    """Egan-Hilgeman's diffuse Fresnel reflectance fit: -1.440/eta^2 + 0.710/eta + 0.668 +
    0.0636 eta (eta >= 1)."""
    e = _f64(eta)
    return -1.440 / e**2 + 0.710 / e + 0.668 + 0.0636 * e


def jensen_rd(alpha_prime, eta):
    """Jensen 2001's total diffuse reflectance: a'/2 (1 + exp(-4/3 A s)) exp(-s),
    s = sqrt(3 (1 - a')), A = (1 + Fdr)/(1 - Fdr)."""
    a = _f64(alpha_prime)
    fdr = jensen_fdr(eta)
    big_a = (1.0 + fdr) / (1.0 - fdr)
    s = np.sqrt(3.0 * (1.0 - a))
    return 0.5 * a * (1.0 + np.exp(-4.0 / 3.0 * big_a * s)) * np.exp(-s)


def cycles_skin_alpha_prime(colour, eta):
    """Cycles' ``bssrdf_dipole_compute_alpha_prime``, emulated in float32: Jensen's Rd
    inverted by a 12-step bisection on [0, 1] (the midpoint of the last step is returned);
    Rd < 1e-4 gives 0, Rd >= 0.995 gives 0.999999. Its quantisation (steps of 2^-12 in
    alpha') is what Cycles renders."""
    f32 = np.float32
    rd = np.asarray(colour, dtype=f32)
    inv = f32(1.0) / np.asarray(eta, dtype=f32)
    fdr = inv * (f32(-1.440) * inv + f32(0.710)) + f32(0.668) + f32(0.0636) * f32(eta)
    four_thirds_a = f32(4.0 / 3.0) * (f32(1.0) + fdr) / (f32(1.0) - fdr)
    x0, x1 = np.zeros_like(rd), np.ones_like(rd)
    mid = x0
    for _ in range(12):
        mid = f32(0.5) * (x0 + x1)
        s = np.sqrt(f32(3.0) * (f32(1.0) - mid))
        f = f32(0.5) * mid * (f32(1.0) + np.exp(-four_thirds_a * s)) * np.exp(-s)
        below = f < rd
        x0, x1 = np.where(below, mid, x0), np.where(below, x1, mid)
    out = np.where(rd < f32(1e-4), f32(0.0), np.where(rd >= f32(0.995), f32(0.999999), mid))
    return out.astype(np.float64)

# }}}
