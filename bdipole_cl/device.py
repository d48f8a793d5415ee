"""OpenCL device selection, kernel sources and program cache (the thin host layer's core).

Device choice: ``PYOPENCL_CTX`` if set (pyopencl's own syntax, e.g. ``0:0`` or ``portable``),
else the first CPU device (PoCL from ``pocl-binary-distribution``), else any device. One
context and queue per process, made on first use; ``use_device`` replaces it.
"""
from __future__ import annotations

import os
import threading
from dataclasses import dataclass
from pathlib import Path

import numpy as np

try:  # pocl-binary-distribution registers its ICD on import (if pyopencl does not find it)
    import pocl_binary_distribution  # noqa: F401
except ImportError:  # pragma: no cover - optional at import time, a dependency when installed
    pass
import pyopencl as cl

from . import reference

#: The header every kernel source is joined behind.
HEADER = "bdipole.h"


class DeviceError(RuntimeError):
    """No usable OpenCL device, or a kernel failed to build."""


@dataclass(frozen=True)
class Runtime:
    """One OpenCL context, its queue and device."""

    context: cl.Context
    queue: cl.CommandQueue

    @property
    def device(self) -> cl.Device:
        return self.queue.device

    @property
    def has_fp64(self) -> bool:
        return device_has_fp64(self.device)

    def describe(self) -> str:
        d = self.device
        return f"{d.name.strip()} ({d.platform.name.strip()}, {d.version.strip()})"


_lock = threading.Lock()
_runtime: Runtime | None = None
_programs: dict = {}


def device_has_fp64(device) -> bool:
    return "cl_khr_fp64" in device.extensions or device.double_fp_config != 0


def list_devices():
    """All (platform, device) pairs the ICD loader sees, for ``bdipole-cl devices``."""
    out = []
    for platform in cl.get_platforms():
        try:
            devices = platform.get_devices()
        except cl.Error:
            devices = []
        out.extend((platform, d) for d in devices)
    return out


def _platform_listing() -> str:
    try:
        platforms = cl.get_platforms()
    except cl.Error as exc:
        return f"  (no OpenCL platform: {exc})"
    lines = []
    for p in platforms:
        try:
            names = [d.name for d in p.get_devices()]
        except cl.Error as exc:
            names = [f"<error: {exc}>"]
        lines.append(f"  {p.name}: {', '.join(names) or '<no devices>'}")
    return "\n".join(lines) or "  (no OpenCL platform found)"


def _pick_device():
    pairs = list_devices()
    for want in (cl.device_type.CPU, None):
        for _, d in pairs:
            if want is None or d.type & want:
                return d
    raise DeviceError(
        "no usable OpenCL device. Platforms seen:\n" + _platform_listing()
        + "\nInstall pocl-binary-distribution (a dependency of bdipole-cl) for a CPU device, "
          "or set PYOPENCL_CTX.")


def _make_runtime() -> Runtime:
    if os.environ.get("PYOPENCL_CTX"):
        try:
            ctx = cl.create_some_context(interactive=False)
        except Exception as exc:  # pyopencl raises several types here
            raise DeviceError(f"PYOPENCL_CTX={os.environ['PYOPENCL_CTX']!r} selects no usable "
                              f"device ({exc}). Platforms seen:\n{_platform_listing()}") from exc
    else:
        ctx = cl.Context([_pick_device()])
    return Runtime(ctx, cl.CommandQueue(ctx))


def get_runtime() -> Runtime:
    """The process's OpenCL runtime, created on first use."""
    global _runtime
    with _lock:
        if _runtime is None:
            _runtime = _make_runtime()
        return _runtime


def use_device(device=None) -> Runtime:
    """Make ``device`` (a pyopencl Device, or None for the default choice) the process's device."""
    global _runtime
    with _lock:
        if device is None:
            _runtime = _make_runtime()
        else:
            ctx = cl.Context([device])
            _runtime = Runtime(ctx, cl.CommandQueue(ctx))
        return _runtime


# {{{ kernel sources and programs

def kernel_dir() -> Path:
    """``bdipole_cl/kernels`` in an installed wheel, else the source tree's top-level ``kernels``."""
    here = Path(__file__).resolve().parent
    for candidate in (here / "kernels", here.parent / "kernels"):
        if (candidate / HEADER).is_file():
            return candidate
    raise DeviceError(f"kernel sources not found next to {here} (looked for {HEADER})")


def kernel_source(name: str) -> str:
    """The header joined in front of ``kernels/<name>.cl``."""
    d = kernel_dir()
    return (d / HEADER).read_text() + f"\n#line 1 \"{name}.cl\"\n" + (d / f"{name}.cl").read_text()


def build_options(defines: dict | None = None, double: bool = False, model: str = "better"):
    """Build options (sorted, so that equal specializations share one cache entry)."""
    opts = {} if defines is None else dict(defines)
    if double:
        opts["BD_DOUBLE"] = None
    if model == "dipole":
        opts["BD_MODEL_DIPOLE"] = None
    elif model != "better":
        raise ValueError(f"model={model!r}: expected one of {reference.MODELS}")
    return tuple(f"-D{k}" if v is None else f"-D{k}={v}" for k, v in sorted(opts.items()))


def get_program(rt: Runtime, name: str, options=()) -> cl.Program:
    """Build (once per runtime, source name and options) the program of ``kernels/<name>.cl``."""
    key = (id(rt.context), name, tuple(options))
    with _lock:
        prg = _programs.get(key)
    if prg is None:
        if any(o == "-DBD_DOUBLE" for o in options) and not rt.has_fp64:
            raise DeviceError(f"{rt.describe()} has no cl_khr_fp64: float64 is not available")
        try:
            prg = cl.Program(rt.context, kernel_source(name)).build(options=list(options))
        except cl.RuntimeError as exc:
            raise DeviceError(f"building kernels/{name}.cl with {' '.join(options)} failed:\n"
                              f"{exc}") from exc
        with _lock:
            _programs[key] = prg
    return prg

# }}}


def real_dtype(double: bool):
    return np.dtype(np.float64 if double else np.float32)
