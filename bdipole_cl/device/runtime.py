"""OpenCL devices: finding, probing and choosing them (the device layer).

Devices come from every OpenCL runtime the ICD loader sees: system drivers, PoCL from
pyopencl's wheel, and the runtimes installed into the Python environment (``bdipole_cl.device.icd``
registers Intel's CPU runtime from PyPI before the first platform query).

Each device is *probed* once per device, driver and kernel sources, in a child process
(``isolation``): every kernel configuration the library may pick is built, run and checked
there, so that a compiler that crashes takes down only the child. A configuration that fails
is never used; a device on which none works (the PyPI PoCL on CPUs its LLVM does not know
fails with ``unknown target CPU 'generic'``) is *broken*, with a one-line reason. The verdict
is cached in the user's cache folder.

The automatic choice (``device=None`` everywhere): ``PYOPENCL_CTX`` if set (pyopencl's syntax;
the device it names must work), else the first working device in ``RANK`` order: GPUs, then
accelerators, then CPUs, and among CPUs Intel's runtime before PoCL (faster in every benchmark
in docs/runtimes.md), ties in the loader's order. ``device=`` also takes a ``Runtime``, a pyopencl
``Device``, or a string: ``"P:D"`` (platform and device index as in ``bdipole-cl devices``) or a
case-insensitive part of "platform device" (``"intel"``, ``"pocl"``, ``"portable"``).

Every call resolves its device to a ``Runtime`` once and passes it down; each process (a Dask
worker, say) opens its own. ``use_device`` replaces the process default.
"""
from __future__ import annotations

import contextlib
import os
import threading
import warnings
from dataclasses import dataclass, field, replace


from . import cache_home, icd, isolation
from .isolation import TARGET_FEATURE_VARIABLE
from .numerics import DEVICE_NUMERICS, NUMERICS, Numerics
from .sources import kernels_digest

cache_home.ensure_writable_cache_home()   # before pyopencl's import and the registration
icd.register_environment_runtimes()   # before pyopencl's first platform query

try:  # pocl-binary-distribution registers its ICD on import (if pyopencl does not find it)
    import pocl_binary_distribution  # noqa: F401
except ImportError:  # pragma: no cover - optional at import time, a dependency when installed
    pass
import pyopencl as cl  # noqa: E402


REMEDIES = (
    "remedies: `pip install intel-opencl-rt intel-cmplr-lib-rt` into this environment (x86-64 "
    "CPUs; a dependency of bdipole-cl there), or a system driver (Debian/Ubuntu: `apt install "
    "pocl-opencl-icd`; a GPU vendor's OpenCL driver), or PYOPENCL_CTX=P:D naming a working "
    "device (see `bdipole-cl devices`)")


class DeviceError(RuntimeError):
    """No usable OpenCL device, or a kernel failed to build."""


@dataclass(frozen=True)
class Runtime:
    """One OpenCL context, its queue and device, and the float32 arithmetic its programs are
    built for (``numerics``: the device's own unless ``with_numerics`` asked for another)."""

    context: cl.Context
    queue: cl.CommandQueue
    numerics: Numerics = DEVICE_NUMERICS

    @property
    def device(self) -> cl.Device:
        return self.queue.device

    @property
    def has_fp64(self) -> bool:
        return device_has_fp64(self.device)

    def with_numerics(self, name: str) -> "Runtime":
        """This context and queue, its programs built for the arithmetic ``name`` names
        (``numerics.NUMERICS``: "gpu" makes a CPU runtime flush subnormals and round sqrt and
        division as inexactly as OpenCL allows, as a GPU may)."""
        return replace(self, numerics=NUMERICS[name])

    def describe(self) -> str:
        d = self.device
        arithmetic = ("" if self.numerics is DEVICE_NUMERICS
                      else f", numerics {self.numerics.name}")
        return f"{d.name.strip()} ({d.platform.name.strip()}, {d.version.strip()}{arithmetic})"


@dataclass(frozen=True)
class DeviceState:
    """One device as ``bdipole-cl devices`` shows it: where it is, what it is, whether it works."""

    index: str                  # "P:D", pyopencl's numbering (PYOPENCL_CTX takes it)
    platform: str
    name: str
    kind: str                   # "gpu", "cpu", "accelerator", "other"
    version: str
    fp64: bool
    works: bool
    reason: str                 # one line; "" when it works
    device: object = field(default=None, compare=False, repr=False)
    rejected: str = ""          # the configurations its probe rejected, said in one line

    def describe(self) -> str:
        state = "works" if self.works else f"broken: {self.reason}"
        if self.works and self.rejected:
            state += f" ({self.rejected})"
        return (f"[{self.index}] {self.name} | {self.platform} | {self.version} | {self.kind} | "
                f"fp64: {'yes' if self.fp64 else 'no'} | {state}")


_lock = threading.RLock()
_default: Runtime | None = None
_runtimes: dict = {}          # device int_ptr -> Runtime (one context per device and process)
_probes: dict = {}            # device int_ptr -> reason ("" = works)

#: PoCL's OpenCL platform (a case-insensitive part of its name). Its worker threads do not
#: survive fork(): in a child of a process that had made a PoCL context, every PoCL call hangs
#: (a new context included), so there PoCL is refused with the remedy instead (``_usable``)
POCL_PLATFORM = "portable computing language"
_pocl_started = False         # this process made a PoCL context
_pocl_forked = False          # this process is a fork of one that had (``_after_fork``)


def is_pocl(device) -> bool:
    return POCL_PLATFORM in device.platform.name.strip().lower()


def _after_fork():
    global _pocl_forked
    _pocl_forked = _pocl_forked or _pocl_started


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_after_fork)


def _usable(device):
    """``device``, or a DeviceError where this process cannot use it (PoCL after a fork)."""
    if _pocl_forked and is_pocl(device):
        raise DeviceError(
            f"{device.name.strip()} (PoCL): this process was forked from one that had started "
            f"PoCL, whose threads do not survive a fork (every call would hang); start worker "
            f"processes with multiprocessing's 'spawn' or 'forkserver' method, or use another "
            f"device in them (e.g. 'intel')")
    return device


#: set in the probe's child process: its devices are opened unprobed, its builds unguarded
PROBE_CHILD_VARIABLE = "BDIPOLE_CL_PROBE_CHILD"


def in_probe_child() -> bool:
    return bool(os.environ.get(PROBE_CHILD_VARIABLE))


def device_has_fp64(device) -> bool:
    return "cl_khr_fp64" in device.extensions or device.double_fp_config != 0


def device_kind(device) -> str:
    t = device.type
    for flag, name in ((cl.device_type.GPU, "gpu"), (cl.device_type.ACCELERATOR, "accelerator"),
                       (cl.device_type.CPU, "cpu")):
        if t & flag:
            return name
    return "other"


def platform_entry(device, table: dict, default):
    """``table``'s value for a CPU device's OpenCL platform (keys: a case-insensitive part of
    its name), else ``default`` (other platforms, and devices that are not CPUs)."""
    if device_kind(device) != "cpu":
        return default
    platform = device.platform.name.strip().lower()
    return next((v for name, v in table.items() if name in platform), default)


def forced_width(variable: str, allowed) -> int | None:
    """The elements per work-item the environment variable ``variable`` forces (a ValueError
    naming it unless one of ``allowed``), or None where it is not set."""
    text = os.environ.get(variable)
    if not text:
        return None
    if text not in {str(w) for w in allowed}:
        raise ValueError(f"{variable}={text!r}: expected one of {', '.join(map(str, allowed))}")
    return int(text)


@contextlib.contextmanager
def forced(variable, value):
    """A context in which the environment variable ``variable`` is ``value`` (the width
    overrides, ``forced_width``, that the kernels read when they are built)."""
    before = os.environ.get(variable)
    os.environ[variable] = str(value)
    try:
        yield
    finally:
        if before is None:
            os.environ.pop(variable, None)
        else:
            os.environ[variable] = before


def _one_line(text: str, limit: int = 200) -> str:
    """The most telling line of a driver's message: the first one that says 'error'."""
    lines = [ln.strip() for ln in str(text).splitlines() if ln.strip()]
    pick = next((ln for ln in lines if "error" in ln.lower()), lines[0] if lines else "failed")
    return pick if len(pick) <= limit else pick[:limit - 3] + "..."


def _runtime_of(device) -> Runtime:
    global _pocl_started
    key = _usable(device).int_ptr
    with _lock:
        rt = _runtimes.get(key)
        if rt is None:
            ctx = cl.Context([device])
            rt = _runtimes[key] = Runtime(ctx, cl.CommandQueue(ctx))
            _pocl_started = _pocl_started or is_pocl(device)
        return rt


def probe(device) -> str:
    """"" if ``device`` works, else the one-line reason: its verdict (``verdict``), once per
    process."""
    key = device.int_ptr
    with _lock:
        if key in _probes:
            return _probes[key]
    if in_probe_child():
        reason = ""
    else:
        try:
            reason = verdict(device).reason
        except Exception as exc:  # a driver that fails even to describe its device
            reason = _one_line(exc)
    with _lock:
        _probes[key] = reason
    return reason


def device_index(device) -> str:
    """The device's "P:D" (``bdipole-cl devices``, PYOPENCL_CTX)."""
    for index, _platform, d in _candidates():
        if d.int_ptr == device.int_ptr:
            return index
    raise DeviceError(f"{device.name.strip()} is not among the loader's devices")


def _describe_device(device) -> str:
    return f"{device.name.strip()} ({device.platform.name.strip()})"


def verdict(device) -> "isolation.Verdict":
    """Which kernel configurations build and run on ``device``: probed in a child process
    once per device, driver and kernel sources, then cached (``isolation.device_verdict``)."""
    return isolation.device_verdict(device, device_index(device), kernels_digest(),
                                    _describe_device(device))


def known_verdict(device):
    """The device's verdict where one is at hand (this process's or the cache's), else None:
    never starts a probe (None in the probe's own child, and for a device whose driver cannot
    say what it is)."""
    if in_probe_child():
        return None
    try:
        return isolation.cached_verdict(device, kernels_digest())
    except (AttributeError, cl.Error):
        return None


def runtime_at(index: str) -> Runtime:
    """The Runtime of the device "P:D", unprobed (the probe's child opens its device so)."""
    for i, _platform, d in _candidates():
        if i == index:
            return _runtime_of(d)
    raise DeviceError(f"device {index!r}: no such device")


def _before_platform_query() -> None:
    icd.ensure_registered()
    cache_home.say_once()


def _candidates():
    """(index, platform, device) for every device the loader sees, in its order."""
    _before_platform_query()
    out = []
    for p_i, platform in enumerate(cl.get_platforms()):
        try:
            devices = platform.get_devices()
        except cl.Error:
            devices = []
        out.extend((f"{p_i}:{d_i}", platform, d) for d_i, d in enumerate(devices))
    return out


def _state(index, platform, device, reason=None) -> DeviceState:
    rejected = ""
    if reason is None:
        reason = probe(device)
        known = known_verdict(device) if not reason else None
        rejected = known.describe_rejected() if known is not None else ""
    return DeviceState(index, platform.name.strip(), device.name.strip(), device_kind(device),
                       device.version.strip(), device_has_fp64(device), not reason, reason,
                       device, rejected)


def survey() -> list[DeviceState]:
    """Every device the loader sees, each probed (``bdipole-cl devices``)."""
    try:
        return [_state(*c) for c in _candidates()]
    except cl.Error as exc:
        raise DeviceError(f"no OpenCL platform found ({_one_line(exc)}); {REMEDIES}") from exc


#: automatic preference: lower ranks first (kind, then implementation), ties in loader order
KIND_RANK = {"gpu": 0, "accelerator": 1, "cpu": 2, "other": 3}


def rank(state: DeviceState) -> tuple:
    platform = state.platform.lower()
    impl = 0 if "intel" in platform else 1 if "portable" in platform else 2
    return (KIND_RANK.get(state.kind, 3), impl)


def choose(states, probe_fn=None) -> DeviceState:
    """The automatic choice among ``states`` (DeviceState with ``works`` unknown or known):
    the best-ranked device whose probe passes. Probes lazily in rank order, so a broken device
    costs one failed build and the rest are not built at all. Raises DeviceError naming every
    device's failure and the remedies when none works."""
    states = list(states)
    order = sorted(range(len(states)), key=lambda i: (rank(states[i]), i))
    failures = []
    for i in order:
        s = states[i]
        reason = s.reason if probe_fn is None else probe_fn(s)
        if not reason:
            return s
        failures.append(f"[{s.index}] {s.name} ({s.platform}): {reason}")
    if not failures:
        raise DeviceError(f"no OpenCL device found; {REMEDIES}")
    raise DeviceError("no working OpenCL device: " + "; ".join(failures) + f"; {REMEDIES}")


def _lazy_states():
    """Candidates as DeviceStates whose probe has not run yet (reason filled by ``choose``)."""
    try:
        cands = _candidates()
    except cl.Error as exc:
        raise DeviceError(f"no OpenCL platform found ({_one_line(exc)}); {REMEDIES}") from exc
    return [_state(i, p, d, reason="?") for i, p, d in cands]


def _from_pyopencl_ctx(spec: str) -> Runtime:
    _before_platform_query()
    try:
        ctx = cl.create_some_context(interactive=False)
    except Exception as exc:  # pyopencl raises several types here
        raise DeviceError(f"PYOPENCL_CTX={spec!r} selects no device ({_one_line(exc)}); "
                          f"`bdipole-cl devices` lists them") from exc
    device = ctx.devices[0]
    reason = probe(device)
    if reason:
        raise DeviceError(f"PYOPENCL_CTX={spec!r} selects {device.name.strip()} "
                          f"({device.platform.name.strip()}), which is broken: {reason}; "
                          f"{REMEDIES}")
    return _runtime_of(device)


#: short names users type for implementations whose platform name is long
ALIASES = {"pocl": "portable computing language"}




def simulated_target(context) -> list:
    """The build option TARGET_FEATURE_VARIABLE asks for on a PoCL context, else none."""
    feature = os.environ.get(TARGET_FEATURE_VARIABLE)
    if not feature or not any(is_pocl(d) for d in context.devices):
        return []
    return [f"-DBD_TARGET_FEATURE\t-target-feature\t{feature}"]


def build_quietly(context, source, options=()):
    """Build quietly: a non-empty build log is normal for some drivers (Intel's prints one for
    every build) and pyopencl would warn on each; failures still raise with the log."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", cl.CompilerWarning)
        return cl.Program(context, source).build(
            options=list(options) + simulated_target(context))


def _from_string(spec: str) -> Runtime:
    states = _lazy_states()
    if ":" in spec and all(part.isdigit() for part in spec.split(":", 1)):
        matches = [s for s in states if s.index == spec]
    else:
        # a platform's name first ("intel" is Intel's runtime, not PoCL on an Intel CPU,
        # whose device name says Intel too), else the devices' names
        needle = ALIASES.get(spec.lower(), spec.lower())
        matches = ([s for s in states if needle in s.platform.lower()]
                   or [s for s in states if needle in f"{s.platform} {s.name}".lower()])
    if not matches:
        listing = ", ".join(f"{s.index} {s.platform} / {s.name}" for s in states) or "none"
        raise DeviceError(f"device {spec!r} matches no OpenCL device (seen: {listing})")
    return _runtime_of(choose(matches, probe_fn=lambda s: probe(s.device)).device)


def _make_default() -> Runtime:
    spec = os.environ.get("PYOPENCL_CTX")
    if spec:
        return _from_pyopencl_ctx(spec)
    return _runtime_of(choose(_lazy_states(), probe_fn=lambda s: probe(s.device)).device)


def get_runtime(device=None) -> Runtime:
    """The Runtime for ``device`` (see the module docstring); None: the process default,
    chosen on first use."""
    global _default
    if isinstance(device, Runtime):
        _usable(device.device)
        # a Runtime made by hand is probed too (not a stand-in without a device)
        reason = probe(device.device) if isinstance(device.device, cl.Device) else ""
        if reason:
            raise DeviceError(f"{device.describe()} is broken: {reason}")
        return device
    if device is None:
        with _lock:
            if _default is None:
                _default = _make_default()
            _usable(_default.device)
            return _default
    if isinstance(device, str):
        return _from_string(device)
    if isinstance(device, cl.Device):
        reason = probe(device)
        if reason:
            raise DeviceError(f"{device.name.strip()} ({device.platform.name.strip()}) is "
                              f"broken: {reason}")
        return _runtime_of(device)
    raise TypeError(f"device={device!r}: expected None, a Runtime, a pyopencl Device or a "
                    f"string such as '0:0' or 'intel'")


def runtime_of_array(array) -> Runtime:
    """The Runtime a device array (``pyopencl.array.Array``) lives on: this process's own for
    its context where it made it, else one of its context and queue (probed when used, as any
    Runtime made by hand)."""
    with _lock:
        for rt in _runtimes.values():
            if rt.context == array.context:
                return rt
    return Runtime(array.context, array.queue or cl.CommandQueue(array.context))


def use_device(device=None) -> Runtime:
    """Make ``device`` (anything ``get_runtime`` takes; None: choose again) the default."""
    global _default
    with _lock:
        _default = None if device is None else get_runtime(device)
    return get_runtime()


def working_runtimes() -> list[Runtime]:
    """A Runtime for every working device (tests and ``crosscheck --all-devices``)."""
    return [_runtime_of(s.device) for s in survey() if s.works]
