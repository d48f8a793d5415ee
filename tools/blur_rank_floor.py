#!/usr/bin/env python3
"""The texture-varying blur's structural floor: how few FFT basis blurs the benchmark's maps
need, and what even a free gather would cost against the constant blur, in one run.

For the texture-varying workload of ``tools/bench_blur.py`` (albedo (0.8, 0.6, 0.4) x (1 + 0.2
p), mfp x 2^(p/2), p in [-1, 1]) at each mfp, per channel: the fewest far eigen-kernels that fit
every kernel of the channel's parameter range within L1 error tol beyond each near field radius
(``near_field.far_rank``: where the plan's ranks start; the interpolation can only add), the
radii the gather supports (0-6) and wider ones (8-12) that it does not. Then, at --size, timed
in the same run: the constant default blur, and per channel the basis blurs (``fft.
basis_blurs``: the padded copy, the forward transform and one inverse per kernel) with the
fewest kernels any supported near field allows. Their sum over the channels, with the gather
and the rest taken as free, against the constant blur is a floor on the texture-varying
blur's time ratio with this decomposition (docs/model.md "What bounds its cost").

    python tools/blur_rank_floor.py
    python tools/blur_rank_floor.py --mfp 16 --size 1024 --device 1:0
"""
import argparse
import dataclasses


from bdipole_cl import blur, get_runtime, use_device
from bdipole_cl.apps.benchmark import best_time, varying_workload
from bdipole_cl.ops.blur.fft import basis_blurs, fft_shape
from bdipole_cl.ops.blur.near_field import NEAR_RADII, far_rank
from bdipole_cl.ops.blur.textured import host_array, textured_plans
from bdipole_cl.ops.blur.textured_plan import (lattice_kernels, parameter_ranges,
                                               training_kernels)

ALBEDO = (0.8, 0.6, 0.4)
#: near field radii the gather does not support, to show the ranks would not fall far there
WIDER = (8, 10, 12)


def channel_ranks(channel, tol, radii):
    """{near radius: fewest far eigen-kernels} for one channel's parameter range."""
    rd_range, ld_range = parameter_ranges(channel.extremes)
    lat = lattice_kernels(rd_range, ld_range, channel.plan.eta, tol)
    train = training_kernels(lat.targets, lat.checks, lat.inside)
    return {near: far_rank(train, near, lat.radius, tol) for near in radii
            if near <= lat.radius}


def basis_time(e, c, plan, nbasis, repeats):
    """Best time of channel c's basis blurs with the plan's first ``nbasis`` kernels."""
    few = dataclasses.replace(plan, kernels=plan.kernels[:nbasis])
    shape = fft_shape(e.shape[:2], plan.radius)
    planes = host_array((nbasis, e.shape[0], shape[1]))
    basis_blurs(e, c, few, "clamp", planes)            # warm: the spectra cached
    return best_time(lambda: basis_blurs(e, c, few, "clamp", planes), repeats)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--size", type=int, default=2048)
    ap.add_argument("--mfp", type=float, nargs="+", default=[1.0, 4.0, 16.0])
    ap.add_argument("--tol", type=float, default=1e-3)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--device", help="OpenCL device (as `bdipole-cl --device`)")
    args = ap.parse_args(argv)
    if args.device:
        use_device(args.device)
    print(f"device: {get_runtime().describe()}")
    supported = tuple(NEAR_RADII)
    radii = supported + WIDER
    print(f"{args.size}x{args.size} RGB, tol {args.tol}: fewest far eigen-kernels per near "
          f"field radius (-1: none; {', '.join(map(str, WIDER))}: beyond the gather's)")
    for mfp in args.mfp:
        e, albedo, mfps = varying_workload(args.size, mfp)
        channels = textured_plans(e.shape, tol=args.tol, albedo=albedo, mfp=mfps, eta=1.4)
        fewest, floor = [], 0.0
        for c, ch in enumerate(channels):
            ranks = channel_ranks(ch, args.tol, radii)
            fewest.append(min(g for r, g in ranks.items() if r in supported))
            print(f"  mfp {mfp:g} channel {c} (plan: {len(ch.plan.kernels)} basis, near "
                  f"{ch.plan.near}): " + " ".join(f"{r}:{g}" for r, g in ranks.items()))
            floor += basis_time(e, c, ch.plan, fewest[-1], args.repeats)
        const = best_time(lambda: blur(e, albedo=ALBEDO, mfp=mfp, eta=1.4, tol=args.tol),
                        args.repeats)
        vary = best_time(lambda: blur(e, albedo=albedo, mfp=mfps, eta=1.4, tol=args.tol),
                       args.repeats)
        print(f"  mfp {mfp:g}: constant {const * 1e3:.0f} ms; basis blurs alone with "
              f"{fewest} kernels {floor * 1e3:.0f} ms = {floor / const:.2f}x (a free gather's "
              f"floor); the texture-varying default {vary * 1e3:.0f} ms = {vary / const:.2f}x")


if __name__ == "__main__":
    main()
