"""What a GPU's float32 arithmetic does to the kernels, tested on any device (docs/numerics.md
"What a GPU does"): an H200's OpenCL flushes subnormals and rounds sqrt inexactly, and the
default table reversed there near FLT_MIN. The CPU runtimes built with GPU-like numerics
(``Runtime.with_numerics``: subnormals flushed by -cl-denorms-are-zero, every float32 sqrt and
the inversion's divisions moved by up to 2 ulps, as OpenCL allows) must keep the inversion
monotone (docs/model.md "Monotone inverse") and within its accuracy bounds.

The emulations need a clang-based CPU runtime; on another device (a GPU) those tests skip, and
the device's own arithmetic is what the tests without emulation check (here and in
tests/test_contract.py)."""
import numpy as np
import pytest

from bdipole_cl import albedo_to_coefficients
from bdipole_cl import reference as ref
from bdipole_cl.apps.cli import main as cli_main
from bdipole_cl.apps.crosscheck import run_crosscheck
from bdipole_cl.apps.monotone import sweep
from bdipole_cl.device.numerics import NUMERICS, numerics_options
from bdipole_cl.device.runtime import device_kind
from bdipole_cl.methods.registry import MethodConfig
from bdipole_cl.ops import physics_eval as physics
from bdipole_cl.ops.invert import InversionKernel
from bdipole_cl.physics import tables
from conftest import rel_err, stiff_albedos

#: every test here runs once per working OpenCL device (tests/conftest.py)
pytestmark = pytest.mark.usefixtures("on_device")

SMALLEST = float(np.float32(1.4e-45))          # the smallest positive float32 (a subnormal)
FLT_MIN = float(np.finfo(np.float32).tiny)     # the smallest normal float32, 2^-126
EMULATED = [name for name in NUMERICS.names if name != "device"]


def emulating(runtime, name):
    """``runtime`` built for the numerics ``name``; a skip where the emulation cannot run."""
    if device_kind(runtime.device) != "cpu":
        pytest.skip("the emulated numerics need a clang-based CPU runtime; this device's own "
                    "arithmetic is tested as it is")
    return runtime.with_numerics(name)


def float32_range(lo, hi):
    """Every float32 in [lo, hi) (positive lo, hi), in order."""
    a, b = (int(np.float32(v).view(np.uint32)) for v in (lo, hi))
    return np.arange(a, b, dtype=np.uint32).view(np.float32)


#: binades where a sqrt can go wrong: FLT_MIN's neighbourhood (the H200's reversals were at
#: 1.5e-38 .. 5.9e-38), around 2^-60 (where BD_SQRT_RN starts scaling), and [1/4, 1)
SQRT_RANGES = [(FLT_MIN, 2.0**-124), (2.0**-61, 2.0**-59), (0.25, 1.0)]


def sqrt_inputs():
    """Every float32 of SQRT_RANGES, and 2^20 random positive float32 below 1 (normal)."""
    rng = np.random.default_rng(7)
    bits = rng.integers(np.float32(FLT_MIN).view(np.uint32), np.float32(1).view(np.uint32),
                        1 << 20, dtype=np.uint32)
    return np.concatenate([float32_range(lo, hi) for lo, hi in SQRT_RANGES]
                          + [bits.view(np.float32)])


def evaluate_sqrt(func, x, rt, chunk=1 << 22):
    """``physics_eval``'s ``func`` ("sqrt" or "sqrt_rn") of float32 ``x`` on ``rt``."""
    return np.concatenate([physics.evaluate(func, x[i:i + chunk], device=rt).astype(np.float32)
                           for i in range(0, x.size, chunk)])


def ulps_between(a, b):
    return np.abs(a.view(np.int32).astype(np.int64) - b.view(np.int32).astype(np.int64))


# {{{ the numerics and their build options

def test_each_numerics_adds_its_options_to_every_program(runtime):
    # one registry holds the -cl-* options and defines; the device's sqrt is used as it is only
    # on a CPU and only where the numerics trust it
    cpu = device_kind(runtime.device) == "cpu"
    assert numerics_options(runtime.device, NUMERICS["device"]) == (
        ("-DBD_DEVICE_SQRT_RN",) if cpu else ())
    assert numerics_options(runtime.device, NUMERICS["gpu"]) == (
        "-cl-denorms-are-zero", "-DBD_INEXACT_MATH")
    assert numerics_options(runtime.device, NUMERICS["corrected"]) == ()
    gpu_like = runtime.with_numerics("gpu")
    assert (gpu_like.context, gpu_like.queue) == (runtime.context, runtime.queue)
    assert gpu_like.describe().endswith(", numerics gpu)") and runtime.numerics.name == "device"
    with pytest.raises(ValueError, match="numerics='cuda': expected one of device, ftz"):
        runtime.with_numerics("cuda")

# }}}


# {{{ the sqrt the inversion's variable is made of

@pytest.mark.parametrize("numerics", NUMERICS.names)
def test_the_inversions_sqrt_is_correctly_rounded_whatever_the_devices(runtime, numerics):
    # BD_SQRT_RN: the device's sqrt corrected (or, where the device's is known to be correctly
    # rounded, used as it is): equal to float32's correctly rounded sqrt, bit for bit, under
    # flushed subnormals and a sqrt off by 2 ulps alike
    rt = runtime if numerics == "device" else emulating(runtime, numerics)
    x = sqrt_inputs()
    got, want = evaluate_sqrt("sqrt_rn", x, rt), np.sqrt(x)
    wrong = np.flatnonzero(got != want)
    assert wrong.size == 0, (numerics, wrong.size, x[wrong[:3]], got[wrong[:3]], want[wrong[:3]])


def test_the_cpu_runtimes_sqrt_is_correctly_rounded(runtime):
    # what BD_DEVICE_SQRT_RN (device.numerics.sqrt_is_correctly_rounded) assumes of a CPU:
    # its compiler's sqrt is the instruction set's IEEE one
    if device_kind(runtime.device) != "cpu":
        pytest.skip("only CPUs' sqrt is used uncorrected")
    x = sqrt_inputs()
    got = evaluate_sqrt("sqrt", x, runtime)
    wrong = np.flatnonzero(got != np.sqrt(x))
    assert wrong.size == 0, (wrong.size, x[wrong[:3]], got[wrong[:3]])


def test_the_emulated_sqrt_errs_as_far_as_opencl_allows_and_reverses(runtime):
    # "inexact" must be a sqrt that a test can catch: within OpenCL's 3 ulp, yet not monotone
    rt = emulating(runtime, "inexact")
    x = float32_range(0.25, 0.25 + 2.0**-12)                # 8192 consecutive floats
    got = evaluate_sqrt("sqrt", x, rt)
    err = ulps_between(got, np.sqrt(x))
    assert 1 <= err.max() <= 2, err.max()                   # 2 ulps moved + 0.5 of rounding
    assert np.count_nonzero(got[1:] < got[:-1]) > 100       # reversals everywhere


@pytest.mark.parametrize("numerics", ["device", "ftz"])
def test_ftz_flushes_subnormal_albedos_to_zero(runtime, numerics):
    # -cl-denorms-are-zero: a subnormal Rd reads as 0 (alpha' 0, as Rd <= 0 gives), a normal
    # one is untouched; the CPU runtimes keep subnormals without it (CL_FP_DENORM)
    rt = runtime if numerics == "device" else emulating(runtime, numerics)
    rd = np.float32([SMALLEST, 1e-40, FLT_MIN, 2 * FLT_MIN])
    alpha = InversionKernel((1.4,), MethodConfig("table"), runtime=rt).run(rd)["alpha"]
    assert np.all(alpha[2:] > 0), alpha
    if numerics == "ftz":
        assert np.all(alpha[:2] == 0), alpha
    elif device_kind(runtime.device) == "cpu":
        assert np.all(alpha[:2] > 0) and np.all(np.diff(alpha) > 0), alpha

# }}}


# {{{ the inversion stays monotone under a GPU's arithmetic

#: the float32 stretches a GPU's arithmetic can spoil: the subnormals and FLT_MIN's binades
#: (flushed inputs, tiny products), around the split, around Rd = 1/2 and the top
def stiff_ranges(eta, model="better"):
    split = float(ref.rd_split(ref.dipole_constants(eta, False, model), model))
    return ((SMALLEST, 1e-37), (split * 0.99, split * 1.01), (0.499, 0.501), (1 - 2**-4, 1.0))


def test_the_tables_keep_the_margin_a_flushed_product_needs():
    # docs/model.md "On every device": a product of s(u) = u^2 (c2 + c3 u) flushes only where
    # u > 2^-63/sqrt(|c2| + |c3|) > 2^-60, where the fma's argument grows by |c1| ulp(u) >
    # |c1| 2^-84 > 2^-102 a step, far more than the flush's 2^-125: the bounds stated there
    worst_c23, least_c1 = 0.0, np.inf
    for model in ("better", "dipole"):
        for n in (32, 64, 128, 256, 1024):
            for eta in (0.5, 0.8, 1.0, 1.4, 2.0, 2.5, 2.8):
                rows = tables.inversion_table(eta, n, False, model)[0].astype(np.float64)
                cubic = rows.reshape(tables.SEGMENTS, n + 1, 4)[:, :n]
                worst_c23 = max(worst_c23, float((abs(cubic[..., 2]) + abs(cubic[..., 3])).max()))
                least_c1 = min(least_c1, float(abs(cubic[..., 1]).min()))
    assert worst_c23 < 0.007 and least_c1 >= 5.7e-6, (worst_c23, least_c1)
    assert 2.0**-63 / np.sqrt(worst_c23) > 2.0**-60 and least_c1 * 2.0**-84 > 2.0**-102


@pytest.mark.parametrize("numerics", EMULATED)
@pytest.mark.parametrize("eta", [0.5, 1.4, 2.8])
def test_default_table_is_monotone_under_gpu_numerics(runtime, numerics, eta):
    rt = emulating(runtime, numerics)
    for lo, hi in stiff_ranges(eta):
        res = sweep(MethodConfig("table"), eta, lo, hi, device=rt)
        assert res.monotone, (numerics, lo, hi, res.reversals, res.rho_reversals, res.first)


@pytest.mark.parametrize("model, eta", [("dipole", 1.4), ("better", 1.0)])
@pytest.mark.parametrize("size", [64, 1024])
def test_other_tables_are_monotone_under_gpu_numerics(runtime, model, eta, size):
    # the GPU's reversals at eta 1.0, sizes 64 and 1024 (tests/test_contract.py's stiff ranges)
    rt = emulating(runtime, "gpu")
    cfg = MethodConfig("table", table_size=size)
    for lo, hi in stiff_ranges(eta, model):
        res = sweep(cfg, eta, lo, hi, model=model, device=rt)
        assert res.monotone, (lo, hi, res.reversals, res.rho_reversals, res.first)


@pytest.mark.parametrize("eta", [0.5, 1.4, 2.79])
def test_bisection_is_monotone_under_gpu_numerics(runtime, eta):
    # its lower half's target is the same sqrt as the table's variable
    rt = emulating(runtime, "gpu")
    split = float(ref.rd_split(ref.dipole_constants(eta), "better"))
    for lo, hi in ((1e-39, 1.3e-38), (1e-7, 1.0001e-7), (split * 0.999, split * 1.001),
                   (0.4999, 0.5001), (1 - 2**-10, 1.0)):
        res = sweep(MethodConfig("bisection"), eta, lo, hi, device=rt)
        assert res.monotone, (lo, hi, res.reversals, res.rho_reversals, res.first)


@pytest.mark.slow
def test_default_table_is_monotone_over_every_float32_albedo_under_gpu_numerics(runtime):
    # ~20 s on a 2-core CI machine: on the first device only (the stretches above on all)
    from conftest import RUNTIMES
    if runtime is not RUNTIMES[0]:
        pytest.skip("swept on the first device; the stiff stretches on every device")
    rt = emulating(runtime, "gpu")
    res = sweep(MethodConfig("table"), 1.4, SMALLEST, 1.0, device=rt)
    assert res.count == 1065353215
    assert res.monotone, (res.reversals, res.rho_reversals, res.first)


def test_gpu_numerics_leave_the_tables_results_unchanged(runtime):
    # from a normal Rd the lookup's only inexact step was the sqrt, now correctly rounded: the
    # same bits as the device's own arithmetic (a subnormal Rd is 0 under FTZ)
    rt = emulating(runtime, "gpu")
    rng = np.random.default_rng(3)
    rd = np.concatenate([float32_range(FLT_MIN, 1.5 * FLT_MIN)[::7],
                         rng.uniform(1e-6, 1.0, 1 << 20).astype(np.float32),
                         np.float32(np.geomspace(FLT_MIN, 1e-6, 100000))])
    for table_size in (64, 256):
        cfg = MethodConfig("table", table_size=table_size)
        want = InversionKernel((0.5, 1.4, 2.8), cfg, runtime=runtime).run(
            np.repeat(rd, 3), None, ("alpha", "rho"))
        got = InversionKernel((0.5, 1.4, 2.8), cfg, runtime=rt).run(
            np.repeat(rd, 3), None, ("alpha", "rho"))
        for name in ("alpha", "rho"):
            differ = np.flatnonzero(got[name] != want[name])
            assert differ.size == 0, (table_size, name, np.repeat(rd, 3)[differ[:3]])

# }}}


# {{{ the accuracy bounds hold under a GPU's arithmetic

def test_every_kernel_meets_its_bound_under_gpu_numerics(runtime, capsys):
    # the physics (16 u) and every inversion method (alpha' 1e-6, rho 1e-4) with flushed
    # subnormals and inexact sqrt and divisions; the CLI says which arithmetic it checked
    rt = emulating(runtime, "gpu")
    rows = run_crosscheck((0.5, 1.4, 2.8), n=300, include=("physics", "invert"), device=rt)
    assert {r.status for r in rows} <= {"PASS", "INFO"}, [r for r in rows if r.status == "FAIL"]
    assert any("invert bisection" in r.function for r in rows)
    assert cli_main(["crosscheck", "--eta", "1.4", "--n", "60", "--numerics", "gpu"]) == 0
    out = capsys.readouterr().out
    assert "numerics gpu)" in out.splitlines()[0] and "0 over their bound" in out, out


@pytest.mark.parametrize("model", ["better", "dipole"])
@pytest.mark.parametrize("method", ["table", "bisection", "secant"])
def test_coefficients_meet_their_bounds_under_gpu_numerics(runtime, model, method):
    # sigma_t' = 1/(mfp mu_tr/sigma_t') through the emulated sqrt and division (the table's
    # vectorised kernel, and kernels/invert.cl for the others): tests/test_invert.py's bounds
    # (measured <= 8.9e-7 under gpu numerics, <= 6.0e-7 with the CPU's own)
    rt = emulating(runtime, "gpu")
    rd = stiff_albedos()
    mfp = np.geomspace(0.01, 100.0, rd.size)
    sigma_a, sigma_s = albedo_to_coefficients(rd, mfp, 1.4, method, model=model, device=rt)
    want_a, want_s = ref.albedo_to_coefficients(rd, mfp, 1.4, model=model)
    assert rel_err(sigma_a, want_a).max() < 1e-4 and rel_err(sigma_s, want_s).max() < 1e-5

# }}}
