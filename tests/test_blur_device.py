"""The constant blur on the device end to end (bdipole_cl/ops/blur/whole_device.py,
fft_device.py, kernels/blur_fft.cl), and device-resident arrays in and out of the blur and the
inversion (bdipole_cl/ops/inversion_device.py, kernels/array_ops.cl), on every device under
test.

The device path is checked against the host path (the same plan: the host's FFT engine,
``widths.FFT_ENGINE_VARIABLE``): the direct and separable kernels are the same kernels, so the
same bits; the FFT blurs are two float32 FFT convolutions of one kernel, so within twice the
float32 FFT's round-off bound of each other (``fft.FFT32_ROUNDOFF`` relative to max|E| Rd,
docs/model.md "Blur error bound")."""
import numpy as np
import pyopencl.array as cla
import pytest

import bdipole_cl as bd
from bdipole_cl.device.runtime import forced
from bdipole_cl.ops.blur.fft import FFT32_ROUNDOFF
from bdipole_cl.ops.widths import FFT_ENGINE_VARIABLE, fft_engine

ALBEDO, MFP = (0.8, 0.6, 0.4), (3.0, 2.0, 1.0)


def _pair(e, rt, **kw):
    """(device path's, host path's) exitance of one blur."""
    with forced(FFT_ENGINE_VARIABLE, "device"):
        got = bd.blur(e, device=rt, **kw)
    with forced(FFT_ENGINE_VARIABLE, "host"):
        want = bd.blur(e, device=rt, **kw)
    return got, want


def _fft_close(got, want, e, rd=max(ALBEDO)):
    """Two float32 FFT blurs of one kernel: each within FFT32_ROUNDOFF max|E| Rd of the exact
    convolution, so within twice that of each other."""
    scale = float(np.max(np.abs(e))) * rd
    assert np.max(np.abs(got - want)) <= 2 * FFT32_ROUNDOFF * scale


@pytest.mark.parametrize("border", ["clamp", "zero", "wrap"])
@pytest.mark.parametrize("method", ["fft", "direct", "gaussians"])
def test_the_device_path_is_the_host_path(runtime, method, border):
    e = np.random.default_rng(0).random((45, 38, 3)).astype(np.float32)
    kw = dict(albedo=ALBEDO, mfp=MFP, method=method, border=border, return_info=True)
    (got, info), (want, host_info) = _pair(e, runtime, **kw)
    if method == "fft":
        _fft_close(got, want, e)
    else:
        np.testing.assert_array_equal(got, want)
    assert [c.error_bound for c in info.channels] == [c.error_bound for c in host_info.channels]


def test_device_arrays_in_and_out(runtime):
    """A device array's irradiance is blurred where it is, into a device array of its shape
    (HxW for HxW), the same exitance as the host's."""
    e = np.random.default_rng(1).random((30, 41, 2)).astype(np.float32)
    for image in (e, e[..., 0]):
        dev = cla.to_device(runtime.queue, np.ascontiguousarray(image))
        with forced(FFT_ENGINE_VARIABLE, "device"):
            out = bd.blur(dev, albedo=0.7, mfp=2.0, method="fft")
        assert isinstance(out, cla.Array) and out.shape == image.shape
        with forced(FFT_ENGINE_VARIABLE, "host"):
            want = bd.blur(image, albedo=0.7, mfp=2.0, method="fft", device=runtime)
        _fft_close(out.get(), want, image, 0.7)


def test_non_finite_texels_on_the_device_are_named_or_clamped_as_on_the_host(runtime):
    e = np.random.default_rng(2).random((20, 24, 3)).astype(np.float32)
    e[7, 5, 1], e[3, 9, 2] = np.nan, np.inf
    for irradiance in (e, cla.to_device(runtime.queue, e)):
        with forced(FFT_ENGINE_VARIABLE, "device"), \
                pytest.raises(bd.InvalidInputError, match=r"first at x=9, y=3, channel 2"):
            bd.blur(irradiance, albedo=0.6, mfp=2.0, method="fft", device=runtime)
    (got, info), (want, host_info) = _pair(e, runtime, albedo=0.6, mfp=2.0, method="fft",
                                           on_invalid="clamp", return_info=True)
    assert info.invalid == host_info.invalid == {"irradiance": 2}
    _fft_close(got, want, np.nan_to_num(e, posinf=0), 0.6)


def test_bands_on_the_device_are_the_whole_image(runtime):
    e = np.random.default_rng(3).random((120, 50, 3)).astype(np.float32)
    with forced(FFT_ENGINE_VARIABLE, "device"):
        whole = bd.blur(e, albedo=ALBEDO, mfp=MFP, method="fft", device=runtime)
        banded = bd.blur(e, albedo=ALBEDO, mfp=MFP, method="fft", device=runtime,
                         max_memory=120_000)
    _fft_close(banded, whole, e)


def test_a_peak_far_below_one_is_scaled_on_the_device(runtime):
    """A 1e-44 irradiance (subnormal products): scaled by a power of two on the device as on
    the host, each channel's bound taking float32's absolute floor."""
    e = np.zeros((24, 24, 2), np.float32)
    e[12, 12] = np.float32(1e-44)
    e[4:8, 4:8, 1] = np.float32(3e-40)
    for method in ("fft", "direct", "gaussians"):
        (got, info), (want, host_info) = _pair(e, runtime, albedo=0.6, mfp=2.0, method=method,
                                               return_info=True)
        np.testing.assert_allclose(got, want, rtol=1e-5, atol=2.0 ** -149)
        bounds = [c.error_bound for c in info.channels]
        host_bounds = [c.error_bound for c in host_info.channels]
        if method == "fft":     # the device's charges the precision it used (float64 for an
            assert all(b <= h for b, h in zip(bounds, host_bounds))    # impulse), the host's
        else:                                                         # float32's always
            assert bounds == pytest.approx(host_bounds)


def test_a_peak_far_above_the_mean_takes_float64_transforms_where_the_device_has_them(runtime):
    """A 1e6 texel in a field of ~0.5 (float32's round-off would be most of the light
    elsewhere): float64 transforms, on the device where it has fp64."""
    e = np.full((40, 40, 1), 0.5, np.float32)
    e[20, 20] = 1e6
    (got, info), (want, _) = _pair(e, runtime, albedo=0.6, mfp=2.0, method="fft",
                                   return_info=True, tol=1e-4)
    far = got[:5, :5]
    np.testing.assert_allclose(far, want[:5, :5], rtol=1e-5)
    np.testing.assert_allclose(far, 0.5 * 0.6, rtol=1e-4)


def test_the_fft_engine_is_chosen_by_this_devices_timings(runtime, monkeypatch):
    from bdipole_cl.device import isolation
    from bdipole_cl.device.runtime import known_verdict
    from bdipole_cl.ops import widths
    verdict = known_verdict(runtime.device)
    results = [r for r in verdict.results if not r.name.startswith(widths.BLUR_TIMING)]
    for device_faster in (True, False):
        times = {"fft": 2.0, widths.DEVICE_FFT_TIMING: 1.0 if device_faster else 3.0}
        timed = [isolation.ConfigResult(widths.blur_timing_name(m, r), True, seconds=t)
                 for m, t in times.items() for r in (2, 6, 17)]
        monkeypatch.setattr(widths, "known_verdict",
                            lambda device: isolation.Verdict("d", tuple(results + timed)))
        assert fft_engine(runtime) == ("device" if device_faster else "host")
        assert widths.blur_timings(runtime)[("fft", 6)] == min(times.values())
    monkeypatch.setenv(FFT_ENGINE_VARIABLE, "gpu")
    with pytest.raises(ValueError, match="BDIPOLE_CL_FFT_ENGINE='gpu': expected one of host"):
        fft_engine(runtime)


def _textures(h=72, w=60):
    y, x = np.mgrid[0:h, 0:w]
    albedo = np.stack([0.4 + 0.4 * x / (w - 1), 0.3 + 0.2 * y / (h - 1)], -1)
    mfp = np.stack([2.0 + y / 40, 1.0 + x / 60], -1)
    return albedo.astype(np.float32), mfp.astype(np.float32)


@pytest.mark.parametrize("scale", [1.0, 1e-40, 1e35])
@pytest.mark.parametrize("method", ["fft", "gaussians"])
def test_texture_varying_blurs_on_the_device_are_the_hosts(runtime, method, scale):
    """The basis blurs transformed on the device, the gather reading device buffers, the
    separable basis settled against the Rd map there; peaks far below 1 and far above it
    scaled by a power of two (the host's rules): the host's exitance and bounds."""
    albedo, mfp = _textures()
    e = np.random.default_rng(6).random((72, 60, 2)).astype(np.float32) * np.float32(scale)
    (got, info), (want, host_info) = _pair(e, runtime, albedo=albedo, mfp=mfp, method=method,
                                           return_info=True)
    if method == "gaussians":             # the same kernels, the same settle: the same bits
        np.testing.assert_array_equal(got, want)
    else:     # two float32 FFT convolutions of the basis (and float32's absolute floor, 2^-149)
        peak = float(np.max(e)) * float(np.max(albedo))
        assert np.max(np.abs(got - want)) <= 2 * FFT32_ROUNDOFF * peak + 2.0 ** -148
    assert [c.error_bound for c in info.channels] == [c.error_bound for c in host_info.channels]


def test_texture_varying_bands_on_the_device_are_the_whole_image(runtime):
    albedo, mfp = _textures()
    e = np.random.default_rng(7).random((72, 60, 2)).astype(np.float32)
    with forced(FFT_ENGINE_VARIABLE, "device"):
        whole = bd.blur(e, albedo=albedo, mfp=mfp, device=runtime)
        banded = bd.blur(e, albedo=albedo, mfp=mfp, device=runtime, max_memory=150_000)
    _fft_close(banded, whole, e)


def test_an_invert_then_blur_chain_stays_on_the_device(runtime):
    """Albedos inverted on the device (alpha', and sigma_t' from the coefficients), then a light
    map blurred with those maps: device arrays all along; the maps are read once to make the
    blur's plan (docs/python.md "Arrays on the device"), the exitance is the host's."""
    albedo, mfp = _textures(40, 36)
    rd = cla.to_device(runtime.queue, np.ascontiguousarray(albedo[..., 0]))
    alpha = bd.invert_albedo(rd, 1.4)
    sigma_t = bd.albedo_to_coefficients(rd, 1.5, 1.4, outputs=("sigma_t",))
    e = cla.to_device(runtime.queue, np.random.default_rng(8).random((40, 36), np.float32))
    with forced(FFT_ENGINE_VARIABLE, "device"):
        out = bd.blur(e, alpha=alpha, sigma_t=sigma_t, method="fft")
    assert isinstance(alpha, cla.Array) and isinstance(out, cla.Array) and out.shape == (40, 36)
    with forced(FFT_ENGINE_VARIABLE, "host"):
        want = bd.blur(e.get(), alpha=alpha.get(), sigma_t=sigma_t.get(), method="fft",
                       device=runtime)
    _fft_close(out.get(), want, e.get(), 1.0)


def test_a_wide_direct_kernel_is_launched_in_parts_of_a_row_of_tiles(runtime, monkeypatch):
    """The direct blur checks for a stop between launches of about LAUNCH_TAPS taps, also where
    one row of work-group tiles holds more (a wide kernel: 16 rows of a 2048-wide map at radius
    447 are 2.6e10 taps, a minute on a CPU); the parts give the one-launch exitance."""
    from bdipole_cl.ops.blur import dispatch
    e = np.random.default_rng(5).random((64, 64, 1)).astype(np.float32)
    kw = dict(albedo=0.6, mfp=6.0, method="direct", device=runtime, return_info=True)
    want, info = bd.blur(e, **kw)
    taps = (2 * info.channels[0].radius + 1) ** 2
    checks = []
    monkeypatch.setattr(dispatch, "LAUNCH_TAPS", dispatch.TILE ** 2 * taps)   # a tile each
    monkeypatch.setattr(dispatch, "check_stop", lambda: checks.append(1))
    got = bd.blur(e, **kw)[0]
    assert len(checks) >= (64 // dispatch.TILE) ** 2
    np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize("method", ["fft", "gaussians"])
def test_a_second_map_of_the_same_ranges_is_its_own_on_the_device(runtime, method):
    """Two albedo maps with the same ranges share one texture-varying plan (plans are kept by
    ranges), but never its maps: the second map's blur on the device is the host's blur of the
    second map, not of the first map's texels (kept on the device with the plan)."""
    albedo, mfp = _textures()
    flipped = np.ascontiguousarray(albedo[::-1, ::-1])      # the same values, other texels
    e = np.random.default_rng(8).random((72, 60, 2)).astype(np.float32)
    with forced(FFT_ENGINE_VARIABLE, "device"):
        bd.blur(e, albedo=albedo, mfp=mfp, method=method, device=runtime)
    (got, _), (want, _) = _pair(e, runtime, albedo=flipped, mfp=mfp, method=method,
                                return_info=True)
    _fft_close(got, want, e)
