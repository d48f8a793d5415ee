"""Elements per work-item of the vectorised kernels, chosen on the device in use (operations).

The best width differs between CPUs and runtimes (Intel's runtime vectorises the one-element
table kernel itself on one AVX-512 Xeon and is 25% slower so on an AVX2 EPYC; PoCL's LLVM
crashes building 16 lanes on a Zen 4), so it is decided on the device: a calibration
(``report --calibrate``) where there is one, else the widths the device's probe timed
(``device.isolation``: each width's workload, run in the probe's child), else the shipped
per-platform default. A width the probe rejected is never chosen.
"""
from __future__ import annotations

import logging
import os
from dataclasses import dataclass

from ..device.guard import BuildRefused
from ..device.isolation import VECTOR_ABI_WIDTHS, config_name
from ..device.runtime import DeviceError, device_kind, known_verdict

log = logging.getLogger("bdipole_cl")

#: the widest vector (floats) in the probe's own child, where no verdict is at hand yet (it
#: sets it from its vector ABI checks, ``ops.kernel_checks``)
VECTOR_CAP_VARIABLE = "BDIPOLE_CL_VECTOR_CAP"


def device_vector_cap(rt) -> int:
    """The widest vector (floats) ``rt``'s kernels may use: the probe's vector ABI verdict
    (``device.isolation.Verdict.vector_cap``; 16 where every width passed or none was
    checked)."""
    named = os.environ.get(VECTOR_CAP_VARIABLE)
    if named:
        return int(named)
    known = known_verdict(rt.device)
    return known.vector_cap if known is not None else max(VECTOR_ABI_WIDTHS)


@dataclass(frozen=True)
class WidthChoice:
    """A kernel's width on a device, and what decided it (one phrase)."""

    width: int
    source: str


def passes(rt, source: str, width: int | None = None) -> bool:
    """Whether the device's probe passed kernels/<source>.cl (at ``width``; True where it has
    no verdict: the probe's own child, which is what measures it)."""
    known = known_verdict(rt.device)
    if known is None:
        return True
    ok = known.passed(config_name(source, () if width is None else (f"-DBD_WIDTH={width}",)))
    return ok is not False


def probed_times(rt, source: str, allowed) -> dict:
    """{width: seconds} of the widths the device's probe passed and timed."""
    known = known_verdict(rt.device)
    if known is None:
        return {}
    out = {}
    for w in allowed:
        r = known.result(config_name(source, (f"-DBD_WIDTH={w}",)))
        if r is not None and r.ok and r.seconds is not None:
            out[w] = r.seconds
    return out


def choose_width(rt, source: str, allowed, calibrated, default) -> WidthChoice:
    """The width of kernels/<source>.cl on ``rt``'s device: ``calibrated`` (a calibration's,
    or None), else the fastest the probe timed, else ``default``; each only where the probe
    passed it, else the fastest (or narrowest) width that passed; none past the device's
    vector cap (``device_vector_cap``: the probe's own child has no verdict yet, so ``passes``
    is True there for every width)."""
    cap = device_vector_cap(rt)
    allowed = [w for w in allowed if w <= cap] or [min(allowed)]
    if calibrated and calibrated > cap:
        calibrated = None
    if default > cap:
        default = max(allowed)
    if calibrated and passes(rt, source, calibrated):
        return WidthChoice(calibrated, "calibrated on this device (report --calibrate)")
    times = probed_times(rt, source, allowed)
    if times:
        best = min(times, key=times.get)
        return WidthChoice(best, "the fastest of the widths this device's probe timed")
    if passes(rt, source, default):
        return WidthChoice(default, "the runtime's default (not measured on this device)")
    working = [w for w in allowed if passes(rt, source, w)]
    if working:
        return WidthChoice(working[0], f"the narrowest width that passed the probe "
                                       f"({default} was rejected)")
    raise DeviceError(f"kernels/{source}.cl failed this device's probe at every width "
                      f"({', '.join(map(str, allowed))}) on {rt.describe()}: choose another "
                      f"device with --device (`bdipole-cl devices` lists them)")


def built_at_width(rt, source: str, width: int, allowed, build):
    """(w, build(w)): ``build`` (a program's kernel at a width) at ``width``, else, where its
    build was refused (it crashed the runtime in the guard's child, ``device.guard``), at each
    narrower width of ``allowed`` the probe passed, saying each refusal in one line."""
    narrower = [w for w in sorted(allowed, reverse=True) if w < width and passes(rt, source, w)]
    for w in [width, *narrower]:
        try:
            return w, build(w)
        except BuildRefused as exc:
            if w == min([width, *narrower]):
                raise
            log.warning("%s; a narrower width is used", exc)
    raise AssertionError("unreachable")                      # pragma: no cover


#: the probe's blur timings' name prefix (``blur_timing_name``; ``ops.kernel_checks`` writes
#: them, ``ops.blur.planning.probed_blur_data`` reads them)
BLUR_TIMING = "blur-timing"


def blur_timing_name(method: str, radius: int) -> str:
    return f"{BLUR_TIMING}/{method}/r{radius}"


#: forces where method="fft" transforms: "host" (scipy.fft on all cores) or "device"
#: (kernels/fft.cl, ``ops.device_fft``)
FFT_ENGINE_VARIABLE = "BDIPOLE_CL_FFT_ENGINE"
FFT_ENGINES = ("host", "device")
#: the probe's name of the device engine's FFT blur timings (``blur_timing_name``'s method)
DEVICE_FFT_TIMING = "fft@device"
#: the probe's checks of the device FFT's kernels (``passes`` them before using it)
DEVICE_FFT_CONFIGS = ("fft", "blur_fft")


def fft_engine(rt) -> str:
    """Where ``method="fft"`` transforms on ``rt``'s device: forced by FFT_ENGINE_VARIABLE,
    else the faster of the two at the radii the probe timed both (its blur timings), else the
    device on a device that is not a CPU (the host's FFT there means the bus both ways) and
    the host on a CPU; never the device where the probe rejected its kernels."""
    forced = os.environ.get(FFT_ENGINE_VARIABLE)
    if forced:
        if forced not in FFT_ENGINES:
            raise ValueError(f"{FFT_ENGINE_VARIABLE}={forced!r}: expected one of "
                             f"{', '.join(FFT_ENGINES)}")
        return forced
    if not all(passes(rt, name) for name in DEVICE_FFT_CONFIGS):
        return "host"
    times = blur_timings(rt, raw=True)
    host = {r: t for (m, r), t in times.items() if m == "fft"}
    device = {r: t for (m, r), t in times.items() if m == DEVICE_FFT_TIMING}
    both = sorted(set(host) & set(device))
    if both:
        return "device" if sum(device[r] for r in both) < sum(host[r] for r in both) else "host"
    return "host" if device_kind(rt.device) == "cpu" else "device"


def blur_timings(rt, raw=False) -> dict:
    """{(method, radius): seconds} of the blur timings of ``rt``'s device's probe, the
    ``fft`` method's those of its engine (``fft_engine``; ``raw``: both engines', the
    device's as DEVICE_FFT_TIMING)."""
    known = known_verdict(rt.device)
    if known is None:
        return {}
    prefix = BLUR_TIMING + "/"
    out = {}
    for r in known.results:
        if r.ok and r.seconds is not None and r.name.startswith(prefix):
            method, radius = r.name[len(prefix):].rsplit("/r", 1)
            out[(method, int(radius))] = r.seconds
    if raw:
        return out
    engine = fft_engine(rt)          # "fft" costs what its engine does
    for (method, radius), seconds in list(out.items()):
        if method == DEVICE_FFT_TIMING:
            if engine == "device":
                out[("fft", radius)] = seconds
            del out[(method, radius)]
    return out
