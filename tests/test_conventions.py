"""Renderer conventions (docs/conventions.md): each formula against a value computed another
way (the exact half-space albedo from Chandrasekhar's H-function, quadrature of the profiles,
mpmath roots, a float64 bisection), and the registry's shape."""
import mpmath
import numpy as np
import pytest
from scipy import integrate

from bdipole_cl.physics import reference
from bdipole_cl.physics import renderer_fits as fits
from bdipole_cl.physics.conventions import (BOUNDARIES, CONVENTION, CONVENTIONS, dipole_tail,
                                            profile_median)

_X, _W = np.polynomial.legendre.leggauss(160)
_MU, _W = 0.5 * (_X + 1.0), 0.5 * _W


def half_space_albedo(c):
    """Exact diffuse albedo of an index-matched isotropic half-space of single-scattering
    albedo c: 1 - 2 sqrt(1 - c) Int H(mu) mu dmu, H from Chandrasekhar's equation
    1/H(mu) = sqrt(1 - c) + c/2 Int mu' H(mu')/(mu + mu') dmu' (fixed point)."""
    s, h = np.sqrt(1.0 - c), np.ones_like(_MU)
    kernel = _MU / (_MU[:, None] + _MU)
    for _ in range(5000):
        new = 1.0 / (s + 0.5 * c * (kernel * h) @ _W)
        if np.max(np.abs(new - h)) < 1e-14:
            break
        h = new
    return 1.0 - 2.0 * s * np.sum(_W * h * _MU)


def exact_alpha(colour):
    """The single-scattering albedo whose exact half-space albedo is ``colour`` (bisection)."""
    lo, hi = 0.0, 1.0
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if half_space_albedo(mid) < colour else (lo, mid)
    return 0.5 * (lo + hi)


@pytest.mark.parametrize("c", [0.3, 0.6, 0.9, 0.99])
def test_van_de_hulst_colour_near_the_exact_half_space(c):
    # van de Hulst's formula is a fit of this very quantity: ~1-2% at low albedo (measured
    # 2.0% at c = 0.3), 1e-4 at high; a wrong sign or coefficient is off by far more
    exact = half_space_albedo(c)
    got = float(fits.van_de_hulst_colour(c))
    assert abs(got - exact) <= 0.025 * exact, (c, got, exact)


@pytest.mark.parametrize("colour", [0.2, 0.5, 0.8, 0.95])
def test_index_matched_fits_invert_the_exact_half_space(colour):
    # the index-matched inverse fits (OpenPBR's van de Hulst, Wrenninge's at g = 0, Chiang's
    # and MoonRay's) against the exact inverse, in 1 - alpha (the stiff variable): each
    # within its published few-% accuracy except where it is known to break (Wrenninge's
    # passes 1 above colour ~0.9 and Cycles clamps it: docs/conventions.md)
    rho = 1.0 - exact_alpha(colour)
    assert abs(1.0 - fits.van_de_hulst_alpha(colour) - rho) <= 0.02 * rho + 1e-7, colour
    for fit in (fits.chiang_alpha, fits.moonray_alpha):
        assert abs(1.0 - fit(colour) - rho) <= 4.5 * rho, (fit.__name__, colour)
    if colour <= 0.8:
        assert abs(1.0 - fits.wvh_alpha(colour) - rho) <= 0.25 * rho, colour


def test_van_de_hulst_inverse_fit_inverts_the_forward_formula():
    # the two printed formulas are inverse fits of each other: measured 1.2e-5 apart in C
    c = np.linspace(0.01, 0.99, 999)
    back = fits.van_de_hulst_colour(fits.van_de_hulst_alpha(c))
    assert np.max(np.abs(back - c)) < 2e-5


def test_closed_form_fits_against_mpmath():
    # each exponential-polynomial and polynomial fit evaluated as printed, in mpmath
    a = mpmath.mpf("0.37")
    expect = {
        fits.chiang_alpha: 1 - mpmath.exp(-5.09406 * a + 2.61188 * a**2 - 4.31805 * a**3),
        fits.moonray_alpha: 1 - mpmath.exp(-4.75914 * a + 1.2166 * a**2 - 3.25172 * a**3),
        fits.hyperion_alpha: 1 - mpmath.exp(-11.43 * a + 15.38 * a**2 - 13.91 * a**3),
        fits.hyperion_s: 4.012 - 15.21 * a + 32.34 * a**2 - 34.68 * a**3 + 13.91 * a**4,
        fits.burley_s_searchlight: 3.5 + 100 * (a - 0.33) ** 4,
        fits.burley_s_perpendicular: 1.85 - a + 7 * abs(a - 0.8) ** 3,
        fits.burley_s_transmission: 1.9 - a + 3.5 * (a - 0.8) ** 2,
    }
    for fit, value in expect.items():
        got = float(fit(0.37))
        assert abs(got - float(value)) <= 4e-16 * abs(float(value)) * 8, (fit.__name__, got)


def test_wvh_at_g0_against_its_printed_coefficients():
    # Cycles' coefficient polynomials at g = 0 are their constant terms
    a = mpmath.mpf("0.6")
    blend = a ** mpmath.mpf("0.25")
    value = ((1 - blend) * 1.8260523782 * mpmath.atan((4.98511194385 + 0.127355959438) * a)
             ** 1.09686102424
             + blend * 0.496310210422 * mpmath.atan((4.23190299701 + 0.00310603949088) * a)
             ** 2.40602999408)
    assert abs(float(fits.wvh_alpha(0.6)) - float(value)) < 1e-14


def test_burley_median_is_the_profiles_half_energy_radius():
    # mpmath root of the printed CDF, and quadrature of the printed profile
    # R(r) = (e^{-r/d} + e^{-r/(3d)})/(8 pi d r) to that radius
    x = mpmath.findroot(lambda x: 1 - mpmath.exp(-x) / 4 - 0.75 * mpmath.exp(-x / 3) - 0.5, 1.5)
    assert abs(fits.BURLEY_MEDIAN_X - float(x)) < 1e-14
    energy, _ = integrate.quad(lambda r: 2 * np.pi * r * (np.exp(-r) + np.exp(-r / 3))
                               / (8 * np.pi * r), 0, fits.BURLEY_MEDIAN_X, epsabs=1e-14)
    assert abs(energy - 0.5) < 1e-12


@pytest.mark.parametrize("eta", [1.0, 1.4])
@pytest.mark.parametrize("colour", [0.05, 0.5, 0.9])
def test_better_dipole_median_by_quadrature(colour, eta):
    # half the profile's energy (memo eq. 1 integrated numerically) within the median
    median = float(profile_median("better-dipole", colour, eta))
    sa, ss = reference.albedo_to_coefficients(colour, 1.0, eta)
    st, a = sa + ss, ss / (sa + ss)
    inside, _ = integrate.quad(lambda r: 2 * np.pi * r * reference.profile(r, a, st, eta),
                               0, median, epsabs=1e-13, limit=200)
    assert abs(inside - 0.5 * colour) < 2e-8 * colour, (inside, colour)


@pytest.mark.parametrize("colour", [0.1, 0.6, 0.9])
def test_jensen_dipole_energy_by_quadrature(colour):
    # Jensen's R(r) = a'/(4 pi) [z_r (mu d_r + 1) e^{-mu d_r}/d_r^3 + z_v (...)]: its
    # integral is Jensen's Rd, and the closed-form tail agrees with the quadrature's
    eta = 1.4
    a = float(reference.invert_rd(colour, eta, model="dipole"))
    st = 1.0 / np.sqrt(3.0 * (1.0 - a))           # unit diffuse mfp
    fdr = fits.jensen_fdr(eta)
    mu, z_r = np.sqrt(3 * (1 - a)) * st, 1 / st
    z_v = z_r * (1 + 4 / 3 * (1 + fdr) / (1 - fdr))

    def profile(r):
        d_r, d_v = np.hypot(r, z_r), np.hypot(r, z_v)
        return a / (4 * np.pi) * sum(z * (mu * d + 1) * np.exp(-mu * d) / d**3
                                     for z, d in ((z_r, d_r), (z_v, d_v)))
    total, _ = integrate.quad(lambda r: 2 * np.pi * r * profile(r), 0, np.inf, epsabs=1e-13)
    assert abs(total - colour) < 1e-9
    assert abs(float(fits.jensen_rd(a, eta)) - colour) < 1e-12
    beyond, _ = integrate.quad(lambda r: 2 * np.pi * r * profile(r), 0.7, np.inf, epsabs=1e-13)
    assert abs(float(dipole_tail(0.7, a, st, eta)) - beyond) < 1e-10


def test_cycles_skin_bisection_is_within_its_step_of_jensen():
    # Cycles' 12-step float bisection lands within 2^-12 of the float64 inverse
    colour = np.linspace(0.01, 0.99, 97)
    got = fits.cycles_skin_alpha_prime(colour, 1.4)
    exact = reference.invert_rd(colour, 1.4, model="dipole")
    step = 2.0 ** -12
    inside = colour < 0.995
    assert np.all(np.abs(got - exact)[inside] <= step + 1e-6), np.max(np.abs(got - exact))
    assert np.all(got[::8] == np.round(got[::8] / (step / 2)) * (step / 2))  # on the grid


def test_registry_names_every_required_convention():
    for name in ("better-dipole", "dipole", "burley", "van-de-hulst", "cycles-legacy",
                 "cycles-skin", "moonray-walk", "chiang-burley-2016", "hyperion-2018",
                 "random-walk"):
        assert name in CONVENTION, name
    for conv in CONVENTION:
        assert conv.boundary in BOUNDARIES, conv.name
        assert (conv.profile is None) == (conv.alpha_fit is not None), conv.name
        assert conv.colour and conv.radius and conv.source, conv.name
    assert CONVENTION["openpbr"].name == "van-de-hulst"
    assert CONVENTION["pxrsurface"].name == "better-dipole"
    assert len(CONVENTIONS) == len(set(CONVENTIONS))


@pytest.mark.parametrize("name", [c.name for c in CONVENTION if c.alpha_fit is not None])
def test_walk_fits_increase_with_colour(name):
    # the colour -> single-scattering albedo map must be monotone for the conversion to
    # be invertible: checked on a fine grid above the van de Hulst fit's 1e-3 wiggle
    conv = CONVENTION[name]
    c = np.linspace(1e-3, 1.0, 20001)
    a = np.clip(conv.alpha_fit(c, 0.0), 0.0, conv.alpha_max)
    assert np.all(np.diff(a) >= 0.0), name


@pytest.mark.parametrize("c", [0.3, 0.9, 0.999])
def test_half_space_integral_form_matches_the_fixed_point(c):
    # two forms of Chandrasekhar's H: the integral representation (physics.half_space) and
    # the fixed point of the H-equation (this file): 1e-12 apart
    from bdipole_cl.physics import half_space
    assert abs(float(half_space.matched_reflectance(c)) - half_space_albedo(c)) < 1e-12


def test_entry_boundary_limits():
    # at eta -> 1 the entry walk is the index-matched one; at alpha = 1 it returns all that
    # the surface let in (1 - the diffuse Fresnel reflectance, by quadrature here)
    from bdipole_cl.physics import half_space
    from bdipole_cl.physics.fresnel import fresnel_reflectance
    a = np.array([0.3, 0.9])
    np.testing.assert_allclose(half_space.entry_reflectance(a, 1.0 + 1e-12),
                               half_space.matched_reflectance(a), rtol=1e-9)
    f_dr, _ = integrate.quad(lambda m: 2 * m * fresnel_reflectance(m, 1 / 1.4), 0, 1,
                             epsabs=1e-13)
    assert abs(float(half_space.entry_reflectance_fast(1.0, 1.4)) - (1 - f_dr)) < 1e-9
    np.testing.assert_allclose(half_space.entry_reflectance_fast(a, 1.4),
                               half_space.entry_reflectance(a, 1.4), atol=1e-12)


def test_walk_reference_agrees_with_the_h_function():
    # physics.transport (a discrete-ordinates solver) and Chandrasekhar's H (an integral):
    # two independent methods for the index-matched isotropic half-space (measured 1.2e-13)
    transport = pytest.importorskip("bdipole_cl.physics.transport")
    from bdipole_cl.physics import half_space
    a = np.array([0.3, 0.6, 0.9, 0.99, 0.999])
    np.testing.assert_allclose(transport.walk_reflectance(a, g=0.0, eta=1.0),
                               half_space.matched_reflectance(a), atol=1e-10)


def test_cycles_clamps_its_anisotropy_to_0_and_0_9():
    # Cycles' Subsurface Anisotropy is clamped to [0, 0.9] (svm_closure.h): a negative g
    # renders as 0, 0.95 as 0.9, for each of its walks; the other walks take g as given
    from bdipole_cl.physics.conventions import rendered_rd
    c = np.array([0.3, 0.6])
    for name in ("cycles-random-walk", "cycles-legacy", "cycles-skin"):
        np.testing.assert_array_equal(rendered_rd(name, c, 1.4, -0.3), rendered_rd(name, c, 1.4))
        np.testing.assert_array_equal(rendered_rd(name, c, 1.4, 0.95),
                                      rendered_rd(name, c, 1.4, 0.9))
    assert not np.array_equal(rendered_rd("van-de-hulst", c, 1.4, -0.3),
                              rendered_rd("van-de-hulst", c, 1.4))
