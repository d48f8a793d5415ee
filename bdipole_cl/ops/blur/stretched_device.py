"""The stretched blur of one window's band on the device end to end (docs/stretch.md "Where it
runs"; the twin of ``stretched_gather.blur_band`` on the host), where the FFT engine is the
device (``widths.fft_engine``): the band's irradiance (``Window.band_irradiance``: its rows and
halo) uploaded once, its range and sum reduced there (``fft_device.image_stats``), padded by
the window's border rule and transformed there, each basis kernel's spectrum multiplied in and
the band's rows transformed back (``textured_device.device_basis_blurs``, the texture-varying
blur's own), then the gather (kernels/blur_stretched.cl) reading the planes, the padded
irradiance, the window's maps and the plan's table from device buffers; the exitance read back
once. The plan's table and spectra stay on the device across bands and calls, the window's maps
across its bands (``textured_device.PLAN_BUFFERS``; each call makes its maps anew).

The host's rules, on the device's statistics: the transforms' precision (``fft.image_fft_dtype``:
float64 where the band's peak is too far above its mean for float32, None where the device has
no fp64: the host's FFT then), the settle floor (``fft.settle_floor``), and a peak above
``fft.HDR_UNIT_ABOVE`` blurred at [0.5, 1) by a power of two (``fft.hdr_unit``'s unit); a peak
far below 1 is scaled so too (``textured_device.channel_shift``: exact, and no subnormal
products on a device that flushes them)."""
from __future__ import annotations

import numpy as np
import pyopencl as cl

from ...caches import ByteCache
from ...device.transfer import device_image
from .dispatch import BlurKernels
from .fft import FFT32_ROUNDOFF_ULPS, ROUNDOFF_ULPS, image_fft_dtype, settle_floor
from .fft_device import device_fft_shape, image_stats
from .stretched_gather import enqueue_gather, stretched_kernel, table_records
from .stretched_plan import StretchedPlan
from .textured import host_array
from .textured_device import channel_shift, device_basis_blurs, plan_buffer, upload_buffer

#: the blur's programs per device and border rule (a window's: clamp, zero or wrap), kept
BORDER_KERNELS = ByteCache("stretched blur kernels per border", 1 << 20)


def border_kernels(rt, border) -> BlurKernels:
    """The BlurKernels of ``rt`` for ``border`` (the padded planes' rule), made once."""
    key = (id(rt.context), border)
    hit = BORDER_KERNELS.get(key)
    if hit is None or hit[0] is not rt.context:
        hit = BORDER_KERNELS.put(key, (rt.context, BlurKernels(rt, border)), 1024)
    return hit[1]


def window_buffers(rt, plan: StretchedPlan, maps, chunk):
    """The device buffers the gather reads: a window's (Rd, l_u, l_v) ``maps`` (a tuple, the
    buffers held with it: once per call's maps) and its plan's table records of ``chunk``
    floats (once per plan)."""
    maps = tuple(plan_buffer(rt, maps, ("map", i), lambda m=m: upload_buffer(
        rt, np.ascontiguousarray(m, np.float32))) for i, m in enumerate(maps))
    table = plan_buffer(rt, plan, ("stretched table", chunk), lambda: upload_buffer(
        rt, table_records(plan.fine, chunk)))
    return maps, table


def blur_band_device(src, plan: StretchedPlan, maps, mrow, border, row0, rows, rt):
    """The stretched blur (rows x w float32) of rows [row0, row0 + rows) of a window's band
    whose irradiance (with its halo) is ``src`` (H x w float32, finite), padded beyond by
    ``border``, on ``rt``'s device; ``maps``: the window's (Rd, l_u, l_v) (a tuple, kept on
    the device with it), the output's first row at their row ``mrow``. None where the device
    cannot (float64 transforms without fp64)."""
    h, w = src.shape
    kernels = border_kernels(rt, border)
    host = np.ascontiguousarray(src, np.float32).reshape(h, w, 1)
    e_dev = device_image(rt, host)
    stats = image_stats(kernels, e_dev)[0].clamped()
    res = host_array((rows, w))
    if stats.peak == 0:                # no light: the host's blur of zeros is zeros too
        res[...] = 0
        return res
    shift = channel_shift(stats)
    unit = 2.0 ** -shift
    e_range = (stats.low * unit, stats.high * unit)
    k = plan.radius
    shape = device_fft_shape((h, w), k)
    dtype = image_fft_dtype(0.0, plan.truncation_tol, e_range, stats.total * unit, h * w,
                            shape)
    if dtype == np.float64 and not rt.has_fp64:
        return None
    padded32, planes, event = device_basis_blurs(kernels, e_dev, 0, plan, shift, dtype, None)
    kernel = stretched_kernel(rt, plan, w)
    (rd, lu, lv), table = window_buffers(rt, plan, maps, kernel[1])
    dst = cl.Buffer(rt.context, cl.mem_flags.WRITE_ONLY, res.nbytes)
    ulps = FFT32_ROUNDOFF_ULPS if dtype == np.float32 else ROUNDOFF_ULPS
    n1 = shape[1]
    event = enqueue_gather(rt, plan, kernel, (rd, lu, lv, table, planes, padded32), dst,
                           w, rows, (n1, h * n1, n1), row0, mrow, settle_floor(e_range, ulps),
                           [event])
    cl.enqueue_copy(rt.queue, res, dst, wait_for=[event])      # blocking: src's too
    if shift:                          # back from the band's unit: exact, a power of two
        np.ldexp(res, shift, out=res)
    return res
