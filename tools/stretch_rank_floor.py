#!/usr/bin/env python3
"""The stretched blur's rank against its maps' anisotropy: how many FFT eigen-kernels a plan
needs as the range of aspects it covers widens, against the texture-varying blur's basis.

For the texture-varying workload of ``tools/bench_blur.py`` at each mfp (texels of 1 mm), per
channel: the texture-varying plan's basis and near field, then the stretched plan
(``stretched_plan.stretched_plan``, the one the blur makes: far fit, interpolation and near
field at the default gather costs' radius) over the same albedo and diffusion-length ranges
with the anisotropy s = ln(l_u / l_v) in [-h, h] for each --half-widths h (0: one aspect, as a
cylinder's chart; 0.05: aspects within 5%, as most charts of an artist's unwrap; 0.35: the
smooth stretch of ``bench_blur.py --stretch``). Each inverse FFT a channel costs about as much
in either blur, so (1 + rank) over (1 + basis) is the stretched blur's transforms' share of
the ratio on one window (docs/stretch.md "Speed, and what is not done").

    python tools/stretch_rank_floor.py
    python tools/stretch_rank_floor.py --mfp 1 4 --half-widths 0 0.02 0.1
"""
import argparse
import math
import time

from bdipole_cl import get_runtime
from bdipole_cl.apps.benchmark import varying_workload
from bdipole_cl.ops.blur.near_field import DEFAULT_GATHER_COSTS
from bdipole_cl.ops.blur.stretched_plan import stretched_plan
from bdipole_cl.ops.blur.textured import textured_plans
from bdipole_cl.ops.blur.textured_plan import parameter_ranges


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--size", type=int, default=256,
                    help="texels a side of the workload's maps (their ranges do not depend "
                         "on it beyond a few texels)")
    ap.add_argument("--mfp", type=float, nargs="+", default=[4.0])
    ap.add_argument("--tol", type=float, default=1e-3)
    ap.add_argument("--half-widths", type=float, nargs="+",
                    default=[0.0, 0.02, 0.05, 0.1, 0.15, 0.35])
    args = ap.parse_args(argv)
    print(f"device: {get_runtime().describe()}; tol {args.tol}")
    for mfp in args.mfp:
        e, albedo, mfps = varying_workload(args.size, mfp)
        channels = textured_plans(e.shape, tol=args.tol, albedo=albedo, mfp=mfps, eta=1.4)
        for c, ch in enumerate(channels):
            base = parameter_ranges(ch.extremes)
            print(f"mfp {mfp:g} channel {c}: texture-varying {len(ch.plan.kernels)} basis "
                  f"kernels, near field {ch.plan.near}; logit Rd {base[0][0]:.2f}..."
                  f"{base[0][1]:.2f}, ln l {base[1][0]:.2f}...{base[1][1]:.2f}")
            for h in args.half_widths:
                t0 = time.perf_counter()
                plan = stretched_plan(base + ((-h, h),), 1.4, args.tol,
                                      costs=DEFAULT_GATHER_COSTS)
                print(f"  s in [-{h:g}, {h:g}] (aspect {math.exp(-h):.3f}..."
                      f"{math.exp(h):.3f}): {len(plan.kernels)} eigen-kernels, near field "
                      f"{plan.near}; fit {plan.fit_error:.1e}, interpolation "
                      f"{plan.interp_error:.1e} ({time.perf_counter() - t0:.1f} s to plan)",
                      flush=True)


if __name__ == "__main__":
    main()
