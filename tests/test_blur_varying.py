"""Texture-varying blur parameters (bdipole_cl/ops/blur/textured*.py, kernels/blur_textured.cl)."""
import functools
import warnings

import numpy as np
import pytest
from scipy.integrate import dblquad

from bdipole_cl import reference as ref
from bdipole_cl import InvalidInputError
from bdipole_cl.ops.blur import blur, channel_parameters
from bdipole_cl.ops.blur import fft as blur_fft
from bdipole_cl.ops.blur.dispatch import weight_planes
from bdipole_cl.ops.blur.stretched import Stretch
from bdipole_cl.ops.blur.planning import BlurAccuracyWarning
from bdipole_cl.ops.blur.fft import cached_spectra, kernel_spectra, times_spectrum
from bdipole_cl.ops.blur.textured import textured_plans as channel_plans
from bdipole_cl.ops.blur.textured_plan import (RD_MAX, RD_MIN, REFINE, interpolated_weights,
                                               node_kernel, texel_coords, transformed)
from bdipole_cl.ops.blur.weights import quadrant_weights, unfold_quadrant

#: every test here runs once per working OpenCL device (tests/conftest.py)
pytestmark = pytest.mark.usefixtures("on_device")

H, W = 20, 22


def gradient_maps(c=1):
    """Albedo 0.2 -> 0.9 along x, mfp 1 -> 2 texels along y (a smooth painted texture)."""
    yy, xx = np.mgrid[0:H, 0:W]
    albedo = np.repeat((0.2 + 0.7 * xx / (W - 1))[..., None], c, axis=2)
    mfp = np.repeat((2.0 ** (yy / (H - 1)))[..., None], c, axis=2)
    return albedo, mfp


def per_texel_reference(e, albedo, mfp, eta, radius, border="edge"):
    """M(x) = sum_cells E(cell) W_x(cell - x), W_x the exact texel-integrated kernel of x's own
    parameters (float64, one kernel per texel), truncated at ``radius`` and summing to Rd(x)."""
    k = radius
    pad = np.pad(e.astype(np.float64), k, mode=border)
    out = np.zeros(e.shape)
    for y in range(e.shape[0]):
        for x in range(e.shape[1]):
            rd = albedo[y, x]
            q = node_kernel(float(np.clip(rd, RD_MIN, RD_MAX)), float(mfp[y, x]), eta, k)
            out[y, x] = (pad[y:y + 2 * k + 1, x:x + 2 * k + 1] * unfold_quadrant(q)).sum() * rd
    return out


@pytest.mark.parametrize("varying", ["both", "albedo", "mfp"])
@pytest.mark.parametrize("method", ["fft", "gaussians"])
def test_matches_the_per_exit_texel_reference(method, varying):
    rng = np.random.default_rng(5)
    e = rng.uniform(0, 1, (H, W, 1)).astype(np.float32)
    albedo, mfp = gradient_maps()
    if varying == "albedo":          # a constant ld axis: one node, one tap on it
        mfp = np.full_like(mfp, 1.7)
    elif varying == "mfp":
        albedo = np.full_like(albedo, 0.6)
    out, info = blur(e, albedo=albedo, mfp=mfp, eta=1.4, method=method, return_info=True)
    ch = info.channels[0]
    want = per_texel_reference(e[..., 0], albedo[..., 0], mfp[..., 0], 1.4, ch.radius)
    err = np.abs(out[..., 0] - want) / (e.max() * albedo[..., 0])
    # the kernel error measured by the plan (fit + interpolation, L1 of the normalized kernel)
    # bounds the output error relative to max(E) * Rd(x); + 1e-5 for float32 accumulation
    assert err.max() <= max(ch.fit_error, ch.interp_error) + 1e-5, (err.max(), ch)
    assert err.max() < 2e-3
    assert ch.error_bound < 3e-3


@functools.lru_cache(maxsize=1)
def near_case():
    """(E with one bright texel, albedo, mfp of ld 2..4 texels: K ~ 20) and its per-texel
    reference at the common radius (the same for every near field)."""
    rng = np.random.default_rng(9)
    e = rng.uniform(0, 1, (H, W, 1)).astype(np.float32)
    e[5, 7] = 30.0                                  # a bright texel: the near cells carry it
    albedo, mfp = gradient_maps()
    mfp *= 2.0
    _, info = blur(e, albedo=albedo, mfp=mfp, eta=1.4, return_info=True)
    radius = info.channels[0].radius
    return e, albedo, mfp, radius, per_texel_reference(e[..., 0], albedo[..., 0],
                                                       mfp[..., 0], 1.4, radius)


@pytest.mark.parametrize("near", [-1, 1, 3, 6])
def test_every_near_field_matches_the_per_exit_texel_reference(monkeypatch, near):
    """Each near field radius (its kernels convolved with the irradiance in the gather and
    weighted per texel, the rest in the FFT basis) within the plan's measured error of the
    per-texel reference; the near kernels reconstruct every node in the texture's range
    within their share of tol."""
    from bdipole_cl.ops.blur import near_field, textured_plan
    e, albedo, mfp, radius, want = near_case()
    monkeypatch.setattr(near_field, "NEAR_RADII", (near,))
    textured_plan.PLAN_CACHE.clear()
    try:
        out, info = blur(e, albedo=albedo, mfp=mfp, eta=1.4, return_info=True)
        (plan, rd, ld, ext), = channel_plans((H, W, 1), tol=1e-3, albedo=albedo, mfp=mfp)
    finally:
        textured_plan.PLAN_CACHE.clear()
    assert plan.near == near
    ch = info.channels[0]
    assert ch.radius == radius
    err = np.abs(out[..., 0] - want) / (e.max() * albedo[..., 0])
    # as test_matches_the_per_exit_texel_reference: the plan's measured kernel error bounds
    # the output's relative to max(E) * Rd(x), + 1e-5 for float32 accumulation
    assert err.max() <= max(ch.fit_error, ch.interp_error) + 1e-5, (near, err.max(), ch)
    # the near field of every node inside the range, from the table's float32 weights and
    # the near kernels' float32 values: within NEAR_TOL_SHARE * tol in L1 (the SVD's
    # criterion) + 1e-6 for the float32 rounding of ~10 weights and values
    rd_range, ld_range = textured_plan.parameter_ranges(ext)
    inside = np.outer(textured_plan.inside_range(plan.axes[0], rd_range),
                      textured_plan.inside_range(plan.axes[1], ld_range))
    assert inside.any()
    r = near + 1
    mult = near_field.multiplicity(plan.radius)[:r, :r]
    for iu, iv in zip(*np.nonzero(inside)):
        got = np.tensordot(plan.table[iu, iv].astype(np.float64), plan.quadrants(), 1)
        exact = node_kernel(plan.axes[0].values[iu], plan.axes[1].values[iv], 1.4, plan.radius)
        near_err = (np.abs(got - exact)[:r, :r] * mult).sum()
        assert near_err <= near_field.NEAR_TOL_SHARE * 1e-3 + 1e-6, (near, iu, iv, near_err)


def test_near_field_shrinks_the_fft_basis(monkeypatch):
    from bdipole_cl.ops.blur import near_field, textured_plan
    albedo, mfp = gradient_maps()
    sizes = []
    for near in (-1, 3):
        monkeypatch.setattr(near_field, "NEAR_RADII", (near,))
        textured_plan.PLAN_CACHE.clear()
        (plan, *_), = channel_plans((H, W, 1), tol=1e-3, albedo=albedo, mfp=4 * mfp)
        sizes.append(len(plan.kernels))
    textured_plan.PLAN_CACHE.clear()
    assert sizes[1] < sizes[0], sizes


def test_uniform_texture_equals_constant_parameters():
    rng = np.random.default_rng(6)
    e = rng.uniform(0, 1, (H, W, 2)).astype(np.float32)
    albedo, mfp = (0.7, 0.4), (1.5, 3.0)
    const = blur(e, albedo=albedo, mfp=mfp, eta=1.4, method="fft", tol=1e-4)
    tex_a = np.broadcast_to(np.array(albedo), (H, W, 2))
    tex_m = np.broadcast_to(np.array(mfp), (H, W, 2))
    out, info = blur(e, albedo=tex_a, mfp=tex_m, eta=1.4, method="fft", tol=1e-4,
                     return_info=True)
    # one node per channel: its exact kernel, at the same truncation radius as the constant
    # path; they differ by float32 FFT rounding only
    assert [c.nodes for c in info.channels] == [1, 1]
    np.testing.assert_allclose(out, const, rtol=0, atol=2e-6 * e.max())


@pytest.mark.parametrize("method", ["fft", "gaussians"])
def test_constant_irradiance_returns_rd_per_texel(method):
    albedo, mfp = gradient_maps(3)
    e = np.full((H, W, 3), 3.0, np.float32)
    out = blur(e, albedo=albedo, mfp=mfp, eta=(1.3, 1.4, 1.5), method=method)
    # clamp border: every texel sees a constant field; node kernels sum to 1 exactly, so the
    # only error is float32 rounding
    np.testing.assert_allclose(out, 3.0 * albedo, rtol=2e-5)


def test_alpha_sigma_t_maps_match_albedo_mfp_maps():
    rng = np.random.default_rng(7)
    e = rng.uniform(0, 1, (H, W, 1)).astype(np.float32)
    albedo, mfp = gradient_maps()
    sa, ss = ref.albedo_to_coefficients(albedo, mfp, 1.4)
    a = blur(e, albedo=albedo, mfp=mfp, eta=1.4, method="fft")
    b = blur(e, alpha=ss / (sa + ss), sigma_t=sa + ss, eta=1.4, method="fft")
    np.testing.assert_allclose(a, b, rtol=1e-4, atol=1e-6)


def test_texel_size_scales_like_mfp():
    rng = np.random.default_rng(8)
    e = rng.uniform(0, 1, (H, W, 1)).astype(np.float32)
    albedo, mfp = gradient_maps()
    a = blur(e, albedo=albedo, mfp=mfp, eta=1.4)
    b = blur(e, albedo=albedo, mfp=mfp * 0.1, texel_size=0.1, eta=1.4)
    np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-6)


def test_banded_equals_whole():
    rng = np.random.default_rng(9)
    e = rng.uniform(0, 1, (40, W, 1)).astype(np.float32)
    yy, xx = np.mgrid[0:40, 0:W]
    albedo = (0.3 + 0.5 * xx / W)[..., None]
    mfp = (1.0 + yy / 40.0)[..., None]
    for border in ("clamp", "wrap", "zero"):
        whole = blur(e, albedo=albedo, mfp=mfp, eta=1.4, border=border)
        banded = blur(e, albedo=albedo, mfp=mfp, eta=1.4, border=border, max_memory=30_000)
        np.testing.assert_allclose(banded, whole, rtol=1e-5, atol=1e-7)


def test_device_weights_match_host_interpolation(runtime):
    albedo, mfp = gradient_maps()
    (plan, rd, ld, _), = channel_plans((H, W, 1), tol=1e-3, albedo=albedo, mfp=mfp)
    dev = weight_planes(plan, rd, ld, runtime)
    cu, cv = texel_coords(plan, rd, ld)
    host = interpolated_weights(plan, cu, cv) * rd[..., None].astype(np.float64)
    # float32 bilinear weights and sums of <= 4 taps: a few ulp of the largest weight
    np.testing.assert_allclose(dev, np.moveaxis(host, -1, 0), rtol=0,
                               atol=1e-5 * np.abs(host).max())


@pytest.mark.parametrize("nweights", [1, 4, 5, 8, 9, 16, 17, 23])
def test_device_reads_node_records_of_every_size(runtime, nweights):
    """The kernels read the table as node records of 4, 8 or 16 floats, or several chunks of
    the widest the device's vector cap allows (dispatch.node_records; 8 where its compiler's
    16-float ABI is wrong): every weight count, its padding included, gives the host's
    interpolation of the table (here a random value per weight, so that a weight read from
    another slot or the padding shows, varying by 1% between nodes, so that the coordinates'
    float32 rounding moves the result no more than in a fitted table)."""
    from dataclasses import replace
    from bdipole_cl.ops.blur.dispatch import node_records, record_chunk
    albedo, mfp = gradient_maps()
    (plan, rd, ld, _), = channel_plans((H, W, 1), tol=1e-3, albedo=albedo, mfp=mfp)
    rng = np.random.default_rng(nweights)
    fine = (rng.uniform(-1, 1, nweights)
            + 0.01 * rng.uniform(-1, 1, plan.fine.shape[:2] + (nweights,))).astype(np.float32)
    plan = replace(plan, fine=fine, kernels=tuple(range(nweights)), near=-1,
                   near_values=np.zeros((0, 0), np.float32))
    from bdipole_cl.ops.widths import device_vector_cap
    chunk = record_chunk(nweights, device_vector_cap(runtime))
    records = node_records(fine, chunk)
    assert records.shape[2] % chunk == 0 and records.shape[2] - chunk < nweights
    assert not records[..., nweights:].any()
    dev = weight_planes(plan, rd, ld, runtime)
    cu, cv = texel_coords(plan, rd, ld)
    host = interpolated_weights(plan, cu, cv) * rd[..., None].astype(np.float64)
    # as test_device_weights_match_host_interpolation: float32 sums of <= 4 taps
    np.testing.assert_allclose(dev, np.moveaxis(host, -1, 0), rtol=0,
                               atol=1e-5 * np.abs(host).max())


@pytest.mark.parametrize("e_range", [(0.0, 3.0), (-2.0, 3.0)])
def test_device_gather_settles_as_the_host_does(runtime, e_range):
    """The gather's settle (kernels/blur_textured.cl) is fft.settled's rule on the same float32
    values: equal to the unsettled gather settled on the host, bit for bit, with results near
    the floor, below it and negative."""
    from bdipole_cl.ops.blur.dispatch import gather_exitance
    from bdipole_cl.ops.blur.textured import host_array
    albedo, mfp = gradient_maps()
    (plan, rd, ld, _), = channel_plans((H, W, 1), tol=1e-3, albedo=albedo, mfp=mfp)
    g, x0 = len(plan.kernels), max(3, plan.near)      # the gather reads the near field there
    rng = np.random.default_rng(5)
    planes = host_array((g, H, W + 2 * x0))
    # values spread over decades around the settle floor (~1e-6 here), of both signs
    planes[...] = rng.choice([-1, 1], planes.shape) * 10.0 ** rng.uniform(-9, 0, planes.shape)
    floor = blur_fft.settle_floor(e_range, blur_fft.FFT32_ROUNDOFF_ULPS)
    raw, dev = host_array((H, W, 1)), host_array((H, W, 1))
    padded = np.zeros((H + 2 * x0, W + 2 * x0), np.float32)
    padded[x0:-x0, x0:-x0] = rng.uniform(-1e-6, 1e-6, (H, W))
    gather_exitance(raw, 0, plan, rd, ld, planes, padded, x0, runtime, settle=(0.0, False))
    gather_exitance(dev, 0, plan, rd, ld, planes, padded, x0, runtime, settle=floor)
    host = blur_fft.settled(raw[..., 0].copy(), None, rd, blur_fft.FFT32_ROUNDOFF_ULPS, e_range)
    assert 0 < np.count_nonzero(host == 0) < host.size     # the floor cut some, not all
    np.testing.assert_array_equal(dev[..., 0], host)


def test_float32_node_coordinates_match_float64():
    albedo, mfp = gradient_maps()
    albedo[0, 0], albedo[1, 1] = 0.0, 0.9995       # clipped to the shape bounds
    (plan, rd, ld, _), = channel_plans((H, W, 1), tol=1e-3, albedo=albedo, mfp=mfp)
    cu, cv = texel_coords(plan, rd, ld)
    assert cu.dtype == cv.dtype == np.float32
    t_rd, t_ld = transformed(rd, ld)
    # float32 logit/log: a few ulp of |logit| <= 7 over a >= 0.2 step, except at the clip
    # bound RD_MAX itself, which rounds to 0.99900001 in float32: 1 - Rd then differs by
    # 1.3e-5 relatively, and so does logit, 3.3e-5 of a 0.4 step (a shape difference far below
    # the kernel's interpolation error)
    # (texel_coords is in fine-table steps, REFINE per lattice step)
    np.testing.assert_allclose(cu / REFINE, plan.axes[0].coords(t_rd), rtol=0, atol=5e-5)
    np.testing.assert_allclose(cv / REFINE, plan.axes[1].coords(t_ld), rtol=0, atol=1e-5)


@pytest.mark.parametrize("k, shape", [(3, (16, 20)), (9, (40, 34)), (12, (26, 26))])
def test_kernel_spectra_equal_fft_of_the_centred_kernel(k, shape):
    import scipy.fft as sfft
    quads = np.random.default_rng(k).uniform(0, 1, (2, k + 1, k + 1))
    got = kernel_spectra(quads, shape)
    for q, spec in zip(quads, got):
        full = np.zeros(shape)
        idx = np.arange(-k, k + 1)
        full[np.ix_(idx % shape[0], idx % shape[1])] = unfold_quadrant(q)
        want = sfft.rfft2(full)
        assert np.abs(want.imag).max() < 1e-12 * np.abs(want).max()    # even kernel: real
        # float32 DCT of <= (k+1)^2 terms: ~1e-7 of the spectrum's peak
        assert spec.shape == (shape[0] // 2 + 1, shape[1] // 2 + 1)
        np.testing.assert_allclose(spec, want.real[:shape[0] // 2 + 1], rtol=0,
                                   atol=1e-6 * np.abs(want).max())
        # the rows above N0/2 mirror those below (what times_spectrum relies on)
        full_spec = np.empty(want.shape, np.complex128)
        times_spectrum(spec.astype(np.float64), np.ones(want.shape, np.complex128), full_spec)
        np.testing.assert_allclose(full_spec.real, want.real, rtol=0,
                                   atol=1e-6 * np.abs(want).max())


def test_zero_albedo_texels_give_zero_and_extremes_stay_finite():
    albedo, mfp = gradient_maps()
    albedo[0, 0] = 0.0
    albedo[1, 1] = 1e-6          # shape of RD_MIN, energy 1e-6
    albedo[2, 2] = 0.9995        # shape of RD_MAX
    e = np.ones((H, W, 1), np.float32)
    out = blur(e, albedo=albedo, mfp=mfp, eta=1.4)
    assert out[0, 0, 0] == 0.0
    assert np.all(np.isfinite(out))
    np.testing.assert_allclose(out[..., 0], albedo[..., 0], rtol=2e-5)


@pytest.mark.parametrize("method", ["fft", "gaussians"])
@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_negative_zero_albedo_gives_positive_zero(runtime, method, sign):
    """An albedo texel of -0.0 (a valid Rd of 0) exits +0.0, under light of either sign: its
    product and its settle floor are -0.0, and a zero's sign is no light a file should carry."""
    albedo, mfp = gradient_maps()
    albedo[2, 3] = -0.0
    out = blur(np.full((H, W, 1), sign, np.float32), albedo=albedo, mfp=mfp, eta=1.4,
               method=method, device=runtime)
    assert out[2, 3, 0] == 0.0 and not np.signbit(out[2, 3, 0])
    assert not np.signbit(out).any() if sign > 0 else np.all(out[albedo > 0] < 0)


@pytest.mark.parametrize("level", [1e37, 1e38, 3e38])
def test_a_field_near_float32s_largest_blurs_finite(runtime, level):
    """A finite irradiance up to float32's largest blurs to finite exitance (its basis planes
    and near-field sums would pass 3.4e38: the channel is blurred in a power-of-two unit,
    ``fft.hdr_unit``), Rd E on a constant field, and exactly 2^k times the blur of E 2^-k."""
    albedo, mfp = gradient_maps()
    e = np.full((H, W, 1), level, np.float32)
    out = blur(e, albedo=albedo, mfp=mfp, eta=1.4, device=runtime)
    assert np.all(np.isfinite(out))
    np.testing.assert_allclose(out[..., 0], level * albedo[..., 0], rtol=2e-5)
    lit = np.random.default_rng(2).uniform(0, 1, (H, W, 1)).astype(np.float32)
    lit[4:9, 4:9] = 1.0
    small = blur(lit, albedo=albedo, mfp=mfp, eta=1.4, device=runtime)
    big = blur(lit * np.float32(level), albedo=albedo, mfp=mfp, eta=1.4, device=runtime)
    # the big field is blurred in a unit that brings its peak to [0.5, 1): the small one's
    # own scale but for a power of two, so the same floats up to its rounding of E * level
    np.testing.assert_allclose(big / np.float32(level), small, rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("size", [0, -1.0, np.nan, np.inf, True, "2", (0.5, 1.0)])
@pytest.mark.parametrize("pair", ["albedo", "alpha"])
def test_a_bad_texel_size_is_named_with_texture_parameters(size, pair):
    """texel_size is checked as for constant parameters (it was read into the mfp, counted as
    invalid mfp texels or blurred nothing under clamp, or a raw conversion error)."""
    albedo, mfp = gradient_maps()
    maps = ({"albedo": albedo, "mfp": mfp} if pair == "albedo"
            else {"alpha": np.full_like(albedo, 0.9), "sigma_t": np.full_like(mfp, 2.0)})
    for policy in ("raise", "clamp"):
        with pytest.raises(ValueError, match=r"texel_size=.* must be one finite number > 0"):
            blur(np.ones((H, W, 1), np.float32), texel_size=size, on_invalid=policy, **maps)


def test_extreme_sigma_t_texels_give_a_one_texel_kernel_or_a_named_error():
    """sigma_t' of 1e300 (valid: (0, inf)) is a one-texel kernel (its ld, 1e-301 texels, was 0
    in float32: the plan's SVD failed); one too small for any kernel is named."""
    e = np.random.default_rng(3).uniform(0.5, 1, (H, W, 1)).astype(np.float32)
    alpha = np.full((H, W, 1), 0.9, np.float64)
    st = np.full((H, W, 1), 1e300, np.float64)
    out = blur(e, alpha=alpha, sigma_t=st)
    np.testing.assert_allclose(out, blur(e, alpha=alpha, sigma_t=np.full_like(st, 1e30)),
                               rtol=1e-6)
    st[2, 3] = 1e-320
    with pytest.raises(ValueError, match=r"sigma_t at x=3, y=2, channel 0: .* beyond float32"):
        blur(e, alpha=alpha, sigma_t=st)


@pytest.mark.parametrize("name, value, what", [
    ("albedo", 1.0, "albedo"), ("albedo", np.nan, "albedo"), ("albedo", -0.1, "albedo"),
    ("mfp", 0.0, "mfp"), ("mfp", np.inf, "mfp")])
def test_bad_texels_name_the_texel(name, value, what):
    albedo, mfp = gradient_maps()
    maps = {"albedo": albedo, "mfp": mfp}
    maps[name][3, 5] = value
    with pytest.raises(InvalidInputError, match=rf"{what}.*x=5, y=3, channel 0"):
        blur(np.ones((H, W, 1), np.float32), eta=1.4, **maps)


def test_unsupported_combinations_are_clear_errors():
    albedo, mfp = gradient_maps()
    e = np.ones((H, W, 1), np.float32)
    with pytest.raises(ValueError, match="needs constant parameters"):
        blur(e, albedo=albedo, mfp=mfp, method="direct")
    with pytest.raises(ValueError, match="eta must be"):
        blur(e, albedo=0.5, mfp=1.0, eta=np.full((H, W), 1.4))
    with pytest.raises(ValueError, match="shape"):
        blur(e, albedo=albedo[:5], mfp=mfp)


def test_far_cells_match_independent_quadrature():
    # cells beyond EXACT_CELLS use a 5x5 Gauss-Legendre product rule of R
    (alpha, st, eta), = channel_parameters(1, albedo=0.8, mfp=3.0, eta=1.4)
    q = quadrant_weights(alpha, st, eta, 12)
    f = lambda y, x: ref.profile(np.hypot(x, y), alpha, st, eta)  # noqa: E731
    for i, j in [(4, 0), (5, 2), (8, 8), (12, 3)]:
        want = dblquad(f, i - 0.5, i + 0.5, j - 0.5, j + 0.5, epsabs=1e-15, epsrel=1e-11)[0]
        assert abs(q[j, i] / want - 1) < 1e-8, (i, j, q[j, i] / want - 1)


def test_transformed_coordinates_clip_albedo_shape_only():
    t_rd, _ = transformed(np.array([0.0, 0.5, 0.99999]), np.ones(3))
    assert np.all(np.isfinite(t_rd))


def test_cli_with_parameter_textures(tmp_path, capsys):
    import OpenImageIO as oiio

    from bdipole_cl.apps.cli import main as cli_main
    from bdipole_cl.apps.demo import write_exr
    rng = np.random.default_rng(10)
    e = rng.uniform(0, 1, (H, W, 3)).astype(np.float32)
    albedo, mfp = gradient_maps(3)
    write_exr(tmp_path / "e.exr", e, ("R", "G", "B"))
    write_exr(tmp_path / "albedo.exr", albedo.astype(np.float32), ("R", "G", "B"))
    write_exr(tmp_path / "mfp.exr", mfp[..., :1].astype(np.float32), ("Y",))
    args = ["blur", str(tmp_path / "e.exr"), "-o", str(tmp_path / "m.exr"),
            "--albedo", str(tmp_path / "albedo.exr"), "--mfp", str(tmp_path / "mfp.exr"),
            "--max-memory", "30K"]
    assert cli_main(args) == 0
    assert "Rd per texel" in capsys.readouterr().out
    inp = oiio.ImageInput.open(str(tmp_path / "m.exr"))
    got = inp.read_image(0, 0, 0, 3, oiio.FLOAT)
    inp.close()
    want = blur(e, albedo=albedo.astype(np.float32), mfp=mfp[..., :1].astype(np.float32))
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-7)
    # a bad texel: exit 1, the file and texel named, no output left behind
    albedo[4, 7, 1] = 1.5
    write_exr(tmp_path / "albedo.exr", albedo.astype(np.float32), ("R", "G", "B"))
    assert cli_main(args[:3] + [str(tmp_path / "bad.exr")] + args[4:]) == 1
    err = capsys.readouterr().err
    # the parameter texture that holds the bad texel is named, not the irradiance
    assert "albedo.exr: " in err and "x=7, y=4, channel G: 1.5" in err
    assert not (tmp_path / "bad.exr").exists()


def test_spectra_cached_per_plan_and_shape():
    albedo, mfp = gradient_maps()
    (plan, _, _, _), = channel_plans((H, W, 1), tol=1e-3, albedo=albedo, mfp=mfp)
    first = cached_spectra(plan, (40, 42))
    assert cached_spectra(plan, (40, 42)) is first
    other = cached_spectra(plan, (40, 44))
    assert other is not first and other.shape[2] == 44 // 2 + 1
    np.testing.assert_array_equal(first, kernel_spectra(plan.blurred_quadrants(), (40, 42)))


def test_spectra_cache_keeps_to_its_byte_budget(monkeypatch):
    albedo, mfp = gradient_maps()
    (plan, _, _, _), = channel_plans((H, W, 1), tol=1e-3, albedo=albedo, mfp=mfp)
    one = kernel_spectra(plan.blurred_quadrants(), (40, 42)).nbytes
    cache = blur_fft.SPECTRA_CACHE
    monkeypatch.setattr(cache, "max_bytes", 2 * one)
    cache.clear()
    for n1 in (42, 44, 46):           # a third shape pushes the first out
        cached_spectra(plan, (40, n1))
    assert cache.nbytes <= 2 * one
    f32 = np.dtype(np.float32).str
    assert cache.get((id(plan), (40, 42), f32)) is None
    assert cache.get((id(plan), (40, 46), f32)) is not None


def test_a_hot_texel_does_not_drown_the_rest_of_a_varying_blur():
    """A 1e6 texel in an irradiance of ~0.5: the basis blurs then run in float64 (the float32
    round-off, ~1e-6 of max|E|, would be ~1 everywhere), so texels beyond the kernel radius of
    it are within the plan's kernel error of their own light."""
    rng = np.random.default_rng(4)
    n = 40
    e = rng.uniform(0, 1, (n, n, 1)).astype(np.float32)
    e[4, 4] = 1e6
    yy, xx = np.mgrid[0:n, 0:n]
    albedo = (0.3 + 0.15 * (xx // 10))[..., None].astype(np.float32)    # 4 albedos, 4 mfps:
    mfp = (1.0 + 0.25 * (yy // 10))[..., None].astype(np.float32)       # 16 node kernels
    out, info = blur(e, albedo=albedo, mfp=mfp, eta=1.4, return_info=True)
    ch = info.channels[0]
    want = per_texel_reference(e[..., 0], albedo[..., 0], mfp[..., 0], 1.4, ch.radius)
    far = np.maximum(np.abs(yy - 4), np.abs(xx - 4)) > ch.radius
    assert far.mean() > 0.5
    # each far texel's light is <= 1 (E in [0, 1) within its radius): the kernel error
    # (fit + interpolation, L1) times that, + 1e-5 for float32 accumulation
    err = np.abs(out[..., 0] - want)[far] / albedo[..., 0][far]
    assert err.max() <= max(ch.fit_error, ch.interp_error) + 1e-5, err.max()


def test_a_plan_too_large_to_build_is_refused_first(monkeypatch):
    """Planning holds every lattice node's kernel: ranges wide in both albedo and mfp need
    thousands of large kernels whatever the image's size. Beyond PLAN_PEAK_BYTES the plan is
    refused up front, by a message naming the ranges, before any node kernel is built."""
    from bdipole_cl.ops.blur import textured_plan
    monkeypatch.setattr(textured_plan, "PLAN_PEAK_BYTES", 1 << 20)
    built = []
    monkeypatch.setattr(textured_plan, "node_kernel", lambda *a, **k: built.append(a))
    textured_plan.PLAN_CACHE.clear()
    albedo = np.array([[0.05, 0.95], [0.95, 0.05]])
    mfp = np.array([[0.5, 0.5], [8.0, 8.0]])
    with pytest.raises(ValueError, match=r"albedo 0\.05\.\.0\.95 with mfp 0\.5\.\.8 texels "
                                         r"needs \d+ lattice kernels of radius \d+.*separately"):
        blur(np.ones((2, 2), np.float32), albedo=albedo, mfp=mfp)
    assert not built
    textured_plan.PLAN_CACHE.clear()


def test_a_basis_that_cannot_fit_within_tol_is_warned_of():
    """Separable Gaussians cannot fit albedo 0.9999's kernel within tol 1e-4 (6.6e-3): the
    bound says so and BlurAccuracyWarning names it (it was reported, not warned of); the
    eigen-kernels fit within tol, so the default warns of nothing."""
    albedo = np.full((24, 24, 1), 0.5, np.float32)
    albedo[:12, :12] = 0.9999
    mfp = np.ones((24, 24), np.float32)
    e = np.ones((24, 24, 1), np.float32)
    with pytest.warns(BlurAccuracyWarning, match="gaussians basis fits the texture's kernels"):
        blur(e, albedo=albedo, mfp=mfp, eta=1.4, tol=1e-4, method="gaussians")
    with warnings.catch_warnings():
        warnings.simplefilter("error", BlurAccuracyWarning)
        blur(e, albedo=albedo, mfp=mfp, eta=1.4, tol=1e-4)


def test_accuracy_warnings_point_at_the_callers_line():
    """A BlurAccuracyWarning names the user's line that called ``blur`` (so that a filter by
    module, or the printed location, finds it), not the library's line that found it: the
    texture-varying basis's, the plain Gaussians fit's and the stretched shear's."""
    albedo = np.full((24, 24, 1), 0.5, np.float32)
    albedo[:12, :12] = 0.9999
    e = np.ones((24, 24, 1), np.float32)
    impulse = np.zeros((21, 21, 1), np.float32)
    impulse[10, 10] = 1.0
    su = np.ones((24, 24), np.float32)
    sheared = Stretch(su, 2 * su, max_shear=0.3)
    calls = (lambda: blur(e, albedo=albedo, mfp=np.ones((24, 24), np.float32), eta=1.4,
                          tol=1e-4, method="gaussians"),
             lambda: blur(impulse, albedo=0.99, mfp=0.3, method="gaussians", border="zero"),
             lambda: blur(e, albedo=0.5, mfp=2.0, stretch=sheared))
    for call in calls:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            call()
        ours = [w for w in caught if issubclass(w.category, BlurAccuracyWarning)]
        assert ours and all(w.filename == __file__ for w in ours), [
            (w.filename, w.lineno) for w in ours]
