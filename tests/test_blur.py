"""Radial-profile blur (bdipole_cl/blur.py, kernels/blur_direct.cl, kernels/blur_separable.cl)."""
import numpy as np
import pytest
from scipy.integrate import dblquad

from bdipole_cl import InvalidInputError
from bdipole_cl import reference as ref
from bdipole_cl.ops.bands import band_rows, bands
from bdipole_cl.ops.blur import blur, channel_kernel, channel_parameters, fit_gaussians
from bdipole_cl.ops.blur.params import all_finite, checked_irradiance
from bdipole_cl.ops.blur.planning import channel_plans, constant_row_bytes, halo_of

METHODS = ["direct", "gaussians", "fft", "auto"]
# 2e-3 relative: the blur's accuracy target for centre and near texels. direct/fft use the exact weights
# (float32 accumulation ~1e-6); gaussians carry their fit error, reported as error_bound.


#: every test here runs once per working OpenCL device (tests/conftest.py)
pytestmark = pytest.mark.usefixtures("on_device")


def impulse(h=31, w=33, c=1, value=1.0):
    e = np.zeros((h, w, c), np.float32)
    e[h // 2, w // 2] = value
    return e


def test_weights_match_independent_2d_quadrature():
    # docs/model.md "Texel-integrated weights": albedo 0.8, mfp 1.5 texels, eta 1.4 -> centre 0.497 (point: 3.64)
    (alpha, st, eta), = channel_parameters(1, albedo=0.8, mfp=1.5, eta=1.4)
    ck = channel_kernel(alpha, st, eta, 1e-6)
    k = ck.radius
    raw = ck.weights * (1.0 - ck.truncated)     # undo the renormalisation
    f = lambda y, x: ref.profile(np.hypot(x, y), alpha, st, eta)  # noqa: E731
    for i, j in [(0, 0), (1, 0), (1, 1), (2, 1), (3, 3)]:
        want = dblquad(f, i - 0.5, i + 0.5, j - 0.5, j + 0.5, epsabs=1e-13, epsrel=1e-11)[0]
        assert abs(raw[k + j, k + i] / want - 1) < 1e-9, (i, j)
    assert abs(raw[k, k] - 0.497) < 5e-4 and abs(ref.profile(0, alpha, st, eta) - 3.64) < 5e-3


@pytest.mark.parametrize("method", METHODS)
def test_impulse_response_is_the_texel_integrated_profile(method):
    out, info = blur(impulse(), albedo=0.8, mfp=1.5, eta=1.4, method=method, border="zero",
                     return_info=True)
    # the weights of the configuration used (auto may pick a tighter truncation from data)
    auto = info.channels[0].auto
    used_tol = auto.truncation_tol if auto is not None else 1e-3
    ck = channel_kernel(*channel_parameters(1, albedo=0.8, mfp=1.5, eta=1.4)[0], used_tol)
    k = ck.radius
    got = out[15 - k:16 + k, 16 - k:17 + k, 0]
    near = slice(k - 2, k + 3)
    rel = np.abs(got[near, near] / ck.weights[near, near] - 1).max()
    assert rel < 2e-3, (method, rel)
    # everywhere: within the method's own bound relative to max(E) * Rd
    assert np.abs(got - ck.weights).max() <= info.channels[0].error_bound * ck.rd


@pytest.mark.parametrize("method", METHODS)
def test_constant_irradiance_returns_rd_in_the_interior(method):
    albedo = (0.8, 0.5, 0.2)
    e = np.full((48, 48, 3), 2.0, np.float32)
    out, info = blur(e, albedo=albedo, mfp=(2.0, 1.0, 0.5), eta=(1.3, 1.4, 1.5), method=method,
                     return_info=True)
    for c in range(3):
        bound = max(info.channels[c].error_bound, 1e-5)
        np.testing.assert_allclose(out[24, 24, c], 2.0 * albedo[c], rtol=bound)
    # clamp border: constant everywhere, edges included
    np.testing.assert_allclose(out[0, 0], 2.0 * np.array(albedo), rtol=3e-3)


@pytest.mark.parametrize("method", ["direct", "gaussians", "fft"])
def test_linearity_and_symmetry(method):
    rng = np.random.default_rng(3)
    a = rng.uniform(0, 1, (24, 24, 1)).astype(np.float32)
    b = rng.uniform(0, 1, (24, 24, 1)).astype(np.float32)
    kw = dict(albedo=0.7, mfp=1.0, eta=1.4, method=method, border="wrap")
    np.testing.assert_allclose(blur(2 * a + 3 * b, **kw), 2 * blur(a, **kw) + 3 * blur(b, **kw),
                               rtol=1e-5, atol=1e-6)
    # mirror and transpose symmetry of the radial kernel
    np.testing.assert_allclose(blur(a[::-1], **kw), blur(a, **kw)[::-1], rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(blur(a.transpose(1, 0, 2), **kw),
                               blur(a, **kw).transpose(1, 0, 2), rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("method", ["direct", "gaussians", "fft"])
def test_hdr_values_do_not_overflow(method):
    out = blur(impulse(value=1e30) + 1e-30, albedo=0.9, mfp=1.0, eta=1.4, method=method)
    assert np.all(np.isfinite(out)) and out.max() <= 1e30


def test_nan_irradiance_policy():
    e = impulse()
    e[3, 4, 0] = np.nan
    with pytest.raises(InvalidInputError,
                       match=r"1 invalid irradiance value\(s\) \(NaN or infinite\).*x=4, y=3"):
        blur(e, albedo=0.8, mfp=1.0)
    # clamp: non-finite irradiance is unlit (the one policy vocabulary, bdipole_cl/errors.py)
    out = blur(e, albedo=0.8, mfp=1.0, on_invalid="clamp")
    np.testing.assert_allclose(out, blur(impulse(), albedo=0.8, mfp=1.0), rtol=1e-6)
    with pytest.raises(ValueError, match="on_invalid='zero': expected one of raise, clamp"):
        blur(e, albedo=0.8, mfp=1.0, on_invalid="zero")


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_every_non_finite_irradiance_is_found_past_the_one_reduction(bad):
    # all_finite's one sum answers for the whole map; a non-finite texel anywhere (and a sum
    # that overflows, which is not one) must still send the check texel by texel
    e = impulse(value=3e38)
    e[-1, -1, 0] = 3e38                            # the sum overflows: finite, not known so
    assert not all_finite(e)
    assert checked_irradiance(e) is not None       # ... and the texel test passes it
    e[5, 2, 0] = bad
    assert not all_finite(e)
    with pytest.raises(InvalidInputError, match=r"1 invalid irradiance.*x=2, y=5"):
        checked_irradiance(e)
    assert all_finite(impulse()) and all_finite(np.zeros((2, 2, 1), np.float32))


def test_alpha_sigma_t_parameters_and_texel_size():
    (a, st, _), = channel_parameters(1, albedo=0.6, mfp=2.0, eta=1.4)
    e = impulse()
    # atol: the FFT's round-off floor (~1e-16 of the peak) in the far, empty texels
    np.testing.assert_allclose(blur(e, alpha=a, sigma_t=st / 0.5, texel_size=0.5),
                               blur(e, albedo=0.6, mfp=1.0, texel_size=0.5), rtol=1e-6,
                               atol=1e-9)
    # same physics in other units: mfp 2 mm, texel 1 mm == mfp 2 texels
    np.testing.assert_allclose(blur(e, albedo=0.6, mfp=2.0, texel_size=1.0),
                               blur(e, albedo=0.6, mfp=0.2, texel_size=0.1), rtol=1e-5,
                               atol=1e-9)


def test_gaussian_fit_error_is_reported_and_small():
    for mfp in (0.5, 2.0, 8.0):
        (a, st, eta), = channel_parameters(1, albedo=0.8, mfp=mfp, eta=1.4)
        fit = fit_gaussians(a, st, eta, 1e-3)
        # L1 within tol; near cells within the 2e-3 target (measured <= 1e-3 at albedo 0.8)
        assert 0 <= fit.l1_error <= 1e-3 and fit.near_rel_error <= 2e-3, (mfp, fit)


def test_bad_arguments():
    with pytest.raises(ValueError, match="texture-varying"):
        blur(impulse(), albedo=np.full((31, 33, 1), 0.5), mfp=1.0, method="direct")
    with pytest.raises(ValueError, match="method"):
        blur(impulse(), albedo=0.5, mfp=1.0, method="box")
    with pytest.raises(ValueError, match=r"albedo=\[1.0\]: expected values in \(0, 1\)"):
        blur(impulse(), albedo=1.0, mfp=1.0)
    with pytest.raises(ValueError, match="border"):
        blur(impulse(), albedo=0.5, mfp=1.0, border="mirror", method="direct")


def test_blur_cli_on_an_exr(tmp_path, capsys):
    import OpenImageIO as oiio

    from bdipole_cl.apps.cli import main as cli_main
    from bdipole_cl.apps.demo import write_exr
    e = np.random.default_rng(5).uniform(0, 1, (20, 22, 3)).astype(np.float32)
    write_exr(tmp_path / "e.exr", e, ("R", "G", "B"))
    rc = cli_main(["blur", str(tmp_path / "e.exr"), "-o", str(tmp_path / "m.exr"),
                   "--albedo", "0.8,0.6,0.4", "--mfp", "1,0.5,0.25", "--texel-size", "0.5"])
    assert rc == 0 and "wrote" in capsys.readouterr().out
    inp = oiio.ImageInput.open(str(tmp_path / "m.exr"))
    got = inp.read_image(0, 0, 0, 3, oiio.FLOAT)
    assert inp.spec().getattribute("bdipole:source").endswith("e.exr")
    inp.close()
    want = blur(e, albedo=(0.8, 0.6, 0.4), mfp=(1, 0.5, 0.25), texel_size=0.5)
    np.testing.assert_allclose(got, want, rtol=1e-6, atol=1e-7)
    # streamed in bands of a few rows with halos: the same result (auto, data-driven plans)
    for border in ("clamp", "wrap"):
        assert cli_main(["blur", str(tmp_path / "e.exr"), "-o", str(tmp_path / "b.exr"),
                         "--albedo", "0.8,0.6,0.4", "--mfp", "1,0.5,0.25", "--texel-size", "0.5",
                         "--border", border, "--max-memory", "30K"]) == 0
        inp = oiio.ImageInput.open(str(tmp_path / "b.exr"))
        banded = inp.read_image(0, 0, 0, 3, oiio.FLOAT)
        inp.close()
        np.testing.assert_allclose(banded, blur(e, albedo=(0.8, 0.6, 0.4), mfp=(1, 0.5, 0.25),
                                                texel_size=0.5, border=border),
                                   rtol=1e-5, atol=1e-6)
    assert cli_main(["blur", str(tmp_path / "missing.exr"), "-o", str(tmp_path / "x.exr"),
                     "--albedo", "0.8", "--mfp", "1"]) == 1
    assert not (tmp_path / "x.exr").exists()


@pytest.mark.parametrize("border", ["clamp", "zero", "wrap"])
@pytest.mark.parametrize("method", ["direct", "gaussians", "fft"])
def test_banded_blur_with_halo_equals_whole_image(method, border):
    e = np.random.default_rng(9).uniform(0, 1, (37, 29, 2)).astype(np.float32)
    kw = dict(albedo=(0.8, 0.5), mfp=(2.0, 1.0), eta=1.4, method=method, border=border)
    whole = blur(e, **kw)
    _, plans = channel_plans(2, method=method, tol=1e-3, exact=False,
                             **{k: v for k, v in kw.items() if k not in ("method", "border")})
    k = halo_of(plans)
    # a budget of 5 rows plus the halos, by the one band rule (bdipole_cl/ops/bands.py)
    budget = constant_row_bytes(29, 2) * (5 + 2 * k)
    assert band_rows(37, constant_row_bytes(29, 2), budget, halo=k) == 5
    banded = blur(e, max_memory=budget, **kw)
    np.testing.assert_allclose(banded, whole, rtol=1e-5, atol=1e-6)


def test_band_rule():
    assert band_rows(100, 10, None) == 100                       # no budget: one band
    assert band_rows(100, 10, 500, halo=3) == 44                 # 50 rows less two halos
    assert band_rows(100, 10, 10, halo=3) == 1                   # at least one row
    assert band_rows(100, 10, 500, halo=3, tile_height=16) == 32  # whole tiles
    assert band_rows(100, 10, 5000) == 100                       # never past the image
    assert [b[:2] for b in bands(10, 4)] == [(0, 4), (4, 8), (8, 10)]
    assert bands(10, 4, 2, "clamp").__next__()[2].tolist() == [0, 0, 0, 1, 2, 3, 4, 5]


def test_banded_file_blur_halo_follows_auto_plan(tmp_path, monkeypatch):
    # choice data (BDIPOLE_CL_CHOICE_DATA) in which the cheapest configuration meeting 1e-3 is
    # a tighter truncation: auto's kernel is larger than tol's, and so must the halo be
    from bdipole_cl.apps.demo import write_exr
    from bdipole_cl.io.blur_file import blur_file
    from bdipole_cl.methods.choice import ChoiceData, load_choice_data, write_choice_data
    from bdipole_cl.methods.registry import BlurChoice
    from bdipole_cl.ops.blur.planning import plan_channel
    data = ChoiceData("test", load_choice_data().inversion,
                      (BlurChoice("fft", 1e-4, 4, 1.0, 2e-5, 0.001),
                       BlurChoice("direct", 1e-3, 4, 1.0, 2e-4, 0.002)))
    monkeypatch.setenv("BDIPOLE_CL_CHOICE_DATA", str(write_choice_data(data, tmp_path / "c.json")))
    (a, st, eta), = channel_parameters(1, albedo=0.8, mfp=1.0, eta=1.4)
    plan = plan_channel("auto", a, st, eta, 1e-3, False)
    assert plan.kernel.radius > channel_kernel(a, st, eta, 1e-3).radius, plan
    e = np.random.default_rng(6).uniform(0, 1, (24, 20, 1)).astype(np.float32)
    write_exr(tmp_path / "e.exr", e, ("Y",))
    blur_file(tmp_path / "e.exr", tmp_path / "m.exr", albedo=0.8, mfp=1.0, max_memory=1)
    import OpenImageIO as oiio
    inp = oiio.ImageInput.open(str(tmp_path / "m.exr"))
    got = inp.read_image(0, 0, 0, 1, oiio.FLOAT)
    inp.close()
    np.testing.assert_allclose(got.reshape(e.shape), blur(e, albedo=0.8, mfp=1.0),
                               rtol=1e-5, atol=1e-7)


@pytest.mark.parametrize("method, albedo", [
    ("fft", 0.8), ("direct", 0.8), ("gaussians", 0.8), ("auto", 0.8),
    ("fft", "texture"), ("gaussians", "texture")])
def test_exitance_of_a_bright_texel_among_zeros_has_no_negative_or_round_off_values(method,
                                                                                   albedo):
    # R >= 0: the exitance of E >= 0 is >= 0, and a value below the round-off floor (eps32 x
    # max E x Rd; 16 eps32 for the float32 texture-varying FFTs) is a zero result's round-off
    e = impulse(48, 48, 2)
    if albedo == "texture":
        albedo = np.full((48, 48), 0.8, np.float32)
        albedo[0, 0] = 0.5
    out = blur(e, albedo=albedo, mfp=3.0, method=method)
    # an impulse's peak is 2304x its mean: every FFT runs in float64 (``fft_dtype``'s
    # peak_to_mean), whose floor is 1 eps32 (the float32 paths' 16: test_blur_varying.py
    # test_device_gather_settles_as_the_host_does)
    ulps = 1
    floor = ulps * np.finfo(np.float32).eps * 1.0 * 0.5
    assert out.min() >= 0, out.min()
    tiny = (out != 0) & (out < floor)
    assert not tiny.any(), out[tiny][:5]
    assert out.sum() == pytest.approx(2 * 0.8, rel=2e-3)        # the light is all there
    # a channel with negative irradiance is not clamped: -E gives -M
    neg = blur(-e, albedo=albedo, mfp=3.0, method=method)
    np.testing.assert_allclose(neg, -out, atol=floor)


@pytest.mark.parametrize("method", ["fft", "direct"])
def test_the_bound_holds_for_irradiance_of_both_signs(method):
    """+1 within the kernel's radius of a texel and -1 beyond: the renormalized truncation's
    two errors (the kept weights' excess, the dropped tail) add up, to 2 t max|E| Rd; the
    bound says so (and warns: it is above tol), against a float64 convolution with the exact
    weights to radius 120."""
    import warnings
    from bdipole_cl.ops.blur.weights import quadrant_weights, unfold_quadrant
    from scipy.signal import fftconvolve
    e = -np.ones((64, 64))
    e[26:39, 26:39] = 1.0
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        out, info = blur(e.astype(np.float32), albedo=0.8, mfp=1.5, tol=1e-3, method=method,
                         return_info=True)
    assert any("both signs" in str(c.message) for c in caught)
    (a, st, et), = channel_parameters(1, albedo=0.8, mfp=1.5, eta=1.4)
    w = unfold_quadrant(quadrant_weights(a, st, et, 120))
    want = fftconvolve(np.pad(e, 120, mode="edge"), w, mode="valid")
    err = np.abs(out - want).max() / 0.8             # HxW in, HxW out
    assert 1e-3 < err <= info.channels[0].error_bound, (err, info.channels[0])


def test_alpha_prime_zero_gives_zero_not_nan():
    for method in ("auto", "direct", "fft"):
        out = blur(np.ones((8, 8, 3), np.float32), alpha=(0.9, 0.0, 0.5), sigma_t=1.0,
                   method=method)
        assert np.isfinite(out).all() and not out[..., 1].any() and out[..., 0].min() > 0


@pytest.mark.parametrize("value", [1e36, 3e38])
def test_a_field_near_the_float32_limit_stays_finite(value):
    """A float32 FFT of 1e36 x 4096 texels would overflow: such planes are transformed in
    float64 (``fft_dtype``'s peak_sum), and the exitance is E x Rd."""
    out = blur(np.full((64, 64), value, np.float32), albedo=0.8, mfp=2.0, method="fft")
    np.testing.assert_allclose(out[8:-8, 8:-8], 0.8 * value, rtol=1e-6)


@pytest.mark.parametrize("albedo", [0.8, "texture"])
def test_result_has_the_irradiance_shape(albedo):
    """HxW in, HxW out (as bdipole_cl.dask.blur); HxWx1 in, HxWx1 out; the same values, from
    blur and from a plan's apply."""
    from bdipole_cl.ops.blur import Scattering, plan_blur
    rng = np.random.default_rng(3)
    e = rng.uniform(0, 1, (12, 14)).astype(np.float32)
    a = rng.uniform(0.3, 0.9, (12, 14)).astype(np.float32) if albedo == "texture" else albedo
    flat = blur(e, albedo=a, mfp=1.5)
    deep = blur(e[..., None], albedo=a, mfp=1.5)
    assert flat.shape == (12, 14) and deep.shape == (12, 14, 1)
    np.testing.assert_array_equal(flat, deep[..., 0])
    planned, _ = plan_blur(e.shape, Scattering(albedo=a, mfp=1.5)).apply(e)
    assert planned.shape == (12, 14)
    np.testing.assert_array_equal(planned, flat)


@pytest.mark.parametrize("max_memory", [float("nan"), -5, 0, "100", True])
def test_max_memory_must_be_a_number_of_bytes(max_memory):
    with pytest.raises(ValueError, match="max_memory=.*expected a number of bytes > 0"):
        blur(np.ones((8, 8), np.float32), albedo=0.5, mfp=2.0, max_memory=max_memory)


def test_max_memory_infinite_is_no_budget():
    e = np.random.default_rng(2).uniform(0, 1, (8, 8)).astype(np.float32)
    np.testing.assert_array_equal(blur(e, albedo=0.5, mfp=2.0, max_memory=float("inf")),
                                  blur(e, albedo=0.5, mfp=2.0))


@pytest.mark.parametrize("shape", [(12,), (1, 12, 9, 1), (12, 9, 0), (0, 9), (-3, 9),
                                   (12.0, 9), 5])
def test_plan_blur_names_a_bad_shape(shape):
    from bdipole_cl.ops.blur import Scattering, plan_blur
    with pytest.raises(ValueError, match=r"shape .*expected \(height, width\)"):
        plan_blur(shape, Scattering(albedo=0.5, mfp=2.0))


@pytest.mark.parametrize("method", ["direct", "fft", "gaussians"])
def test_a_tol_below_float32s_round_off_reports_the_round_off(runtime, method):
    """tol 1e-9: float32 exitance cannot be within it, so the bound reports the method's
    round-off (direct: sums of 33 taps, Neumaier over rows; fft: the float64 transform's
    exitance in float32; gaussians: its separable sums, after its fit's L1 error) and warns;
    the error against a float64 reference (the exact weights at tol 1e-12, whose truncation,
    ~1e-12, is far below the round-off) is within it. Gaussians' fit could not converge at such
    tols: it keeps the best basis that did and warns, not scipy's RuntimeError."""
    import warnings

    from bdipole_cl.ops.blur.fft import fft_blur_channel
    from bdipole_cl.ops.blur.planning import BlurAccuracyWarning
    albedo, mfp, eta = 0.5, 0.7, 1.4
    e = np.random.default_rng(1).random((24, 24)).astype(np.float32)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        out, info = blur(e, albedo=albedo, mfp=mfp, eta=eta, tol=1e-9, method=method,
                         return_info=True, device=runtime)
    assert any(issubclass(w.category, BlurAccuracyWarning) for w in caught)
    bound = info.channels[0].error_bound
    assert 1e-7 < bound < 1e-4
    (a, st, et), = channel_parameters(1, albedo=albedo, mfp=mfp, eta=eta)
    exact = fft_blur_channel(e.astype(np.float64), channel_kernel(a, st, et, 1e-12).weights,
                             "clamp")
    assert np.abs(out - exact).max() / (e.max() * albedo) <= bound      # HxW in, HxW out


@pytest.mark.parametrize("peak", [1e-44, 3e-39, 1e-25], ids=lambda p: f"{p:g}")
@pytest.mark.parametrize("method", METHODS + ["texture", "texture, an unlit texel", "stretch"])
def test_a_tiny_irradiance_stays_within_the_reported_bound(method, peak):
    """docs/model.md: the bound holds "for any irradiance". A 1e-44 peak lost every bit of its
    exitance to float32 underflow (gaussians 370x its bound, auto 1470x); now the channel is
    blurred scaled to a peak near 1 and the bound takes float32's absolute floor (2^-150 /
    (max E Rd)), against a float64 convolution with the exact weights to radius 40."""
    import warnings

    from scipy.signal import fftconvolve

    from bdipole_cl.ops.blur.weights import quadrant_weights, unfold_quadrant
    e = np.zeros((40, 40))
    e[20, 20], e[10, 25], e[30, 8] = 1.0, 0.5, 0.25
    e = (e * peak).astype(np.float32)          # the irradiance as given: float32 (subnormal)
    peak = float(e.max())
    from bdipole_cl.ops.blur.stretched import Stretch
    textured = method.startswith("texture")
    mfp = np.full((40, 40), 1.5, np.float32) if textured else 1.5
    albedo = np.full((40, 40), 0.8, np.float32) if textured else 0.8
    if method == "texture, an unlit texel":      # its Rd 0 did not take the floor away
        albedo[0, 0] = 0.0
    one = np.ones((40, 40), np.float32)          # the stretched blur of unit texels: the same
    extra = {"stretch": Stretch(one, one)} if method == "stretch" else {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")          # the floor above tol is warned of
        out, info = blur(e, albedo=albedo, mfp=mfp, tol=1e-3,
                         method="fft" if textured or method == "stretch" else method,
                         border="zero", return_info=True, **extra)
    (a, st, et), = channel_parameters(1, albedo=0.8, mfp=1.5, eta=1.4)
    w = unfold_quadrant(quadrant_weights(a, st, et, 40))
    unit = e.astype(np.float64) / peak             # float64, exact weights
    want = fftconvolve(unit, w, mode="same") * peak
    rd = float(ref.rd(a, et))
    err = np.abs(out.astype(np.float64) - want).max() / (peak * rd)
    assert err <= info.channels[0].error_bound, (method, peak, err, info.channels[0])
    if peak < 1e-38:                             # the floor is there, and only there
        assert info.channels[0].error_bound >= 2.0 ** -150 / (peak * rd)


def test_auto_passes_over_a_measured_truncation_wider_than_max_radius(monkeypatch):
    """mfp 500 texels at tol 1e-2: ``auto``'s data pick fft at truncation 1e-4, a kernel of
    radius 3727 > max_radius 2048, and it raised where ``method="fft"`` (radius 1757) meets
    tol. It now passes over that configuration for one that fits, within tol. Made small
    here (a 2048-texel kernel takes 20 s to build): max_radius 40 and mfp 8 texels, whose
    kernel is 28 texels at 1e-2, 44 at 1e-3 and 60 at the data's 1e-4."""
    from bdipole_cl.ops.blur import planning, weights
    monkeypatch.setattr(planning, "channel_kernel",
                        lambda *a, **k: weights.channel_kernel(*a, **k, max_radius=40))
    e = impulse(h=16, w=16)
    with pytest.raises(ValueError, match="exceeds max_radius=40"):
        blur(e, albedo=0.5, mfp=8.0, tol=1e-4, method="fft")      # the data's pick: too wide
    got, info = blur(e, albedo=0.5, mfp=8.0, tol=1e-2, method="auto", return_info=True)
    want, fft = blur(e, albedo=0.5, mfp=8.0, tol=1e-2, method="fft", return_info=True)
    ch = info.channels[0]
    assert ch.radius <= 40 and ch.error_bound <= 1e-2, ch
    assert ch.auto is not None and ch.auto.truncation_tol <= 1e-2
    # both exitances within their bounds of the exact one: within the sum of each other
    scale = float(e.max()) * ch.rd
    assert np.abs(got - want).max() <= (ch.error_bound + fft.channels[0].error_bound) * scale


@pytest.mark.parametrize("kind", ["constant", "texture", "direct", "gaussians"])
def test_a_faint_band_of_a_lit_image_takes_the_images_floor(kind):
    """An image lit (0.5-1) but for rows of 1e-44 blurred in bands: each band's float32 floor
    is relative to the image's peak, as blurred whole (it was the band's own: 9e-2 for 6e-4,
    and warned of), so the bound does not depend on max_memory."""
    import warnings
    e = (np.random.default_rng(5).random((64, 64, 3)) * 0.5 + 0.5).astype(np.float32)
    e[40:] = 1e-44
    albedo = np.full((64, 64, 3), 0.8, np.float32) if kind == "texture" else 0.8
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        # (direct and gaussians run on the device end to end, banded there)
        method = kind if kind in ("direct", "gaussians") else "auto"
        whole, one = blur(e, albedo=albedo, mfp=2.0, return_info=True, method=method)
        banded, many = blur(e, albedo=albedo, mfp=2.0, return_info=True, max_memory=16384,
                            method=method)
    for a, b in zip(one.channels, many.channels):
        assert b.error_bound <= a.error_bound * (1 + 1e-9) + 1e-12, (a, b)
    assert np.abs(banded - whole).max() <= 1e-5


def test_a_stretched_blur_of_both_signs_counts_its_truncation_twice():
    """As every blur: an irradiance of both signs can add the renormalized truncation's error
    from both (docs/model.md "Blur error bound"): the stretched bound takes tol once more
    than for the same irradiance of one sign, and says so past tol."""
    import warnings

    from bdipole_cl.ops.blur.planning import BlurAccuracyWarning
    from bdipole_cl.ops.blur.stretched import Stretch
    one = np.ones((32, 32), np.float32)
    e = np.random.default_rng(2).random((32, 32, 1)).astype(np.float32)
    _, plus = blur(e, albedo=0.6, mfp=2.0, stretch=Stretch(one, 2 * one), return_info=True)
    with pytest.warns(BlurAccuracyWarning, match="both signs"):
        _, both = blur(e - 0.5, albedo=0.6, mfp=2.0, stretch=Stretch(one, 2 * one),
                       return_info=True)
    assert both.channels[0].error_bound == pytest.approx(plus.channels[0].error_bound + 1e-3,
                                                         rel=1e-12)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        blur(e, albedo=0.6, mfp=2.0, stretch=Stretch(one, 2 * one))


@pytest.mark.parametrize("method", METHODS)
def test_a_clamped_nan_is_read_as_zero_by_every_method(method):
    """on_invalid="clamp" reads a NaN texel as 0: the output finite everywhere, for each
    method (direct and gaussians, on the device end to end, read the NaN itself where nothing
    was scaled: a third of the image NaN), whole and in bands; the bands' floor relative to
    the image's finite peak (a NaN there made every band take its own: 0.12 for 4e-4)."""
    import warnings
    e = np.ones((48, 40, 2), np.float32)
    e[24, 3, 0] = np.nan
    out = blur(e, albedo=0.6, mfp=0.8, texel_size=0.3, method=method, on_invalid="clamp")
    assert np.all(np.isfinite(out))
    faint = (np.random.default_rng(3).random((48, 40)) * 1e-30).astype(np.float32)
    faint[:30] *= np.float32(1e-14)
    faint[5, 3] = np.nan
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        _, whole = blur(faint, albedo=0.6, mfp=0.8, texel_size=0.3, method=method,
                        on_invalid="clamp", return_info=True)
        banded, many = blur(faint, albedo=0.6, mfp=0.8, texel_size=0.3, method=method,
                            on_invalid="clamp", max_memory=20000, return_info=True)
    assert np.all(np.isfinite(banded))
    assert many.channels[0].error_bound <= whole.channels[0].error_bound * (1 + 1e-9) + 1e-12
