#!/usr/bin/env python3
"""Blur benchmark: a 2048x2048 RGB irradiance map, mfp of 1, 4 and 16 texels, every method, in
one run on the current device. For each: median time, max error against the exact discrete
convolution (the exact texel-integrated weights by float64 FFT), relative to max(E) * Rd, and
the speed ratio against ``scipy.signal.fftconvolve`` of the same weights (timed here too).

    python tools/bench_blur.py
    python tools/bench_blur.py --size 1024 --mfp 1 4 --tol 1e-3
"""
import argparse
import statistics
import sys
import time

import numpy as np
from scipy.signal import fftconvolve

from bdipole_cl import get_runtime
from bdipole_cl.blur import blur, channel_kernel, channel_parameters

ALBEDO = (0.8, 0.6, 0.4)


def timed(fn, repeats):
    times, out = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--size", type=int, default=2048)
    ap.add_argument("--mfp", type=float, nargs="+", default=[1.0, 4.0, 16.0])
    ap.add_argument("--tol", type=float, default=1e-3)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--methods", nargs="+", default=["auto", "direct", "gaussians", "fft"])
    args = ap.parse_args(argv)
    print(f"device: {get_runtime().describe()}")
    rng = np.random.default_rng(0)
    e = rng.uniform(0.0, 1.0, (args.size, args.size, 3)).astype(np.float32)
    e[rng.uniform(size=e.shape[:2]) < 1e-3] = 50.0      # a few HDR highlights
    print(f"input {args.size}x{args.size} RGB, albedo {ALBEDO}, eta 1.4, tol {args.tol}, "
          f"border clamp; error = max|M - exact| / (max E * Rd)")
    print(f"{'mfp':>5s} {'method':10s} {'radius':>6s} {'s':>8s} {'max err':>9s} "
          f"{'x scipy fft':>11s}")
    for mfp in args.mfp:
        params = channel_parameters(3, albedo=ALBEDO, mfp=mfp, eta=1.4)
        kernels = [channel_kernel(*p, args.tol) for p in params]
        k = max(ck.radius for ck in kernels)
        pad = np.pad(e, ((k, k), (k, k), (0, 0)), mode="edge").astype(np.float64)

        def scipy_fft():
            return np.stack([fftconvolve(pad[..., c], kernels[c].weights, mode="same")
                             [k:-k or None, k:-k or None] for c in range(3)], axis=-1)

        t_ref, exact = timed(scipy_fft, 1 if args.size > 1024 else args.repeats)
        norm = np.array([e[..., c].max() * kernels[c].rd for c in range(3)])
        print(f"{mfp:5g} {'scipy fft':10s} {k:6d} {t_ref:8.2f} {'(exact)':>9s} {1.0:11.2f}")
        for m in args.methods:
            blur(e[:64, :64], albedo=ALBEDO, mfp=mfp, eta=1.4, tol=args.tol, method=m)  # warm
            t, out = timed(lambda: blur(e, albedo=ALBEDO, mfp=mfp, eta=1.4, tol=args.tol,
                                        method=m), args.repeats)
            err = (np.abs(out - exact).max(axis=(0, 1)) / norm).max()
            print(f"{mfp:5g} {m:10s} {k:6d} {t:8.2f} {err:9.1e} {t_ref / t:11.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
