#!/usr/bin/env python3
"""The blur's energy on large kernels, too heavy for the test suite: a constant irradiance
under the clamp border (exact answer E * Rd everywhere, Rd by quadrature of 2 pi r R(r)),
albedo 0.8, at kernel radii up to the largest that ``direct`` takes in the suite's terms
(mfp 300 texels: radius 1257 at tol 1e-3), every method, on every working OpenCL device.
Printed per row: the measured max |M / (E Rd) - 1|, the reported error bound, and their ratio
(<= 1: the bound holds). tests/test_numerics_contract.py runs the same check at radius 419.

    python tools/accuracy_sweep.py
    python tools/accuracy_sweep.py --mfp 100 300 --methods direct --size 16
"""
import argparse
import time
import warnings

import numpy as np
from scipy.integrate import quad

from bdipole_cl import reference as ref
from bdipole_cl.device import working_runtimes
from bdipole_cl.ops.blur import blur, channel_parameters


def quadrature_rd(alpha, sigma_t, eta, mfp):
    edges = np.concatenate([[0.0], np.geomspace(1e-9, 1e4, 40) * mfp, [np.inf]])
    return sum(quad(lambda r: 2 * np.pi * r * ref.profile(r, alpha, sigma_t, eta), lo, hi,
                    epsabs=0, epsrel=1e-12, limit=200)[0] for lo, hi in zip(edges[:-1], edges[1:]))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mfp", type=float, nargs="+", default=[100.0, 300.0])
    ap.add_argument("--tol", type=float, default=1e-3)
    ap.add_argument("--size", type=int, default=16, help="image side (texels)")
    ap.add_argument("--methods", nargs="+", default=["direct", "gaussians", "fft", "auto"])
    args = ap.parse_args(argv)
    e = np.full((args.size, args.size), 2.0, np.float32)
    print("| device | mfp | radius | method | max rel error | bound | error/bound | s |")
    print("|---|---:|---:|---|---:|---:|---:|---:|")
    for rt in working_runtimes():
        name = rt.describe().split("(")[1].split(",")[0] if "(" in rt.describe() else rt.describe()
        for mfp in args.mfp:
            (alpha, st, eta), = channel_parameters(1, albedo=0.8, mfp=mfp)
            rd = quadrature_rd(alpha, st, eta, mfp)
            for method in args.methods:
                t0 = time.perf_counter()
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    out, info = blur(e, albedo=0.8, mfp=mfp, tol=args.tol, method=method,
                                     return_info=True, device=rt)
                ch = info.channels[0]
                err = float(np.abs(out.astype(np.float64) / (2.0 * rd) - 1).max())
                label = f"auto: {ch.method}" if method == "auto" else ch.method
                print(f"| {name} | {mfp:g} | {ch.radius} | {label} | {err:.2e} | "
                      f"{ch.error_bound:.2e} | {err / ch.error_bound:.3f} | "
                      f"{time.perf_counter() - t0:.1f} |", flush=True)


if __name__ == "__main__":
    main()
