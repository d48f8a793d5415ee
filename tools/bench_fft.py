#!/usr/bin/env python3
"""Device FFT benchmark: a batched 2D real FFT round trip (forward, then inverse) of 3 float32
planes at 2048^2 and 4320^2 (``--sizes``), timed on the device in use for

- ``bdipole_cl``: ``ops.device_fft.DeviceFFT`` (kernels/fft.cl), data on the device;
- ``reikna``: reikna's FFT through pyopencl on the same queue, data on the device. reikna has
  no real transform: its complex FFT of the planes as complex numbers (twice the points; what
  its user would write). Where reikna is not installed or fails on the device, the line says
  why;
- ``scipy``: ``scipy.fft.rfft2`` then ``irfft2`` on the host, all cores (``workers=-1``), data
  in host memory.

Each line: the best of --repeats round trips (the machine may be shared: the fastest repeat
is the least disturbed one; the three are timed in turn within each repeat, so a slow moment
slows all of them; a peer whose timed calls passed --budget seconds is not repeated, and its
line says of how many), the speed ratio of each peer's time to bdipole_cl's (``peer / ours``: above
1, ours is faster) and the round trip's error against numpy's float64 FFTs of the same input
(relative L2 over the whole batch; docs/device_fft.md bounds ours). The first lines name the
CPU, the OpenCL device and driver.

    python tools/bench_fft.py
    python tools/bench_fft.py --device pocl --sizes 1024 2048 --repeats 3
"""
import argparse
import time
import warnings

import numpy as np
import pyopencl as cl
import pyopencl.array as cla

from bdipole_cl import get_runtime
from bdipole_cl.apps.benchmark import machine_lines
from bdipole_cl.ops.device_fft import DeviceFFT

PLANES = 3


def best_times(fns, repeats, budget):
    """{name: (best wall time, repeats timed)} of each fn() (which finishes its own work), in
    turn per repeat, after one untimed call each (builds, plans, caches). A peer stops once
    its timed calls have taken ``budget`` seconds (at least one is timed)."""
    spent = {}
    for name, fn in fns.items():
        t0 = time.perf_counter()
        fn()
        spent[name] = time.perf_counter() - t0
    best, count = dict.fromkeys(fns, np.inf), dict.fromkeys(fns, 0)
    for _ in range(repeats):
        for name, fn in fns.items():
            if count[name] and spent[name] > budget:
                continue
            t0 = time.perf_counter()
            fn()
            took = time.perf_counter() - t0
            best[name], count[name] = min(best[name], took), count[name] + 1
            spent[name] += took
    return {name: (best[name], count[name]) for name in fns}


def rel_l2(got, want) -> float:
    got, want = np.asarray(got, np.float64), np.asarray(want, np.float64)
    return float(np.linalg.norm(got - want) / np.linalg.norm(want))


def ours(rt, x):
    """(round trip, its result getter) of DeviceFFT on device copies of the planes x."""
    plan = DeviceFFT(rt, x.shape[1:], x.shape[0])
    src = cla.to_device(rt.queue, x)
    spec = cla.empty(rt.queue, plan.spectrum_shape, plan.complex_dtype)
    back = cla.empty_like(src)

    def run():
        plan.forward(src, spec)
        plan.inverse(spec, back).wait()
    return run, back.get


def reikna_peer(rt, x):
    """(round trip, result getter) of reikna's complex FFT of the planes, or a reason string
    where reikna is missing or fails here."""
    try:
        from reikna.cluda import ocl_api
        from reikna.fft import FFT
    except ImportError as exc:
        return f"not installed ({exc}); `pip install reikna` to compare"
    try:
        thr = ocl_api().Thread(rt.queue)
        xc = x.astype(np.complex64)
        with warnings.catch_warnings():      # its builds' logs: normal on Intel's runtime
            warnings.simplefilter("ignore", cl.CompilerWarning)
            fft = FFT(xc, axes=(1, 2)).compile(thr)
        src = thr.to_device(xc)
        spec, back = thr.empty_like(src), thr.empty_like(src)

        def run():
            fft(spec, src, inverse=0)
            fft(back, spec, inverse=1)
            thr.synchronize()
        run()
        return run, lambda: back.get().real
    except Exception as exc:            # any failure of a third-party library: said, not fatal
        return f"failed on this device: {type(exc).__name__}: {str(exc).splitlines()[0][:200]}"


def scipy_peer(x):
    import scipy.fft as sfft
    out = {}

    def run():
        spec = sfft.rfft2(x, workers=-1)
        out["back"] = sfft.irfft2(spec, x.shape[1:], workers=-1)
    return run, lambda: out["back"]


def bench_size(rt, n, repeats, budget):
    x = np.random.default_rng(n).standard_normal((PLANES, n, n)).astype(np.float32)
    peers = {"bdipole_cl": ours(rt, x), "reikna": reikna_peer(rt, x), "scipy": scipy_peer(x)}
    failed = {k: v for k, v in peers.items() if isinstance(v, str)}
    timed = {k: v for k, v in peers.items() if k not in failed}
    best = best_times({k: v[0] for k, v in timed.items()}, repeats, budget)
    # the round trip's reference: numpy's float64 transforms of the same float32 input
    want = np.fft.irfft2(np.fft.rfft2(x.astype(np.float64)), x.shape[1:])
    print(f"{PLANES} x {n}^2 float32 planes, round trip (forward + inverse), best of "
          f"{repeats} (fewer where a peer's took {budget:g} s):")
    for name, (_, result) in timed.items():
        seconds, count = best[name]
        ratio = seconds / best["bdipole_cl"][0]
        print(f"  {name:11s} {seconds * 1e3:9.1f} ms   peer/ours {ratio:5.2f}   "
              f"error {rel_l2(result(), want):.1e}"
              + (f"   (best of {count})" if count < repeats else ""))
    for name, why in failed.items():
        print(f"  {name:11s} {why}")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[2048, 4320],
                    help="plane sizes N (N x N; default 2048 4320)")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--budget", type=float, default=60.0,
                    help="seconds of timed calls after which a peer is not repeated "
                         "(default 60: reikna's non-power-of-two sizes on a CPU)")
    ap.add_argument("--device", help="OpenCL device (as `bdipole-cl --device`); default: "
                                     "automatic")
    args = ap.parse_args(argv)
    rt = get_runtime(args.device)
    for line in machine_lines(rt):
        print(line)
    print("  (data on the device for bdipole_cl and reikna; scipy on the host's cores)")
    for n in args.sizes:
        bench_size(rt, n, args.repeats, args.budget)


if __name__ == "__main__":
    main()
