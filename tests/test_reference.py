"""The float64 reference against independent computations: quadrature, mpmath, identities."""
import mpmath
import numpy as np
import pytest
from scipy.integrate import quad

from bdipole_cl import reference as ref

ETAS = [0.6, 1.0, 1.33, 1.4, 1.6, 2.0, 2.5]
ALPHAS = [1e-3, 0.05, 0.3, 0.7, 0.95, 0.999, 1.0 - 1e-6]


@pytest.mark.parametrize("sigma_t", [0.1, 1.0, 10.0])
@pytest.mark.parametrize("eta", ETAS)
def test_profile_integrates_to_rd(eta, sigma_t):
    # memo eq. 2 by adaptive quadrature against the closed form eq. 3. 1e-9: quad's own
    # relative accuracy on these smooth, exponentially decaying integrands is ~1e-12.
    for alpha in ALPHAS:
        mu = sigma_t * ref.mu_tr_over_sigma_t(1.0 - alpha)
        f = lambda r: 2.0 * np.pi * r * ref.profile(r, alpha, sigma_t, eta)  # noqa: E731
        breaks = [0.0, 1.0 / sigma_t, 10.0 / sigma_t, 1.0 / mu, 30.0 / mu]
        breaks = sorted(set(b for b in breaks if np.isfinite(b)))
        total = sum(quad(f, a, b, epsabs=0, epsrel=1e-13, limit=400)[0]
                    for a, b in zip(breaks, breaks[1:]))
        total += quad(f, breaks[-1], np.inf, epsabs=0, epsrel=1e-13, limit=400)[0]
        want = ref.rd(alpha, eta)
        assert abs(total / want - 1.0) < 1e-9, (eta, sigma_t, alpha, total, want)


@pytest.mark.parametrize("eta", ETAS)
def test_closed_form_matches_literal_memo_formula(eta):
    a = np.concatenate([np.geomspace(1e-6, 0.5, 50), 1.0 - np.geomspace(1e-9, 0.5, 50)])
    np.testing.assert_allclose(ref.rd(a, eta), ref.rd_closed_form(a, eta), rtol=1e-13)


def test_rd_of_one_is_one_for_every_eta():
    etas = np.linspace(*ref.ETA_FIT_RANGE, 200)
    assert np.all(ref.rd(1.0, etas) == 1.0)
    assert np.all(ref.rd(1.0, np.linspace(*ref.ETA_EXACT_RANGE, 50), exact=True) == 1.0)
    assert np.all(ref.rd(1.0, etas, model="dipole") == 1.0)


@pytest.mark.parametrize("exact", [False, True], ids=["fit", "exact"])
def test_rd_is_monotone_over_the_valid_eta_range(exact):
    lo, hi = ref.ETA_EXACT_RANGE if exact else ref.ETA_FIT_RANGE
    a = np.linspace(0.0, 1.0, 4001)
    for eta in np.linspace(lo, hi, 60):
        r = ref.rd(a, eta, exact)
        assert np.all(np.diff(r) > 0), (eta, exact)


def test_fits_beyond_their_range_are_rejected_and_really_break():
    with pytest.raises(ValueError, match=r"eta=2\.9"):
        ref.rd(0.5, 2.9)
    # the reason for the bound: past it the fit gives 2 C1 > 1 and Rd is not monotone
    c1, _ = ref.fresnel_moments_fit(3.0)
    assert 2 * c1 > 1.0
    with pytest.raises(ValueError, match="eta"):
        ref.rd(0.5, 6.0, exact=True)
    assert ref.rd(0.5, 2.9, exact=True) > 0  # exact moments are fine there


def test_profile_cdf_at_infinity_is_rd_and_tail_complements_it():
    for eta in ETAS:
        for alpha in ALPHAS:
            for st in (0.1, 1.0, 10.0):
                rd = ref.rd(alpha, eta)
                assert abs(ref.profile_cdf(np.inf, alpha, st, eta) / rd - 1) < 1e-14
                assert abs(ref.profile_tail(0.0, alpha, st, eta) / rd - 1) < 1e-13
                for r in (0.01 / st, 1.0 / st, 30.0 / st):
                    s = ref.profile_cdf(r, alpha, st, eta) + ref.profile_tail(r, alpha, st, eta)
                    assert abs(s / rd - 1) < 1e-12, (eta, alpha, st, r)


def test_profile_cdf_matches_quadrature_of_the_profile():
    for alpha, st, eta in [(0.9, 1.0, 1.4), (0.3, 10.0, 2.5), (0.999, 0.1, 1.0)]:
        for r in (0.03 / st, 0.5 / st, 4.0 / st):
            q = quad(lambda s: 2 * np.pi * s * ref.profile(s, alpha, st, eta), 0, r,
                     epsabs=0, epsrel=1e-13, limit=200)[0]
            assert abs(ref.profile_cdf(r, alpha, st, eta) / q - 1) < 1e-10, (alpha, st, r)


def test_profile_scales_with_sigma_t():
    # R(r; st) = st^2 R(st r; 1) (docs/model.md "Model")
    r = np.geomspace(1e-3, 10, 30)
    np.testing.assert_allclose(ref.profile(r, 0.8, 7.0, 1.4), 49.0 * ref.profile(7 * r, 0.8, 1.0, 1.4),
                               rtol=1e-13)


def test_stable_profile_matches_literal_formula_where_it_does_not_cancel():
    r = np.geomspace(1e-4, 3.0, 50)
    for alpha in (0.01, 0.5, 0.99):
        np.testing.assert_allclose(ref.profile(r, alpha, 1.0, 1.4),
                                   ref.profile_literal(r, alpha, 1.0, 1.4), rtol=1e-12)


@pytest.mark.parametrize("eta", [0.7, 1.0, 1.4, 2.5, 4.0])
def test_exact_fresnel_moments_match_adaptive_quadrature(eta):
    mu_c = np.sqrt(max(1.0 - 1.0 / eta**2, 0.0))
    want = []
    for i in (1, 2):
        f = lambda m: m**i * ref.fresnel_reflectance(m, eta)  # noqa: E731
        pieces = [(0.0, mu_c), (mu_c, 1.0)] if mu_c > 0 else [(0.0, 1.0)]
        want.append(sum(quad(f, a, b, epsabs=1e-17, epsrel=1e-13, limit=400)[0]
                       for a, b in pieces))  # eta = 1: F ~ 0, hence the absolute floor
    got = ref.fresnel_moments(eta, exact=True)
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-15)


def test_fits_match_exact_moments_to_1e3_and_spec_values():
    eta = np.linspace(0.6, 2.5, 40)
    fit = np.array(ref.fresnel_moments(eta))
    exact = np.array(ref.fresnel_moments(eta, exact=True))
    # docs/model.md "Fresnel moments": "about 1e-3"; the largest gap on [0.6, 2.5] is 1.9e-3 (FM1 at eta = 2.5)
    assert np.max(np.abs(fit - exact)) < 2e-3
    # docs/model.md "Fresnel moments": the quoted values at eta = 1.4
    np.testing.assert_allclose(ref.fresnel_moments(1.4), (0.26496, 0.12881), atol=1e-5)
    np.testing.assert_allclose(ref.fresnel_moments(1.4, exact=True), (0.26449, 0.12959), atol=1e-5)
    # matched index: no reflection at all
    np.testing.assert_allclose(ref.fresnel_moments(1.0, exact=True), (0.0, 0.0), atol=1e-15)


def _mp_rd(alpha, eta):
    """Memo eq. 3 at 40 digits. The constants come from the moments in mpmath, so that
    Ce + 2 A Cphi = 1 holds to 40 digits: float64-rounded constants would put a 1e-16 error
    into Rd near 1 and spoil 1 - Rd = 1e-9 at the 1e-7 level."""
    c1, c2 = (mpmath.mpf(float(v)) for v in ref.fresnel_moments(eta))
    cphi, ce, a_coef = (1 - 2 * c1) / 4, (1 - 3 * c2) / 2, (1 + 3 * c2) / (1 - 2 * c1)
    a = mpmath.mpf(alpha)
    m = mpmath.sqrt((1 - a) * (2 - a) / 3)
    x = 4 * a_coef * m
    tail = cphi * 4 * a_coef if m == 0 else cphi / m * (1 - mpmath.exp(-x))
    return a**2 / 2 * mpmath.exp(-mpmath.sqrt(3 * (1 - a) / (2 - a))) * (ce * (1 + mpmath.exp(-x)) + tail)


@pytest.mark.parametrize("eta", [1.0, 1.4, 2.5])
def test_inversion_matches_mpmath(eta):
    # docs/model.md "Stiffness": the table, recomputed by mpmath root finding at 40 digits
    mpmath.mp.dps = 40
    for rd in (1e-6, 0.01, 0.5, 0.9, 0.99, 0.999, 1 - 1e-9):
        rho_mp = mpmath.findroot(lambda r: _mp_rd(1 - r, eta) - mpmath.mpf(rd),
                                 (mpmath.mpf("1e-30"), mpmath.mpf(1)), solver="anderson")
        alpha, rho = ref.invert_rd_rho(rd, eta)
        assert abs(rho / float(rho_mp) - 1) < 1e-11, (eta, rd, rho, rho_mp)
        assert abs(alpha / float(1 - rho_mp) - 1) < 1e-13, (eta, rd)


@pytest.mark.parametrize("model", ["better", "dipole"])
def test_inversion_round_trips_at_both_stiff_ends(model):
    rd = np.concatenate([np.geomspace(1e-30, 0.5, 300), 1 - np.geomspace(1e-15, 0.5, 300)])
    for eta in (0.6, 1.0, 1.4, 2.5):
        alpha, rho = ref.invert_rd_rho(rd, eta, model=model)
        small = rd < 0.5
        np.testing.assert_allclose(ref.rd(alpha[small], eta, model=model), rd[small], rtol=1e-13)
        np.testing.assert_allclose(ref.one_minus_rd_of_rho(rho[~small], eta, model=model),
                                   1 - rd[~small], rtol=1e-12)


def test_inversion_edge_values():
    alpha, rho = ref.invert_rd_rho(np.array([-1.0, 0.0, 1.0, 2.0, np.nan]), 1.4)
    np.testing.assert_array_equal(alpha[:4], [0, 0, 1, 1])
    np.testing.assert_array_equal(rho[:4], [1, 1, 0, 0])
    assert np.isnan(alpha[4]) and np.isnan(rho[4])


def test_derivative_matches_finite_difference():
    a = np.array([0.01, 0.3, 0.7, 0.99])
    h = 1e-6
    fd = (ref.rd(a + h, 1.4) - ref.rd(a - h, 1.4)) / (2 * h)
    np.testing.assert_allclose(ref.rd_derivative(a, 1.4), fd, rtol=1e-7)


def test_series_helpers_are_continuous_at_their_switch():
    for f in (ref.phi2, ref.psi):
        lo, hi = f(np.nextafter(0.5, 0)), f(0.5)
        assert abs(lo / hi - 1) < 1e-14


def test_the_reference_is_importable_by_its_public_path():
    """docs/python.md and the package docstring name it ``bdipole_cl.reference``: both import forms
    give the one module (physics/reference.py)."""
    import bdipole_cl.reference as public
    from bdipole_cl.physics import reference as own
    assert public is own and hasattr(public, "invert_rd_rho")
