#!/usr/bin/env python3
"""How large a band must be for full speed, on the device in use.

Jobs stream images in bands of rows sized by a memory budget (``--max-memory``, 256M by
default: ``ops/bands.band_rows``). This measures what that budget costs in speed:

1. in memory: ``invert_albedo(rd, eta, return_rho=True, out=...)`` called on consecutive
   slices of one float32 array, for slice sizes 4K..16M texels (the band a job hands the
   device), in Mtexel/s and as a fraction of NumPy's own 1-read-2-write pass over the same
   array (``np.sqrt(rd, out=a); np.subtract(1, a, out=r)``, timed in the same run);
2. file to file: ``process_textures`` of one RGB float EXR at several ``max_memory``
   budgets, in seconds and rows per band, against the largest budget.

    python tools/bench_bands.py                 # Intel's runtime where there is one
    python tools/bench_bands.py --device pocl --size 2048
"""
import argparse
import tempfile
from pathlib import Path

import numpy as np
import OpenImageIO as oiio

from bdipole_cl import get_runtime, invert_albedo
from bdipole_cl.apps.benchmark import best_time, machine_lines
from bdipole_cl.io.batch import process_textures

BUDGETS = (4 << 20, 16 << 20, 64 << 20, 256 << 20, 1 << 30)


def in_memory(rt, n, repeats):
    rd = np.random.default_rng(0).uniform(0.01, 0.95, n).astype(np.float32)
    alpha, rho = np.empty_like(rd), np.empty_like(rd)

    def numpy_pass():
        np.sqrt(rd, out=alpha)
        np.subtract(np.float32(1), alpha, out=rho)

    peer = best_time(numpy_pass, repeats)
    print(f"\nin memory: {n} texels, invert_albedo(return_rho=True, out=) per slice; NumPy's "
          f"pass {n / peer / 1e6:.0f} Mtexel/s")
    print(f"{'slice (texels)':>15} {'MiB in+out':>11} {'Mtexel/s':>9} {'of NumPy':>9}")
    invert_albedo(rd[:4096], 1.4, device=rt)                    # build outside the timing
    for k in range(12, 25, 2):
        chunk = 1 << k
        if chunk > n:
            break

        def sliced():
            for i in range(0, n, chunk):
                invert_albedo(rd[i:i + chunk], 1.4, device=rt, return_rho=True,
                              out=(alpha[i:i + chunk], rho[i:i + chunk]))

        t = best_time(sliced, repeats)
        print(f"{chunk:>15} {chunk * 12 / 2**20:>11.2f} {n / t / 1e6:>9.0f} "
              f"{peer / t:>8.0%}")


def file_to_file(rt, size, repeats):
    with tempfile.TemporaryDirectory() as tmp:
        src = Path(tmp) / "albedo.exr"
        px = np.random.default_rng(1).uniform(0.05, 0.9, (size, size, 3)).astype(np.float32)
        out = oiio.ImageOutput.create(str(src))
        out.open(str(src), oiio.ImageSpec(size, size, 3, "float"))
        out.write_image(px)
        out.close()
        print(f"\nfile to file: {size}x{size} RGB float EXR, process_textures (mfp 1, eta 1.4)")
        print(f"{'max_memory':>11} {'seconds':>8} {'vs 1G':>6}")
        times = {}
        for budget in BUDGETS:
            def job():
                report = process_textures(str(src), mfp=1.0, eta=1.4, device=rt,
                                          max_memory=budget, output=str(Path(tmp) / "o.exr"),
                                          progress=False)
                assert report.ok, report.summary()
            times[budget] = best_time(job, repeats)
        for budget in BUDGETS:
            print(f"{budget >> 20:>10}M {times[budget]:>8.2f} "
                  f"{times[budget] / times[BUDGETS[-1]]:>6.2f}")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--device", default="intel")
    ap.add_argument("--n", type=int, default=1 << 24, help="texels of the in-memory part")
    ap.add_argument("--size", type=int, default=2048, help="side of the file part's image")
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    rt = get_runtime(args.device)
    print("\n".join(machine_lines(rt)))
    in_memory(rt, args.n, args.repeats)
    file_to_file(rt, args.size, args.repeats)


if __name__ == "__main__":
    main()
