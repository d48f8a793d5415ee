"""The stretched blur of one window's band (docs/stretch.md "The gather"): the basis blurs of
its irradiance by the host FFT (``fft.basis_blurs``, as the texture-varying blur), then the
per-texel gather on the device (kernels/blur_stretched.cl): the table's weights at the texel's
(Rd, l_u, l_v), the basis blurs there and the near field's classes summed from the irradiance
itself."""
from __future__ import annotations

import weakref

import numpy as np
import pyopencl as cl

from ...caches import ByteCache
from ...device import build_options, get_program
from ...methods.choice import GATHER_WIDTHS_ALLOWED
from ..widths import built_at_width, device_vector_cap
from .dispatch import gather_width, host_buffer, node_records, read_back, record_chunk
from .fft import (FFT32_ROUNDOFF_ULPS, ROUNDOFF_ULPS, basis_blurs, fft_shape, settle_floor)
from .stretched_plan import StretchedPlan
from .textured import host_array
from .textured_plan import RD_MAX, RD_MIN


def stretched_kernel(rt, plan: StretchedPlan, n):
    """(width, chunk, kernel) of kernels/blur_stretched.cl for a plan over rows of n texels:
    the texture-varying gather's width on this device (the two gathers share their loads'
    pattern), narrower where that build was refused, records read in chunks within the
    device's vector cap."""
    if plan.near >= 0 and not plan.near_direct:
        raise ValueError("the stretched gather reads a near field of its classes (a plan of "
                         "stretched_plan)")
    nweights = plan.fine.shape[3]
    chunk = record_chunk(nweights, device_vector_cap(rt))

    def build(width):
        opts = build_options({"BD_NBASIS": len(plan.kernels), "BD_NEAR": plan.near,
                              "BD_WIDTH": width, "BD_CHUNK": chunk})
        return cl.Kernel(get_program(rt, "blur_stretched", opts), "gather_stretched")
    width, knl = built_at_width(rt, "blur_stretched", gather_width(rt, n),
                                GATHER_WIDTHS_ALLOWED, build)
    return width, chunk, knl


#: the gathers' tables as records, kept across calls by the table's identity (a plan is
#: memoized: its table is the same array each time), each entry with a weak reference to its
#: table (its id is not taken for another table while the entry matches); counted by the
#: records' bytes, the table being its plan's
TABLE_RECORDS = ByteCache("stretched gather tables", 256 << 20)


def table_records(fine, chunk):
    """The fine table (f0, f1, f2, weights) as records of a whole number of ``chunk`` floats
    (``dispatch.node_records`` of the table flattened over its first two axes), made once per
    table and chunk."""
    key = (id(fine), chunk)
    hit = TABLE_RECORDS.get(key)
    if hit is not None and hit[0]() is fine:
        return hit[1]
    f0, f1, f2, nw = fine.shape
    records = node_records(fine.reshape(f0 * f1, f2, nw), chunk)
    TABLE_RECORDS.put(key, (weakref.ref(fine), records), records.nbytes)
    return records


def enqueue_gather(rt, plan: StretchedPlan, kernel, bufs, dst, w, rows, strides, row0, mrow,
                   settle, wait_for=None):
    """Launch the stretched gather (``kernel``: ``stretched_kernel``'s (width, chunk, kernel))
    of ``rows`` rows of w texels into ``dst`` from the device buffers ``bufs`` = (Rd, l_u, l_v,
    table records, basis blurs, padded irradiance); ``strides`` = (a basis
    blur's row, one basis blur, the padded irradiance's row) in floats; the band's first row
    at the planes' row ``row0`` and at the maps' row ``mrow``; settled by ``settle`` = (scale,
    non-negative). Returns its event."""
    width, _, knl = kernel
    pitch, plane, epitch = strides
    (s0, o0), (s1, o1), (s2, o2) = plan.axis_maps()
    n0, n1, n2 = plan.fine.shape[:3]
    scale, nonneg = settle
    return knl(rt.queue, (-(-w // width), rows), None, *bufs, dst, np.int32(w),
               np.int32(pitch), np.int32(plane), np.int32(epitch), np.int32(plan.radius),
               np.int32(row0), np.int32(mrow), np.float32(scale), np.int32(bool(nonneg)),
               np.int32(n0), np.int32(n1), np.int32(n2), np.float32(RD_MIN),
               np.float32(RD_MAX), s0, o0, s1, o1, s2, o2, wait_for=wait_for)


def gather(res, plan: StretchedPlan, maps, mrow, planes, padded, row0, rt, settle):
    """res (h x w) = the stretched gather of a band's rows [row0, row0 + h) of its basis blurs
    ``planes`` and padded irradiance ``padded`` (``fft.basis_blurs``), on ``rt``'s device,
    settled by ``settle`` = (scale, non-negative); ``maps`` = the window's (Rd, l_u, l_v)
    (aligned float32, w texels a row), the band's first row at their row ``mrow``. Every array
    is read in place (zero-copy on a CPU device: the planes are G images)."""
    h, w = res.shape
    mf = cl.mem_flags
    kernel = stretched_kernel(rt, plan, w)
    bufs = [host_buffer(rt, a if a.size else np.zeros(1, np.float32), mf.READ_ONLY)
            for a in (*maps, table_records(plan.fine, kernel[1]), planes, padded)]
    dst = host_buffer(rt, res, mf.READ_WRITE)
    strides = (planes.shape[2], planes.shape[1] * planes.shape[2], padded.shape[1])
    enqueue_gather(rt, plan, kernel, bufs, dst, w, h, strides, row0, mrow, settle)
    read_back(rt, dst, res)


def blur_band(src, plan: StretchedPlan, maps, mrow, border, row0, rows, rt):
    """The stretched blur (rows x w float32) of rows [row0, row0 + rows) of a window's band
    whose irradiance (with its halo) is ``src`` (H x w float32), padded beyond by ``border``;
    ``maps``: the window's (Rd, l_u, l_v), the output's first row at their row ``mrow``."""
    h, w = src.shape
    shape = fft_shape((h, w), plan.radius)
    planes = host_array((max(len(plan.kernels), 1), h, shape[1]))
    padded, e_range, dtype, unit = basis_blurs(src[..., None], 0, plan, border, planes)
    ulps = FFT32_ROUNDOFF_ULPS if dtype == np.float32 else ROUNDOFF_ULPS
    res = host_array((rows, w))
    gather(res, plan, maps, mrow, planes, padded, row0, rt, settle_floor(e_range, ulps))
    if unit != 1.0:                    # back from the HDR unit: exact, a power of two
        np.ldexp(res, -int(np.log2(unit)), out=res)
    return res
