"""Inversion kernels (kernels/invert.cl) against the float64 reference inverse.

Every method is judged against the exact inverse of its float32 input. Bounds (docs/model.md "Accuracy"):
alpha' relative error <= 1e-6 (~8 float32 ulps: the inverse is well conditioned in the split
variables, so a few ulps of residual rounding is all that should remain) and rho relative error
<= 1e-4 for Rd in [1e-6, 0.999], eta in [1.0, 2.5]. The memo's own bisection is kept to show
that it cannot meet the rho bound (docs/model.md "Stiffness"), and it must fail it.
"""
import numpy as np
import pytest

import bdipole_cl
from bdipole_cl import InvalidInputError, albedo_to_coefficients, invert_albedo
from bdipole_cl import reference as ref
from conftest import f32, rel_err

ALPHA_TOL = 1e-6
RHO_TOL = 1e-4

CONFIGS = [
    pytest.param("table", {}, id="table-default"),
    pytest.param("table", {"table_size": 64, "polish": 1}, id="table64-polish1"),
    pytest.param("secant", {}, id="secant-default"),
    pytest.param("secant", {"seed_size": 1, "iterations": 60}, id="secant-seed1"),
    pytest.param("bisection", {}, id="bisection"),
]


#: every test here runs once per working OpenCL device (tests/conftest.py)
pytestmark = pytest.mark.usefixtures("on_device")


def sweep():
    rng = np.random.default_rng(7)
    return f32(np.concatenate([np.geomspace(1e-6, 0.5, 3000), 1 - np.geomspace(1e-3, 0.5, 3000),
                               rng.uniform(1e-6, 0.999, 3000)]))


@pytest.mark.parametrize("method,knobs", CONFIGS)
@pytest.mark.parametrize("eta", [1.0, 1.4, 2.5])
def test_methods_meet_the_accuracy_bounds(method, knobs, eta):
    rd = sweep()
    want_a, want_rho = ref.invert_rd_rho(rd, eta)
    alpha, rho = invert_albedo(rd.astype(np.float32), eta, method, return_rho=True, **knobs)
    ea, er = rel_err(alpha, want_a).max(), rel_err(rho, want_rho).max()
    assert ea <= ALPHA_TOL and er <= RHO_TOL, (method, knobs, eta, ea, er)


@pytest.mark.parametrize("method", ["table", "secant", "bisection"])
@pytest.mark.parametrize("eta", [0.6, 1.0, 1.4, 2.5])
def test_continuity_at_the_segment_and_half_switches(method, eta):
    # Rd_split (alpha' = 1/2) and Rd = 1/2, with their float32 neighbours on each side
    split = ref.rd_split(ref.dipole_constants(eta))
    pts = []
    for x in (np.float32(split), np.float32(0.5)):
        pts += [np.nextafter(x, np.float32(0), dtype=np.float32), x,
                np.nextafter(x, np.float32(1), dtype=np.float32)]
    rd = np.array(pts, np.float32)
    alpha, rho = invert_albedo(rd, eta, method, return_rho=True)
    want_a, want_rho = ref.invert_rd_rho(rd.astype(np.float64), eta)
    assert rel_err(alpha, want_a).max() <= ALPHA_TOL, (method, eta)
    assert rel_err(rho, want_rho).max() <= RHO_TOL, (method, eta)


def test_knob_validation():
    for bad in ({"table_size": 0}, {"seed_size": 2.5}, {"iterations": -1}, {"tol": 0.0}):
        with pytest.raises(ValueError, match=next(iter(bad))):
            invert_albedo(0.5, 1.4, "secant" if "seed_size" in bad else "table", **bad)


def test_memo_bisection_loses_rho_as_spec_says():
    rd = sweep()
    _, want_rho = ref.invert_rd_rho(rd, 1.4)
    alpha, rho = invert_albedo(rd, 1.4, "memo", return_rho=True)
    assert rel_err(rho, want_rho).max() > 1e-2   # docs/model.md "Stiffness": rho error up to 1.0
    assert rel_err(alpha, ref.invert_rd(rd, 1.4)).max() < 1e-6  # alpha' itself is fine


def test_float64_device_path_is_float64_accurate(has_fp64):
    if not has_fp64:
        pytest.skip("no cl_khr_fp64")
    rd = np.concatenate([np.geomspace(1e-12, 0.5, 500), 1 - np.geomspace(1e-12, 0.5, 500)])
    want_a, want_rho = ref.invert_rd_rho(rd, 1.4)
    for method in ("secant", "bisection"):
        kw = {"iterations": 80} if method == "bisection" else {}
        a, rho = invert_albedo(rd, 1.4, method, double=True, return_rho=True, **kw)
        assert a.dtype == np.float64
        # 1e-12: float64 residuals carry ~1e-15; the secant stops at 1e-12 relative
        assert rel_err(a, want_a).max() < 1e-12 and rel_err(rho, want_rho).max() < 1e-10, method


@pytest.mark.parametrize("model", ["better", "dipole"])
def test_round_trip_coefficients_give_back_rd_and_mfp(model):
    rd = sweep()[::3]
    mfp = np.geomspace(0.01, 100.0, rd.size)
    sigma_a, sigma_s = albedo_to_coefficients(rd, mfp, 1.4, model=model)
    sigma_a, sigma_s = sigma_a.astype(np.float64), sigma_s.astype(np.float64)
    st = sigma_a + sigma_s
    rho = sigma_a / st
    back_rd = ref.rd_of_rho(rho, 1.4, model=model)
    back_mfp = 1.0 / (st * ref.mu_tr_over_sigma_t(rho, model))
    assert rel_err(back_rd, rd).max() <= 1e-5
    assert rel_err(back_mfp, mfp).max() <= 1e-5
    # and against the float64 reference mapping directly
    ra, rs = ref.albedo_to_coefficients(rd, mfp, 1.4, model=model)
    assert rel_err(sigma_a, ra).max() < 1e-4 and rel_err(sigma_s, rs).max() < 1e-5


def test_dipole_model_matches_its_reference_and_differs_from_better():
    rd = sweep()
    a_dip = invert_albedo(rd, 1.4, model="dipole")
    assert rel_err(a_dip, ref.invert_rd(rd, 1.4, model="dipole")).max() <= ALPHA_TOL
    assert np.max(np.abs(a_dip - invert_albedo(rd, 1.4))) > 1e-2


def test_shapes_dtypes_and_per_channel_eta():
    rd = f32(np.random.default_rng(1).uniform(0.01, 0.99, (5, 7, 3)))
    etas = (1.3, 1.4, 1.5)
    alpha, rho = invert_albedo(rd, etas, return_rho=True)
    assert alpha.shape == rd.shape and alpha.dtype == np.float32
    for c, eta in enumerate(etas):
        want = ref.invert_rd(rd[..., c], eta)
        assert rel_err(alpha[..., c], want).max() <= ALPHA_TOL, c
    assert invert_albedo(0.5, 1.4).shape == ()
    assert invert_albedo([], 1.4).shape == (0,)
    with pytest.raises(ValueError, match="3 values but the input's last axis has 2"):
        invert_albedo(np.full((4, 2), 0.5), etas)


def test_broadcast_scalars_and_tuples_in_coefficients():
    sa, ss = albedo_to_coefficients((0.8, 0.5, 0.3), 2.0, (1.3, 1.4, 1.5))
    assert sa.shape == (3,)
    sa2, _ = albedo_to_coefficients(np.full((2, 2, 3), (0.8, 0.5, 0.3)), (1.0, 2.0, 4.0), 1.4)
    assert sa2.shape == (2, 2, 3)
    want = ref.albedo_to_coefficients(np.array([0.8, 0.5, 0.3]), np.array([1.0, 2.0, 4.0]), 1.4)[0]
    assert rel_err(sa2[1, 1], want).max() < 1e-5


def test_outputs_selection_and_sigma_t():
    a, rho, st = albedo_to_coefficients(0.7, 3.0, 1.4, outputs=("alpha", "rho", "sigma_t"))
    want_a, want_rho = ref.invert_rd_rho(0.7, 1.4)
    assert abs(a / want_a - 1) < 1e-6 and abs(rho / want_rho - 1) < 1e-5
    assert abs(st * 3.0 * ref.mu_tr_over_sigma_t(want_rho) - 1) < 1e-5


def test_input_policy():
    a, rho = invert_albedo(np.array([-0.5, 0.0, 1.0]), 1.4, return_rho=True)
    np.testing.assert_array_equal(a, [0, 0, 1])
    np.testing.assert_array_equal(rho, [1, 1, 0])
    bad = np.array([0.5, np.nan, 1.5, 0.2, np.inf])
    with pytest.raises(InvalidInputError, match=r"3 invalid albedo.*index \(1,\): nan") as info:
        invert_albedo(bad, 1.4)
    assert info.value.count == 3 and info.value.first_index == (1,)
    a = invert_albedo(bad, 1.4, on_invalid="clamp")
    assert np.all(np.isfinite(a)) and a[1] == 0 and a[2] == 1 and a[4] == 1


def test_coefficient_input_policy():
    with pytest.raises(InvalidInputError, match="albedo.*>= 1"):
        albedo_to_coefficients(1.0, 1.0, 1.4)
    with pytest.raises(InvalidInputError, match=r"mfp.*index \(2,\)"):
        albedo_to_coefficients(0.5, np.array([1.0, 2.0, -1.0, np.nan]), 1.4)
    sa, ss = albedo_to_coefficients(np.array([1.0, np.nan, 0.5, 0.5]),
                                    np.array([1.0, 1.0, 0.0, np.nan]), 1.4, on_invalid="clamp")
    assert np.all(np.isfinite(sa)) and np.all(np.isfinite(ss)), (sa, ss)
    assert np.all(sa >= 0) and np.all(ss >= 0)


def test_bad_eta_and_method_are_clear_errors():
    with pytest.raises(ValueError, match=r"eta=3\.2 is outside"):
        invert_albedo(0.5, 3.2)
    assert np.isfinite(invert_albedo(0.5, 3.2, exact=True))
    with pytest.raises(ValueError, match="method='newton'"):
        invert_albedo(0.5, 1.4, "newton")
    with pytest.raises(ValueError, match="on_invalid"):
        invert_albedo(0.5, 1.4, on_invalid="ignore")


def test_runtime_describes_device(runtime):
    assert runtime.describe()
    assert any(s.works for s in bdipole_cl.survey())
