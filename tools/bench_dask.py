#!/usr/bin/env python3
"""Beyond one machine, measured on this one: a 16-tile scene bake in-process against a Dask
LocalCluster, and a huge file-to-file blur on the cluster with a memory limit per worker.

    python tools/bench_dask.py                      # 16 tiles of 1024^2; a 16384^2 RGB blur
    python tools/bench_dask.py --tile 512 --blur 4096
"""
import argparse
import resource
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import OpenImageIO as oiio

from bdipole_cl import dask as bdask
from bdipole_cl.cluster import connect
from bdipole_cl import get_runtime
from bdipole_cl import scene as scenes

SCENE = """
[defaults]
eta = 1.4
tol = 1e-4
[[material]]
name = "skin"
albedo = "tex/skin.<UDIM>.exr"
mfp = [1.2, 0.6, 0.3]
outputs = ["sigma_a", "sigma_s"]
output = "out/skin.<UDIM>.exr"
mask = "alpha"
"""


def write_rows(path, width, height, channels, rows_fn, band=1024):
    spec = oiio.ImageSpec(width, height, len(channels), "float")
    spec.channelnames = tuple(channels)
    spec.attribute("compression", "zip")
    out = oiio.ImageOutput.create(str(path))
    out.open(str(path), spec)
    for y0 in range(0, height, band):
        y1 = min(y0 + band, height)
        out.write_scanlines(y0, y1, 0, np.ascontiguousarray(rows_fn(y0, y1), np.float32))
    out.close()


def make_tiles(root, n, size):
    (root / "tex").mkdir(parents=True)
    yy, xx = np.mgrid[0:size, 0:size] / size
    for k in range(n):
        disc = ((xx - 0.5) ** 2 + (yy - 0.5) ** 2 < 0.15).astype(np.float32)
        rgb = np.stack([0.5 + 0.3 * xx, 0.3 + 0.2 * yy, 0.2 + 0.01 * k + 0 * xx], -1)
        rgb = np.where(disc[..., None] > 0, rgb, 1.0)
        px = np.concatenate([rgb, disc[..., None]], -1)
        write_rows(root / "tex" / f"skin.{1001 + k}.exr", size, size, "RGBA",
                   lambda y0, y1: px[y0:y1])
    (root / "scene.toml").write_text(SCENE)


def peak_rss_mib():
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--tiles", type=int, default=16)
    ap.add_argument("--tile", type=int, default=1024)
    ap.add_argument("--blur", type=int, default=16384, help="side of the blurred map")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--worker-memory", default="1GiB")
    args = ap.parse_args(argv)
    print(f"device: {get_runtime().describe()}")
    root = Path(tempfile.mkdtemp(prefix="bdipole_dask_"))
    try:
        make_tiles(root, args.tiles, args.tile)
        scenes.load(root / "scene.toml").plan().run()          # warm: kernels built
        shutil.rmtree(root / "out")
        t0 = time.perf_counter()
        assert scenes.load(root / "scene.toml").plan().run().exit_code == 0
        t_local = time.perf_counter() - t0
        shutil.rmtree(root / "out")
        with connect(f"local:{args.workers}", memory_limit=args.worker_memory) as client:
            client.run(lambda: get_runtime().describe())        # each worker opens its device
            t0 = time.perf_counter()
            report = bdask.bake_on_cluster(scenes.load(root / "scene.toml").plan(), client,
                                           progress=False)
            t_cluster = time.perf_counter() - t0
            assert report.exit_code == 0, report.summary()
            print(f"{args.tiles}-tile bake ({args.tile}^2 RGB + alpha): in-process "
                  f"{t_local:.1f} s, local:{args.workers} {t_cluster:.1f} s "
                  f"({t_local / t_cluster:.2f}x)")
            side = args.blur
            src = root / "huge.exr"
            t0 = time.perf_counter()
            write_rows(src, side, side, "RGB", lambda y0, y1: np.where(
                (np.arange(y0, y1)[:, None, None] % 512 < 8), np.float32(4.0),
                np.float32(0.05)) * np.ones((1, side, 3), np.float32))
            print(f"wrote a {side}^2 RGB float input in {time.perf_counter() - t0:.1f} s "
                  f"({src.stat().st_size / 2**20:.0f} MiB zip)")
            t0 = time.perf_counter()
            n = bdask.blur_file_on_cluster(src, root / "huge_sss.exr", client,
                                           max_memory=256 << 20, progress=False,
                                           albedo=(0.8, 0.6, 0.4), mfp=(4.0, 2.0, 1.0),
                                           eta=1.4, texel_size=1.0)
            t_blur = time.perf_counter() - t0
            peaks = client.run(peak_rss_mib)
            print(f"{side}^2 RGB blur file to file on local:{args.workers} (workers limited to "
                  f"{args.worker_memory}, bands of 256 MiB working set): {t_blur:.1f} s, "
                  f"{n} bands; peak RSS per worker: "
                  + ", ".join(f"{v:.0f} MiB" for v in peaks.values())
                  + f"; this process {peak_rss_mib():.0f} MiB")
    finally:
        shutil.rmtree(root, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
