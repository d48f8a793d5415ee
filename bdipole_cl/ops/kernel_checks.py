"""Every kernel configuration the library may pick, built and run on one device: the probe's
child process (``bdipole_cl.device.isolation``), ``python -m bdipole_cl.ops.kernel_checks
--device P:D [--skip NAME,...]``.

Each check builds its configuration through the library's own code (so the programs are the
ones later built, and a runtime's on-disk kernel cache is warm for them), runs it on a small
input and compares with the float64 reference loosely: the probe asks whether the runtime
builds and runs the kernel, the crosscheck and the tests ask how accurately. Then what differs
between CPUs is timed: each width that passed (``ops.widths`` picks the fastest for
``ops.inversion_kernel.table_width`` and ``ops.blur.dispatch.gather_width``) and each blur
method at each radius of the shipped choice data (``ops.blur.planning.auto_data`` rescales
those data's timings with them, so ``auto``'s crossovers are this device's).

First of all the vector ABI is checked (``vector_abi_reason``): where the compiler would pass
16 (or 8) floats to its built-ins otherwise than they take them, no configuration that wide is
built at all (each is rejected unbuilt), and the table records' chunks stay within the cap
(``ops.widths.vector_cap``).

Output: one JSON line ``{"begin": NAME}`` before a check and ``{"end": NAME, "ok": ..., "reason":
...}`` after it; then ``{"run": NAME}`` before each run of a workload timed (``timed_runs``: the
widths, the blur's methods: a child that dies there costs that configuration), a ``{"time":
NAME, "seconds": ...}`` line for each, and ``{"done": true}``.
"""
from __future__ import annotations

import argparse
import os
import re
import sys
import time
import uuid
from dataclasses import dataclass
from typing import Callable

import numpy as np

from ..device.children import die_with, emit, inject_fault
from ..device.faults import environment_fault, fault_words, underlying
from ..device.isolation import EXIT, VECTOR_ABI, VECTOR_ABI_WIDTHS, vector_cap
from ..device.runtime import forced
from .widths import (DEVICE_FFT_CONFIGS, DEVICE_FFT_TIMING, FFT_ENGINE_VARIABLE,
                     VECTOR_CAP_VARIABLE, blur_timing_name)

#: a probe's loose agreement with the float64 reference (relative, of rho and of the blur's
#: exitance): a working float32 kernel is within ~1e-5 (docs/model.md "Accuracy"); a
#: miscompiled one is off by orders of magnitude, or NaN
PROBE_RTOL = 1e-3
#: elements of the table widths' timing workload: 16 MB of float32 in, 32 MB out, enough to
#: be memory-bound as the real passes are, and a few milliseconds a run on a CPU
TIMING_N = 1 << 22


@dataclass(frozen=True)
class KernelCheck:
    """One configuration: its name (``device.isolation.config_name`` of what it builds), the
    function that builds, runs and checks it on a Runtime (returning its timing in seconds,
    or None), whether it needs float64, and its vectors' floats (0: no explicit vectors)."""

    name: str
    run: Callable
    fp64: bool = False
    width: int = 0


#: clang's warning where a vector crosses a call in another ABI than the callee's: PoCL's
#: built-in library compiled for the CPU's features, the kernel for the target its LLVM named
ABI_WARNING = re.compile(r"vector (?:argument|return) of type .*? without '[\w.+-]+' enabled "
                         r"changes the ABI")


def vector_abi_reason(rt, width: int) -> str:
    """"" where the device's compiler passes ``width``-float vectors to its built-ins as they
    take them, else one line saying it does not (its warning quoted). The kernel is built, never
    run nor asked for its binary (with the mismatch, both crash LLVM), under a new name each
    time: a runtime's kernel cache would give back the first build without its log."""
    import pyopencl as cl
    from ..device.runtime import build_quietly
    source = (f"__kernel void bd_abi_{uuid.uuid4().hex}(__global float{width} *a)\n"
              f"{{ const size_t i = get_global_id(0); a[i] = sqrt(a[i]); }}\n")
    prg = build_quietly(rt.context, source)
    log = prg.get_build_info(rt.device, cl.program_build_info.LOG) or ""
    found = ABI_WARNING.search(log)
    if found is None:
        return ""
    return (f"the compiler passes float{width} to its built-ins otherwise than they take it "
            f"(its log: {found.group(0)})")


def _assert_small(err, what):
    """A relative error within PROBE_RTOL, else the check fails naming ``what``."""
    if not np.isfinite(err) or err > PROBE_RTOL:
        raise RuntimeError(f"{what} computed wrongly (max relative error {err:.3g})")


def _assert_close(got, want, what):
    got = np.asarray(got, np.float64)
    want = np.asarray(want, np.float64)
    err = np.abs(got - want) / np.maximum(np.abs(want), 1e-30)
    worst = float(np.nanmax(err)) if err.size else 0.0
    if not np.all(np.isfinite(got)) or worst > PROBE_RTOL:
        raise RuntimeError(f"{what} computed wrongly (max relative error {worst:.3g})")


def _albedos(n, seed=0):
    """``n`` albedos over the whole range, both stiff ends first."""
    ends = np.float32([1e-6, 1e-3, 0.5, 0.9, 0.999])
    rest = np.random.default_rng(seed).random(max(n - ends.size, 0), np.float32)
    return np.concatenate([ends, rest])[:n].astype(np.float32)


def table_check(width):
    """kernels/invert_table.cl at ``width`` elements a work-item: 3 channels of albedos and
    coefficients checked."""
    def run(rt):
        from ..physics import reference as ref
        from .inversion_kernel import TABLE_WIDTH_VARIABLE
        from .invert import albedo_to_coefficients, invert_albedo
        with forced(TABLE_WIDTH_VARIABLE, width):
            rd = _albedos(3 * 4093).reshape(-1, 3)       # a count no width divides
            etas = (1.3, 1.4, 1.5)
            _alpha, rho = invert_albedo(rd, etas, return_rho=True, device=rt)
            for c, eta in enumerate(etas):
                want = ref.invert_rd_rho(rd[:, c].astype(np.float64), eta)[1]
                _assert_close(rho[:, c], want, "rho")
            valid = rd[rd[:, 1] < 1]
            sigma_a, _ = albedo_to_coefficients(valid, 0.5, etas, device=rt)
            want = ref.albedo_to_coefficients(valid[:, 1].astype(np.float64), 0.5, 1.4)[0]
            _assert_close(sigma_a[:, 1], want, "sigma_a")
        return None
    return run


def method_check(method, double):
    """kernels/invert.cl (every method but the float32 table without polish)."""
    def run(rt):
        from ..physics import reference as ref
        from .invert import invert_albedo
        rd = _albedos(1021).astype(np.float64 if double else np.float32)
        _alpha, rho = invert_albedo(rd, 1.4, method=method, return_rho=True, double=double,
                                    device=rt)
        _assert_close(rho, ref.invert_rd_rho(rd.astype(np.float64), 1.4)[1], "rho")
        return None
    return run


def physics_check(double):
    """kernels/physics_eval.cl: Rd(alpha') (the crosscheck's forward functions)."""
    def run(rt):
        from .physics_eval import evaluate, reference_value
        alpha = np.linspace(0.01, 0.999, 257)
        got = evaluate("rd", alpha, eta=1.4, double=double, device=rt)
        _assert_close(got, reference_value("rd", alpha, eta=1.4), "Rd")
        return None
    return run


def _impulse(size=48, channels=1):
    e = np.zeros((size, size, channels), np.float32)
    e[size // 2, size // 2] = 1.0
    return e


def blur_check(method):
    """kernels/blur_direct.cl (``direct``) or kernels/blur_separable.cl (``gaussians``): an
    impulse's exitance sums to Rd (the weights are renormalised to it)."""
    def run(rt):
        from .blur import blur
        out = blur(_impulse(), albedo=0.6, mfp=2.0, method=method, border="zero", tol=1e-3,
                   device=rt)
        _assert_close(out.sum(dtype=np.float64), 0.6, f"{method} blur's energy")
        return None
    return run


def device_fft_check(double):
    """kernels/fft.cl (``ops.device_fft``): a batch of two planes of a mixed-radix size,
    forward and back, against NumPy's FFT, within PROBE_RTOL of the largest value (a working
    float32 transform is within ~1e-6; a miscompiled one is off by far more)."""
    def run(rt):
        import pyopencl as cl
        from .device_fft import DeviceFFT, device_fft_len
        dtype = np.float64 if double else np.float32
        shape = (device_fft_len(30), device_fft_len(44))
        x = np.random.default_rng(4).random((2, *shape)).astype(dtype)
        fft = DeviceFFT(rt, shape, 2, double)
        mf = cl.mem_flags
        src = cl.Buffer(rt.context, mf.READ_WRITE | mf.COPY_HOST_PTR, hostbuf=x)
        spec = cl.Buffer(rt.context, mf.READ_WRITE, x.size * 2 * x.itemsize * 2)
        fft.forward(src, spec)
        got = np.empty((2, shape[0], shape[1] // 2 + 1), np.complex128 if double
                       else np.complex64)
        cl.enqueue_copy(rt.queue, got, spec)
        want = np.fft.rfft2(x.astype(np.float64))
        _assert_small(np.abs(got - want).max() / np.abs(want).max(), "forward FFT")
        fft.inverse(spec, src)
        back = np.empty_like(x)
        cl.enqueue_copy(rt.queue, back, src)
        _assert_small(np.abs(back - x).max() / np.abs(x).max(), "inverse FFT")
        return None
    return run


def blur_fft_check():
    """kernels/blur_fft.cl with the device's FFT: the FFT blur on the device is the host's
    FFT blur, within PROBE_RTOL of the peak (both float32 FFT convolutions of one kernel:
    ~1e-6 apart when they work)."""
    def run(rt):
        e = np.random.default_rng(5).random((40, 52, 2), np.float32)
        got, want = (_forced_engine_blur(e, rt, engine) for engine in ("device", "host"))
        _assert_small(np.abs(got - want).max() / np.abs(want).max(), "device FFT blur")
        return None
    return run


def _forced_engine_blur(e, rt, engine):
    from .blur import blur
    with forced(FFT_ENGINE_VARIABLE, engine):
        return blur(e, albedo=(0.6, 0.3), mfp=2.0, method="fft", border="clamp", device=rt)


def stretched_check():
    """kernels/blur_stretched.cl: a stretched blur whose texel steps are all one unit long is
    the constant blur (within 1e-2 of it: both within ~2 tol of the exact blur, docs/stretch.md;
    a miscompiled gather is off by far more, or not finite)."""
    def run(rt):
        from .blur import blur
        size = 40
        e = np.random.default_rng(6).random((size, size, 1), np.float32)
        ones = np.ones((size, size), np.float32)
        got = blur(e, albedo=0.6, mfp=3.0, stretch=(ones, ones), charts="none", tol=1e-3,
                   device=rt)
        want = blur(e, albedo=0.6, mfp=3.0, method="fft", border="clamp", tol=1e-3, device=rt)
        err = float(np.max(np.abs(got - want)) / np.max(np.abs(want)))
        if not np.isfinite(got).all() or err > 1e-2:
            raise RuntimeError(f"stretched blur computed wrongly (error {err:.3g})")
        return None
    return run


def _smooth_textures(size):
    """Albedo 0.5..0.7 and mfp 2.5..3.5 texels varying across a ``size`` square: a
    texture-varying blur with several basis kernels and a near field."""
    y, x = np.mgrid[0:size, 0:size] / max(size - 1, 1)
    return (0.5 + 0.2 * x).astype(np.float32), (2.5 + 1.0 * y).astype(np.float32)


def gather_check(width):
    """kernels/blur_textured.cl at ``width`` texels a work-item: with constant-valued
    textures it matches the constant blur (1e-2: both are within ~2 tol of the exact blur,
    ops/blur's docstring); with smoothly varying ones it stays within 30% of the constant blur
    at the middle values (the parameters vary by +-17%: a miscompiled gather is off by far
    more, or not finite)."""
    def run(rt):
        from .blur import blur
        from .blur.dispatch import GATHER_WIDTH_VARIABLE
        size = 64
        e = np.random.default_rng(2).random((size, size, 1), np.float32)
        want = blur(e, albedo=0.6, mfp=3.0, method="fft", border="clamp", tol=1e-3, device=rt)
        albedo, mfp = _smooth_textures(size)
        with forced(GATHER_WIDTH_VARIABLE, width):
            for a, m, bound in ((np.full_like(albedo, 0.6), np.full_like(mfp, 3.0), 1e-2),
                                (albedo, mfp, 0.3)):
                got = blur(e, albedo=a, mfp=m, method="fft", border="clamp", tol=1e-3,
                           device=rt)
                err = float(np.max(np.abs(got - want)) / np.max(np.abs(want)))
                if not np.isfinite(got).all() or err > bound:
                    raise RuntimeError(f"texture-varying blur computed wrongly (error "
                                       f"{err:.3g})")
        return None
    return run


# {{{ timing the widths that passed

def table_timer(rt, width):
    """One run of kernels/invert_table.cl at ``width`` over TIMING_N albedos on device
    buffers (alpha' and rho written: the default pass), as a function of no arguments."""
    import pyopencl as cl
    from ..methods.registry import MethodConfig
    from .inversion_kernel import TABLE_WIDTH_VARIABLE, InversionKernel
    with forced(TABLE_WIDTH_VARIABLE, width):
        kernel = InversionKernel((1.4,), MethodConfig(), runtime=rt)
    host = np.random.default_rng(1).uniform(1e-6, 0.999, TIMING_N).astype(np.float32)
    mf = cl.mem_flags
    rd = cl.Buffer(rt.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=host)
    alpha, rho = (cl.Buffer(rt.context, mf.WRITE_ONLY, host.nbytes) for _ in range(2))
    return lambda: kernel(host.size, rd, alpha=alpha, rho=rho).wait()


def gather_timer(rt, width):
    """One texture-varying blur of a 256x256 map with smoothly varying textures, its gather
    at ``width`` texels a work-item (the rest of the blur costs the same at every width)."""
    from .blur import blur
    from .blur.dispatch import GATHER_WIDTH_VARIABLE
    e = np.random.default_rng(2).random((256, 256, 1), np.float32)
    albedo, mfp = _smooth_textures(256)

    def run():
        with forced(GATHER_WIDTH_VARIABLE, width):
            blur(e, albedo=albedo, mfp=mfp, method="fft", border="clamp", tol=1e-3, device=rt)
    return run


#: (kernel source, widths, timer): the widths whose best differs between CPUs and runtimes
TIMED_WIDTHS = (("invert_table", "TABLE", table_timer), ("blur_textured", "GATHER", gather_timer))
#: rounds of the interleaved timing: every workload once a round, its best round kept, so that
#: a busy moment of a shared machine slows one round of every workload rather than one of them
TIMING_ROUNDS = 5
#: the side of the blur timings' image: the shipped data's workload is 512^2; a quarter of it
#: keeps the probe to seconds, and ``auto`` compares the methods at one radius, whose costs
#: scale alike with the area
BLUR_TIMING_SIZE = 256
#: the side of the blur timings' image on a device that is not a CPU: a GPU's fixed costs per
#: launch (tens of microseconds) would decide at 256^2, where its throughput decides at the
#: sizes users blur
GPU_BLUR_TIMING_SIZE = 1024


def blur_timers(rt, passed=frozenset()) -> dict:
    """{name: one blur}: each (method, kernel radius) of the shipped choice data, on its
    workload's mfp at its reference tol (``methods.choice.timing_references``): what decides
    the crossovers of ``blur(method="auto")`` between methods on this device; the ``fft``
    method on each engine (the host's, and the device's where its kernels ``passed``): what
    decides ``widths.fft_engine``."""
    from ..device.runtime import device_kind
    from ..methods.choice import PACKAGED_CHOICE_DATA, load_choice_data, timing_references
    from .blur import blur
    side = BLUR_TIMING_SIZE if device_kind(rt.device) == "cpu" else GPU_BLUR_TIMING_SIZE
    e = np.random.default_rng(3).random((side, side, 1), np.float32)

    def one(ref, engine):
        with forced(FFT_ENGINE_VARIABLE, engine):
            blur(e, albedo=0.8, mfp=ref.mfp, method=ref.method, tol=ref.tol, border="clamp",
                 device=rt)
    timers = {}
    for ref in timing_references(load_choice_data(PACKAGED_CHOICE_DATA)):
        timers[blur_timing_name(ref.method, ref.radius)] = lambda ref=ref: one(ref, "host")
        if ref.method == "fft" and set(DEVICE_FFT_CONFIGS) <= set(passed):
            timers[blur_timing_name(DEVICE_FFT_TIMING, ref.radius)] = (
                lambda ref=ref: one(ref, "device"))
    return timers


def timed_runs(rt, passed, failed=frozenset()) -> dict:
    """{name: one run} of every workload timed on the device: each width that ``passed``
    (names) of each kernel in TIMED_WIDTHS, and the blur's methods (``blur_timers``), but for
    those ``failed`` (an earlier child died timing them)."""
    from ..methods.choice import GATHER_WIDTHS_ALLOWED, TABLE_WIDTHS_ALLOWED
    allowed = {"TABLE": TABLE_WIDTHS_ALLOWED, "GATHER": GATHER_WIDTHS_ALLOWED}
    runs = {}
    for source, kind, make in TIMED_WIDTHS:
        runs.update({f"{source}/w{w}": make(rt, w) for w in allowed[kind]
                     if f"{source}/w{w}" in passed})
    if {"blur_direct", "blur_separable"} <= passed:
        runs.update(blur_timers(rt, passed))
    return {name: run for name, run in runs.items() if name not in failed}


def _announced(name, run):
    """``run``, saying on stdout which workload runs (a child that dies in it costs that
    configuration, ``device.isolation``), with its simulated fault (tests)."""
    emit({"run": name})
    _inject_fault(f"time:{name}")
    run()


def time_runs(runs: dict) -> dict:
    """{name: best seconds} of ``runs``, timed in TIMING_ROUNDS interleaved rounds (after one
    untimed run each: builds, first touches), each run announced (``_announced``)."""
    for name, run in runs.items():
        _announced(name, run)
    best = {}
    for _ in range(TIMING_ROUNDS):
        for name, run in runs.items():
            emit({"run": name})
            t0 = time.perf_counter()
            run()
            best[name] = min(best.get(name, float("inf")), time.perf_counter() - t0)
    return best

# }}}


def checks(fp64: bool) -> list:
    """The configurations probed on a device (with float64 ones where it has fp64)."""
    from ..methods.choice import GATHER_WIDTHS_ALLOWED, TABLE_WIDTHS_ALLOWED
    out = [KernelCheck(f"invert_table/w{w}", table_check(w), width=w)
           for w in TABLE_WIDTHS_ALLOWED]
    out += [KernelCheck("invert", method_check("bisection", False)),
            KernelCheck("invert/f64", method_check("table", True), fp64=True),
            KernelCheck("physics_eval", physics_check(False)),
            KernelCheck("physics_eval/f64", physics_check(True), fp64=True),
            KernelCheck("blur_direct", blur_check("direct")),
            KernelCheck("blur_separable", blur_check("gaussians")),
            KernelCheck("fft", device_fft_check(False)),
            KernelCheck("fft/f64", device_fft_check(True), fp64=True),
            KernelCheck("blur_fft", blur_fft_check()),
            KernelCheck("blur_stretched", stretched_check())]
    out += [KernelCheck(f"blur_textured/w{w}", gather_check(w), width=w)
            for w in GATHER_WIDTHS_ALLOWED]
    return [c for c in out if fp64 or not c.fp64]


# {{{ the child's main

def _inject_fault(name: str):
    """The fault ``device.isolation.FAULT_VARIABLE`` asks for at check ``name`` (tests)."""
    from ..device.isolation import FAULT_VARIABLE
    inject_fault(os.environ.get(FAULT_VARIABLE, ""), lambda target: target == name)


def _checked_vector_abi(rt, skip, failed) -> int:
    """Run the vector ABI checks not yet done (``skip``), adding the failed ones' names to
    ``failed``: the widest vector (floats) the device's kernels may use."""
    for width in VECTOR_ABI_WIDTHS:
        name = f"{VECTOR_ABI}/w{width}"
        if name in skip:
            continue
        emit({"begin": name})
        _inject_fault(name)
        try:
            reason = vector_abi_reason(rt, width)
        except Exception as exc:   # the tiny build itself failed: nothing that wide is safe
            reason = " ".join(str(exc).split())[:300] or type(exc).__name__
        if reason:
            failed.add(name)
        emit({"end": name, "ok": not reason, "reason": reason})
    return vector_cap(failed)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bdipole_cl.ops.kernel_checks")
    parser.add_argument("--device", required=True, help="P:D, as `bdipole-cl devices` lists")
    parser.add_argument("--skip", default="", help="comma list of configurations done")
    parser.add_argument("--passed", default="", help="those of them that passed")
    parser.add_argument("--parent", type=int, help="end when this process ends")
    args = parser.parse_args(argv)
    if args.parent:
        die_with(args.parent)
    from ..device.runtime import PROBE_CHILD_VARIABLE, runtime_at
    os.environ[PROBE_CHILD_VARIABLE] = "1"
    try:
        rt = runtime_at(args.device)
    except Exception as exc:       # every driver failure: the device cannot be opened at all
        emit({"error": " ".join(str(exc).split())[:300]})
        return 0
    skip = set(filter(None, args.skip.split(",")))
    passed = set(filter(None, args.passed.split(",")))
    failed = skip - passed
    cap = _checked_vector_abi(rt, skip, failed)
    os.environ[VECTOR_CAP_VARIABLE] = str(cap)      # the chunks' cap, where no verdict is yet
    for check in checks(rt.has_fp64):
        if check.name in skip:
            continue
        if check.width > cap:      # never built: the compiler's vector ABI is wrong that wide
            emit({"end": check.name, "ok": False, "reason": f"not built: vectors of "
                  f"{check.width} floats fail this device's vector ABI check ({VECTOR_ABI})"})
            continue
        emit({"begin": check.name})
        try:
            _inject_fault(check.name)
            check.run(rt)
            passed.add(check.name)
            emit({"end": check.name, "ok": True, "reason": ""})
        except Exception as exc:   # a build error, a driver error, a wrong result
            if environment_fault(exc):      # the probe's error: its verdict is not cached
                emit({"error": f"{check.name}: {fault_words(exc)}"})
                return 0
            text = " ".join(str(underlying(exc)).split())[:300] or type(exc).__name__
            emit({"end": check.name, "ok": False, "reason": text})
    for name, seconds in time_runs(timed_runs(rt, passed, failed)).items():
        emit({"time": name, "seconds": seconds})
    emit({"done": True})
    _inject_fault(EXIT)                       # a runtime's abort at its teardown (tests)
    return 0


if __name__ == "__main__":
    sys.exit(main())

# }}}
