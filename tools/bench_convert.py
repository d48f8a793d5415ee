#!/usr/bin/env python3
"""What ``convert`` costs per distinct colour value (docs/conventions.md "Conversion").

Every distinct colour of an array is converted exactly, in float64 on the host, whatever the
array's size; the cost is per distinct value of a band's channel. This times
``bdipole_cl.convert`` on N distinct float32 colours for a few convention pairs, in values
per second and against a peer timed in the same run on the same values: the float64
reference inversion of the Better Dipole (``physics.reference.albedo_to_coefficients``, a
safeguarded Newton per value), which every profile conversion calls once.

    python tools/bench_convert.py                # 262144 values (a 512^2 float channel)
    python tools/bench_convert.py --n 65536 --repeats 3
"""
import argparse

import numpy as np

from bdipole_cl import convert
from bdipole_cl.apps.benchmark import best_time, cpu_model
from bdipole_cl.physics.reference import albedo_to_coefficients

PAIRS = (("better-dipole", "burley"), ("dipole", "better-dipole"),
         ("better-dipole", "van-de-hulst"), ("random-walk", "better-dipole"),
         ("better-dipole", "cycles-random-walk"))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=1 << 18, help="distinct colour values")
    ap.add_argument("--repeats", type=int, default=2)
    args = ap.parse_args(argv)
    print(f"CPU: {cpu_model()} (host float64: no OpenCL device)")
    colour = np.random.default_rng(0).uniform(0.02, 0.8, args.n).astype(np.float32)
    n = np.unique(colour).size
    peer = best_time(lambda: albedo_to_coefficients(colour.astype(np.float64), 1.0, 1.4),
                   args.repeats)
    print(f"{n} distinct float32 colours in [0.02, 0.8], eta 1.4, radius 1; peer: the "
          f"reference inversion, {n / peer / 1e3:.0f} k values/s")
    print(f"{'source -> target':>36} {'k values/s':>11} {'s':>7} {'x peer':>7}")
    for source, target in PAIRS:
        convert(colour[:16], 1.0, source, target, eta=1.4)      # tables built outside
        t = best_time(lambda: convert(colour, 1.0, source, target, eta=1.4), args.repeats)
        print(f"{source + ' -> ' + target:>36} {n / t / 1e3:>11.0f} {t:>7.2f} "
              f"{t / peer:>7.1f}")


if __name__ == "__main__":
    main()
