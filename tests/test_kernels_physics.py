"""kernels/bdipole.h (through kernels/physics_eval.cl) against bdipole_cl/reference.py.

Bounds are in units of the unit roundoff u (2^-24 float32, 2^-53 float64). Each function is a
chain of <= 8 correctly-signed operations whose built-ins carry <= 4 ulp (OpenCL 1.2 tables
7.2/7.3), with no cancellation left (see the header's comments), so ~16 u bounds them; the
profile's exp(-mu d) turns the absolute rounding of its argument into relative error, hence
the extra (1 + mu d) factor. Energies (cdf, tail) are judged relative to the total Rd.
"""
import numpy as np
import pytest

from bdipole_cl import reference as ref
from bdipole_cl.ops import physics_eval as physics
from conftest import EPS32, EPS64, f32

PRECISIONS = [pytest.param(False, id="float32"), pytest.param(True, id="float64")]
ETAS = [0.6, 1.0, 1.4, 2.5]


#: every test here runs once per working OpenCL device (tests/conftest.py)
pytestmark = pytest.mark.usefixtures("on_device")


def unit(double):
    return EPS64 if double else EPS32


def representable(want, double):
    """Where the true value is a normal number of the precision (float32 underflows to 0 or
    to denormals below 1.2e-38: a range limit, not an accuracy loss)."""
    return want > (1e-300 if double else 1e-37)


def _skip_without_fp64(double, runtime):
    if double and not runtime.has_fp64:
        pytest.skip("device has no cl_khr_fp64")


@pytest.mark.parametrize("double", PRECISIONS)
@pytest.mark.parametrize("eta", ETAS)
def test_rd_kernel(eta, double, runtime):
    _skip_without_fp64(double, runtime)
    a = f32(np.concatenate([[0.0, 1e-30, 1e-6], np.geomspace(1e-6, 0.5, 1500),
                            1 - np.geomspace(2**-24, 0.5, 1500), [1.0]]))
    got = physics.evaluate("rd", a, eta=eta, double=double)
    want = ref.rd(a, eta)
    ok = representable(want, double)
    err = np.max(np.abs(got[ok] / want[ok] - 1)) / unit(double)
    assert err <= 16, (err, "rd", eta, double)
    assert got[0] == 0 and got[-1] == 1.0


@pytest.mark.parametrize("double", PRECISIONS)
@pytest.mark.parametrize("eta", ETAS)
def test_one_minus_rd_kernel_keeps_relative_accuracy_as_rd_goes_to_one(eta, double, runtime):
    _skip_without_fp64(double, runtime)
    q = f32(np.concatenate([np.geomspace(1e-12, 0.7071, 2000)]))
    got = physics.evaluate("one_minus_rd", q, eta=eta, double=double)
    want = ref.one_minus_rd_of_rho(q * q, eta)
    err = np.max(np.abs(got / want - 1)) / unit(double)
    assert err <= 16, (err, "one_minus_rd", eta, double)


ALPHAS = f32([1e-3, 0.3, 0.9, 0.999, 1 - 1e-6, 1.0])[:, None]
RADII = f32(np.concatenate([[0.0], np.geomspace(1e-4, 1e3, 300)]))[None, :]


@pytest.mark.parametrize("double", PRECISIONS)
@pytest.mark.parametrize("sigma_t", [0.1, 1.0, 10.0])
@pytest.mark.parametrize("eta", ETAS)
def test_profile_kernel(eta, sigma_t, double, runtime):
    _skip_without_fp64(double, runtime)
    got = physics.evaluate("profile", RADII, ALPHAS, sigma_t, eta=eta, double=double)
    want = ref.profile(RADII, ALPHAS, sigma_t, eta)
    mu_d = sigma_t * ref.mu_tr_over_sigma_t(1 - ALPHAS) * np.sqrt(RADII**2 + 9 / sigma_t**2)
    ok = representable(want, double)
    err = (np.abs(got - want)[ok] / (want * (1 + mu_d))[ok]).max() / unit(double)
    assert err <= 16, (err, "profile", eta, sigma_t, double)
    assert np.all(np.isfinite(got))


@pytest.mark.parametrize("double", PRECISIONS)
@pytest.mark.parametrize("func", ["profile_cdf", "profile_tail"])
@pytest.mark.parametrize("sigma_t", [0.1, 1.0, 10.0])
@pytest.mark.parametrize("eta", ETAS)
def test_energy_kernels(eta, sigma_t, func, double, runtime):
    _skip_without_fp64(double, runtime)
    got = physics.evaluate(func, RADII, ALPHAS, sigma_t, eta=eta, double=double)
    want = physics.reference_value(func, RADII, ALPHAS, sigma_t, eta=eta)
    total = ref.rd(ALPHAS, eta)
    err = (np.abs(got - want) / total).max() / unit(double)
    assert err <= 16, (err, func, eta, sigma_t, double)


def test_cdf_kernel_reaches_rd_and_starts_at_zero(runtime):
    got = physics.evaluate("profile_cdf", f32([[0.0, 1e30, np.inf]]), ALPHAS, 1.0, eta=1.4)
    assert np.all(got[:, 0] == 0)
    rd = ref.rd(ALPHAS[:, 0], 1.4)
    np.testing.assert_allclose(got[:, 2], rd, rtol=16 * EPS32)
    # at r = 1e30 all the energy is inside, except at alpha' = 1 (mu_tr = 0), where the
    # tail decays as 1/r: then it is Rd - O(1/r), still finite
    np.testing.assert_allclose(got[:, 1], rd, rtol=16 * EPS32)
    assert np.all(np.isfinite(got))
