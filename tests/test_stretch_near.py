"""The stretched blur's near field, rank and bands (bdipole_cl/ops/blur/stretched*.py,
kernels/blur_stretched.cl; docs/stretch.md "The near field", "Bands"): against the direct
per-texel convolution with each texel's exact kernel, the basis's rank on a smoothly varying
stretch, and a blur in bands of rows within max_memory equal to the whole image's."""
import numpy as np
import pytest

import bdipole_cl as bd
import bdipole_cl.ops.blur.stretched as stretched_mod
from bdipole_cl.ops.blur.stretched import as_stretch
from bdipole_cl.ops.blur.stretched_plan import node_kernel
from bdipole_cl.ops.blur.weights import unfold_quadrant
from bdipole_cl.io.stretch_maps import stretch_maps
from stretch_meshes import cylinder_stage


def smooth_stretch(h, w, amplitude=0.25, t=0.25):
    """(su, sv) texel lengths t 2^(+-amplitude p) (mm), p smooth patterns in [-1, 1] of two
    periods across the map, as tools/bench_blur.py's "smooth" stretch."""
    yy, xx = np.mgrid[0:h, 0:w] / np.array([h, w])[:, None, None]
    p = np.sin(2 * np.pi * (2 * xx + yy))
    q = np.cos(2 * np.pi * (xx - 2 * yy))
    return ((t * 2.0 ** (amplitude * p)).astype(np.float32),
            (t * 2.0 ** (amplitude * q)).astype(np.float32))


def direct_blur(e, rd, lu, lv, eta, radius, texels):
    """The exitance at ``texels`` ((row, col) pairs) of irradiance e (H x W, clamped beyond its
    edges) by the direct sum over each texel's own exact kernel (``node_kernel`` at its Rd,
    l_u, l_v, float64, (2K + 1)^2 cells), times its Rd: no basis, lattice, FFT or near field."""
    h, w = e.shape
    k = radius
    ys = np.clip(np.arange(-k, h + k), 0, h - 1)
    xs = np.clip(np.arange(-k, w + k), 0, w - 1)
    padded = e.astype(np.float64)[np.ix_(ys, xs)]
    out = []
    for y, x in texels:
        kern = unfold_quadrant(node_kernel(float(rd[y, x]), float(lu[y, x]), float(lv[y, x]),
                                           eta, k))
        out.append(float(rd[y, x]) * float((kern * padded[y:y + 2 * k + 1,
                                                           x:x + 2 * k + 1]).sum()))
    return np.array(out)


def test_near_field_matches_direct_per_texel_sum(on_device):
    """A random irradiance under a smooth stretch (texels 2^(+-0.25) x 0.25 mm along each axis)
    and varying albedo and mfp: the stretched blur (near field, eigen-kernels, the lattice's
    table) equals the direct sum over each texel's exact kernel within the reported bound
    (an L1 bound on the kernel: |error| <= bound x Rd x max E) at texels across the map."""
    h, w, eta = 40, 48, 1.4
    rng = np.random.default_rng(48)
    e = rng.random((h, w)).astype(np.float32)
    yy, xx = np.mgrid[0:h, 0:w]
    albedo = (0.55 + 0.3 * xx / w).astype(np.float32)
    mfp = (0.8 + 0.4 * yy / h).astype(np.float32)
    su, sv = smooth_stretch(h, w)
    out, info = bd.blur(e, albedo=albedo, mfp=mfp, eta=eta, stretch=(su, sv), tol=1e-3,
                        border="clamp", return_info=True)
    ch = info.channels[0]
    assert "near field" in ch.method, ch.method
    maps = stretched_mod.channel_maps((h, w, 1), 0, as_stretch((su, sv), (h, w)),
                                      {"albedo": albedo, "mfp": mfp}, eta, False, "raise", {},
                                      None)
    texels = [(int(y), int(x)) for y, x in zip(rng.integers(0, h, 24), rng.integers(0, w, 24))]
    texels += [(0, 0), (h - 1, w - 1), (h // 2, 0)]
    want = direct_blur(e, *maps, eta, ch.radius, texels)
    got = np.array([out[y, x] for y, x in texels], np.float64)
    rd = np.array([maps[0][y, x] for y, x in texels], np.float64)
    err = np.abs(got - want) / rd
    assert err.max() <= ch.error_bound * float(e.max()), (err.max(), ch)
    # and not trivially: the kernels differ from texel to texel by far more than the bound
    assert np.ptp(want / rd) > 10 * ch.error_bound


def test_rank_on_smooth_stretch(on_device):
    """A smoothly varying stretch (each axis 2^(+-0.25), aspect 2^(+-0.5)) at a diffusion length
    of ~3-8 texels, tol 1e-3: the near field takes the kernels' sharp centre, and the
    eigen-kernels the FFT blurs (one inverse FFT of the image each) number at most 12 (round
    1, without a near field, needed 20-27 for this family), the bound within 2 tol."""
    h = w = 96
    su, sv = smooth_stretch(h, w)
    yy, xx = np.mgrid[0:h, 0:w]
    mfp = (4.0 * 0.25 * 2.0 ** (0.5 * np.sin(2 * np.pi * (xx + yy) / w))).astype(np.float32)
    e = np.zeros((h, w), np.float32)
    e[h // 2, w // 2] = 1.0
    _, info = bd.blur(e, albedo=0.7, mfp=mfp, eta=1.4, stretch=(su, sv), tol=1e-3,
                      return_info=True)
    ch = info.channels[0]
    rank = int(ch.method.split("stretched, ")[1].split(" eigen")[0])
    assert "near field" in ch.method and rank <= 12, ch.method
    assert ch.error_bound <= 2.2e-3, ch


def counted_bands(monkeypatch):
    """A list that gets the rows of each band blurred, on the host's FFT or on the device
    (``stretched.blur_band``, ``blur_band_device``: the engine the device under test takes)."""
    calls = []
    for name in ("blur_band", "blur_band_device"):
        real = getattr(stretched_mod, name)
        monkeypatch.setattr(stretched_mod, name,
                            lambda *a, real=real, **k: calls.append(a[6]) or real(*a, **k))
    return calls


@pytest.mark.parametrize("border", ["clamp", "wrap", "zero"])
def test_banded_equals_whole(on_device, monkeypatch, border):
    """max_memory small enough for bands of a few rows: the stretched blur runs in several
    bands (counted) with the halo of the largest radius, and equals the whole image's blur to
    the float32 FFTs' round-off (their sizes differ)."""
    h, w = 72, 40
    rng = np.random.default_rng(7)
    e = rng.random((h, w, 2)).astype(np.float32)
    su, sv = smooth_stretch(h, w, t=0.3)
    kw = dict(albedo=(0.6, 0.8), mfp=(0.6, 0.9), eta=1.4, stretch=(su, sv), border=border)
    whole = bd.blur(e, **kw)
    calls = counted_bands(monkeypatch)
    banded = bd.blur(e, **kw, max_memory=400_000)
    assert len(calls) > 4 and max(calls) < h, calls            # rows per band
    np.testing.assert_allclose(banded, whole, rtol=1e-5, atol=1e-6 * float(whole.max()))


def test_banded_charts_equal_whole(on_device, monkeypatch, tmp_path):
    """The same with charts kept apart (one window per chart, each banded on its own)."""
    size = 96
    (tile, _), = stretch_maps(cylinder_stage(tmp_path / "cyl.usda"), size=size)
    rng = np.random.default_rng(3)
    e = rng.random((size, size)).astype(np.float32)
    kw = dict(albedo=0.7, mfp=1.0, eta=1.4, stretch=tile, charts="clamp")
    whole = bd.blur(e, **kw)
    calls = counted_bands(monkeypatch)
    banded = bd.blur(e, **kw, max_memory=150_000)
    assert len(calls) > 4, calls
    np.testing.assert_allclose(banded, whole, rtol=1e-5, atol=1e-6 * float(whole.max()))
