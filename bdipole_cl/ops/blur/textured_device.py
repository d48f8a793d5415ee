"""The texture-varying blur on the device end to end (the twin of ``textured.blur_band`` on
the host): per channel, the irradiance padded on the device, one forward transform, per basis
kernel its spectrum multiplied in and the image's rows transformed back (``ops.device_fft``),
then the per-texel gather (kernels/blur_textured.cl) reading the basis blurs, the padded
channel and the Rd and ld maps from device buffers into the exitance; or, for the separable
Gaussian basis, the separable kernels and the weight planes, settled against the Rd map on the
device. Statistics (ranges, sums, non-finite counts) are reduced on the device
(``fft_device.image_stats``); the host keeps the plans and reads nothing else back.

A channel whose peak is far from 1 (below 2^-PEAK_RANGE, as ``planning.peak_exponents``, or
above ``fft.HDR_UNIT_ABOVE``, as ``fft.hdr_unit``) is blurred scaled by a power of two and
scaled back (exact but for the last rounding).
"""
from __future__ import annotations

import numpy as np
import pyopencl as cl
import pyopencl.array as cla

from ...caches import ByteCache
from ...device.launch import enqueue_items
from ...device.transfer import device_image
from ...signals import check_stop
from .dispatch import DeviceBlur, device_weight_planes, node_records, textured_kernel
from .fft import (FFT32_ROUNDOFF_ULPS, HDR_UNIT_ABOVE, ROUNDOFF_ULPS, cached_spectra,
                  image_fft_dtype, settle_floor)
from .fft_device import device_fft_shape, device_transforms, floor_peaks, image_stats
from .planning import PEAK_RANGE, BlurInfo, signed_irradiance_bound, with_output_floor

#: a texture-varying plan's arrays on the device (Rd and ld maps, node records, basis
#: spectra), kept across bands and calls while the plan lives
PLAN_BUFFERS = ByteCache("texture-varying plans on the device", 1 << 30)


def channel_shift(stats) -> int:
    """The power of two a channel is blurred at: its peak brought to [0.5, 1) where it is
    below 2^-PEAK_RANGE or above HDR_UNIT_ABOVE, else 0."""
    top = stats.peak
    if top > 0 and (top < 2.0 ** -PEAK_RANGE or top > HDR_UNIT_ABOVE):
        return int(np.frexp(top)[1])
    return 0


def plan_buffer(rt, plan, name, make):
    """PLAN_BUFFERS' entry ``name`` of ``plan`` on ``rt`` (made by ``make()``: a buffer and
    its bytes), held with the plan (its id is its own while it lives). ``plan``: any object
    the buffer belongs to (a texture-varying or stretched plan, a stretched window's maps)."""
    key = (id(rt.context), id(plan), name)
    hit = PLAN_BUFFERS.get(key)
    if hit is None or hit[0] is not rt.context or hit[1] is not plan:
        buf, nbytes = make()
        hit = PLAN_BUFFERS.put(key, (rt.context, plan, buf), nbytes)
    return hit[2]


def _maps(rt, channel, rows):
    """The channel's Rd and ld maps for ``rows`` as device arrays (the whole maps kept with
    the blur plan's channel, not with its TexturedPlan: that is shared by every map of the
    same ranges, and a second map must not find the first one's texels)."""
    _, rd, ld, _ = channel
    whole = isinstance(rows, slice) and rows == slice(0, rd.shape[0])

    def upload(m):
        return device_image(rt, np.ascontiguousarray(m[rows], np.float32))
    if not whole:
        return upload(rd), upload(ld)
    return tuple(plan_buffer(rt, channel, name, lambda m=m: (upload(m), m.nbytes))
                 for name, m in (("rd", rd), ("ld", ld)))


def device_basis_blurs(kernels, e_dev, c, plan, shift, dtype, wait_for):
    """(padded float32 channel (N0, N1), basis blurs (G, H, N1) float32, event): channel c of
    e_dev times 2^-shift padded by the plan's radius by ``kernels``' border rule, and its
    convolution with each basis kernel at the image's rows (``fft.basis_blurs`` on the
    device), its transforms in ``dtype``. ``plan``: a texture-varying or stretched plan (its
    radius, basis ``kernels`` and ``blurred_quadrants``)."""
    rt = kernels.rt
    h, w, nch = e_dev.shape
    k = plan.radius
    n0, n1 = shape = device_fft_shape((h, w), k)
    double = dtype == np.float64
    chan = cla.to_device(rt.queue, np.int32([c]))
    shifts = cla.to_device(rt.queue, np.int32([shift]))
    mf = cl.mem_flags

    def padded(real):
        buf = cl.Buffer(rt.context, mf.READ_WRITE, n0 * n1 * np.dtype(real).itemsize)
        ev = kernels.kernel("blur_fft", "pad_planes", double=real == np.float64)(
            rt.queue, (n1, n0, 1), None, e_dev.data, buf, chan.data, shifts.data, np.int32(h),
            np.int32(w), np.int32(nch), np.int32(k), np.int32(n0), np.int32(n1),
            wait_for=wait_for)
        return buf, ev
    padded32, event = padded(np.float32)
    nbasis = len(plan.kernels)
    planes = cl.Buffer(rt.context, mf.READ_WRITE, max(nbasis * h * n1 * 4, 4))
    if not nbasis:                     # the near field holds the whole kernel
        return padded32, planes, event
    real = np.float64 if double else np.float32
    size = np.dtype(real).itemsize
    source, event = (padded32, event) if not double else padded(np.float64)
    fft = device_transforms(rt, shape, 1, double)
    spec = cl.Buffer(rt.context, mf.READ_WRITE, n0 * (n1 // 2 + 1) * 2 * size)
    prod = cl.Buffer(rt.context, mf.READ_WRITE, n0 * (n1 // 2 + 1) * 2 * size)
    rows = cl.Buffer(rt.context, mf.READ_WRITE, h * n1 * size) if double else None
    event = fft.forward(source, spec, wait_for=[event])
    ks = plan_buffer(rt, plan, ("spectra", shape, np.dtype(real).str),
                     lambda: upload_buffer(rt, cached_spectra(plan, shape, real)))
    times = kernels.kernel("blur_fft", "times_spectrum_to", double=double)
    narrow = kernels.kernel("blur_fft", "narrow", double=double) if double else None
    for j in range(nbasis):
        check_stop()
        event = times(rt.queue, (n1 // 2 + 1, n0), None, spec, ks, prod, np.int32(n0),
                      np.int32(n1 // 2 + 1), np.int32(j), wait_for=[event])
        if double:                     # float64 rows, then narrowed into basis plane j
            event = fft.inverse(prod, rows, rows=(k, k + h), wait_for=[event])
            event = enqueue_items(narrow, rt.queue, h * n1, rows, planes,
                                  np.uint64(j * h * n1), np.uint64(h * n1), wait_for=[event])
        else:                          # straight into basis plane j
            event = fft.inverse(prod, planes, rows=(k, k + h), wait_for=[event],
                                dst_offset=j * h * n1)
    return padded32, planes, event


def upload_buffer(rt, values):
    """A read-only device buffer of ``values`` (float arrays as float32 where they are), and
    its bytes."""
    a = np.ascontiguousarray(values)
    return (cl.Buffer(rt.context, cl.mem_flags.READ_ONLY | cl.mem_flags.COPY_HOST_PTR,
                      hostbuf=a), a.nbytes)


def _gather(kernels, out_dev, c, plan, rd_dev, ld_dev, planes, padded32, settle, wait_for):
    """kernels/blur_textured.cl's gather of channel c into out_dev (the device's buffers)."""
    rt = kernels.rt
    h, w, nch = out_dev.shape
    k = plan.radius
    n1 = device_fft_shape((h, w), k)[1]
    width, chunk, knl, axis_args = textured_kernel(rt, plan, w, "gather_exitance")
    records = plan_buffer(rt, plan, ("records", chunk), lambda: upload_buffer(
        rt, node_records(plan.fine, chunk)))
    near = plan_buffer(rt, plan, "near", lambda: upload_buffer(
        rt, plan.near_basis if plan.near_basis.size else np.zeros(1, np.float32)))
    scale, nonneg = settle
    return knl(rt.queue, (-(-w // width), h), None, rd_dev.data, ld_dev.data, records, planes,
               padded32, near, out_dev.data, np.int32(w), np.int32(h), np.int32(n1),
               np.int32(h * n1), np.int32(n1), np.int32(k), np.int32(nch), np.int32(c),
               np.float32(scale), np.int32(bool(nonneg)), *axis_args, wait_for=wait_for)


def blur_band_textured_device(bplan, e_dev, rows, method, on_nonfinite, peaks=None):
    """(exitance device array, BlurInfo) of one band (or image) of a texture-varying plan
    ``bplan`` on its device (``rows``: the rows of the parameter maps it covers), None where
    the device cannot (float64 transforms without fp64). Non-finite texels and ``peaks``: as
    ``whole_device.blur_band_device``."""
    kernels = bplan.bound_kernels()
    rt = kernels.rt
    h, w, nch = e_dev.shape
    stats = image_stats(kernels, e_dev)
    if any(st.nonfinite for st in stats):
        on_nonfinite()
        stats = [st.clamped() for st in stats]
    shifts = [channel_shift(st) for st in stats]
    out_dev = cla.empty_like(e_dev)
    event = cl.enqueue_fill_buffer(rt.queue, out_dev.data, np.float32(0), 0, out_dev.nbytes)
    src = e_dev
    if method == "gaussians" and (any(shifts) or any(st.unclean for st in stats)):
        src = cla.empty_like(e_dev)
        shift = cla.to_device(rt.queue, np.int32(shifts))
        event = enqueue_items(kernels.kernel("blur_fft", "clean_scaled"), rt.queue, e_dev.size,
                              e_dev.data, src.data, shift.data, np.int32(nch),
                              np.uint64(e_dev.size), wait_for=[event])
    for c, channel in enumerate(bplan.textured):
        check_stop()
        plan = channel.plan
        unit = 2.0 ** -shifts[c]
        e_range = (stats[c].low * unit, stats[c].high * unit)
        rd_dev, ld_dev = _maps(rt, channel, rows)
        if method == "gaussians":
            event.wait()
            device = DeviceBlur(e_dev, kernels, src=src.data, dst=out_dev.data)
            device.run_textured(c, plan, device_weight_planes(plan, rd_dev, ld_dev, rt))
            scale, nonneg = settle_floor(e_range, ROUNDOFF_ULPS)
            event = enqueue_items(kernels.kernel("blur_fft", "settle_channel_map"), rt.queue,
                                  h * w, out_dev.data, np.int32(c), np.int32(nch), rd_dev.data,
                                  np.float32(scale), np.int32(nonneg), np.int32(shifts[c]),
                                  np.uint64(h * w))
            continue
        k = plan.radius
        dtype = image_fft_dtype(0.0, plan.truncation_tol, e_range, stats[c].total * unit,
                                h * w, device_fft_shape((h, w), k))
        if dtype == np.float64 and not rt.has_fp64:
            return None
        padded32, planes, event = device_basis_blurs(kernels, e_dev, c, plan, shifts[c],
                                                     dtype, [event])
        ulps = FFT32_ROUNDOFF_ULPS if dtype == np.float32 else ROUNDOFF_ULPS
        event = _gather(kernels, out_dev, c, plan, rd_dev, ld_dev, planes, padded32,
                        settle_floor(e_range, ulps), [event])
        if shifts[c]:                  # back from the channel's unit: exact, a power of two
            event = enqueue_items(kernels.kernel("blur_fft", "settle_channel"), rt.queue,
                                  h * w, out_dev.data, np.int32(c), np.int32(nch),
                                  np.float32(-1.0), np.int32(0), np.int32(shifts[c]),
                                  np.uint64(h * w), wait_for=[event])
    out_dev.add_event(event)
    chans = list(bplan.textured_info.channels)
    for c, st in enumerate(stats):
        if st.low < 0 < st.high:
            chans[c] = signed_irradiance_bound(chans[c], bplan.textured[c].plan.truncation_tol,
                                               bplan.tol)
    info = BlurInfo(tuple(chans))
    if any(s and st.peak < 2.0 ** -PEAK_RANGE for s, st in zip(shifts, stats)):
        info = with_output_floor(info, floor_peaks(stats, peaks), bplan.channel_rd_floor(),
                                 bplan.tol)
    return out_dev, info
