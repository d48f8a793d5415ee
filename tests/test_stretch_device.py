"""The stretched blur on the device end to end (bdipole_cl/ops/blur/stretched_device.py;
docs/stretch.md "Where it runs"), on every device under test with the FFT engine forced to the
device (``widths.FFT_ENGINE_VARIABLE``), against the host path (the same plan, the host's FFT
engine): the whole image under each border rule, charts kept apart (clamp, zero), bands, a
channel far above 1 and one far below it.

Each device run is made with the host's FFT of the basis blurs (``fft.basis_blurs``) refused:
the device path must not fall back to it. The two paths run the same gather kernel on the same
device over basis blurs made by two float32 FFTs (scipy's and kernels/fft.cl, at different
sizes), each within the plan's round-off bound of the exact convolution of the plan's basis
(``stretched.roundoff``: FFT32_ROUNDOFF plus the gather's float32 sums, relative to max|E| Rd;
docs/stretch.md "The near field", its bound), so within twice that bound of each other
(measured: under 2% of it on Intel's CPU runtime)."""
import numpy as np
import pytest

import bdipole_cl as bd
from bdipole_cl.device.runtime import forced
from bdipole_cl.ops.blur import fft, stretched_device, stretched_gather, textured_device
from bdipole_cl.ops.blur import stretched as stretched_mod
from bdipole_cl.ops.blur.plan import Scattering, plan_blur
from bdipole_cl.ops.stretch import StretchTile
from bdipole_cl.ops.widths import FFT_ENGINE_VARIABLE

ALBEDO, MFP = (0.8, 0.5), (1.0, 0.6)


def smooth_stretch(h, w, t=0.25):
    """(su, sv) texel lengths (mm) varying smoothly by 2^(+-0.25) across the map."""
    yy, xx = np.mgrid[0:h, 0:w] / np.array([h, w])[:, None, None]
    return ((t * 2.0 ** (0.25 * np.sin(2 * np.pi * (2 * xx + yy)))).astype(np.float32),
            (t * 2.0 ** (0.25 * np.cos(2 * np.pi * (xx - 2 * yy)))).astype(np.float32))


def two_charts(h=40, w=48):
    """A StretchTile of two UV charts side by side of different stretch (0.25 x 0.25 mm and
    0.5 x 0.2 mm a texel), three columns of gutter between them (uncovered, each the nearest
    chart's)."""
    x = np.broadcast_to(np.arange(w), (h, w))
    chart = (x >= w // 2).astype(np.int32)
    covered = np.abs(x - (w // 2 - 0.5)) > 2
    su = np.where(chart == 0, 0.25, 0.5).astype(np.float32)
    sv = np.where(chart == 0, 0.25, 0.2).astype(np.float32)
    return StretchTile((0, 0), su, sv, chart, covered, np.zeros((h, w), np.float32))


def refuse_host_fft(*args, **kwargs):
    raise AssertionError("the stretched blur's basis blurs were made by the host's FFT")


def blur_both(runtime, monkeypatch, e, stretch, max_memory=None, host_fallback=False, **kw):
    """(device path's, host path's) exitance of one stretched plan, and the plan; the device
    run with the host's basis blurs refused (unless ``host_fallback``: float64 transforms on
    a device without fp64 are the host's)."""
    nch = e.shape[2]
    plan = plan_blur(e.shape, Scattering(ALBEDO[:nch], MFP[:nch], stretch=stretch),
                     device=runtime, **kw)
    with monkeypatch.context() as m, forced(FFT_ENGINE_VARIABLE, "device"):
        if not host_fallback:
            m.setattr(fft, "basis_blurs", refuse_host_fft)
            m.setattr(stretched_gather, "basis_blurs", refuse_host_fft)
        got = plan.apply(e, max_memory=max_memory)[0]
    with forced(FFT_ENGINE_VARIABLE, "host"):
        want = plan.apply(e, max_memory=max_memory)[0]
    return got, want, plan


def assert_fft_close(got, want, e, plan):
    """Within twice the worst window's round-off bound of max|E| x max Rd (see above), plus
    float32's absolute floor (2^-149 each) for a channel far below 1."""
    for c, per_window in enumerate(plan.channels):
        bound = max(stretched_mod.roundoff(wch.plan) for wch in per_window)
        peak = float(np.max(np.abs(e[..., c]))) * max(float(np.max(wch.maps[0]))
                                                      for wch in per_window)
        err = float(np.max(np.abs(got[..., c] - want[..., c])))
        assert err <= 2 * bound * peak + 2.0 ** -148, (c, err, bound * peak)


@pytest.mark.parametrize("border", ["clamp", "zero", "wrap"])
def test_the_whole_image_on_the_device_is_the_hosts(runtime, monkeypatch, border):
    h, w = 48, 40
    e = np.random.default_rng(0).random((h, w, 2)).astype(np.float32)
    got, want, plan = blur_both(runtime, monkeypatch, e, smooth_stretch(h, w), border=border)
    assert len(plan.windows) == 1
    assert_fft_close(got, want, e, plan)


@pytest.mark.parametrize("charts", ["clamp", "zero"])
def test_charts_on_the_device_are_the_hosts(runtime, monkeypatch, charts):
    """One window per chart, each padded by its chart's rule (clamp: its nearest covered
    texel; zero: 0) on the device as on the host."""
    e = np.random.default_rng(1).random((40, 48, 2)).astype(np.float32)
    got, want, plan = blur_both(runtime, monkeypatch, e, two_charts(), charts=charts)
    assert len(plan.windows) == 2 and {w.border for w in plan.windows} == {charts}
    assert_fft_close(got, want, e, plan)


def test_bands_on_the_device_are_the_hosts_and_the_whole_image(runtime, monkeypatch):
    h, w = 72, 40
    e = np.random.default_rng(2).random((h, w, 2)).astype(np.float32)
    stretch = smooth_stretch(h, w, t=0.3)
    calls = []
    real = stretched_mod.blur_band_device
    monkeypatch.setattr(stretched_mod, "blur_band_device",
                        lambda *a, **k: calls.append(a[6]) or real(*a, **k))
    got, want, plan = blur_both(runtime, monkeypatch, e, stretch, max_memory=400_000)
    assert len(calls) > 4 and max(calls) < h, calls            # rows per band
    assert_fft_close(got, want, e, plan)
    with forced(FFT_ENGINE_VARIABLE, "device"):
        whole = plan.apply(e)[0]
    assert_fft_close(got, whole, e, plan)


@pytest.mark.parametrize("case", ["hot texel 1e6", "field 1e35", "field 1e-30"])
def test_channels_far_from_one_on_the_device_are_the_hosts(runtime, monkeypatch, case):
    """A 1e6 texel in a field of ~0.5 (float64 transforms where the device has fp64, as on
    the host: float32's round-off would be most of the light away from it); a field of 1e35,
    blurred at [0.5, 1) by a power of two (``fft.hdr_unit``), and one of 1e-30."""
    h, w = 64, 64
    e = np.random.default_rng(3).random((h, w, 1)).astype(np.float32)
    if case == "hot texel 1e6":
        e = np.full((h, w, 1), 0.5, np.float32)
        e[10, 10] = 1e6
    else:
        e *= np.float32(float(case.split()[1]))
    got, want, plan = blur_both(runtime, monkeypatch, e, smooth_stretch(h, w), tol=1e-3,
                                host_fallback=case == "hot texel 1e6" and not runtime.has_fp64)
    assert_fft_close(got, want, e, plan)
    if case == "hot texel 1e6":        # float64 transforms: far from the hot texel, the
        far = np.ones((h, w), bool)    # field's exitance to float32's resolution
        k = max(wch.plan.radius for wch in plan.channels[0])
        far[:10 + k + 1, :10 + k + 1] = False      # beyond its kernels' reach
        assert far.any()
        np.testing.assert_allclose(got[far], want[far], rtol=1e-5)


def test_the_device_path_keeps_its_buffers_and_makes_no_host_fft(runtime, monkeypatch):
    """The device path runs (the host's basis blurs and its band function are never called),
    and a second call uploads nothing of the plan or maps again (table, near kernels,
    spectra and maps stay on the device)."""
    h, w = 48, 40
    e = np.random.default_rng(4).random((h, w, 2)).astype(np.float32)
    plan = plan_blur(e.shape, Scattering(ALBEDO, MFP, stretch=smooth_stretch(h, w)),
                     device=runtime)
    monkeypatch.setattr(fft, "basis_blurs", refuse_host_fft)
    monkeypatch.setattr(stretched_gather, "basis_blurs", refuse_host_fft)
    monkeypatch.setattr(stretched_mod, "blur_band", refuse_host_fft)
    textured_device.PLAN_BUFFERS.clear()       # earlier tests' plans may share this one's
    uploads = []
    real = stretched_device.upload_buffer
    monkeypatch.setattr(stretched_device, "upload_buffer",
                        lambda rt, v: uploads.append(np.shape(v)) or real(rt, v))
    with forced(FFT_ENGINE_VARIABLE, "device"):
        first = plan.apply(e)[0]
        made = len(uploads)
        second = plan.apply(e)[0]
    assert made == 2 * 4 and len(uploads) == made, uploads     # per channel 3 maps and the table
    np.testing.assert_array_equal(first, second)
    assert np.all(first > 0)


def test_float64_transforms_without_fp64_are_the_hosts(runtime, monkeypatch):
    """A band that needs float64 transforms (a 1e6 texel in a field of 0.5) on a device
    without fp64: that band's basis blurs by the host's FFT, the gather still on the device;
    the others' on the device."""
    h, w = 64, 64
    e = np.full((h, w, 2), 0.5, np.float32)
    e[10, 10, 0] = 1e6                 # channel 0 needs float64, channel 1 does not
    plan = plan_blur(e.shape, Scattering(ALBEDO, MFP, stretch=smooth_stretch(h, w)),
                     device=runtime)
    with forced(FFT_ENGINE_VARIABLE, "host"):
        want = plan.apply(e)[0]
    monkeypatch.setattr(type(runtime), "has_fp64", property(lambda self: False))
    calls = []
    real = stretched_mod.blur_band
    monkeypatch.setattr(stretched_mod, "blur_band",
                        lambda *a, **k: calls.append(a[1]) or real(*a, **k))
    with forced(FFT_ENGINE_VARIABLE, "device"):
        got = plan.apply(e)[0]
    assert len(calls) == 1 and calls[0] is plan.channels[0][0].plan, calls
    assert_fft_close(got, want, e, plan)
