"""The constant-parameter host FFT in float32 (bdipole_cl/ops/blur/fft.py
``fft_blur_channels``): every channel in one batched transform, the kernels' cached real
spectra, and the round-off its error bound charges (docs/model.md "Blur error bound")."""
import numpy as np
import pytest

from bdipole_cl.ops.blur import blur, channel_kernel, channel_parameters
from bdipole_cl.ops.blur import fft as blur_fft
from bdipole_cl.ops.blur.fft import (FFT32_ROUNDOFF, FFT32_ROUNDOFF_ULPS, FFT64_ROUNDOFF,
                                     fft_blur_channel, fft_blur_channels)

ALBEDO, MFP = (0.8, 0.6, 0.4), (1.0, 2.5, 6.0)        # three radii: the batch pads by the largest
EPS32 = float(np.finfo(np.float32).eps)


def kernels(tol, mfp=MFP):
    return [channel_kernel(*p, tol) for p in channel_parameters(3, albedo=ALBEDO, mfp=mfp,
                                                                  eta=1.4)]


def irradiances(h, w):
    """The workloads of the round-off measure: random, random with HDR highlights, a constant,
    one bright texel among zeros, half lit, and a signed random map."""
    rng = np.random.default_rng(h * w)
    random = rng.uniform(0, 1, (h, w, 3)).astype(np.float32)
    hdr = random.copy()
    hdr[rng.uniform(size=(h, w)) < 3e-3] = 50.0
    bright = np.zeros((h, w, 3), np.float32)
    bright[h // 3, w // 2] = 1.0
    half = np.zeros((h, w, 3), np.float32)
    half[:, : w // 2] = 1.0
    return {"random": random, "hdr": hdr, "constant": np.full((h, w, 3), 2.0, np.float32),
            "bright": bright, "half lit": half, "signed": random - 0.5}


def relative_error(out, e, ks, border):
    """max over channels of max |M - M64| / (max|E| Rd), M64 the float64 FFT of one channel
    with the full kernel (np.pad and rfft2: the path the batch replaced)."""
    return max(float(np.abs(out[..., c] - fft_blur_channel(e[..., c], ck.weights, border)).max()
                     / (np.abs(e[..., c]).max() * ck.rd)) for c, ck in enumerate(ks))


@pytest.mark.parametrize("border", ["clamp", "zero", "wrap"])
@pytest.mark.parametrize("h, w", [(64, 64), (45, 70), (200, 129)])
def test_float32_batch_is_within_its_round_off_of_the_float64_convolution(h, w, border):
    # the batch (planes padded by the largest radius, one transform, real spectra, the inverse
    # pruned to the image's rows) is the float64 per-channel convolution to within round-off:
    # the FFT's (measured <= 7e-7 up to 4096^2) plus the settle floor (16 eps32 where the
    # exact value is a tail below it), inside the FFT32_ROUNDOFF the bound charges
    ks = kernels(1e-3)
    for name, e in irradiances(h, w).items():
        out = fft_blur_channels(e, [0, 1, 2], ks, np.float32, border, np.empty_like(e))
        err = relative_error(out, e, ks, border)
        assert err <= FFT32_ROUNDOFF_ULPS * EPS32 + 1e-6 <= FFT32_ROUNDOFF / 3, (name, err)
    # float64: the same convolution to the output's float32 rounding (the settle floor is
    # 1 eps32 there)
    e = irradiances(h, w)["hdr"]
    out = fft_blur_channels(e, [0, 1, 2], ks, np.float64, border, np.empty_like(e))
    assert relative_error(out, e, ks, border) <= 2 * EPS32


def test_channel_subset_leaves_the_other_channels_alone():
    e = irradiances(40, 50)["random"]
    ks = kernels(1e-3)
    out = np.full_like(e, -7.0)
    fft_blur_channels(e, [2, 0], [ks[2], ks[0]], np.float32, "clamp", out)
    assert np.all(out[..., 1] == -7.0)
    for c in (0, 2):
        want = fft_blur_channel(e[..., c], ks[c].weights, "clamp")
        assert np.abs(out[..., c] - want).max() <= FFT32_ROUNDOFF * e[..., c].max() * ks[c].rd


@pytest.mark.usefixtures("on_device")
@pytest.mark.parametrize("tol", [1e-2, 1e-3, 1e-4])
def test_fft_bound_is_its_truncation_plus_float32_round_off_and_within_tol(tol):
    e = irradiances(48, 48)["hdr"]
    out, info = blur(e, albedo=ALBEDO, mfp=MFP, eta=1.4, tol=tol, method="fft",
                     return_info=True)
    for c, ck in enumerate(kernels(tol)):
        ch = info.channels[c]
        # float32: the energy the truncation left out plus the round-off, <= tol
        assert ch.error_bound == pytest.approx(ck.truncated + FFT32_ROUNDOFF, rel=1e-12), ch
        assert ch.error_bound <= tol, ch
        want = fft_blur_channel(e[..., c], ck.weights, "clamp")
        assert np.abs(out[..., c] - want).max() <= FFT32_ROUNDOFF * e[..., c].max() * ck.rd


@pytest.mark.usefixtures("on_device")
def test_tol_too_tight_for_float32_round_off_blurs_in_float64():
    # tol 1e-5: the truncation leaves out more than tol - FFT32_ROUNDOFF (< 0), so the FFT is
    # float64, its bound the energy the truncation left out plus FFT64_ROUNDOFF, and the
    # result the float64 convolution rounded to float32 (the settle floor 1 eps32)
    e = irradiances(40, 40)["hdr"]
    ks = kernels(1e-5, mfp=(0.5, 0.7, 1.0))
    out, info = blur(e, albedo=ALBEDO, mfp=(0.5, 0.7, 1.0), eta=1.4, tol=1e-5, method="fft",
                     return_info=True)
    assert [ch.error_bound for ch in info.channels] == pytest.approx(
        [ck.truncated + FFT64_ROUNDOFF for ck in ks], rel=1e-12), info
    assert all(ch.error_bound <= 1e-5 for ch in info.channels)
    assert relative_error(out, e, ks, "clamp") <= 2 * EPS32


def test_kernel_spectra_are_cached_per_kernels_and_shape():
    e = irradiances(30, 30)["random"]
    ks = kernels(1e-3)
    blur_fft.SPECTRA_CACHE.clear()
    first = fft_blur_channels(e, [0, 1, 2], ks, np.float32, "clamp", np.empty_like(e))
    assert len(blur_fft.SPECTRA_CACHE) == 1
    again = fft_blur_channels(e, [0, 1, 2], ks, np.float32, "clamp", np.empty_like(e))
    assert len(blur_fft.SPECTRA_CACHE) == 1                 # a hit, not a second entry
    np.testing.assert_array_equal(again, first)
    fft_blur_channels(e[:20], [0, 1, 2], ks, np.float32, "clamp", np.empty_like(e[:20]))
    assert len(blur_fft.SPECTRA_CACHE) == 2                 # another FFT shape


def test_a_hot_texel_does_not_drown_the_rest_of_the_image():
    """A 1e6 texel in an irradiance of ~0.5: the float32 FFT's round-off (which scales with
    max|E|) would be most of the light elsewhere, and its settle floor would zero it; the
    constant FFT then runs in float64 (``fft_dtype``'s peak_to_mean), and every lit texel
    matches the direct gather to float32 accuracy of its own value."""
    from bdipole_cl.ops.blur import blur
    e = np.random.default_rng(1).random((64, 64, 3), dtype=np.float32)
    e[10, 20, 1] = 1e6
    fft = blur(e, albedo=0.8, mfp=1.0, eta=1.4, method="fft")
    direct = blur(e, albedo=0.8, mfp=1.0, eta=1.4, method="direct")
    lit = direct > 0.05
    assert lit.mean() > 0.95
    # direct: float32 sums of a few hundred taps, ~1e-6 relative; 1e-4 leaves 100x margin
    np.testing.assert_allclose(fft[lit], direct[lit], rtol=1e-4)
