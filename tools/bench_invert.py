#!/usr/bin/env python3
"""Benchmark every inversion method on one input, in one run, on the current OpenCL device.

Prints Mtexel/s (median of --repeats), max relative error of alpha' and rho against the float64
reference inverse of the float32 input, the speed ratio against the memo's 50-iteration float
bisection (the baseline, timed in this same run) and the fraction of a plain copy kernel's
throughput (the memory-bound floor; the inversion moves 3 arrays per texel, the copy 2).

    python tools/bench_invert.py                 # 4M texels, eta 1.4
    python tools/bench_invert.py --n 1048576 --eta 2.5 --double
"""
import argparse
import sys
import time

from bdipole_cl import get_runtime, use_device
from bdipole_cl.apps.benchmark import (inversion_workload, reference_inverse, time_copy,
                                  time_inversion)
from bdipole_cl.methods.registry import MethodConfig

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
    MethodConfig("table", table_size=256),
    MethodConfig("table", table_size=1024),
]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--n", type=int, default=1 << 22, help="texels (default 4194304)")
    ap.add_argument("--eta", type=float, default=1.4)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--double", action="store_true", help="also time float64 kernels")
    ap.add_argument("--device", help="OpenCL device (as `bdipole-cl --device`); default: automatic")
    args = ap.parse_args(argv)
    if args.device:
        use_device(args.device)
    rt = get_runtime()
    print(f"device: {rt.describe()}")
    rd = inversion_workload(args.n)
    t0 = time.perf_counter()
    want_a, want_rho = reference_inverse(rd, args.eta)
    print(f"input: {args.n} float32 albedos uniform on [1e-6, 0.999], eta {args.eta}; "
          f"float64 reference inverse in {time.perf_counter() - t0:.1f} s")
    copy_s = time_copy(args.n, repeats=args.repeats)
    precisions = [False] + ([True] if args.double and rt.has_fp64 else [])
    results = [time_inversion(c, rd, args.eta, want_a, want_rho, double=d, repeats=args.repeats)
               for d in precisions for c in CONFIGS]
    base = next(r for r in results if r.config == CONFIGS[0] and not r.double)
    print(f"\n{'method':34s} {'prec':5s} {'Mtexel/s':>9s} {'ms':>9s} {'max rel err':>11s} "
          f"{'max rel err':>11s} {'x memo':>8s} {'% copy':>7s}")
    print(f"{'':34s} {'':5s} {'':>9s} {'':>9s} {'alpha':>11s} {'rho':>11s}")
    for r in results:
        print(f"{r.config.describe():34s} {'f64' if r.double else 'f32':5s} "
              f"{r.mtexel_per_s:9.2f} {r.seconds * 1e3:9.2f} {r.max_err_alpha:11.2e} "
              f"{r.max_err_rho:11.2e} {base.seconds / r.seconds:8.1f} "
              f"{100 * copy_s / r.seconds:6.1f}%")
    print(f"{'copy kernel (memory floor)':34s} {'f32':5s} {args.n / copy_s / 1e6:9.2f} "
          f"{copy_s * 1e3:9.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
