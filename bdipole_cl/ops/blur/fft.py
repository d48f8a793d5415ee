"""The host FFT paths of the blur: the constant kernels' convolution, and the texture-varying
basis blurs with their kernel spectra (scipy.fft and numpy.fft on all cores).

Shapes are even and fast (``fft_shape``), padded by the border rule; a circular convolution on
the padded image then equals the linear one on the image. The kernels are even, so their
spectra are real (a DCT-I of the quadrant), kept across calls in ``SPECTRA_CACHE``, bounded in
bytes. The constant kernels' convolution (``fft_blur_channels``) is float32 where its round-off
fits in tol beside the truncation (``fft_dtype``), all channels in one transform;
``fft_blur_channel`` is the float64 one-channel convolution the tools and tests measure against.
"""
from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from functools import lru_cache

import numpy as np

from ...caches import ByteCache
from ...device.transfer import aligned_empty
from ...signals import check_stop


#: threads for the row-wise inverse FFTs and the row blocks of the constant FFT's copies
#: (NumPy releases the GIL in both): the cores this process may run on
FFT_THREADS = (len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity")
               else os.cpu_count() or 1)


@lru_cache(maxsize=1)
def _fft_threads():
    return ThreadPoolExecutor(FFT_THREADS, thread_name_prefix="bdipole-irfft")


def fft_shape(shape, k):
    """The fast even FFT shape (>= the image padded by k) for the circular convolution of the
    padded image with a (2k+1)^2 kernel: the wrap-around reaches only the first 2k rows and
    columns of the result, which are the padding (the image is at [2k, 2k + n) with the kernel
    at [0, 2k], at [k, k + n) with it centred on 0)."""
    import scipy.fft as sfft

    def even_fast(n):          # even, so that an even kernel's spectrum is a DCT-I
        n = sfft.next_fast_len(n, real=True)
        return n if n % 2 == 0 else even_fast(n + 1)
    return [even_fast(n + 2 * k) for n in shape]


def fft_padded(e2d, k, border):
    """The image padded by k texels by the border rule, and its ``fft_shape``."""
    mode = {"clamp": "edge", "zero": "constant", "wrap": "wrap"}[border]
    return np.pad(e2d, k, mode=mode), fft_shape(e2d.shape, k)


def fft_blur_channel(e2d, weights, border):
    """Exact-weights convolution of one channel by float64 FFT (scipy.fft, all cores), with the
    same border rule as the kernels (the image padded by the kernel radius): the reference."""
    import scipy.fft as sfft
    k = (weights.shape[0] - 1) // 2
    pad, shape = fft_padded(e2d.astype(np.float64), k, border)
    spec = sfft.rfft2(pad, shape, workers=-1) * sfft.rfft2(weights, shape, workers=-1)
    full = sfft.irfft2(spec, shape, workers=-1)
    h, w = e2d.shape
    return full[2 * k:2 * k + h, 2 * k:2 * k + w]


#: the blurs' absolute round-off floor, in float32 eps times max|E| * Rd(x) (``settled``): one
#: eps (the float32 resolution of the brightest exitance) for the device kernels and the
#: float64 constant fft (whose round-off far from any light is ~3 eps of float64), and 16 for
#: the float32 FFTs, whose round-off far from any light measured up to 2.1 eps on half-lit
#: random images of 64^2 to 512^2 (8x margin; the constant one's up to 5.7 eps anywhere on
#: 512^2 to 4096^2 maps); docs/model.md "Blur error bound"
ROUNDOFF_ULPS, FFT32_ROUNDOFF_ULPS = 1, 16


def settle_floor(e_range, ulps):
    """(scale, non-negative) of ``settled``'s rule for a channel whose irradiance spans
    e_range = (min E, max E): results below scale * Rd in magnitude are round-off of a zero
    result (scale = ulps * eps32 * max|E|, as float32, the precision of the maps it scales),
    and where the irradiance is non-negative so is the result. The device's gather applies the
    same rule (kernels/blur_textured.cl ``settle``)."""
    low, high = e_range
    scale = ulps * float(np.finfo(np.float32).eps) * max(high, -low)
    return scale, low >= 0


def settled(m, e2d, rd, ulps=ROUNDOFF_ULPS, e_range=None):
    """One channel's exitance m (in place) with the round-off of a zero result removed: values
    at or below ulps * eps32 * max|E| * Rd (Rd a scalar or a per-texel map) in magnitude are 0 (a
    dark texel's -1e-18 is neither light nor a value half floats hold), and where the
    irradiance is non-negative so is the result (R >= 0 and the truncated kernels are >= 0:
    clamping at 0 only reduces the error). ``e_range``: (min E, max E), where known."""
    scale, nonneg = settle_floor(e_range or (float(e2d.min()), float(e2d.max())), ulps)
    # a map's floor in float32 (a threshold: its own rounding is immaterial), a scalar's exact
    floor = rd * np.float32(scale) if np.ndim(rd) else scale * float(rd)
    if nonneg:                        # |m| <= floor to +0 (a zero's sign too), and so is every
        np.copyto(m, 0, where=m <= floor)                         # m < 0: one pass
    else:
        m[np.abs(m) <= floor] = 0
    return m


def kernel_spectra(quads, shape, compute=np.float32, store=np.float32):
    """Real DFTs (G, N0 // 2 + 1, N1 // 2 + 1), rows 0..N0/2, of the even kernels of
    quadrants quads (G, K+1, K+1) centred on 0, at the even FFT shape (N0, N1), computed in
    ``compute`` and stored as ``store``. An even kernel's DFT is the cosine sum sum_{a,b} m_a m_b
    Q(a, b) cos(2 pi f a / N0) cos(2 pi g b / N1) (m: 1 at 0, else 2): the DCT-I of the
    quadrant zero-padded to (N0/2 + 1, N1/2 + 1). Rows N0/2 + 1..N0 - 1 are rows N0/2 - 1..1
    (``times_spectrum``)."""
    import scipy.fft as sfft
    n0, n1 = shape
    nbasis, kk = quads.shape[:2]
    rows = np.zeros((nbasis, kk, n1 // 2 + 1), compute)       # the other rows are zero: so are
    rows[:, :, :kk] = quads                                 # their transforms along axis 2
    half = np.zeros((nbasis, n0 // 2 + 1, n1 // 2 + 1), compute)
    half[:, :kk] = sfft.dct(rows, type=1, axis=2, workers=-1, overwrite_x=True)
    spec = sfft.dct(half, type=1, axis=1, workers=-1, overwrite_x=True)
    return spec.astype(store, copy=False)


#: kernel spectra are kept across calls up to this many bytes (least recently used first out):
#: blurring again with the same parameter maps (a material under new light) skips them
SPECTRA_CACHE_BYTES = 1 << 30
SPECTRA_CACHE = ByteCache("kernel spectra", SPECTRA_CACHE_BYTES)


def cached_spectra(plan, shape, dtype=np.float32):
    """kernel_spectra of the plan's basis at FFT shape (computed and stored in ``dtype``),
    from the cache when it has them."""
    key = (id(plan), tuple(shape), np.dtype(dtype).str)
    hit = SPECTRA_CACHE.get(key)
    if hit is not None and hit[0] is plan:    # the entry holds the plan: its id is its own
        return hit[1]
    spec = kernel_spectra(plan.blurred_quadrants(), shape, dtype, dtype)
    SPECTRA_CACHE.put(key, (plan, spec), spec.nbytes)
    return spec


#: the float32 constant FFT's round-off, relative to max|E| * Rd, that its error bound charges
#: (docs/model.md "Blur error bound"): the statistical model's maximum over 2^26 padded texels,
#: 2.9e-6, plus the settle floor (FFT32_ROUNDOFF_ULPS eps32 = 1.9e-6), with a 2x margin;
#: measured: at most 7e-7 from the FFT on 512^2 to 4096^2 maps, 1.9e-6 with the floor
FFT32_ROUNDOFF = 1e-5


#: the float32 FFT's round-off relative to max|E| * Rd as the round-off model gives it (its
#: maximum over 2^26 texels, 2.9e-6) plus the settle floor (1.9e-6): what a texel at the
#: image's mean level sees, times max|E| / |mean E| (``fft_dtype``)
FFT32_TYPICAL_ROUNDOFF = 5e-6

#: a float32 transform of a plane whose max|E| times its size exceeds this could overflow (its
#: values are bounded by sum |E|, and float32 ends at 3.4e38): float64 then
FFT32_SUM_LIMIT = 1e37


def fft_dtype(truncated, tol, peak_to_mean=1.0, peak_sum=0.0):
    """float32 for the constant FFT where its round-off fits beside the kernel's truncation
    (``truncated`` + FFT32_ROUNDOFF <= tol: the bound stays within tol), else float64. With
    the image's ``peak_to_mean`` (max|E| / |mean E|, once it is known): where the round-off,
    which scales with max|E|, would exceed tol at the image's mean level
    (FFT32_TYPICAL_ROUNDOFF x peak_to_mean > tol: a 1e6 hot texel in an irradiance of ~0.5,
    where the float32 round-off is most of the light elsewhere and the settle floor zeroes
    it; highlights at 50 in a map of ~0.5 stay float32), float64; and where max|E| times the
    transform's size (``peak_sum``) could overflow float32 (FFT32_SUM_LIMIT: a field of 1e36
    at 2048^2)."""
    return (np.float32 if truncated + FFT32_ROUNDOFF <= tol
            and FFT32_TYPICAL_ROUNDOFF * peak_to_mean <= tol
            and peak_sum <= FFT32_SUM_LIMIT else np.float64)


#: float32's unit round-off: a float32 exitance is within U32 of its value, relative
U32 = 2.0 ** -24
#: the float64 constant FFT's round-off relative to max|E| * Rd: its exitance rounded to float32
#: (U32), the settle floor (ROUNDOFF_ULPS eps32 = 2 U32) and the float64 transform's own
#: (~1e-15 log2 n), with a margin
FFT64_ROUNDOFF = 4 * U32


def fft_bound(kernel, dtype):
    """The error bound of the constant FFT in ``dtype``: the energy its truncation left out
    plus its round-off (FFT32_ROUNDOFF or FFT64_ROUNDOFF), relative to max|E| * Rd."""
    return float(kernel.truncated + (FFT32_ROUNDOFF if dtype == np.float32 else FFT64_ROUNDOFF))


def summed_roundoff(terms) -> float:
    """A bound on the round-off, relative to max|E| * Rd, of float32 sums of at most ``terms``
    products of non-negative weights summing to <= Rd and texels of |E| <= max|E|, rounded
    in sequence (gamma_n = n U32, Higham Thm. 3.1 / 4.4), then written as float32 (U32) and
    settled (2 U32), the weights themselves rounded to float32 (U32), with one U32 to spare."""
    return (terms + 5) * U32


def row_blocks(h):
    """[r0, r1) row blocks of an image of h rows, one per FFT thread."""
    edges = np.linspace(0, h, FFT_THREADS + 1).astype(int)
    return list(zip(edges[:-1], edges[1:]))


def in_row_blocks(fn, h):
    """fn(r0, r1) for each row block, on the FFT threads (NumPy's copies and reductions
    release the GIL): its results, in block order."""
    return list(_fft_threads().map(lambda block: fn(*block), row_blocks(h)))


#: rows per piece of ``value_range`` and ``copy_rows`` within a thread's block: a piece of a
#: 4096-wide float32 map is 1 MiB, so its min and max read it from the cache
PIECE_ROWS = 64


def value_range(v):
    """(min, max) of array ``v`` (NaN if any value is NaN), in row blocks on the FFT threads,
    each block's min and max taken piece by piece (one read of the map from memory)."""
    v = np.asarray(v)
    if v.ndim < 2 or v.size < (1 << 16):
        return v.min(), v.max()

    def block(r0, r1):
        if r1 <= r0:                   # more threads than rows
            return None
        lows, highs = [], []
        for p in range(r0, r1, PIECE_ROWS):
            piece = v[p:min(p + PIECE_ROWS, r1)]
            lows.append(piece.min())
            highs.append(piece.max())
        return np.min(lows), np.max(highs)
    parts = [b for b in in_row_blocks(block, v.shape[0]) if b is not None]
    return np.min([lo for lo, _ in parts]), np.max([hi for _, hi in parts])


#: texels per row of ``channel_extremes``' contiguous view: a reduction over rows of many
#: texels' channels runs along memory (NumPy's over an interleaved channel axis strides, ~25x
#: slower on a 2048^2 RGB map)
EXTREMES_ROW_TEXELS = 1024


def channel_extremes(e):
    """(min, max) per channel of an (H, W, C) map (arrays of C), in two passes along memory:
    the map viewed as rows of EXTREMES_ROW_TEXELS texels, reduced over the rows, then per
    channel over the row's texels (NaN if a channel has a NaN)."""
    c = e.shape[-1]
    flat = e.reshape(-1)
    step = EXTREMES_ROW_TEXELS * c
    n = flat.size // step * step
    lows, highs = [], []
    if n:
        body = flat[:n].reshape(-1, step)
        lows.append(body.min(axis=0).reshape(-1, c).min(axis=0))
        highs.append(body.max(axis=0).reshape(-1, c).max(axis=0))
    if n < flat.size:
        tail = flat[n:].reshape(-1, c)
        lows.append(tail.min(axis=0))
        highs.append(tail.max(axis=0))
    return np.min(lows, axis=0), np.max(highs, axis=0)


def channel_peaks(e):
    """max|E| per channel of an (H, W, C) map, float64 (``channel_extremes``)."""
    return peaks_of(*channel_extremes(e))


def peaks_of(lo, hi):
    """max|E| per channel, float64, of its extremes (``channel_extremes``)."""
    return np.maximum(np.abs(lo.astype(np.float64)), np.abs(hi.astype(np.float64)))


def copy_rows(out, v):
    """out[...] = v (cast as ``np.copyto`` does, unsafe), in row blocks on the FFT threads."""
    if np.ndim(v) < 2 or out.size < (1 << 16):
        np.copyto(out, v, casting="unsafe")
        return out
    in_row_blocks(lambda r0, r1: np.copyto(out[r0:r1], v[r0:r1], casting="unsafe"),
                  out.shape[0])
    return out


def padded_planes(e, channels, k, shape, dtype, border, sums=None):
    """(G, N0, N1) ``dtype`` planes: channel ``channels[g]`` of the (H, W, C) image at rows
    [k, k + H), columns [k, k + W), padded by k texels by the border rule, zeros beyond (the
    circular convolution by a kernel of radius k reads rows [0, H + 2k) for outputs [k, k + H));
    and each channel's (min, max), for ``settled``. ``sums``: a list that gets each channel's
    sum (float64), from the same pass."""
    h, w = e.shape[:2]
    # on the device-alignment boundary, so that the texture-varying gather reads the padded
    # channel in place (an unaligned host pointer is copied whole: ``device.transfer``)
    planes = aligned_empty(len(channels) * shape[0] * shape[1], dtype).reshape(
        (len(channels), *shape))
    planes[:, :k] = 0
    planes[:, k + h:] = 0

    def fill(r0, r1):
        rng = []
        for g, c in enumerate(channels):
            planes[g, k + r0:k + r1, :k] = 0
            planes[g, k + r0:k + r1, k + w:] = 0
            block = planes[g, k + r0:k + r1, k:k + w]
            block[...] = e[r0:r1, :, c]
            rng.append((block.min(), block.max(), block.sum(dtype=np.float64) if sums
                        is not None else 0.0) if r1 > r0 else (np.inf, -np.inf, 0.0))
        return rng
    blocks = in_row_blocks(fill, h)
    ranges = [(float(min(b[g][0] for b in blocks)), float(max(b[g][1] for b in blocks)))
              for g in range(len(channels))]
    if sums is not None:
        sums[:] = [float(sum(b[g][2] for b in blocks)) for g in range(len(channels))]
    inner = planes[:, :h + 2 * k]
    if border == "clamp":
        inner[:, :k, k:k + w] = inner[:, k:k + 1, k:k + w]
        inner[:, k + h:, k:k + w] = inner[:, k + h - 1:k + h, k:k + w]
        inner[:, :, :k] = inner[:, :, k:k + 1]
        inner[:, :, k + w:k + w + k] = inner[:, :, k + w - 1:k + w]
    elif border == "wrap":
        for g, c in enumerate(channels):
            inner[g, :, :w + 2 * k] = np.pad(e[..., c], k, mode="wrap")
    return planes, ranges


def image_fft_dtype(truncated, tol, e_range, e_sum, texels, shape):
    """``fft_dtype`` for an image channel of range (min E, max E) ``e_range`` and sum
    ``e_sum`` over ``texels`` texels, transformed at FFT shape ``shape``."""
    return fft_dtype(truncated, tol, peak_to_mean(e_range, e_sum / texels),
                     peak(e_range) * shape[0] * shape[1])


def peak(e_range) -> float:
    """max|E| of a channel of range (min E, max E)."""
    return max(abs(e_range[0]), abs(e_range[1]))


def peak_to_mean(e_range, mean) -> float:
    """max|E| / |mean E| of a channel (infinite for a mean of 0 under a non-zero peak; 1 for
    an all-zero channel)."""
    top = peak(e_range)
    if top == 0:
        return 1.0
    return top / abs(mean) if mean != 0 else np.inf


def times_real_spectrum(kp, spec):
    """spec *= K in place, K the real spectrum of an even kernel as float pairs (each value
    twice: ``constant_spectra``) over its rows 0..N0/2: rows N0/2 + 1..N0 - 1 are rows
    N0/2 - 1..1 (``kernel_spectra``). Real times complex, as one float multiply."""
    m = kp.shape[0]
    flat = spec.view(kp.dtype)
    flat[:m] *= kp
    flat[m:] *= kp[m - 2:0:-1]


def constant_spectra(kernels, k, shape, dtype):
    """The kernels' half spectra at FFT shape (float64 DCT-I of the exact weights, stored in
    ``dtype``) as float pairs (``times_real_spectrum``), from SPECTRA_CACHE when it has them
    (keyed by the kernels, which it holds)."""
    key = ("constant", tuple(id(ck) for ck in kernels), tuple(shape), np.dtype(dtype).str)
    hit = SPECTRA_CACHE.get(key)
    if hit is not None and all(a is b for a, b in zip(hit[0], kernels)):
        return hit[1]
    quads = np.zeros((len(kernels), k + 1, k + 1))
    for g, ck in enumerate(kernels):
        quads[g, :ck.radius + 1, :ck.radius + 1] = ck.weights[ck.radius:, ck.radius:]
    pairs = np.repeat(kernel_spectra(quads, shape, np.float64, dtype), 2, axis=-1)
    SPECTRA_CACHE.put(key, (tuple(kernels), pairs), pairs.nbytes)
    return pairs


def fft_blur_channels(e, channels, kernels, dtype, border, out, tols=None, ranges=None):
    """out[..., c] = channel c of the (H, W, C) image convolved with its constant kernel, for
    each c of ``channels`` (``kernels`` theirs), all in one batched FFT in ``dtype`` on all
    cores: the planes padded by the largest radius K at the fast even shape, one forward
    transform, the cached real kernel spectra multiplied in place, the inverse over the columns
    and then over the image's rows only; each result settled (``settled``) on its plane. With
    ``tols`` (each channel's), a float32 blur of an image whose peak is too far above its mean
    for the float32 round-off, or whose sums could overflow float32 (``image_fft_dtype``), is
    done in float64 instead. ``ranges``: a list that gets each channel's (min, max)
    irradiance. Returns ``out``."""
    import scipy.fft as sfft
    h, w = e.shape[:2]
    k = max(ck.radius for ck in kernels)
    shape = fft_shape((h, w), k)
    sums = [] if tols is not None and dtype == np.float32 else None
    planes, e_ranges = padded_planes(e, channels, k, shape, dtype, border, sums)
    if ranges is not None:
        ranges[:] = e_ranges
    if sums is not None and any(
            image_fft_dtype(ck.truncated, t, r, total, h * w, shape) != np.float32
            for ck, t, r, total in zip(kernels, tols, e_ranges, sums)):
        del planes
        return fft_blur_channels(e, channels, kernels, np.float64, border, out)
    ks = constant_spectra(kernels, k, shape, dtype)
    spec = sfft.rfft2(planes, axes=(1, 2), workers=-1, overwrite_x=True)
    check_stop()
    list(_fft_threads().map(times_real_spectrum, ks, spec))
    cols = sfft.ifft(spec, axis=1, workers=-1, overwrite_x=True)
    check_stop()
    rows = sfft.irfft(cols[:, k:k + h], shape[1], axis=2, workers=-1)
    ulps = FFT32_ROUNDOFF_ULPS if dtype == np.float32 else ROUNDOFF_ULPS

    def settle_and_store(r0, r1):
        for g, (c, ck) in enumerate(zip(channels, kernels)):
            plane = rows[g, r0:r1, k:k + w]
            settled(plane, None, ck.rd, ulps, e_ranges[g])
            out[r0:r1, :, c] = plane
    in_row_blocks(settle_and_store, h)
    return out


def times_spectrum(ks, spec, out):
    """out = K * spec, K the full (N0, N1 // 2 + 1) spectrum of half spectrum ks (rows
    0..N0/2): an even kernel's rows N0 - f and f are equal. In row blocks on the FFT threads."""
    m, n0 = ks.shape[0], spec.shape[0]

    def rows(r0, r1):
        a1, b0 = min(r1, m), max(r0, m)
        if a1 > r0:                                      # rows f < m: K's row f
            np.multiply(ks[r0:a1], spec[r0:a1], out=out[r0:a1])
        if r1 > b0:                                      # rows f >= m: K's row n0 - f
            np.multiply(ks[n0 - b0:n0 - r1:-1], spec[b0:r1], out=out[b0:r1])
    in_row_blocks(rows, n0)


#: a texture-varying blur of a channel whose max|E| is above this blurs E times a power of two
#: that brings it to [0.5, 1) (``hdr_unit``): its float32 basis planes (|B_j * E| up to the
#: eigen-kernel's L1 norm times max|E|) and the gather's near-field class sums (8 cells) would
#: pass float32's 3.4e38 from a field of ~1e37 up
HDR_UNIT_ABOVE = 2.0 ** 100


def hdr_unit(e_range) -> float:
    """1, or the power of two 2^-e that brings max|E| of a channel of range (min E, max E) to
    [0.5, 1) where it is above HDR_UNIT_ABOVE (exact in float32: the texels below 2^-126 of
    the new unit, 1e-38 of the peak and far below its float32 resolution, lose bits)."""
    top = peak(e_range)
    return float(2.0 ** -np.frexp(top)[1]) if top > HDR_UNIT_ABOVE else 1.0


def basis_blurs(e, c, plan, border, planes):
    """planes[j] = (B_j * E) for every basis kernel of the plan, E channel c of the (H, W, C)
    image, as (H, W + 2K) float32 rows whose columns [K, K + W) are the image's: one forward
    transform (of ``padded_planes``' plane), and per basis kernel an inverse transform pruned
    to the image's rows. One basis kernel at a time, in place: scipy.fft (all cores) in place
    over the columns, then numpy's ``irfft`` into the plane, in row blocks on all cores (fresh
    large arrays and copies cost more here than the FFTs' own threads save). The transforms
    are float32 unless the channel's peak is too far above its mean for their round-off
    (``fft_dtype``'s peak_to_mean at the plan's tol: then float64, the planes still float32,
    good to eps32 of each texel's own value). Returns the padded float32 channel (N0, N1) (the
    image at rows and columns [K, K + H), [K, K + W): the near field's irradiance), its
    (min, max), and the transforms' dtype, for ``settle_floor``, all in units of ``unit``
    (``hdr_unit``: the planes and the channel are E times unit), and unit."""
    import scipy.fft as sfft
    k = plan.radius
    h, w = e.shape[:2]
    shape = fft_shape((h, w), k)
    sums = []
    padded, (e_range,) = padded_planes(e, [c], k, shape, np.float32, border, sums)
    unit = hdr_unit(e_range)
    if unit != 1.0:                    # exact: a power of two
        padded *= np.float32(unit)
        e_range, sums = (e_range[0] * unit, e_range[1] * unit), [sums[0] * unit]
    dtype = image_fft_dtype(0.0, plan.truncation_tol, e_range, sums[0], h * w, shape)
    if not len(plan.kernels):          # the near field holds the whole kernel
        return padded[0], e_range, dtype, unit
    source = padded if dtype == np.float32 else padded_planes(e, [c], k, shape, dtype,
                                                              border)[0] * unit
    kspec = cached_spectra(plan, shape, dtype)
    spec = sfft.rfft2(source[0], workers=-1)
    del source
    prod = np.empty_like(spec)
    for plane, ks in zip(planes, kspec):
        check_stop()
        times_spectrum(ks, spec, prod)
        cols = sfft.ifft(prod, axis=0, workers=-1, overwrite_x=True)

        def rows_of_plane(r0, r1, cols=cols, plane=plane):
            if dtype == np.float32:
                np.fft.irfft(cols[k + r0:k + r1], shape[1], axis=-1, out=plane[r0:r1])
            else:
                plane[r0:r1] = np.fft.irfft(cols[k + r0:k + r1], shape[1], axis=-1)
        in_row_blocks(rows_of_plane, h)
    return padded[0], e_range, dtype, unit
