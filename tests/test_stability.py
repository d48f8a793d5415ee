"""Stability suite: stiff and extreme inputs. Each case asserts one of two outcomes, named in
its id: FINITE (finite and within the stated bound) or ERROR (a clear error naming the value).
"""
import numpy as np
import pytest

from bdipole_cl import InvalidInputError, albedo_to_coefficients, invert_albedo
from bdipole_cl import reference as ref
from bdipole_cl import blur

DENORMAL = float(np.float32(1e-40))          # a float32 denormal
METHODS = ["table", "secant", "bisection"]
ALPHA_TOL, RHO_TOL = 1e-6, 1e-4              # docs/model.md "Accuracy"


# {{{ albedo

#: every test here runs once per working OpenCL device (tests/conftest.py)
pytestmark = pytest.mark.usefixtures("on_device")


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("rd", [0.0, DENORMAL, 1e-30, 1e-6, 0.5, 1 - 1e-7, 1.0],
                         ids=["0", "denormal", "1e-30", "1e-6", "0.5", "1-1e-7", "1"])
def test_FINITE_albedo_inversion(rd, method):
    rd32 = np.float32(rd)
    alpha, rho = invert_albedo(np.array([rd32]), 1.4, method, return_rho=True)
    assert np.isfinite(alpha).all() and np.isfinite(rho).all()
    want_a, want_rho = ref.invert_rd_rho(np.float64(rd32), 1.4)
    if want_a > 0:
        # alpha' ~ sqrt(Rd/k): for denormal Rd alpha' itself is ~1e-20, a normal number
        assert abs(alpha[0] / want_a - 1) <= ALPHA_TOL
    else:
        assert alpha[0] == 0
    if want_rho > 0:
        assert abs(rho[0] / want_rho - 1) <= RHO_TOL
    else:
        assert rho[0] == 0 and alpha[0] == 1


@pytest.mark.parametrize("rd", [1.5, np.inf, np.nan, -np.inf], ids=[">1", "inf", "nan", "-inf"])
def test_ERROR_invalid_albedo_is_reported_or_clamped(rd):
    with pytest.raises(InvalidInputError, match="invalid albedo"):
        invert_albedo(np.array([0.3, rd]), 1.4)
    a = invert_albedo(np.array([0.3, rd]), 1.4, on_invalid="clamp")   # FINITE under clamp
    assert np.isfinite(a).all()


@pytest.mark.parametrize("rd", [1.0, 1 - 1e-7], ids=["1", "1-1e-7"])
def test_albedo_near_one_in_coefficients(rd):
    if rd == 1.0:   # ERROR: infinitely dense for a finite mfp
        with pytest.raises(InvalidInputError, match=">= 1"):
            albedo_to_coefficients(rd, 1.0, 1.4)
        sa, ss = albedo_to_coefficients(rd, 1.0, 1.4, on_invalid="clamp")
    else:           # FINITE and exact
        sa, ss = albedo_to_coefficients(rd, 1.0, 1.4)
        want = ref.albedo_to_coefficients(np.float64(np.float32(rd)), 1.0, 1.4)
        assert abs(sa / want[0] - 1) < RHO_TOL and abs(ss / want[1] - 1) < 1e-5
    assert np.isfinite(sa) and np.isfinite(ss) and sa > 0 and ss > 0

# }}}


# {{{ eta

@pytest.mark.parametrize("eta", [0.6, 1.0, 1.0001, 2.5])
def test_FINITE_eta_sweep(eta):
    rd = np.float32([1e-6, 0.2, 0.8, 0.999])
    alpha, rho = invert_albedo(rd, eta, return_rho=True)
    want_a, want_rho = ref.invert_rd_rho(rd.astype(np.float64), eta)
    assert np.all(np.abs(alpha / want_a - 1) <= ALPHA_TOL)
    assert np.all(np.abs(rho / want_rho - 1) <= RHO_TOL)


def test_FINITE_eta_one_branch_jump_is_small():
    # docs/model.md "Fresnel moments": the fits' two branches jump slightly at eta = 1; the inverse stays continuous
    # to within that jump (measured: 0.14% in rho at Rd = 0.5)
    lo, hi = invert_albedo(np.float32([0.5, 0.5]), (np.nextafter(1.0, 0), 1.0),
                           return_rho=True)[1]
    assert 1e-4 < abs(lo / hi - 1) < 3e-3


@pytest.mark.parametrize("eta", [0.3, 2.9, 5.5, np.nan], ids=["0.3", "2.9", "5.5", "nan"])
def test_ERROR_eta_out_of_range(eta):
    with pytest.raises(ValueError, match="outside"):
        invert_albedo(0.5, eta)

# }}}


# {{{ mean free path

@pytest.mark.parametrize("mfp", [1e-6, 1.0, 1e6])
def test_FINITE_mfp_extremes_round_trip(mfp):
    rd = np.float32([0.01, 0.5, 0.99])
    sa, ss = albedo_to_coefficients(rd, mfp, 1.4)
    st = sa.astype(np.float64) + ss
    rho = sa / st
    back_mfp = 1.0 / (st * ref.mu_tr_over_sigma_t(rho))
    assert np.all(np.isfinite(sa)) and np.all(np.abs(back_mfp / mfp - 1) < 1e-5)


@pytest.mark.parametrize("mfp", [0.0, -1.0], ids=["0", "negative"])
def test_ERROR_mfp_non_positive(mfp):
    with pytest.raises(InvalidInputError, match="mfp"):
        albedo_to_coefficients(0.5, mfp, 1.4)
    sa, ss = albedo_to_coefficients(0.5, mfp, 1.4, on_invalid="clamp")   # FINITE under clamp
    assert np.isfinite(sa) and np.isfinite(ss)

# }}}


# {{{ blur

@pytest.mark.parametrize("texel_over_mfp", [0.01, 100.0], ids=["texel-100x-smaller",
                                                                 "texel-100x-larger"])
def test_FINITE_texel_size_extremes(texel_over_mfp):
    e = np.full((24, 24, 1), 3.0, np.float32)
    out, info = blur(e, albedo=0.7, mfp=1.0, texel_size=texel_over_mfp, return_info=True)
    assert np.all(np.isfinite(out))
    # constant irradiance: Rd everywhere (clamp border), to the method's bound
    np.testing.assert_allclose(out, 3.0 * 0.7, rtol=max(info.channels[0].error_bound, 1e-5))
    if texel_over_mfp > 1:
        assert info.channels[0].radius == 0          # all energy in the texel itself


@pytest.mark.parametrize("method", ["direct", "gaussians", "fft"])
def test_FINITE_irradiance_extremes(method):
    e = np.zeros((20, 20, 1), np.float32)
    assert np.all(blur(e, albedo=0.8, mfp=1.0, method=method) == 0)          # all-zero image
    e[5, 5] = 1e30
    e[12, 12] = 1e-30
    out = blur(e, albedo=0.8, mfp=1.0, method=method, border="zero")
    assert np.all(np.isfinite(out))
    assert abs(out.sum() / (0.8 * 1e30) - 1) < 2e-3    # energy kept (all inside the image)


def test_ERROR_nan_irradiance_or_zero_policy():
    e = np.ones((8, 8, 1), np.float32)
    e[2, 3] = np.nan
    with pytest.raises(ValueError, match="x=3, y=2"):
        blur(e, albedo=0.8, mfp=1.0)
    assert np.all(np.isfinite(blur(e, albedo=0.8, mfp=1.0, on_invalid="clamp")))

# }}}
