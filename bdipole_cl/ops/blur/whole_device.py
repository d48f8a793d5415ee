"""A constant-parameter blur done on the device end to end (``BlurPlan`` with every channel
there: the direct and separable kernels, and the FFT on the device, ``fft_device``): the
irradiance uploaded once (pinned staging on a discrete device) or given as a device array, its
statistics reduced there, every channel blurred and settled into one exitance buffer, and that
downloaded once (or returned as a device array). The host's twin is ``planning.blur_whole``.
"""
from __future__ import annotations

import numpy as np
import pyopencl as cl
import pyopencl.array as cla

from ...device.launch import enqueue_items
from ...device.transfer import (aligned_empty, device_image, host_copy, is_device_array,
                                ready_array)
from ...signals import check_stop
from ..bands import band_rows, bands, gather_rows
from .dispatch import DeviceBlur
from .fft import ROUNDOFF_ULPS, channel_peaks, settle_floor
from .fft_device import (device_fft_dtype, device_fft_shape, fft_blur_device, floor_peaks,
                         image_stats, peak_shift)
from .fit import fit_gaussians
from .params import checked_irradiance, float32_irradiance, irradiance_array
from .textured import textured_method
from .textured_device import blur_band_textured_device
from .planning import (PEAK_RANGE, BlurInfo, planned_info, signed_irradiance_bound,
                       with_output_floor, worse)


def device_shifts(stats, peak_range) -> list:
    """Per channel the power of two its peak is scaled to [0.5, 1) by (``planning.
    peak_exponents``' rule on the device's statistics)."""
    return [peak_shift(st, peak_range) for st in stats]


def fft_precision(plans, channels, stats, shifts, shape):
    """The precision of the FFT channels' batch on the device (None: none)."""
    if not channels:
        return None
    k = max(plans[c].kernel.radius for c in channels)
    return device_fft_dtype([plans[c].kernel for c in channels],
                            [plans[c].asked_tol for c in channels],
                            [stats[c] for c in channels], [shifts[c] for c in channels],
                            shape[0] * shape[1], device_fft_shape(shape, k))


def blur_whole_device(e_dev, out_dev, stats, shifts, params, plans, exact, kernels, precision,
                      wait_for=None):
    """out_dev = the exitance of ``e_dev`` (both (H, W, C) float32 device arrays) under the
    channels' plans, ``stats`` the irradiance's ChannelStats (its non-finite texels clamped:
    read as 0), ``shifts`` their powers of two, ``precision`` the FFT batch's
    (``fft_precision``). Returns (the last event, BlurInfo)."""
    rt = kernels.rt
    h, w, nch = e_dev.shape
    event = cl.enqueue_fill_buffer(rt.queue, out_dev.data, np.float32(0), 0, out_dev.nbytes,
                                   wait_for=wait_for)
    fft_channels = [c for c, p in enumerate(plans) if p.method == "fft"]
    others = [c for c in range(nch) if c not in fft_channels]
    info = [planned_info(c, params[c], p, exact, precision if c in fft_channels else None)
            for c, p in enumerate(plans)]
    if others:
        src = e_dev
        if any(shifts) or any(st.unclean for st in stats):
            src = cla.empty_like(e_dev)
            shift = cla.to_device(rt.queue, np.int32(shifts))
            event = enqueue_items(kernels.kernel("blur_fft", "clean_scaled"), rt.queue,
                                  e_dev.size, e_dev.data, src.data, shift.data, np.int32(nch),
                                  np.uint64(e_dev.size), wait_for=[event])
        event.wait()
        device = DeviceBlur(e_dev, kernels, src=src.data, dst=out_dev.data)
        settle = kernels.kernel("blur_fft", "settle_channel")
        for c in others:
            check_stop()
            ck = plans[c].kernel
            if plans[c].method == "direct":
                device.run_direct(c, ck)
            else:
                device.run_gaussians(c, fit_gaussians(*params[c], ck.tol, exact))
            unit = 2.0 ** -shifts[c]
            scale, nonneg = settle_floor((stats[c].low * unit, stats[c].high * unit),
                                         ROUNDOFF_ULPS)
            event = enqueue_items(settle, rt.queue, h * w, out_dev.data, np.int32(c),
                                  np.int32(nch), np.float32(scale * ck.rd), np.int32(nonneg),
                                  np.int32(shifts[c]), np.uint64(h * w))
    if fft_channels:
        event = fft_blur_device(kernels, e_dev, out_dev, fft_channels,
                                [plans[c].kernel for c in fft_channels], stats, precision,
                                shifts, wait_for=[event])
    for c, p in enumerate(plans):
        if stats[c].low < 0 < stats[c].high:
            info[c] = signed_irradiance_bound(info[c], p.kernel.truncated, p.asked_tol)
    return event, BlurInfo(tuple(info))


def device_can_blur(rt, precision) -> bool:
    """Whether the device runs the FFT batch's precision (float64 needs fp64)."""
    return precision is None or precision == np.float32 or rt.has_fp64


def blur_band_device(plan, e_dev, on_nonfinite, rows=None, peaks=None):
    """(exitance device array, BlurInfo) of one band (or image) ``e_dev`` on the plan's device
    (``blur_whole_device``; texture-varying parameters: ``textured_device``, ``rows`` the
    parameter maps' rows the band covers, None: all), None where the device cannot (float64
    transforms without fp64). Where it has non-finite texels, ``on_nonfinite()`` is called
    first (the host's check: raise naming the first, or count them); they are read as 0.
    ``peaks``: per channel max|E| of the image the band is of, which float32's floor is
    relative to (None: the band's own)."""
    if plan.textured:
        rows = slice(0, plan.shape[0]) if rows is None else np.maximum(rows, 0)
        return blur_band_textured_device(plan, e_dev, rows, textured_method(plan.method),
                                         on_nonfinite, peaks)
    kernels = plan.bound_kernels()
    rt = kernels.rt
    stats = image_stats(kernels, e_dev)
    if any(st.nonfinite for st in stats):
        on_nonfinite()
        stats = [st.clamped() for st in stats]
    shifts = device_shifts(stats, PEAK_RANGE)
    fft_channels = [c for c, p in enumerate(plan.channels) if p.method == "fft"]
    precision = fft_precision(plan.channels, fft_channels, stats, shifts, e_dev.shape[:2])
    if not device_can_blur(rt, precision):
        return None
    out_dev = cla.empty_like(e_dev)
    event, info = blur_whole_device(e_dev, out_dev, stats, shifts, plan.params, plan.channels,
                                    plan.exact, kernels, precision)
    out_dev.add_event(event)
    if any(shifts):
        info = with_output_floor(info, floor_peaks(stats, peaks), plan.channel_rd_floor(),
                                 plan.tol)
    return out_dev, info


def _host_check(e, on_invalid, counts):
    """The host's check of the whole irradiance ``e`` once (an error naming the first
    non-finite texel, or their count added to ``counts`` with "clamp")."""
    done = []

    def check():
        if not done:
            checked_irradiance(e, on_invalid, counts)
            done.append(True)
    return check


def apply_on_device(plan, irradiance, max_memory=None, counts=None):
    """``BlurPlan.apply`` on the device end to end (``plan.runs_on_device``): (M, BlurInfo),
    M a device array for a device array's irradiance (blurred whole), else a host array (in
    bands of rows within ``max_memory``, each uploaded once and its rows brought back), or
    None where the device cannot (``blur_band_device``)."""
    counts = {} if counts is None else counts
    rt = plan.bound_kernels().rt
    if is_device_array(irradiance):
        e_dev = device_irradiance(irradiance, rt)
        done = blur_band_device(plan, e_dev, lambda: _host_check(
            e_dev.get(), plan.on_invalid, counts)())
        if done is None:
            return None
        out, info = done
        return (out if irradiance.ndim == 3 else out.reshape(out.shape[:2])), info
    e = float32_irradiance(irradiance_array(irradiance), plan.on_invalid, counts)
    check = _host_check(e, plan.on_invalid, counts)
    h = e.shape[0]
    out = aligned_empty(e.size, np.float32).reshape(e.shape)
    rows = band_rows(h, plan.row_bytes(), max_memory, halo=plan.halo)
    info, peaks = None, None
    pieces = ([(0, h, None)] if rows >= h else bands(h, rows, plan.halo, plan.border))
    if rows < h:                       # a band's floor relative to the image's peak
        peaks = finite_peaks(e)
    for y0, y1, idx in pieces:
        check_stop()
        band = e if idx is None else gather_rows(e, idx)
        done = blur_band_device(plan, device_image(rt, band), check, idx, peaks)
        if done is None:
            return None
        out_dev, band_info = done
        info = worse(info, band_info)
        got = out if idx is None else aligned_empty(band.size, np.float32).reshape(band.shape)
        host_copy(rt, out_dev, got)
        if idx is not None:
            out[y0:y1] = got[plan.halo:plan.halo + (y1 - y0)]
    return (out if np.ndim(irradiance) == 3 else out[..., 0]), info


def finite_peaks(e) -> np.ndarray:
    """max|E| per channel of an (H, W, C) map over its finite texels (a non-finite one is
    read as 0 where it is clamped, and raises where it is not)."""
    peaks = channel_peaks(e)
    for c in np.flatnonzero(~np.isfinite(peaks)):
        v = np.abs(e[..., c])
        peaks[c] = float(np.max(v, where=np.isfinite(v), initial=0.0))
    return peaks


def device_irradiance(a, rt):
    """A device array's irradiance as (H, W, C) float32 on ``rt``'s context, checked."""
    a = ready_array(a, rt, "irradiance")       # its context, layout and queue's work
    if a.dtype != np.float32 or a.ndim not in (2, 3):
        raise ValueError(f"irradiance: a device array must be a C-contiguous float32 HxW or "
                         f"HxWxC; got {a.dtype} of shape {a.shape}")
    if a.offset:
        a = a.copy(queue=rt.queue)                     # after its events (pyopencl's copy)
    elif a.events:
        cl.wait_for_events(a.events)   # its writes (and its own queue's, ``ready_array``) done
    return a if a.ndim == 3 else a.reshape(*a.shape, 1)


def apply_band_on_device(plan, e, rows=None):
    """``BlurPlan.apply_band`` of a checked host band (HxWxC float32; ``rows``: the parameter
    maps' rows it covers) on the device: (M, BlurInfo), M a host array, or None where the
    device cannot."""
    rt = plan.bound_kernels().rt
    done = blur_band_device(plan, device_image(rt, e), lambda: None, rows)    # all finite
    if done is None:
        return None
    out_dev, info = done
    return host_copy(rt, out_dev, aligned_empty(e.size, np.float32).reshape(e.shape)), info
