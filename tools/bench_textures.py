#!/usr/bin/env python3
"""End-to-end texture throughput: an N x N RGB float EXR (default 8K) through ``process_textures``
(read, decode, invert, write) against the inversion kernel alone on as many texels, in one run;
prints Mtexel/s for both and the process's peak host memory.

    python tools/bench_textures.py            # 8192 x 8192
    python tools/bench_textures.py --size 2048 --jobs 1
"""
import argparse
import resource
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import OpenImageIO as oiio

from bdipole_cl import get_runtime, use_device
from bdipole_cl.apps.benchmark import inversion_workload, median_time
from bdipole_cl.io.batch import process_textures
from bdipole_cl.methods.registry import MethodConfig
from bdipole_cl.ops.invert import InversionKernel


def make_exr(path, size, band=512):
    spec = oiio.ImageSpec(size, size, 3, "float")
    spec.attribute("compression", "zip")
    out = oiio.ImageOutput.create(str(path))
    out.open(str(path), spec)
    rng = np.random.default_rng(0)
    for y in range(0, size, band):
        rows = min(band, size - y)
        out.write_scanlines(y, y + rows, 0, rng.uniform(0.05, 0.95, (rows, size, 3)).astype(np.float32))
    out.close()


def peak_rss_mib():
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--size", type=int, default=8192)
    ap.add_argument("--max-memory", type=int, default=256 << 20)
    ap.add_argument("--dir", default=None, help="work folder (default: a temporary one)")
    ap.add_argument("--device", help="OpenCL device (as `bdipole-cl --device`); default: automatic")
    args = ap.parse_args(argv)
    if args.device:
        use_device(args.device)
    rt = get_runtime()
    print(f"device: {rt.describe()}")
    work = Path(args.dir or tempfile.mkdtemp(prefix="bdipole_bench_"))
    work.mkdir(parents=True, exist_ok=True)
    src = work / "albedo.exr"
    t0 = time.perf_counter()
    make_exr(src, args.size)
    print(f"wrote {src} ({args.size}x{args.size} RGB float, zip) in {time.perf_counter() - t0:.1f} s;"
          f" peak RSS so far {peak_rss_mib():.0f} MiB")
    texels = args.size * args.size
    t0 = time.perf_counter()
    report = process_textures(src, mfp=1.0, eta=1.4, output=str(work / "coeffs.exr"),
                              max_memory=args.max_memory)
    e2e = time.perf_counter() - t0
    assert report.ok, report.summary()
    peak = peak_rss_mib()
    # the kernel alone on one band's worth of values, scaled to the image
    n = min(3 * texels, 1 << 24)
    import pyopencl as cl
    rd = inversion_workload(n)
    k = InversionKernel((1.4,), MethodConfig("table"))
    mf = cl.mem_flags
    rd_buf = cl.Buffer(rt.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=rd)
    mfp_buf = cl.Buffer(rt.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=np.ones_like(rd))
    sa, ss = (cl.Buffer(rt.context, mf.WRITE_ONLY, rd.nbytes) for _ in range(2))
    t_kernel = median_time(lambda: k(n, rd_buf, mfp_buf, sigma_a=sa, sigma_s=ss), 3)
    kernel_rate = n / 3 / t_kernel / 1e6
    print(f"end to end (read + decode + invert + write sigma_a, sigma_s'): {e2e:.1f} s, "
          f"{texels / e2e / 1e6:.2f} Mtexel/s (RGB texels)")
    print(f"inversion kernel alone (same outputs): {kernel_rate:.1f} Mtexel/s (RGB texels); "
          f"end to end is {kernel_rate / (texels / e2e / 1e6):.1f}x slower")
    print(f"peak host memory (RSS) during the run: {peak:.0f} MiB "
          f"(--max-memory {args.max_memory >> 20} MiB; input {texels * 12 >> 20} MiB as float)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
