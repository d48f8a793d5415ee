"""The constant-parameter FFT blur on the OpenCL device (kernels/blur_fft.cl around the
transforms of ``ops.device_fft``), the twin of ``fft.fft_blur_channels`` on the host.

The irradiance is on the device (uploaded once per band, or a device array given), and so is
every pass over it: each channel's range, sum and count of non-finite texels (``image_stats``:
one work-group reduction, the groups' partials read back, a few KiB), the planes padded by the
border rule, one batched forward transform, the kernels' real spectra multiplied in (computed
once per kernel set and shape on the host, in float64, as ``fft.constant_spectra``, and kept on
the device), the inverse transform of the image's rows only, and the settle into the exitance
(``fft.settled``'s rule). The host decides from the statistics alone (the transforms'
precision, ``fft.image_fft_dtype``; the settle floor; a peak far below 1 scaled by a power of
two, as ``planning.peak_exponents``) and reads nothing else back.

Sizes are the device transforms' (``device_fft_len``: even, with the radices of
kernels/fft.cl); float64 where a channel needs it and the device has fp64, else the host's FFT.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pyopencl as cl
import pyopencl.array as cla

from ...caches import ByteCache
from ...signals import check_stop
from ..device_fft import DeviceFFT, device_fft_len
from .fft import (FFT32_ROUNDOFF_ULPS, ROUNDOFF_ULPS, constant_spectra, image_fft_dtype,
                  settle_floor)

#: work-items of a statistics work-group (kernels/blur_fft.cl BD_STATS_GROUP), and groups per
#: channel at most: 256 x 256 partial records of 4 floats per channel read back (1 MiB at most)
STATS_GROUP, STATS_GROUPS = 256, 256
#: device transforms and kernel spectra kept across calls (a 4320^2 batch of three is 450 MB of
#: scratch): least recently used out
DEVICE_FFT_CACHE = ByteCache("device FFT plans and spectra", 2 << 30)


@dataclass(frozen=True)
class ChannelStats:
    """One channel of an irradiance on the device: its range and sum over its finite texels,
    and how many are NaN or infinite."""

    low: float
    high: float
    total: float
    nonfinite: int
    clamped_texels: int = 0      # non-finite texels ``clamped`` counts as 0 (still in memory)

    def clamped(self) -> "ChannelStats":
        """The statistics once its non-finite texels are 0 (``on_invalid="clamp"``)."""
        if not self.nonfinite:
            return self
        return ChannelStats(min(self.low, 0.0), max(self.high, 0.0), self.total, 0,
                            self.nonfinite)

    @property
    def unclean(self) -> bool:
        """Whether its texels in memory hold a NaN or infinity, clamped or not: a kernel that
        reads them must read a cleaned copy (``clean_scaled``)."""
        return bool(self.nonfinite or self.clamped_texels)

    @property
    def e_range(self) -> tuple:
        return (self.low, self.high)

    @property
    def peak(self) -> float:
        return max(abs(self.low), abs(self.high)) if self.low <= self.high else 0.0


def floor_peaks(stats, peaks=None) -> np.ndarray:
    """The per channel max|E| float32's floor is relative to: ``peaks`` (the image's, for a
    band of it) where given, else the band's own (its ``stats``)."""
    return np.array([st.peak for st in stats]) if peaks is None else peaks


def image_stats(kernels, e_dev: cla.Array, wait_for=None) -> list:
    """ChannelStats of each channel of the (H, W, C) float32 irradiance ``e_dev``."""
    rt = kernels.rt
    h, w, nch = e_dev.shape
    texels = h * w
    groups = max(1, min(STATS_GROUPS, -(-texels // STATS_GROUP)))
    partial = np.empty((nch, groups, 4), np.float32)
    buf = cl.Buffer(rt.context, cl.mem_flags.WRITE_ONLY, partial.nbytes)
    knl = kernels.kernel("blur_fft", "channel_stats", BD_STATS_GROUP=STATS_GROUP)
    knl(rt.queue, (groups * STATS_GROUP, nch), (STATS_GROUP, 1), e_dev.data,
        np.uint64(texels), np.int32(nch), buf, wait_for=wait_for)
    cl.enqueue_copy(rt.queue, partial, buf)
    out = []
    for c in range(nch):
        p = partial[c].astype(np.float64)
        out.append(ChannelStats(float(p[:, 0].min()), float(p[:, 1].max()),
                                float(p[:, 2].sum()), int(p[:, 3].sum())))
    return out


def peak_shift(stats: ChannelStats, peak_range: int) -> int:
    """``planning.peak_exponents``' power of two for one channel: k where its peak |E| is
    2^k x [0.5, 1) below 2^-peak_range, else 0."""
    top = stats.peak
    if not 0 < top < 2.0 ** -peak_range:
        return 0
    return int(np.frexp(top)[1])


def device_fft_shape(shape, k) -> tuple:
    """The device transforms' shape for an (H, W) image padded by k (``fft.fft_shape``'s
    rule at the sizes kernels/fft.cl transforms)."""
    return tuple(device_fft_len(n + 2 * k) for n in shape)


def device_transforms(rt, shape, batch, double) -> DeviceFFT:
    """The DeviceFFT of ``batch`` planes of ``shape`` on ``rt``, kept across calls."""
    key = ("plan", id(rt.context), tuple(shape), batch, double)
    hit = DEVICE_FFT_CACHE.get(key)
    if hit is None or hit[0] is not rt.context:
        plan = DeviceFFT(rt, tuple(shape), batch, double)
        nbytes = batch * shape[0] * (shape[1] + 2) * (8 if double else 4) * 3
        hit = DEVICE_FFT_CACHE.put(key, (rt.context, plan), nbytes)
    return hit[1]


def _device_spectra(rt, chan_kernels, k, shape, dtype) -> cl.Buffer:
    """The kernels' real half spectra (G, N0/2 + 1, N1/2 + 1) on the device, once."""
    key = ("spectra", id(rt.context), tuple(id(ck) for ck in chan_kernels), tuple(shape),
           np.dtype(dtype).str)
    hit = DEVICE_FFT_CACHE.get(key)
    if hit is not None and hit[0] is rt.context and all(
            a is b for a, b in zip(hit[1], chan_kernels)):
        return hit[2]
    pairs = constant_spectra(chan_kernels, k, shape, dtype)       # each value twice
    real = np.ascontiguousarray(pairs[..., ::2])
    buf = cl.Buffer(rt.context, cl.mem_flags.READ_ONLY | cl.mem_flags.COPY_HOST_PTR,
                    hostbuf=real)
    DEVICE_FFT_CACHE.put(key, (rt.context, tuple(chan_kernels), buf), real.nbytes)
    return buf


def fft_blur_device(kernels, e_dev, out_dev, channels, chan_kernels, stats, dtype,
                    shifts, wait_for=None):
    """out_dev[..., c] = channel c of the irradiance ``e_dev`` ((H, W, C) float32 on the
    device) convolved with its constant kernel, for each c of ``channels`` (``chan_kernels``
    theirs; ``stats`` every channel's ChannelStats, ``shifts`` their powers of two), in one
    batch of ``dtype`` transforms on the device, settled. Returns the last event."""
    rt = kernels.rt
    h, w, nch = e_dev.shape
    k = max(ck.radius for ck in chan_kernels)
    shape = device_fft_shape((h, w), k)
    n0, n1 = shape
    g = len(channels)
    double = dtype == np.float64
    real = np.float64 if double else np.float32
    fft = device_transforms(rt, shape, g, double)
    mf = cl.mem_flags
    planes = cl.Buffer(rt.context, mf.READ_WRITE, g * n0 * n1 * np.dtype(real).itemsize)
    spec = cl.Buffer(rt.context, mf.READ_WRITE, g * n0 * (n1 // 2 + 1) * 2
                     * np.dtype(real).itemsize)
    chans = cla.to_device(rt.queue, np.int32(channels))
    shift = cla.to_device(rt.queue, np.int32([shifts[c] for c in channels]))
    event = kernels.kernel("blur_fft", "pad_planes", double=double)(
        rt.queue, (n1, n0, g), None, e_dev.data, planes, chans.data, shift.data,
        np.int32(h), np.int32(w), np.int32(nch), np.int32(k), np.int32(n0), np.int32(n1),
        wait_for=wait_for)
    event = fft.forward(planes, spec, wait_for=[event])
    check_stop()
    event = kernels.kernel("blur_fft", "times_spectrum", double=double)(
        rt.queue, (n1 // 2 + 1, n0, g), None, spec,
        _device_spectra(rt, chan_kernels, k, shape, real), np.int32(n0),
        np.int32(n1 // 2 + 1), wait_for=[event])
    event = fft.inverse(spec, planes, rows=(k, k + h), wait_for=[event])
    ulps = FFT32_ROUNDOFF_ULPS if not double else ROUNDOFF_ULPS
    floors, nonneg = [], []
    for c, ck in zip(channels, chan_kernels):
        unit = 2.0 ** -shifts[c]
        scale, positive = settle_floor((stats[c].low * unit, stats[c].high * unit), ulps)
        floors.append(scale * ck.rd)
        nonneg.append(int(positive))
    floor = cla.to_device(rt.queue, np.asarray(floors, real))
    positive = cla.to_device(rt.queue, np.int32(nonneg))
    return kernels.kernel("blur_fft", "settle_store", double=double)(
        rt.queue, (w, h, g), None, planes, out_dev.data, chans.data, floor.data,
        positive.data, shift.data, np.int32(h), np.int32(w), np.int32(nch), np.int32(k),
        np.int32(h), np.int32(0), np.int32(n1), wait_for=[event])


def device_fft_dtype(chan_kernels, tols, stats, shifts, texels, shape):
    """The batch's transform precision: float64 where some channel's float32 round-off would
    not fit its tol (``fft.image_fft_dtype`` on its statistics, scaled by its power of two)."""
    dtypes = []
    for ck, tol, st, sh in zip(chan_kernels, tols, stats, shifts):
        unit = 2.0 ** -sh
        dtypes.append(image_fft_dtype(ck.truncated, tol, (st.low * unit, st.high * unit),
                                      st.total * unit, texels, shape))
    return np.result_type(*dtypes)
