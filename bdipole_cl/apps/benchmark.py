"""Timing and error measurement shared by tools/bench_*.py and ``bdipole-cl report``.

Timings are medians over repeats of a kernel on device-resident buffers (queue finished before
and after each repeat), so they measure the device, not host transfers. Errors are against the
float64 reference inverse of the exact float32 inputs.
"""
from __future__ import annotations

import statistics
import time
from dataclasses import dataclass

import numpy as np
import pyopencl as cl

from ..device import build_options, get_program, get_runtime, real_dtype
from ..methods.registry import MethodConfig
from ..ops.invert import InversionKernel
from ..physics import reference as ref


def median_time(fn, repeats=5, warmup=1, queue=None, stat=statistics.median):
    """Median (or ``stat``: ``min`` for the best of a noisy machine) wall time of ``fn()``
    (which enqueues work) in seconds, queue drained each time."""
    queue = queue or get_runtime().queue
    for _ in range(warmup):
        fn()
        queue.finish()
    times = []
    for _ in range(repeats):
        queue.finish()
        t0 = time.perf_counter()
        fn()
        queue.finish()
        times.append(time.perf_counter() - t0)
    return stat(times)


def inversion_workload(n, seed=0):
    """``n`` float32 albedos: uniform on [1e-6, 0.999] (the accuracy contract's range,
    docs/model.md "Accuracy"), a fixed seed."""
    rng = np.random.default_rng(seed)
    return rng.uniform(1e-6, 0.999, n).astype(np.float32)


@dataclass
class InversionResult:
    config: MethodConfig
    double: bool
    seconds: float
    n: int
    max_err_alpha: float
    max_err_rho: float
    mean_err_rho: float

    @property
    def mtexel_per_s(self):
        return self.n / self.seconds / 1e6


def time_inversion(config, rd, eta, want_alpha, want_rho, *, double=False, repeats=5,
                   stat=statistics.median):
    """Time one configuration on device buffers holding ``rd``; measure its errors against
    ``want_alpha``, ``want_rho`` (the reference of ``rd``'s first ``want_rho.size`` values)."""
    rt = get_runtime()
    dtype = real_dtype(double)
    kernel = InversionKernel((eta,), config, double=double)
    mf = cl.mem_flags
    host = np.ascontiguousarray(rd, dtype=dtype)
    rd_buf = cl.Buffer(rt.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=host)
    a_buf = cl.Buffer(rt.context, mf.WRITE_ONLY, host.nbytes)
    r_buf = cl.Buffer(rt.context, mf.WRITE_ONLY, host.nbytes)
    seconds = median_time(lambda: kernel(host.size, rd_buf, alpha=a_buf, rho=r_buf), repeats,
                          stat=stat)
    alpha, rho = np.empty_like(host), np.empty_like(host)
    cl.enqueue_copy(rt.queue, alpha, a_buf)
    cl.enqueue_copy(rt.queue, rho, r_buf)
    rt.queue.finish()
    m = want_rho.size
    err_a = np.abs(alpha[:m] / want_alpha - 1.0)
    err_r = np.abs(rho[:m] / want_rho - 1.0)
    return InversionResult(config, double, seconds, host.size, float(err_a.max()),
                           float(err_r.max()), float(err_r.mean()))


def time_copy(n, *, double=False, repeats=5, stat=statistics.median):
    """The memory-bound floor: kernels/copy.cl over ``n`` elements (one read, one write)."""
    rt = get_runtime()
    dtype = real_dtype(double)
    prg = get_program(rt, "copy", build_options(double=double))
    knl = cl.Kernel(prg, "copy")
    mf = cl.mem_flags
    src = cl.Buffer(rt.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=np.ones(n, dtype))
    dst = cl.Buffer(rt.context, mf.WRITE_ONLY, n * dtype.itemsize)
    return median_time(lambda: knl(rt.queue, (n,), None, src, dst, np.uint64(n)), repeats,
                       stat=stat)


def stiff_workload(n=4000):
    """float32 albedos that reach both stiff ends and every table interval: geometric towards
    0 and towards 1, and uniform between (3n values)."""
    return np.float32(np.concatenate([np.geomspace(1e-6, 0.5, n), 1 - np.geomspace(6e-8, 0.5, n),
                                      np.linspace(1e-6, 0.999, n)]))


def reference_inverse(rd, eta):
    """float64 (alpha', rho) of the float32 values in ``rd``."""
    return ref.invert_rd_rho(np.asarray(rd, np.float64), eta)
