#!/usr/bin/env python3
"""Blur benchmark: a 2048x2048 RGB irradiance map, mfp of 1, 4 and 16 texels, every method, in
one run on the current device. For each: median time, max error against the exact discrete
convolution (the exact texel-integrated weights by float64 FFT), relative to max(E) * Rd, and
the speed ratio against two peers timed in the same run:

- ``scipy fft``: the exact reference itself, ``scipy.signal.fftconvolve`` in float64 of the
  edge-padded map with the exact weights (what the error is measured against);
- ``f32 one-liner``: what a user would write, ``fftconvolve(E[..., c], K_c, mode="same")`` in
  float32 per channel, K_c the blur's own truncated kernel (the default blur's impulse
  response, cropped to the radius ``return_info`` reports: the exact weights at the
  truncation its plan chose; zero border). Its time is the
  one the blur's speed goal is measured against ("x f32" column: its time / the method's).

Times are the best of --repeats (the machine may be shared: the fastest repeat is the least
disturbed one). The last lines sum up the goals in the same run: the constant default (``auto``)
against the float32 one-liner (goal: >= 2x faster) and the texture-varying default against the
constant one (goal: <= 2x its time), each as the median ratio of --pairs alternated runs of
its two sides (a pair is timed back to back, so a slow moment of a shared machine slows both
of its sides rather than one side of the comparison), with the range of the pairs' ratios.

Texture-varying parameters (``--varying``, on by default): albedo = the constant albedo times
(1 + 0.2 n(x)) and mfp = mfp * 2^(n(x)/2), n a smooth pattern in [-1, 1]. Printed: the cold
time (first call: the plan's exact node kernels and fits), the median warm time (plans and
their kernel spectra cached per parameter set: the same maps blurred again), the ratio of the
warm time to the constant default in the same run, the warm time with the spectra recomputed
each call, and the max error at sampled texels against their own exact kernels (per-exit-texel
reference).

``--device-arrays`` also times ``auto`` with the map and the exitance as device arrays
(device to device) and host to host, beside CuPy's ``cupyx.scipy.signal.fftconvolve`` of the
same map and kernels, device-only and host to host, where CuPy is installed (the GPU goals;
``tools/gpu_check.sh``).

``--gather`` measures instead the texture-varying gather's costs on the device
(``near_field.GatherCosts``, what chooses the near field): for each near field radius, the
gather's time and the basis blurs' per kernel on the varying workload at mfp 4, and the
least-squares costs per near cell, per near kernel and class, and per table weight, in units
of one basis blur (``dispatch.GATHER_COSTS`` holds the figures for the runtimes measured).

    python tools/bench_blur.py
    python tools/bench_blur.py --size 1024 --mfp 1 4 --tol 1e-3
    python tools/bench_blur.py --gather --device 1:0
    python tools/bench_blur.py --stretch --device intel

``--stretch`` measures instead the stretched blur (docs/stretch.md) against the texture-varying
blur of the same map in the same run (goal: <= 2x its time): the texture-varying workload's
albedo and mfp maps (mfp in mm, texel 1 mm for the texture-varying side), and two stretch
maps: a smooth one (each axis 2^(+-0.25 p(x)) mm a texel: aspect 0.71..1.41, no charts) and a
USD cylinder's (two UV charts of different stretch, aspect 1.3 and 2.5, charts kept apart);
and, where Blender's ``bpy`` is installed, a head's: Blender's Suzanne subdivided twice,
unwrapped as an artist would (smart UV project at 66 degrees, its islands' seams, ABF, packed:
64 charts, aspect within 4% on 98% of its texels), scaled to a median texel of 1 mm at 2048,
blurred with its charts kept apart and again with ``charts="none"`` (one window, as the
texture-varying side: the ratio without the chart windows' FFT area); warm times (plans and spectra cached), median of --pairs alternated pairs.
"""
import argparse
import sys
import time
import warnings

import numpy as np
from scipy.signal import fftconvolve

from bdipole_cl import get_runtime, use_device
from bdipole_cl.apps.benchmark import hdr_irradiance, machine_lines, varying_workload
from bdipole_cl.ops.blur import blur, channel_kernel, channel_parameters
from bdipole_cl.ops.blur.fft import SPECTRA_CACHE
from bdipole_cl.ops.blur.planning import BlurAccuracyWarning

ALBEDO = (0.8, 0.6, 0.4)


def timed(fn, repeats, stat=min):
    times, out = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return stat(times), out


def paired_ratio(slow, fast, pairs):
    """The median over ``pairs`` alternated runs of slow()'s time / fast()'s (each pair timed
    back to back, so a disturbance of the shared machine hits both sides of a pair, not one
    side of the whole comparison), and the pairs' (min, max) ratio. Each side runs once
    untimed first: both are compared warm (the varying rows clear the spectra cache, which
    holds the constant kernels' spectra too)."""
    slow(), fast()
    ratios = []
    for _ in range(pairs):
        t_slow, _ = timed(slow, 1)
        t_fast, _ = timed(fast, 1)
        ratios.append(t_slow / t_fast)
    return float(np.median(ratios)), (min(ratios), max(ratios))


def impulse_responses(mfp, tol):
    """The default blur's own kernels, exactly: its response to a unit impulse, which for each
    channel is the exact weights at the truncation its plan chose (``return_info``: auto may
    pick a tighter one than tol's), float32, (2R+1)^2, R the radius BlurInfo reports (taken
    from the weights, not from an impulse blurred by the library: that would carry the blur's
    own float32 round-off into the peer)."""
    _, info = blur(np.zeros((1, 1, 3), np.float32), albedo=ALBEDO, mfp=mfp, eta=1.4, tol=tol,
                   return_info=True)
    params = channel_parameters(3, albedo=ALBEDO, mfp=mfp, eta=1.4)
    kernels = []
    for c, p in zip(info.channels, params):
        used = c.auto.truncation_tol if c.auto is not None else tol
        ck = channel_kernel(*p, used)
        assert ck.radius == c.radius, (c, ck.radius)
        kernels.append(ck.weights.astype(np.float32))
    return kernels


def one_liner(e, kernels):
    """What a user would write: float32 fftconvolve per channel, mode="same"."""
    return np.stack([fftconvolve(e[..., c], kernels[c], mode="same") for c in range(3)], axis=-1)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--size", type=int, default=2048)
    ap.add_argument("--mfp", type=float, nargs="+", default=[1.0, 4.0, 16.0])
    ap.add_argument("--tol", type=float, default=1e-3)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--methods", nargs="+", default=["auto", "direct", "gaussians", "fft"])
    ap.add_argument("--varying-methods", nargs="*", default=["auto"],
                    help="methods for texture-varying parameters (none: skip)")
    ap.add_argument("--pairs", type=int, default=5,
                    help="alternated runs of each goal's two sides (their median ratio)")
    ap.add_argument("--samples", type=int, default=48, help="texels checked per channel")
    ap.add_argument("--device", help="OpenCL device (as `bdipole-cl --device`); default: automatic")
    ap.add_argument("--device-arrays", action="store_true",
                    help="also time auto with device arrays in and out, and CuPy's "
                         "fftconvolve where CuPy is installed (the GPU goals)")
    ap.add_argument("--gather", action="store_true",
                    help="measure the texture-varying gather's costs per near field radius")
    ap.add_argument("--stretch", action="store_true",
                    help="the stretched blur against the texture-varying one (docs/stretch.md)")
    args = ap.parse_args(argv)
    if "auto" not in args.methods:
        ap.error("--methods: the ratios are to auto's time; include auto")
    if args.device:
        use_device(args.device)
    print("\n".join(machine_lines(get_runtime())))
    if args.gather:
        return gather_costs(args)
    if args.stretch:
        return stretch_rows(args)
    e = hdr_irradiance(args.size)                         # with a few HDR highlights
    print(f"input {args.size}x{args.size} RGB, albedo {ALBEDO}, eta 1.4, tol {args.tol}, "
          f"border clamp; error = max|M - exact| / (max E * Rd)")
    print(f"{'mfp':>5s} {'method':10s} {'radius':>6s} {'s':>8s} {'max err':>9s} "
          f"{'x scipy fft':>11s} {'x f32':>6s}")
    summary = []
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
        peer_k = impulse_responses(mfp, args.tol)
        t_peer, peer = timed(lambda: one_liner(e, peer_k), args.repeats)
        print(f"{mfp:5g} {'scipy fft':10s} {k:6d} {t_ref:8.2f} {'(exact)':>9s} {1.0:11.2f} "
              f"{t_peer / t_ref:6.2f}")
        peer_err = (np.abs(peer - exact)[k:-k or None, k:-k or None].max(axis=(0, 1))
                    / norm).max()
        print(f"{mfp:5g} {'f32 1-line':10s} {max(len(w) // 2 for w in peer_k):6d} "
              f"{t_peer:8.2f} {peer_err:9.1e} {t_ref / t_peer:11.2f} {1.0:6.2f}   "
              f"(error away from the border)")
        for m in args.methods:
            blur(e[:64, :64], albedo=ALBEDO, mfp=mfp, eta=1.4, tol=args.tol, method=m)  # warm
            t, out = timed(lambda: blur(e, albedo=ALBEDO, mfp=mfp, eta=1.4, tol=args.tol,
                                        method=m), args.repeats)
            err = (np.abs(out - exact).max(axis=(0, 1)) / norm).max()
            print(f"{mfp:5g} {m:10s} {k:6d} {t:8.2f} {err:9.1e} {t_ref / t:11.2f} "
                  f"{t_peer / t:6.2f}")
            if m == "auto":
                t_const = t
        def constant_auto():
            return blur(e, albedo=ALBEDO, mfp=mfp, eta=1.4, tol=args.tol)
        vs_peer = paired_ratio(lambda: one_liner(e, peer_k), constant_auto, args.pairs)
        t_vary = varying_rows(e, mfp, t_const, args) if args.varying_methods else None
        vs_vary = None
        if t_vary is not None:
            albedo, mfps = varying_maps(e.shape[0], mfp)
            vs_vary = paired_ratio(lambda: blur(e, albedo=albedo, mfp=mfps, eta=1.4,
                                                tol=args.tol), constant_auto, args.pairs)
        summary.append((mfp, t_peer, t_const, t_vary, vs_peer, vs_vary))
        if args.device_arrays:
            device_rows(e, mfp, args)
    print_summary(summary, args.pairs)
    return 0


def _synced(fn):
    """fn(), its device arrays finished (their events waited for)."""
    out = fn()
    for a in out if isinstance(out, (tuple, list)) else (out,):
        if hasattr(a, "finish"):
            a.finish()
    return out


def cupy_peers(e, kernels, repeats):
    """(device-only, host-to-host) seconds of CuPy's ``cupyx.scipy.signal.fftconvolve`` of the
    map with the blur's kernels (``mode="same"``), the peer a GPU user would write; None where
    CuPy is not installed (it is no dependency: ``tools/gpu_check.sh`` runs it where it is)."""
    try:
        import cupy as cp
        from cupyx.scipy.signal import fftconvolve as cfft
    except ImportError:
        return None
    ks = [cp.asarray(k) for k in kernels]
    e_dev = cp.asarray(e)

    def device_only():
        out = [cfft(e_dev[..., c], ks[c], mode="same") for c in range(3)]
        cp.cuda.runtime.deviceSynchronize()
        return out

    def host_to_host():
        d = cp.asarray(e)
        return cp.stack([cfft(d[..., c], ks[c], mode="same") for c in range(3)], -1).get()
    device_only(), host_to_host()
    return timed(device_only, repeats)[0], timed(host_to_host, repeats)[0]


def device_rows(e, mfp, args):
    """``auto`` with the map as a device array (the exitance one too: device to device) and
    host to host, beside CuPy's fftconvolve of the same map and kernels (the GPU goals: host
    to host faster than CuPy's, device to device within 2x of CuPy's device-only time)."""
    import pyopencl.array as cla
    rt = get_runtime()
    e_dev = cla.to_device(rt.queue, e)

    def on_device():
        return _synced(lambda: blur(e_dev, albedo=ALBEDO, mfp=mfp, eta=1.4, tol=args.tol))
    on_device()
    t_dev, _ = timed(on_device, args.repeats)
    t_host, _ = timed(lambda: blur(e, albedo=ALBEDO, mfp=mfp, eta=1.4, tol=args.tol),
                      args.repeats)
    line = (f"{mfp:5g} device arrays: auto device to device {t_dev * 1e3:8.1f} ms, host to "
            f"host {t_host * 1e3:8.1f} ms")
    peers = cupy_peers(e, impulse_responses(mfp, args.tol), args.repeats)
    if peers is None:
        print(line + "; CuPy not installed here: its peers not measured")
        return
    t_cd, t_ch = peers
    print(line + f"; CuPy fftconvolve device-only {t_cd * 1e3:.1f} ms, host to host "
          f"{t_ch * 1e3:.1f} ms: device to device {t_dev / t_cd:.2f}x CuPy's (goal <= 2), "
          f"host to host {t_ch / t_host:.2f}x CuPy's speed (goal > 1)")


def print_summary(summary, pairs):
    """The goals, from this run: auto against the float32 one-liner, the varying auto against
    the constant one; each the median ratio of alternated pairs (``paired_ratio``), with the
    best-of times beside it."""
    print(f"summary (this run; ratios: median of {pairs} alternated pairs [min, max]):")
    print("  mfp   f32 one-liner / constant auto (goal >= 2)   "
          "varying auto / constant auto, warm (goal <= 2)")
    for mfp, t_peer, t_const, t_vary, (r, (lo, hi)), vary in summary:
        line = (f"  {mfp:<5g} {r:5.2f}x [{lo:.2f}, {hi:.2f}]  ({t_peer:.3f} s / {t_const:.3f} s "
                f"best)")
        if vary is not None:
            vr, (vlo, vhi) = vary
            line += (f"     {vr:5.2f}x [{vlo:.2f}, {vhi:.2f}]  ({t_vary:.3f} s / "
                     f"{t_const:.3f} s best)")
        print(line)


def varying_maps(n, mfp):
    """The texture-varying maps (``apps.benchmark.varying_workload``: albedo ALBEDO x (1 + 0.2
    p(x)), mfp x 2^(p(x)/2))."""
    return varying_workload(n, mfp)[1:]


def sampled_error(e, out, albedo, mfp, info, samples, rng):
    """max |M - exact| / (max E * Rd(x)) over sampled texels, the exact value from the texel's
    own exact kernel at the plan's radius (float64)."""
    from bdipole_cl.ops.blur.textured_plan import RD_MAX, RD_MIN, node_kernel
    from bdipole_cl.ops.blur.weights import unfold_quadrant
    h, w, nch = e.shape
    worst = 0.0
    for c in range(nch):
        k = info.channels[c].radius
        for y, x in zip(rng.integers(0, h, samples), rng.integers(0, w, samples)):
            rd = float(albedo[y, x, c])
            ld = float(mfp[y, x] if mfp.ndim == 2 else mfp[y, x, c])
            q = node_kernel(float(np.clip(rd, RD_MIN, RD_MAX)), ld, 1.4, k)
            ys = np.clip(np.arange(y - k, y + k + 1), 0, h - 1)
            xs = np.clip(np.arange(x - k, x + k + 1), 0, w - 1)
            want = (e[np.ix_(ys, xs, [c])][..., 0].astype(np.float64)
                    * unfold_quadrant(q)).sum() * rd
            worst = max(worst, abs(out[y, x, c] - want) / (e[..., c].max() * rd))
    return worst


def varying_rows(e, mfp, t_const, args):
    """The texture-varying rows; returns the warm time of ``auto`` (None if not run)."""
    albedo, mfps = varying_maps(e.shape[0], mfp)
    t_auto = None
    rng = np.random.default_rng(1)
    for m in args.varying_methods:
        def run():
            return blur(e, albedo=albedo, mfp=mfps, eta=1.4, tol=args.tol, method=m,
                        return_info=True)
        t0 = time.perf_counter()
        run()
        cold = time.perf_counter() - t0
        t, (out, info) = timed(run, args.repeats)
        t_nospec, _ = timed(lambda: (SPECTRA_CACHE.clear(), run()), args.repeats)
        err = sampled_error(e, out, albedo, mfps, info, args.samples, rng)
        k = max(c.radius for c in info.channels)
        basis = "/".join(str(c.method.split(", ")[1].split()[0]) for c in info.channels)
        print(f"{mfp:5g} {'varying ' + m:10s} {k:6d} {t:8.2f} {err:9.1e} "
              f"{'':11s} cold {cold:.2f} s, {t / t_const:.2f}x the constant default, "
              f"without the spectra cache {t_nospec:.2f} s ({t_nospec / t_const:.2f}x), "
              f"basis {basis}, bound {max(c.error_bound for c in info.channels):.1e}")
        if m == "auto":
            t_auto = t
    return t_auto


def gather_costs(args):
    """The gather's time per near field radius on the varying workload at mfp 4 (channel 0),
    the basis blurs' time per kernel, and the least-squares GatherCosts in basis blurs
    (``apps.benchmark.gather_rows``, what ``report --calibrate`` measures)."""
    from bdipole_cl.apps.benchmark import fitted_gather_costs, gather_rows
    print(f"{'near':>4s} {'G':>3s} {'M':>3s} {'cells':>5s} {'terms':>5s} {'weights':>7s} "
          f"{'gather ms':>9s}")
    rows, per_blur = gather_rows(args.size, args.tol, args.repeats + 2, progress=lambda r: print(
        f"{r.near:4d} {r.nbasis:3d} {r.nnear:3d} {r.cells:5d} {r.terms:5d} "
        f"{r.nbasis + r.nnear:7d} {r.seconds * 1e3:9.1f}"))
    (cell, term, weight), fixed = fitted_gather_costs(rows, per_blur)
    print(f"a basis blur: {per_blur * 1e3:.1f} ms; GatherCosts(cell={cell:.2g}, term={term:.2g}, "
          f"weight={weight:.2g}) (gather's fixed part {fixed * 1e3:.1f} ms)")
    return 0



#: Blender's head, as ``stretch_maps_of("head")`` makes it (in a child process: bpy brings
#: its own OpenImageIO and USD libraries)
BLENDER_HEAD = """
import math, sys, bpy
bpy.ops.wm.read_factory_settings(use_empty=True)
bpy.ops.mesh.primitive_monkey_add(size=2.0, calc_uvs=True)
head = bpy.context.active_object
sub = head.modifiers.new("subdivision", "SUBSURF")
sub.levels = 2
bpy.ops.object.modifier_apply(modifier=sub.name)
bpy.ops.object.mode_set(mode="EDIT")
bpy.ops.mesh.select_all(action="SELECT")
bpy.ops.uv.smart_project(angle_limit=math.radians(66), island_margin=0.01)
bpy.ops.uv.seams_from_islands()
bpy.ops.uv.unwrap(method="ANGLE_BASED", margin=0.01)
bpy.ops.uv.pack_islands(margin=0.01)
bpy.ops.object.mode_set(mode="OBJECT")
bpy.ops.wm.obj_export(filepath=sys.argv[1], export_materials=False, export_normals=False)
"""


def blender_head(n):
    """The StretchTile of ``BLENDER_HEAD`` at n texels, scaled to a median texel (over its
    covered texels, sqrt(s_u s_v)) of 2048 / n mm; None where bpy is not installed."""
    import subprocess
    import tempfile
    from pathlib import Path
    from dataclasses import replace
    from bdipole_cl.io.stretch_maps import stretch_maps
    with tempfile.TemporaryDirectory() as d:
        obj = Path(d) / "head.obj"
        made = subprocess.run([sys.executable, "-c", BLENDER_HEAD, str(obj)],
                              capture_output=True, text=True)
        if made.returncode != 0 or not obj.exists():
            return None
        (tile, _), = stretch_maps(obj, size=n)
    median = float(np.median(np.sqrt(tile.su * tile.sv)[tile.covered])) * n / 2048
    return replace(tile, su=tile.su / np.float32(median), sv=tile.sv / np.float32(median))


def stretch_maps_of(n, kind):
    """A (su, sv) pair or a StretchTile for ``--stretch``: "smooth" (each axis 2^(+-0.25 p),
    p smooth patterns in [-1, 1]), "cylinder" (a USD cylinder's two charts) or "head"
    (``blender_head``: None without bpy)."""
    if kind == "head":
        return blender_head(n)
    if kind == "smooth":
        yy, xx = np.mgrid[0:n, 0:n] / n
        p = np.sin(2 * np.pi * (2 * xx + yy))
        q = np.cos(2 * np.pi * (xx - 2 * yy))
        return ((2.0 ** (0.25 * p)).astype(np.float32), (2.0 ** (0.25 * q)).astype(np.float32))
    import tempfile
    from pathlib import Path
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
    from stretch_meshes import cylinder_stage
    from bdipole_cl.io.stretch_maps import stretch_maps
    with tempfile.TemporaryDirectory() as d:
        # radius 320 mm, 1600 mm high: texels of ~1 mm along v and in chart 0 along u, ~2 mm
        # along u in chart 1 at 2048 (as the texture-varying side's 1 mm)
        (tile, _), = stretch_maps(cylinder_stage(Path(d) / "c.usda", radius=320.0 * n / 2048,
                                                 height=1600.0 * n / 2048), size=n)
    return tile


def stretch_rows(args):
    """The stretched blur against the texture-varying blur of the same maps (``--stretch``)."""
    layouts = {}
    for mfp in args.mfp:
        e, albedo, mfps = varying_workload(args.size, mfp)
        def varying():
            return blur(e, albedo=albedo, mfp=mfps, eta=1.4, tol=args.tol)
        t_vary, _ = timed(varying, args.repeats)
        # the head also without its charts (one window, as the texture-varying side): the
        # ratio's part that is the rank's, apart from the chart windows' FFT area
        for kind, charts in (("smooth", "clamp"), ("cylinder", "clamp"), ("head", "clamp"),
                             ("head", "none")):
            if kind not in layouts:
                layouts[kind] = stretch_maps_of(args.size, kind)
            s = layouts[kind]
            if s is None:
                print(f"mfp {mfp:g}: stretch {kind}: not measured (it needs Blender's bpy: "
                      f"pyproject.toml's renderers extra)")
                continue
            def stretched():
                with warnings.catch_warnings():    # the bound is printed below
                    warnings.simplefilter("ignore", BlurAccuracyWarning)
                    return blur(e, albedo=albedo, mfp=mfps, eta=1.4, tol=args.tol,
                                stretch=s, charts=charts, return_info=True)
            t0 = time.perf_counter()
            _, info = stretched()
            cold = time.perf_counter() - t0
            t_s, _ = timed(stretched, args.repeats)
            r, (lo, hi) = paired_ratio(stretched, varying, args.pairs)
            ranks = "; ".join(c.method[c.method.index("stretched, ") + 11:-1]
                              for c in info.channels)
            name = kind if charts == "clamp" else f"{kind}, charts {charts}"
            print(f"mfp {mfp:g}: stretch {name:8s}: cold {cold:6.2f} s, warm {t_s:6.2f} s; "
                  f"texture-varying {t_vary:6.2f} s; stretched / texture-varying {r:5.2f}x "
                  f"[{lo:.2f}, {hi:.2f}] (goal <= 2); eigen-kernels {ranks}; bound "
                  f"{max(c.error_bound for c in info.channels):.1e}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
