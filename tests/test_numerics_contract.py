"""The numerical contract against computations written apart from the package: mpmath
(inversion at 40 digits from the Fresnel fits' decimal coefficients), and brute-force sums of
exact texel-integrated weights (docs/model.md "Blur error bound", "Fresnel moments")."""
import mpmath
import numpy as np
import pytest

import bdipole_cl as bd
from bdipole_cl import InvalidInputError
from bdipole_cl.ops.blur.params import texel_parameters

#: every test here runs once per working OpenCL device (tests/conftest.py)
pytestmark = pytest.mark.usefixtures("on_device")

# d'Eon & Irving 2011 as published (decimal strings), for the independent mpmath inversion
_C1 = {"lo": "0.45966 -1.73965 3.37668 -3.904945 2.49277 -0.68441",
       "hi": "-4.61686 11.1136 -10.4646 5.11455 -1.27198 0.12746"}
_C2_LO = "0.27614 -0.87350 1.12077 -0.65095 0.07883 0.04860"


def _mp_poly(x, coefs):
    return sum(mpmath.mpf(c) * x**k for k, c in enumerate(coefs.split()))


def _mp_moments(eta):
    e = mpmath.mpf(eta)
    if eta < 1:
        return _mp_poly(e, _C1["lo"]), _mp_poly(e, _C2_LO)
    c2 = (mpmath.mpf("-547.033") + mpmath.mpf("45.3087") / e**3 - mpmath.mpf("218.725") / e**2
          + mpmath.mpf("458.843") / e
          + _mp_poly(e, "0 404.557 -189.519 54.9327 -9.00603 0.63942"))
    return _mp_poly(e, _C1["hi"]), c2


def _mp_rd(rho, c1, c2):
    """Memo eq. 3 (docs/model.md "Rd") of rho = 1 - alpha' at the working precision."""
    cphi, ce, a_coef = (1 - 2 * c1) / 4, (1 - 3 * c2) / 2, (1 + 3 * c2) / (1 - 2 * c1)
    a = 1 - rho
    m = mpmath.sqrt(rho * (1 + rho) / 3)
    x = 4 * a_coef * m
    return (a**2 / 2 * mpmath.exp(-mpmath.sqrt(3 * rho / (1 + rho)))
            * (ce * (1 + mpmath.exp(-x)) + cphi / m * (1 - mpmath.exp(-x))))


def _mp_rho(rd, eta):
    c1, c2 = _mp_moments(eta)
    return mpmath.findroot(lambda r: _mp_rd(r, c1, c2) - mpmath.mpf(rd),
                           (mpmath.mpf("1e-30"), mpmath.mpf(1)), solver="anderson")


# {{{ item: double=True rho within 1e-12 at every eta of the fits' range

#: the double=True promise (registry.DOUBLE_RHO_TOL). The float64 solve's own error is a few ulp
#: times the condition of rho in Rd (< 1e3 at these Rd), <= ~1e-13: what is left of the 1e-12
#: is for the constants, which the float64 Horner sums of the fits spoiled (3.6e-12 at eta 2.8)
DOUBLE_RHO_TOL = 1e-12


@pytest.mark.parametrize("eta", [1.0, 1.4, 2.0, 2.5, 2.8])
def test_double_rho_matches_mpmath_from_the_published_fit(runtime, eta):
    if not runtime.has_fp64:
        pytest.skip("no cl_khr_fp64")
    mpmath.mp.dps = 40
    rd = np.array([1e-4, 0.005, 0.02426, 0.1, 0.3, 0.6, 0.9, 0.999])
    _, rho = bd.invert_albedo(rd, eta, double=True, return_rho=True)
    want = np.array([float(_mp_rho(r, eta)) for r in rd])
    err = np.abs(rho / want - 1)
    assert err.max() <= DOUBLE_RHO_TOL, (eta, err.max(), rd[np.argmax(err)])

# }}}


# {{{ item: what the kernel sees is what is checked (float32 rounding of the inputs)

@pytest.mark.parametrize("rd", [0.99999999, 1 - 2.0**-25, 1 - 1e-12])
def test_albedo_rounding_to_one_in_float32_raises_or_clamps_below_one(rd):
    assert rd < 1 and np.float32(rd) == 1         # valid in float64, 1.0 to the kernel
    with pytest.raises(InvalidInputError, match="albedo"):
        bd.albedo_to_coefficients(rd, 1.0, 1.4)
    sa, ss = bd.albedo_to_coefficients(rd, 1.0, 1.4, on_invalid="clamp")
    below = np.nextafter(np.float32(1), np.float32(0))
    want_sa, want_ss = bd.reference.albedo_to_coefficients(float(below), 1.0, 1.4)
    assert np.isfinite(sa) and np.isfinite(ss), (rd, sa, ss)
    # the largest float32 below 1, inverted: within the inversion's 1e-4 rho contract
    assert abs(sa / want_sa - 1) < 1e-4 and abs(ss / want_ss - 1) < 1e-4, (rd, sa, ss)


@pytest.mark.parametrize("mfp", [1e-50, 1e50])
def test_mfp_out_of_float32_range_raises_or_clamps(mfp):
    with pytest.raises(InvalidInputError, match="mfp"):
        bd.albedo_to_coefficients(0.5, mfp, 1.4)
    sa, ss = bd.albedo_to_coefficients(0.5, mfp, 1.4, on_invalid="clamp")
    assert np.isfinite(sa) and np.isfinite(ss) and sa > 0 and ss > 0, (mfp, sa, ss)


def test_clamped_albedo_texels_never_blur_with_rd_one():
    e = np.zeros((9, 9, 1), np.float32)
    e[4, 4] = 1.0
    albedo = np.full((9, 9), 0.5)
    albedo[4, 4] = 1.5                             # invalid: clamped into [0, 1)
    albedo[4, 5] = 0.99999999                      # valid in float64, 1.0 in float32
    with pytest.raises(InvalidInputError, match="2 invalid albedo"):
        bd.blur(e, albedo=albedo, mfp=1.0)
    rd_max = float(np.nextafter(np.float32(1), np.float32(0)))
    out, info = bd.blur(e, albedo=albedo, mfp=1.0, method="fft", on_invalid="clamp",
                        return_info=True)
    # the exit texel's energy is Rd(x) times what reaches it; a constant E = 1 returns Rd(x)
    flat, _ = bd.blur(np.ones((9, 9, 1), np.float32), albedo=albedo, mfp=1.0, method="fft",
                      on_invalid="clamp", return_info=True)
    # the Rd map the kernels read: the largest float32 below 1 at both texels, never 1.0
    rd, _ = texel_parameters((9, 9, 1), 0, albedo=albedo, mfp=1.0, on_invalid="clamp")
    assert rd.dtype == np.float32 and rd[4, 4] == rd_max and rd[4, 5] == rd_max, rd[4, 4:6]
    for x in (4, 5):
        # float32 rounding of the basis sums (~1e-6 of E): far below 1 - rd_max is not
        # resolvable here, so the map above is the check that Rd = 1 is never used
        assert abs(flat[4, x, 0] - rd_max) < 1e-5, (x, flat[4, x, 0])
    assert np.all(np.isfinite(out)) and info.channels[0].method.startswith("fft")

# }}}
