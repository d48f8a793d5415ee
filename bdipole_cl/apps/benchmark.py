"""Timing and error measurement shared by tools/bench_*.py and ``bdipole-cl report``.

Timings are medians over repeats of a kernel on device-resident buffers (queue finished before
and after each repeat), so they measure the device, not host transfers. Errors are against the
float64 reference inverse of the exact float32 inputs.
"""
from __future__ import annotations

import os
import statistics
import time
from dataclasses import dataclass

import numpy as np
import pyopencl as cl

from ..device import build_options, get_program, get_runtime, real_dtype
from ..device.runtime import forced
from ..methods.registry import MethodConfig
from ..ops.invert import InversionKernel
from ..physics import reference as ref


def cpu_model() -> str:
    """This machine's CPU: model name, family and model numbers, widest SIMD, logical cores
    (/proc/cpuinfo where there is one; a VM's model name can be generic)."""
    import platform
    fields = {}
    try:
        with open("/proc/cpuinfo") as f:
            for ln in f:
                key, _, value = ln.partition(":")
                if not ln.strip():
                    break                       # the first processor is enough
                fields.setdefault(key.strip().lower(), value.strip())
    except OSError:
        pass
    name = fields.get("model name") or platform.processor() or platform.machine()
    flags = set(fields.get("flags", "").split())
    simd = next((f for f in ("avx512f", "avx2", "avx", "sse4_2", "neon") if f in flags), "")
    ident = (f"family {fields['cpu family']} model {fields['model']}"
             if "cpu family" in fields and "model" in fields else "")
    extra = ", ".join(x for x in (ident, simd) if x)
    return f"{name}" + (f" ({extra})" if extra else "") + f", {os.cpu_count()} logical cores"


def machine_lines(rt) -> list:
    """What a benchmark's figures were measured on: the CPU, the OpenCL runtime and device,
    and the kernel widths chosen there with what decided them."""
    from ..ops.blur.dispatch import gather_width
    from ..ops.inversion_kernel import table_width_choice
    table = table_width_choice(rt)
    return [f"CPU: {cpu_model()}",
            f"OpenCL: {rt.describe()}, driver {rt.device.driver_version.strip()}",
            f"widths: table kernel {table.width} ({table.source}); gather "
            f"{gather_width(rt, 1 << 20)}"]


def best_time(fn, repeats, warmup=0) -> float:
    """The fastest of ``repeats`` wall times of ``fn()`` (host work, or work that waits for
    itself) in seconds, after ``warmup`` untimed calls."""
    for _ in range(warmup):
        fn()
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


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


#: the widths ``report --calibrate`` tries: elements per work-item of the table kernel and
#: texels per work-item of the texture-varying gather
TABLE_WIDTH_CHOICES = (1, 4, 8, 16)
GATHER_WIDTH_CHOICES = (1, 8, 16)


def table_width_times(n, repeats=3, widths=TABLE_WIDTH_CHOICES) -> dict:
    """{width: seconds} of the default table inversion of ``n`` albedos on the current device
    (device buffers; best of ``repeats``), at each width."""
    from ..ops.inversion_kernel import TABLE_WIDTH_VARIABLE
    rd = inversion_workload(n)
    want_alpha, want_rho = reference_inverse(rd[:1000], 1.4)
    times = {}
    for width in widths:
        with forced(TABLE_WIDTH_VARIABLE, width):
            times[width] = time_inversion(MethodConfig(), rd, 1.4, want_alpha, want_rho,
                                          repeats=repeats, stat=min).seconds
    return times


@dataclass(frozen=True)
class GatherRow:
    """One near field's plan on the texture-varying workload: its radius, FFT basis kernels G,
    near kernels M, and the gather's time."""

    near: int
    nbasis: int
    nnear: int
    cells: int
    terms: int
    seconds: float


def gather_rows(size=1024, tol=1e-3, repeats=3, radii=None, progress=None):
    """(GatherRow per near field radius, seconds of one basis blur) on the texture-varying
    workload at mfp 4 texels (``varying_workload``, channel 0), on the current device."""
    from ..ops.blur import near_field
    from ..ops.blur.dispatch import gather_exitance
    from ..ops.blur.fft import basis_blurs, fft_shape
    from ..ops.blur.textured import host_array, textured_plans
    from ..ops.blur.textured_plan import PLAN_CACHE
    rt = get_runtime()
    e, albedo, mfp = varying_workload(size, 4.0)
    out, rows, per_blur = host_array(e.shape), [], []
    every = near_field.NEAR_RADII
    try:
        for near in radii or every:
            near_field.NEAR_RADII = (near,)
            PLAN_CACHE.clear()
            plan, rd, ld, _ = textured_plans(e.shape, tol=tol, albedo=albedo, mfp=mfp,
                                             eta=1.4)[0]
            planes = host_array((len(plan.kernels), size, fft_shape((size, size),
                                                                     plan.radius)[1]))
            basis_blurs(e, 0, plan, "clamp", planes)      # the kernels' spectra, once
            t0 = time.perf_counter()
            padded, _, _, _ = basis_blurs(e, 0, plan, "clamp", planes)
            blurs = time.perf_counter() - t0            # warm, as a blur under new light
            seconds = median_time(lambda: gather_exitance(out, 0, plan, rd, ld, planes, padded,
                                                          plan.radius, rt), repeats, stat=min)
            g, m = len(plan.kernels), len(plan.near_values)
            rows.append(GatherRow(near, g, m, near_field.near_cells(near),
                                  len(near_field.near_classes(near)) * m, seconds))
            if g:
                per_blur.append(blurs / (g + 1))        # the forward transform and g inverses
            if progress:
                progress(rows[-1])
    finally:
        near_field.NEAR_RADII = every
        PLAN_CACHE.clear()
    return rows, float(np.median(per_blur))


def fitted_gather_costs(rows, per_blur):
    """The non-negative least-squares (cell, term, weight) costs of ``gather_rows``' rows in
    basis blurs, and the fixed part in seconds (the columns move together over the near
    fields, so an unconstrained fit trades them off into negative costs)."""
    from scipy.optimize import nnls
    a = np.array([[1.0, r.cells, r.terms, r.nbasis + r.nnear] for r in rows])
    scale = a.max(axis=0)                       # columns of one size, for the solver
    fit = nnls(a / scale, np.array([r.seconds for r in rows]))[0] / scale
    return tuple(float(v) / per_blur for v in fit[1:]), float(fit[0])


def hdr_irradiance(n):
    """The blur benchmarks' irradiance: n x n RGB uniform on [0, 1), with a few highlights at
    50 (a fixed seed)."""
    rng = np.random.default_rng(0)
    e = rng.uniform(0.0, 1.0, (n, n, 3)).astype(np.float32)
    e[rng.uniform(size=e.shape[:2]) < 1e-3] = 50.0
    return e


def varying_workload(n, mfp):
    """(E, albedo, mfp maps) of the texture-varying benchmark: ``hdr_irradiance``, albedo
    (0.8, 0.6, 0.4) x (1 + 0.2 p(x)), mfp x 2^(p(x)/2), p a smooth pattern in [-1, 1]."""
    e = hdr_irradiance(n)
    yy, xx = np.mgrid[0:n, 0:n] / n
    pattern = np.sin(2 * np.pi * (3 * xx + yy)) * np.cos(2 * np.pi * (2 * yy - xx))
    albedo = np.array((0.8, 0.6, 0.4))[None, None, :] * (1.0 + 0.2 * pattern[..., None])
    return e, albedo.astype(np.float32), (mfp * 2.0 ** (0.5 * pattern)).astype(np.float32)
