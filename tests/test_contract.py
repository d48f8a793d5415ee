"""The numerical contract (docs/model.md "Monotone inverse", "Accuracy"): a monotone inverse
over every float32 albedo, ``auto`` within its tol at every eta, ``double=True`` within 1e-12,
and energy kept by every blur method."""
import warnings

import numpy as np
import pytest

from bdipole_cl import blur, invert_albedo
from bdipole_cl import reference as ref
from bdipole_cl.apps.benchmark import stiff_workload
from bdipole_cl.apps.monotone import sweep
from bdipole_cl.methods.choice import auto_inversion_config
from bdipole_cl.methods.registry import DOUBLE_RHO_TOL, MethodConfig
from bdipole_cl.ops.blur.planning import BlurAccuracyWarning
from bdipole_cl.ops.invert import InversionKernel

#: every test here runs once per working OpenCL device (tests/conftest.py)
pytestmark = pytest.mark.usefixtures("on_device")

SMALLEST = float(np.float32(1.4e-45))    # the smallest positive float32 (a denormal)
FLT_MIN = float(np.finfo(np.float32).tiny)   # the smallest normal float32, 2^-126


# {{{ monotone

@pytest.mark.slow
@pytest.mark.parametrize("eta", [0.5, 1.4, 2.8])
def test_default_table_is_monotone_over_every_float32_albedo(runtime, eta):
    # every positive float32 below 1 (1,065,353,215 of them), in chunks: alpha' must never
    # decrease as Rd increases. Every eta on the first device, the middle one on the others
    # (about 9 s a sweep: the suite's time); the table is the same data on every device
    from conftest import RUNTIMES
    if runtime is not RUNTIMES[0] and eta != 1.4:
        pytest.skip("swept at every eta on the first device, at 1.4 on the others")
    res = sweep(MethodConfig("table"), eta, SMALLEST, 1.0, device=runtime)
    assert res.count == 1065353215
    assert res.reversals == 0 and res.nan == 0, (res.reversals, res.first)


@pytest.mark.parametrize("model, eta", [("dipole", 1.4), ("better", 1.0)])
@pytest.mark.parametrize("size", [64, 1024])
def test_tables_are_monotone_over_the_stiff_ranges(runtime, model, eta, size):
    # every float32 in the stiffest stretches: near 0, around the split, around Rd = 1/2 and
    # the last million below 1
    cfg = MethodConfig("table", table_size=size)
    kernel = InversionKernel((eta,), cfg, model=model, runtime=runtime)
    assert kernel.monotone
    split = float(ref.rd_split(ref.dipole_constants(eta, False, model), model))
    for lo, hi in ((SMALLEST, 1e-30), (split * 0.99, split * 1.01), (0.499, 0.501),
                   (1 - 2**-4, 1.0)):
        res = sweep(cfg, eta, lo, hi, model=model, device=runtime)
        assert res.reversals == 0, (lo, hi, res.first)


@pytest.mark.parametrize("eta", [0.5, 1.4, 2.79])
def test_bisection_is_monotone_near_the_split_and_the_ends(runtime, eta):
    # FLT_MIN's binade too: a device that flushes subnormals (a GPU) reads the first range as 0
    split = float(ref.rd_split(ref.dipole_constants(eta), "better"))
    for lo, hi in ((SMALLEST, 1e-40), (FLT_MIN, 1.3e-38), (split * 0.999, split * 1.001),
                   (0.4999, 0.5001), (1 - 2**-10, 1.0)):
        res = sweep(MethodConfig("bisection"), eta, lo, hi, device=runtime)
        assert res.reversals == 0, (lo, hi, res.first)


def test_the_sweep_finds_reversals_where_there_are_some(runtime):
    # the secant stops at a relative residual: its last step rounds either way, so a ramp of
    # albedos reverses often; the sweep must see it (else the tests above prove nothing)
    res = sweep(MethodConfig("secant"), 1.4, 0.3, 0.3001, device=runtime)
    assert res.reversals > 10 and res.first[0].drop_ulps >= 1
    assert not InversionKernel((1.4,), MethodConfig("secant"), runtime=runtime).monotone


def test_small_tables_and_polish_do_not_claim_monotone(runtime):
    # a coarse table's intervals do not all meet the margin at every eta (table_is_monotone)
    assert not InversionKernel((2.8,), MethodConfig("table", table_size=32),
                               runtime=runtime).monotone
    assert not InversionKernel((1.4,), MethodConfig("table", polish=1), runtime=runtime).monotone
    assert InversionKernel((1.4,), MethodConfig("bisection"), runtime=runtime).monotone

# }}}


# {{{ auto honours tol at every eta, in both precisions

ETAS = [0.5, 0.8, 1.0, 1.4, 2.0, 2.5, 2.79]


@pytest.fixture(scope="module")
def stiff_references():
    rd = stiff_workload(2000)
    return rd, {eta: ref.invert_rd_rho(rd.astype(np.float64), eta)[1] for eta in ETAS}


@pytest.mark.parametrize("tol", [1e-4, 1e-5, 1e-6])
def test_auto_meets_tol_at_every_eta(runtime, tol, stiff_references):
    rd, refs = stiff_references
    choice = auto_inversion_config(tol)
    assert choice.monotone and choice.max_rho_error <= tol
    for eta in ETAS:
        _, rho = invert_albedo(rd, eta, "auto", tol=tol, return_rho=True)
        err = np.max(np.abs(rho / refs[eta] - 1))
        assert err <= tol, (eta, err, choice.config)


def test_auto_the_issue_example():
    # was 1.1e-5 with tol 1e-6: the choice data were measured at eta 1.4 only
    rd = np.float32([0.0720824])
    _, rho = invert_albedo(rd, 2.79, "auto", tol=1e-6, return_rho=True)
    assert abs(rho[0] / ref.invert_rd_rho(rd.astype(np.float64), 2.79)[1][0] - 1) <= 1e-6


def test_auto_in_double_meets_1e_12(runtime, stiff_references):
    if not runtime.has_fp64:
        pytest.skip("no cl_khr_fp64")
    rd, refs = stiff_references
    for eta in (0.5, 1.4, 2.79):
        _, rho = invert_albedo(rd.astype(np.float64), eta, "auto", tol=1e-12, double=True,
                               return_rho=True)
        assert np.max(np.abs(rho / refs[eta] - 1)) <= 1e-12


def test_auto_says_when_no_configuration_meets_tol():
    with pytest.raises(ValueError, match="no monotone f32 configuration reaches it over eta.*"
                                         "float64 reaches 1e-12"):
        invert_albedo([0.5], 1.4, "auto", tol=1e-9)

# }}}


# {{{ double means double

@pytest.mark.parametrize("method", ["table", "secant", "bisection"])
def test_double_reaches_1e_12_for_every_method(runtime, method):
    if not runtime.has_fp64:
        pytest.skip("no cl_khr_fp64")
    # float64 albedos to both stiff ends, far beyond float32's range
    rd = np.concatenate([np.geomspace(1e-300, 0.5, 1500), 1 - np.geomspace(1e-15, 0.5, 1500),
                         np.linspace(1e-6, 1 - 1e-12, 1500)])
    for eta in (0.5, 1.4, 2.8):
        want_a, want_rho = ref.invert_rd_rho(rd, eta)
        a, rho = invert_albedo(rd, eta, method, double=True, return_rho=True)
        assert a.dtype == np.float64
        # DOUBLE_RHO_TOL = 1e-12: what double=True promises (measured <= 6e-14, secant's)
        assert np.max(np.abs(rho / want_rho - 1)) <= DOUBLE_RHO_TOL, (method, eta)
        assert np.max(np.abs(a / want_a - 1)) <= DOUBLE_RHO_TOL, (method, eta)


def test_double_memo_is_refused_with_the_reason():
    with pytest.raises(ValueError, match="float32 baseline: it cannot give rho to 1e-12"):
        invert_albedo([0.5], 1.4, "memo", double=True)

# }}}


# {{{ every blur method keeps energy

@pytest.mark.parametrize("method", ["direct", "gaussians", "fft"])
@pytest.mark.parametrize("albedo, mfp", [(0.99, 0.3), (0.999, 1.0), (0.5, 0.2), (0.8, 3.0)])
def test_constant_irradiance_gives_rd_times_e(runtime, method, albedo, mfp):
    e = np.full((40, 40, 1), 2.5, np.float32)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BlurAccuracyWarning)
        out = blur(e, albedo=albedo, mfp=mfp, method=method, border="clamp")
    # float32 sums of <= (2K+1)^2 weights: a few ulp of the result
    np.testing.assert_allclose(out, 2.5 * albedo, rtol=2e-6)


def test_gaussians_warns_when_its_fit_misses_tol():
    e = np.zeros((21, 21, 1), np.float32)
    e[10, 10] = 1.0
    with pytest.warns(BlurAccuracyWarning, match="L1 error .* > tol"):
        out, info = blur(e, albedo=0.99, mfp=0.3, method="gaussians", border="zero",
                         return_info=True)
    assert info.channels[0].error_bound > 1e-3
    assert abs(out.sum() - 0.99) < 1e-6

# }}}


def test_auto_keeps_a_margin_below_tol_where_sampling_missed_the_worst_albedo(runtime):
    """table(256)'s measured maximum, 8.38e-7, is 9.48e-7 at eta 2.8, Rd 0.4952512 (found by
    an adversarial sweep): auto asked for 8.5e-7 picked it and gave 9.5e-7. With AUTO_MARGIN
    it refuses that tol; at 1e-6 its pick meets tol at that albedo."""
    rd = np.array([0.4952512], np.float32)
    with pytest.raises(ValueError, match="no monotone f32 configuration reaches it"):
        invert_albedo(rd, 2.8, method="auto", tol=8.5e-7, device=runtime)
    _, rho = invert_albedo(rd, 2.8, method="auto", tol=1e-6, return_rho=True, device=runtime)
    _, want = ref.invert_rd_rho(rd.astype(np.float64), 2.8)
    assert abs(rho[0] / want[0] - 1) <= 1e-6
