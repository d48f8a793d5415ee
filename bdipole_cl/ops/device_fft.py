"""Batched 2D real FFTs on the OpenCL device (kernels/fft.cl; the maths and accuracy:
docs/device_fft.md).

``DeviceFFT(rt, (N0, N1), batch, double)`` is a plan: its passes, kernels, twiddle tables and
scratch buffers made once, then ``forward`` and ``inverse`` enqueued on pyopencl buffers as
often as wanted. Layouts are numpy.fft's: ``forward`` takes ``batch`` C-contiguous real planes
(N0, N1) and writes their half spectra (N0, N1 / 2 + 1) as interleaved (re, im) pairs, with
``numpy.fft.rfft2``'s sign; ``inverse`` is ``numpy.fft.irfft2`` (normalised by 1 / (N0 N1)),
optionally only rows [r0, r1) of each plane (its last pass pruned).

The rows go first in the forward transform (a real row of N1 points as N1 / 2 complex ones,
twisted into N1 / 2 + 1: no work on zeros), then the columns; the inverse runs the other way.
A row that fits a work-group's local memory takes one pass (transform and twist fused); the
columns, and rows too long for one, take radix passes of ``fft_passes.axis_passes``.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pyopencl as cl

from ..device import Runtime, build_options, get_program, real_dtype
from ..device.launch import enqueue_items
from .fft_passes import (AxisPass, axis_passes, check_fft_shape, device_fft_len, pack_stages,
                         stage_radices, unit_roots, work_group_size)

__all__ = ["DeviceFFT", "device_fft_len"]

#: the most local memory a work-group's tile takes (two buffers): a GPU's local memory is
#: 48-64 KiB, all of it usable here; a CPU runtime's is ordinary memory, where a tile larger
#: than its core's L2 share would only be slower
LOCAL_BYTES_CAP = 64 << 10
#: local memory a work-group's tile leaves free beyond the kernel's own: NVIDIA's runtime keeps
#: 1 KiB of each block's shared memory for itself (compute capability 8.0 on), and a tile of
#: all 48 KiB fails to launch there (OUT_OF_RESOURCES, seen on an H200)
LOCAL_RESERVE_BYTES = 1 << 10
#: points the fused row kernel's work-group takes at least, as several short rows
ROWS_TILE_POINTS = 256

I32, I64, U64 = np.int32, np.int64, np.uint64


@dataclass(frozen=True)
class Layout:
    """Where batch item b (of ``rows`` a plane) starts: off + (b // rows) plane + (b % rows)
    row, in complex points."""

    off: int
    plane: int
    row: int

    def args(self):
        return I64(self.off), I64(self.plane), I64(self.row)


def buffer_and_offset(x, offset: int, itemsize: int, dtype=None, what: str = "array"):
    """(pyopencl Buffer, offset in elements of ``itemsize`` bytes) of a Buffer or a
    pyopencl.array.Array (its own offset added; a C-contiguous one of ``dtype`` where given:
    a Buffer's bytes are the caller's to lay out, an Array says what it holds)."""
    if hasattr(x, "base_data"):                          # pyopencl.array.Array
        if dtype is not None and x.dtype != dtype:
            raise ValueError(f"{what}: a {x.dtype} array; this plan takes {np.dtype(dtype)}")
        if not x.flags.c_contiguous:
            raise ValueError(f"{what}: a strided array view; give a C-contiguous one")
        if x.offset % itemsize:
            raise ValueError(f"array offset {x.offset} bytes is not a whole number of "
                             f"{itemsize}-byte elements")
        return x.base_data, offset + x.offset // itemsize
    return x, offset


@dataclass(eq=False)
class DeviceFFT:
    """A plan of batched 2D real FFTs of ``batch`` planes of ``shape`` (N0, N1) on ``rt``'s
    device, float32 or float64 (``double``: needs cl_khr_fp64). Both axes even with no prime
    factor above 7 (``device_fft_len``), else a ValueError."""

    rt: Runtime
    shape: tuple
    batch: int = 1
    double: bool = False
    row_passes: tuple = field(init=False)       # () where rows fit a work-group (fused)
    col_passes: tuple = field(init=False)
    rows_tile: int = field(init=False)          # rows a fused row work-group takes

    def __post_init__(self):
        self.shape = check_fft_shape(self.shape)
        if int(self.batch) != self.batch or self.batch < 1:
            raise ValueError(f"device FFT batch {self.batch!r}: a positive number of planes")
        self.batch = int(self.batch)
        n0, n1 = self.shape
        self.m = n1 // 2                         # complex points of a row
        self.dtype = real_dtype(self.double)
        self.point_bytes = 2 * self.dtype.itemsize
        dev = self.rt.device
        prg = get_program(self.rt, "fft", build_options(double=self.double))
        self.kernels = {name: cl.Kernel(prg, name) for name in (
            "fft_pass", "fft_rows_r2c", "fft_rows_c2r", "fft_r2c_twist", "fft_c2r_twist")}
        self.wg_max = {name: k.get_work_group_info(cl.kernel_work_group_info.WORK_GROUP_SIZE,
                                                   dev) for name, k in self.kernels.items()}
        tile_points = self.local_bytes() // (2 * self.point_bytes)
        if self.m <= tile_points:
            self.row_passes = ()
            self.rows_tile = max(1, min(tile_points // self.m, ROWS_TILE_POINTS // self.m,
                                        self.wg_max["fft_rows_r2c"], self.wg_max["fft_rows_c2r"]))
        else:
            self.row_passes = axis_passes(self.m, 1, tile_points, self.point_bytes)
            self.rows_tile = 0
        self.col_passes = axis_passes(n0, self.m + 1, tile_points, self.point_bytes)
        flags = cl.mem_flags.READ_ONLY | cl.mem_flags.COPY_HOST_PTR
        self.row_roots = cl.Buffer(self.rt.context, flags, hostbuf=unit_roots(n1, self.dtype))
        self.col_roots = cl.Buffer(self.rt.context, flags, hostbuf=unit_roots(n0, self.dtype))
        self.scratch = [self._spectrum_buffer()]

    # {{{ sizes

    def local_bytes(self) -> int:
        """The local memory a work-group's two tile buffers may take: the device's (at most
        LOCAL_BYTES_CAP), less the kernels' own and LOCAL_RESERVE_BYTES."""
        dev = self.rt.device
        own = max(k.get_work_group_info(cl.kernel_work_group_info.LOCAL_MEM_SIZE, dev)
                  for k in self.kernels.values())
        return min(dev.local_mem_size, LOCAL_BYTES_CAP) - own - LOCAL_RESERVE_BYTES

    @property
    def spectrum_shape(self) -> tuple:
        """(batch, N0, N1 / 2 + 1): the complex half spectra ``forward`` writes."""
        return (self.batch, self.shape[0], self.m + 1)

    @property
    def complex_dtype(self):
        return np.dtype(np.complex128 if self.double else np.complex64)

    def _spectrum_buffer(self) -> cl.Buffer:
        return cl.Buffer(self.rt.context, cl.mem_flags.READ_WRITE,
                         int(np.prod(self.spectrum_shape)) * self.point_bytes)

    def _scratch(self, i: int) -> cl.Buffer:
        while len(self.scratch) <= i:            # the inverse's second: made on first use
            self.scratch.append(self._spectrum_buffer())
        return self.scratch[i]

    def _complex_view(self, x, offset: int, points: int, what: str, dtype=None):
        """(Buffer, offset in complex points) of ``points`` complex points at ``offset``
        (complex points) of x, checked to fit (an Array: of ``dtype``, the complex one where
        None)."""
        buf, off = buffer_and_offset(x, offset, self.point_bytes,
                                     self.complex_dtype if dtype is None else dtype, what)
        if (off + points) * self.point_bytes > buf.size:
            raise ValueError(f"{what}: {points} points at offset {off} need "
                             f"{(off + points) * self.point_bytes} bytes, the buffer has "
                             f"{buf.size}")
        return buf, off

    def _real_view(self, x, offset: int, reals: int, what: str):
        """As ``_complex_view`` for a real buffer: its offset (in reals) must be even."""
        buf, off = buffer_and_offset(x, offset, self.dtype.itemsize, self.dtype, what)
        if off % 2:
            raise ValueError(f"{what}: offset {off} is odd; real planes start on an even "
                             f"element (they are read and written as pairs)")
        return self._complex_view(buf, off // 2, reals // 2, what)

    # }}}

    # {{{ launches

    def _fft_pass(self, p: AxisPass, lanes, batch, rows, src, lin, dst, lout, keep=None,
                  scale=1.0, inverse=False, wait_for=None):
        k = self.kernels["fft_pass"]
        nt, roots = (self.shape[0], self.col_roots) if lanes > 1 else (self.shape[1],
                                                                       self.row_roots)
        wg = work_group_size(p.tile, p.stages, p.lane_tile * p.j_tile, self.wg_max["fft_pass"])
        lo, hi = keep or (0, p.n)
        ping, pong = (cl.LocalMemory(p.tile * self.point_bytes) for _ in range(2))
        return k(self.rt.queue, (p.groups(batch, lanes) * wg,), (wg,), src, dst, roots, I32(nt),
                 ping, pong, I32(p.n), I32(p.radix),
                 U64(pack_stages(p.stages)), I32(p.span), I32(lanes), I32(p.lane_tile),
                 I32(p.j_tile), I32(rows), *lin.args(), *lout.args(), I32(lo), I32(hi),
                 self.dtype.type(scale), I32(inverse), wait_for=wait_for)

    def _fused_rows(self, name, total_rows, rows, src, lin, dst, lout, extra=(),
                    wait_for=None):
        k = self.kernels[name]
        stages = stage_radices(self.m)
        tile = self.m * self.rows_tile
        wg = work_group_size(tile, stages, self.rows_tile, self.wg_max[name])
        groups = -(-total_rows // self.rows_tile)
        return k(self.rt.queue, (groups * wg,), (wg,), src, dst, self.row_roots,
                 I32(self.shape[1]), cl.LocalMemory(tile * self.point_bytes),
                 cl.LocalMemory(tile * self.point_bytes), I32(self.m),
                 U64(pack_stages(stages)), I32(self.rows_tile), I32(total_rows), I32(rows),
                 *lin.args(), *lout.args(), *extra, wait_for=wait_for)

    def _twist(self, name, buf, total_rows, rows, lay, extra=(), wait_for=None):
        return enqueue_items(self.kernels[name], self.rt.queue,
                             total_rows * (self.m // 2 + 1), buf, self.row_roots, I32(self.m),
                             I32(total_rows), I32(rows), *lay.args(), *extra,
                             wait_for=wait_for)

    def _chain(self, count: int, final, ring) -> list:
        """The output buffers of ``count`` chained passes ending in ``final``: back from the
        end, the others take the entries of ``ring`` in turn (a scratch buffer's index, or
        None for ``final``), so that no pass writes the buffer it reads."""
        outs = [final]
        for k in range(count - 1):
            b = ring[k % len(ring)]
            outs.append(final if b is None else self._scratch(b))
        return outs[::-1]

    # }}}

    def forward(self, src, dst, wait_for=None, src_offset: int = 0, dst_offset: int = 0):
        """dst = rfft2 of the ``batch`` real planes (N0, N1) in ``src`` (a Buffer or
        pyopencl.array.Array; offsets in its elements, even for src) as (batch, N0, N1/2 + 1)
        complex points; returns the last launch's event. ``src`` is not written."""
        (n0, n1), m, g = self.shape, self.m, self.batch
        h = m + 1
        src, s_off = self._real_view(src, src_offset, g * n0 * n1, "forward FFT source")
        dst, d_off = self._complex_view(dst, dst_offset, g * n0 * h, "forward FFT destination")
        spectrum = Layout(0, n0 * h, h)
        steps = max(1, len(self.row_passes)) + len(self.col_passes)
        outs = self._chain(steps, dst, (0, None))        # scratch 0 and dst in turn
        lays = [Layout(d_off, n0 * h, h) if b is dst else spectrum for b in outs]
        rows_in = Layout(s_off, n0 * m, m)
        if not self.row_passes:
            event = self._fused_rows("fft_rows_r2c", g * n0, n0, src, rows_in, outs[0],
                                     lays[0], wait_for=wait_for)
            done = 1
        else:
            buf, lay = src, rows_in
            for i, p in enumerate(self.row_passes):
                event = self._fft_pass(p, 1, g * n0, n0, buf, lay, outs[i], lays[i],
                                       wait_for=wait_for if i == 0 else None)
                buf, lay = outs[i], lays[i]
            event = self._twist("fft_r2c_twist", buf, g * n0, n0, lay)
            done = len(self.row_passes)
        for i, p in enumerate(self.col_passes):
            a = done + i
            event = self._fft_pass(p, h, g, 1, outs[a - 1], lays[a - 1], outs[a], lays[a])
        return event

    def inverse(self, src, dst, rows=None, wait_for=None, src_offset: int = 0,
                dst_offset: int = 0):
        """dst = irfft2 of the ``batch`` half spectra (N0, N1/2 + 1) in ``src`` (complex
        points), rows [r0, r1) of each plane (``rows``; all by default) as (batch, r1 - r0,
        N1) reals at ``dst_offset`` (even). The imaginary parts of columns 0 and N1/2 are
        ignored, as numpy's irfft2 does. ``src`` is not written; returns the last event."""
        (n0, n1), m, g = self.shape, self.m, self.batch
        h = m + 1
        r0, r1 = (0, n0) if rows is None else (int(rows[0]), int(rows[1]))
        if not 0 <= r0 < r1 <= n0:
            raise ValueError(f"inverse FFT rows [{r0}, {r1}): a non-empty range within "
                             f"[0, {n0})")
        nr = r1 - r0
        src, s_off = self._complex_view(src, src_offset, g * n0 * h, "inverse FFT source")
        dst, d_off = self._real_view(dst, dst_offset, g * nr * n1, "inverse FFT destination")
        spectrum = Layout(0, n0 * h, h)
        out_rows = Layout(d_off, nr * m, m)
        steps = len(self.col_passes) + max(1, len(self.row_passes))
        outs = self._chain(steps, dst, (0, 1))           # src is never written
        lays = [spectrum] * (steps - 1) + [out_rows]
        buf, lay = src, Layout(s_off, n0 * h, h)
        scale = 1.0 / (n0 * n1)                  # folded into the first pass's loads
        last_col = len(self.col_passes) - 1
        for i, p in enumerate(self.col_passes):
            event = self._fft_pass(p, h, g, 1, buf, lay, outs[i], lays[i],
                                   keep=(r0, r1) if i == last_col else None,
                                   scale=scale if i == 0 else 1.0, inverse=True,
                                   wait_for=wait_for if i == 0 else None)
            buf, lay = outs[i], lays[i]
        first_row = Layout(lay.off + r0 * h, n0 * h, h)   # the kept rows of each plane
        if not self.row_passes:
            return self._fused_rows("fft_rows_c2r", g * nr, nr, buf, first_row, dst, out_rows,
                                    extra=(self.dtype.type(1.0),))
        self._twist("fft_c2r_twist", buf, g * nr, nr, first_row, extra=(self.dtype.type(1.0),))
        lay = first_row
        for i, p in enumerate(self.row_passes):
            a = len(self.col_passes) + i
            lout = lays[a] if a == steps - 1 else Layout(0, nr * h, h)
            event = self._fft_pass(p, 1, g * nr, nr, buf, lay, outs[a], lout, inverse=True)
            buf, lay = outs[a], lout
        return event
