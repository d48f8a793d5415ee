#!/usr/bin/env python3
"""Benchmark every inversion method on one input, in one run, on the current OpenCL device.

Prints Mtexel/s (best of --repeats: the machine is shared and noisy, so the fastest repeat is
the one least disturbed), max relative error of alpha' and rho against the float64 reference
inverse of the float32 input (its first --check values), the speed ratio against the memo's
50-iteration float bisection (the baseline, timed in this same run) and the fraction of a plain
copy kernel's throughput (the memory-bound floor; the inversion moves 3 arrays per texel, the
copy 2, so a 1-read-2-write kernel's own floor is 2/3 of a copy). The default's fraction is
then measured again as the median of --pairs alternated copy / default measurements (each pair
back to back, so that a slow moment of a shared machine slows both of its sides), and so is its
speed against the issue's peer, the minimal table kernel a user would write outside the
project (MINIMAL_SOURCE: one texel per work-item, no channels, clamps or tests), fed the
default's own table. On a device whose sqrt is used as it is (a CPU), the default is also
timed against itself with the sqrt corrected in the kernel, as a GPU runs it (numerics
"corrected": docs/numerics.md "What a GPU does").

Then, on the same host arrays: ``invert_albedo(rd, eta, return_rho=True)`` and
``albedo_to_coefficients(rd, 2.0, eta)`` (sigma_a, sigma_s') host to host (NumPy in, NumPy
out: what a user holding the arrays in memory sees), each with fresh outputs and with ``out=``
arrays (``np.empty``, made once), beside NumPy's own 1-read-2-write pass over the same input,
the peer a user would write, in the same two forms: ``alpha = np.sqrt(rd); rho = 1 - alpha``
(fresh outputs, whose pages are first touched by the pass) and ``np.sqrt(rd, out=alpha);
np.subtract(1, alpha, out=rho)`` (outputs made once). Each host path is compared with the
NumPy pass of its own form.

    python tools/bench_invert.py                       # 32M texels, eta 1.4, every method
    python tools/bench_invert.py --default-only --device pocl
    python tools/bench_invert.py --n 1048576 --eta 2.5 --double
"""
import argparse
import sys
import time

import numpy as np
import pyopencl as cl

from bdipole_cl import albedo_to_coefficients, get_runtime, invert_albedo, use_device
from bdipole_cl.apps.benchmark import (best_time, inversion_workload, machine_lines, median_time,
                                       reference_inverse, time_copy, time_inversion)
from bdipole_cl.device import build_options, get_program
from bdipole_cl.device.layout import P, channel_params
from bdipole_cl.device.numerics import sqrt_is_correctly_rounded
from bdipole_cl.physics import tables
from bdipole_cl.methods.registry import MethodConfig
from bdipole_cl.ops.invert import InversionKernel

DEFAULT = MethodConfig()
CONFIGS = [
    MethodConfig("memo", iterations=50),
    MethodConfig("memo", iterations=24),
    MethodConfig("bisection", iterations=50),
    MethodConfig("bisection", iterations=32),
    MethodConfig("secant", seed_size=4),
    MethodConfig("secant", seed_size=16),
    MethodConfig("secant", seed_size=64),
    MethodConfig("table", table_size=64),
    MethodConfig("table", table_size=64, polish=1),
    DEFAULT,
    MethodConfig("table", table_size=1024),
]


#: the issue's peer: the minimal three-segment cubic-table kernel a user would write outside
#: the project (one texel per work-item: sqrt, segment select, one float4 gather of c0..c3,
#: the polynomial, two writes; no channels, clamps or validity tests), fed the default's
#: own table rows and scales, so it computes the same inverse to within its rounding
MINIMAL_SOURCE = """
__kernel void minimal_table(__global const float *rd, __global float *alpha,
                            __global float *rho, __global const float4 *table,
                            const float rd_split, const float x_split, const float s0,
                            const float s1, const float s2)
{
    size_t i = get_global_id(0);
    float r = rd[i];
    float x = sqrt(r);
    int seg = (r >= rd_split) + (r >= 0.5f);
    float t = seg == 0 ? x * s0 : seg == 1 ? (x - x_split) * s1 : (1.0f - r) * s2;
    int j = clamp((int)t, 0, N - 1);
    float u = t - (float)j;
    float4 c = table[seg * (N + 1) + j];
    float v = c.x + u * (c.y + u * (c.z + u * c.w));
    alpha[i] = seg == 0 ? v : 1.0f - v * v;
    rho[i] = seg == 0 ? 1.0f - v : v * v;
}
"""


class MinimalTable:
    """MINIMAL_SOURCE built for eta on the current device, with the default's table."""

    def __init__(self, eta, config=DEFAULT):
        self.rt = rt = get_runtime()
        size = config.resolved(False).table_size
        self.knl = cl.Kernel(cl.Program(rt.context, MINIMAL_SOURCE).build(f"-DN={size}"),
                             "minimal_table")
        rows = tables.channel_tables((eta,), config.resolved(False).table_n)
        self.table = cl.Buffer(rt.context, cl.mem_flags.READ_ONLY | cl.mem_flags.COPY_HOST_PTR,
                               hostbuf=np.ascontiguousarray(rows, np.float32))
        prm = channel_params((eta,), table_n=config.resolved(False).table_n)
        self.args = [np.float32(prm[P[k]]) for k in ("RD_SPLIT", "X_SPLIT", "SCALE0", "SCALE1",
                                                      "SCALE2")]

    def __call__(self, n, rd, alpha, rho):
        return self.knl(self.rt.queue, (n,), None, rd, alpha, rho, self.table, *self.args)


def minimal_check(rd, eta, want_alpha):
    """The peer's max relative error of alpha' against the reference (that it computes the
    inverse the default does), on the checked values."""
    src, dst = device_buffers(rd[:want_alpha.size])
    MinimalTable(eta)(want_alpha.size, src, *dst)
    alpha = np.empty(want_alpha.size, np.float32)
    cl.enqueue_copy(get_runtime().queue, alpha, dst[0])
    return float(np.max(np.abs(alpha / want_alpha - 1.0)))


def device_buffers(rd):
    """(input, two outputs): device buffers of ``rd``'s size, the input holding it."""
    rt = get_runtime()
    mf = cl.mem_flags
    host = np.ascontiguousarray(rd, dtype=np.float32)
    src = cl.Buffer(rt.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=host)
    return src, [cl.Buffer(rt.context, mf.WRITE_ONLY, host.nbytes) for _ in range(2)]


def peer_ratios(peer, config, rd, eta, pairs=7, repeats=3):
    """The peer's time over ``config``'s, alpha' and rho written, in ``pairs`` alternated
    measurements on the same device buffers, each side the best of ``repeats``: a pair is
    timed back to back, so a slow moment of a shared machine slows both of its sides rather
    than one side of the comparison. ``peer(n, src, dst)`` enqueues the peer over n elements.
    Returns the pairs' ratios (above 1: the default is the faster)."""
    n = rd.size
    kernel = InversionKernel((eta,), config)
    src, dst = device_buffers(rd)
    ratios = []
    for _ in range(pairs):
        t_peer = median_time(lambda: peer(n, src, dst), repeats, stat=min)
        t_kernel = median_time(lambda: kernel(n, src, alpha=dst[0], rho=dst[1]), repeats,
                               stat=min)
        ratios.append(t_peer / t_kernel)
    return ratios


def copy_ratios(config, rd, eta, pairs=7):
    """``peer_ratios`` against the copy kernel (one read, one write): the fraction of the
    memory floor an inversion kernel reaches."""
    rt = get_runtime()
    copy = cl.Kernel(get_program(rt, "copy", build_options()), "copy")
    return peer_ratios(lambda n, src, dst: copy(rt.queue, (n,), None, src, dst[0],
                                                 np.uint64(n)), config, rd, eta, pairs)


def minimal_ratios(config, rd, eta, pairs=7):
    """``peer_ratios`` against the minimal table kernel (MINIMAL_SOURCE)."""
    peer = MinimalTable(eta, config)
    return peer_ratios(lambda n, src, dst: peer(n, src, *dst), config, rd, eta, pairs)


def corrected_ratios(config, rd, eta, pairs=7):
    """``peer_ratios`` against ``config`` built with the in-kernel sqrt correction (numerics
    "corrected", kernels/bdipole.h BD_SQRT_RN): its time over the default's."""
    peer = InversionKernel((eta,), config, runtime=get_runtime().with_numerics("corrected"))
    return peer_ratios(lambda n, src, dst: peer(n, src, alpha=dst[0], rho=dst[1]), config, rd,
                       eta, pairs)


def numpy_pass(rd, out=None):
    """NumPy's own 1-read-2-write pass: two outputs from one input, fresh or ``out``."""
    if out is None:
        alpha = np.sqrt(rd)
        return alpha, np.subtract(np.float32(1.0), alpha)
    alpha, rho = out
    np.sqrt(rd, out=alpha)
    return alpha, np.subtract(np.float32(1.0), alpha, out=rho)


def host_rows(rd, eta, rt, repeats):
    """(name, seconds, NumPy peer's seconds) of the host-to-host paths, fresh and ``out=``
    (the NumPy pass timed beside each, in the same form)."""
    out = (np.empty_like(rd), np.empty_like(rd))
    numpy_fresh = best_time(lambda: numpy_pass(rd), repeats, warmup=1)
    numpy_out = best_time(lambda: numpy_pass(rd, out), repeats, warmup=1)
    rows = [
        ("invert_albedo(return_rho=True)", lambda: invert_albedo(rd, eta, return_rho=True,
                                                                 device=rt), numpy_fresh),
        ("  out=(alpha, rho)", lambda: invert_albedo(rd, eta, return_rho=True, device=rt,
                                                     out=out), numpy_out),
        ("albedo_to_coefficients(mfp=2)", lambda: albedo_to_coefficients(rd, 2.0, eta,
                                                                         device=rt),
         numpy_fresh),
        ("  out=(sigma_a, sigma_s)", lambda: albedo_to_coefficients(rd, 2.0, eta, device=rt,
                                                                    out=out), numpy_out),
    ]
    timed = [(name, best_time(fn, repeats, warmup=1), peer) for name, fn, peer in rows]
    return timed + [("NumPy 1-read-2-write pass", numpy_fresh, numpy_fresh),
                    ("  out=(alpha, rho)", numpy_out, numpy_out)]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--n", type=int, default=1 << 25, help="texels (default 33554432)")
    ap.add_argument("--eta", type=float, default=1.4)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--check", type=int, default=1 << 20,
                    help="texels checked against the float64 reference (default 1048576)")
    ap.add_argument("--default-only", action="store_true",
                    help="time only the default method (table, size 256)")
    ap.add_argument("--double", action="store_true", help="also time float64 kernels")
    ap.add_argument("--pairs", type=int, default=7,
                    help="alternated copy / default-kernel measurements (their median ratio)")
    ap.add_argument("--device", help="OpenCL device (as `bdipole-cl --device`); default: automatic")
    args = ap.parse_args(argv)
    if args.device:
        use_device(args.device)
    rt = get_runtime()
    print("\n".join(machine_lines(rt)))
    rd = inversion_workload(args.n)
    t0 = time.perf_counter()
    check = min(args.check, args.n)
    want_a, want_rho = reference_inverse(rd[:check], args.eta)
    print(f"input: {args.n} float32 albedos uniform on [1e-6, 0.999], eta {args.eta}; "
          f"float64 reference inverse of the first {check} in {time.perf_counter() - t0:.1f} s; "
          f"times: best of {args.repeats}")
    copy_s = time_copy(args.n, repeats=args.repeats, stat=min)
    configs = [DEFAULT] if args.default_only else CONFIGS
    precisions = [False] + ([True] if args.double and rt.has_fp64 else [])
    results = [time_inversion(c, rd, args.eta, want_a, want_rho, double=d, repeats=args.repeats,
                              stat=min)
               for d in precisions for c in configs]
    base = next((r for r in results if r.config == CONFIGS[0] and not r.double), None)
    print(f"\n{'method':34s} {'prec':5s} {'Mtexel/s':>9s} {'ms':>9s} {'max rel err':>11s} "
          f"{'max rel err':>11s} {'x memo':>8s} {'% copy':>7s}")
    print(f"{'':34s} {'':5s} {'':>9s} {'':>9s} {'alpha':>11s} {'rho':>11s}")
    for r in results:
        vs_memo = f"{base.seconds / r.seconds:8.1f}" if base else f"{'':>8s}"
        print(f"{r.config.describe():34s} {'f64' if r.double else 'f32':5s} "
              f"{r.mtexel_per_s:9.2f} {r.seconds * 1e3:9.2f} {r.max_err_alpha:11.2e} "
              f"{r.max_err_rho:11.2e} {vs_memo} {100 * copy_s / r.seconds:6.1f}%")
    print(f"{'copy kernel (memory floor)':34s} {'f32':5s} {args.n / copy_s / 1e6:9.2f} "
          f"{copy_s * 1e3:9.2f}")
    ratios = copy_ratios(DEFAULT, rd, args.eta, args.pairs)
    print(f"{DEFAULT.describe()} against the copy kernel, {args.pairs} alternated pairs: "
          f"median {100 * np.median(ratios):.1f}% of copy [{100 * min(ratios):.1f}%, "
          f"{100 * max(ratios):.1f}%]")
    peer = minimal_ratios(DEFAULT, rd, args.eta, args.pairs)
    print(f"{DEFAULT.describe()} against the minimal table kernel (max rel err alpha "
          f"{minimal_check(rd, args.eta, want_a):.1e}), {args.pairs} alternated pairs: "
          f"median {np.median(peer):.2f}x its speed [{min(peer):.2f}, {max(peer):.2f}]")
    if sqrt_is_correctly_rounded(rt.device, rt.numerics):
        slower = corrected_ratios(DEFAULT, rd, args.eta, args.pairs)
        print(f"{DEFAULT.describe()} with its sqrt corrected in the kernel (numerics "
              f"'corrected': what a device whose sqrt is not known to be correctly rounded, a "
              f"GPU, runs), {args.pairs} alternated pairs: median {np.median(slower):.2f}x the "
              f"default's time [{min(slower):.2f}, {max(slower):.2f}]")
    print(f"\nhost to host, same {args.n} float32 albedos (% of NumPy's pass of the same form):")
    for name, seconds, peer in host_rows(rd, args.eta, rt, args.repeats):
        print(f"{name:34s} {'f32':5s} {args.n / seconds / 1e6:9.2f} {seconds * 1e3:9.2f}"
              f"   {100 * peer / seconds:.0f}%")
    return 0


if __name__ == "__main__":
    sys.exit(main())
