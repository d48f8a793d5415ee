"""Kernel sources, build options and the program cache (the device layer).

A kernel's source is the generated parameter layout (``layout.header``), then the one physics
header kernels/bdipole.h, then ``kernels/<name>.cl``, joined as text (no ``#include``: PoCL
compiles from a temporary file, so relative include paths break), with ``#line`` markers so
that compiler messages point at the right file. Build options specialize it; every option is
``-DBD_<NAME>`` (kernels/bdipole.h lists them), but for the runtime's numerics
(``numerics.NUMERICS``: one registry holds their OpenCL ``-cl-*`` options and defines), which
``get_program`` adds to every program. A program is built in a child process first, once per
device (``guard``: a compiler crash costs the program, not the process), then here, once per
context, source name and options, in a cache bounded by the programs' binary sizes
(``PROGRAM_CACHE_BYTES``), and dropped by ``bdipole_cl.clear_caches()``.
"""
from __future__ import annotations


import numpy as np
import pyopencl as cl

from ..caches import ByteCache
from ..physics.models import MODEL
from . import layout
from .guard import checked_build
from .isolation import config_name
from .numerics import numerics_options
from .sources import HEADER, kernel_dir, kernels_digest  # noqa: F401 (kernels_digest: the
#                                                        device layer's name for it)
from .runtime import (DeviceError, Runtime, build_quietly, device_index, in_probe_child,
                      known_verdict)

#: the explicit vector lanes (BD_WIDTH) of the kernels that take several elements a work-item
LANES = "lanes.h"
#: the per-texel gathers' shared header, prepended to their programs after LANES
GATHER = "gather.h"
GATHER_PROGRAMS = ("blur_textured", "blur_stretched")

#: the built programs' budget: their device binaries' bytes (a program is a few hundred KiB)
PROGRAM_CACHE_BYTES = 256 << 20
#: what a program counts for when its runtime does not report its binary's size
NOMINAL_PROGRAM_BYTES = 1 << 20
PROGRAM_CACHE = ByteCache("programs", PROGRAM_CACHE_BYTES)


def program_bytes(prg: cl.Program) -> int:
    """The program's device binaries' bytes, as the runtime reports them."""
    try:
        return max(1, int(sum(prg.get_info(cl.program_info.BINARY_SIZES))))
    except cl.Error:
        return NOMINAL_PROGRAM_BYTES


def kernel_source(name: str, body: str | None = None) -> str:
    """The generated layout, then the physics header and the lane types (empty without
    BD_WIDTH), the gathers' header for GATHER_PROGRAMS, then ``kernels/<name>.cl`` (or
    ``body``, a kernel's text given directly, named ``name``)."""
    d = kernel_dir()
    text = (d / f"{name}.cl").read_text() if body is None else body
    gather = (f"\n#line 1 \"{GATHER}\"\n" + (d / GATHER).read_text()
              if name in GATHER_PROGRAMS else "")
    return (layout.header() + f"#line 1 \"{HEADER}\"\n" + (d / HEADER).read_text()
            + f"\n#line 1 \"{LANES}\"\n" + (d / LANES).read_text() + gather
            + f"\n#line 1 \"{name}.cl\"\n" + text)


def build_options(defines: dict | None = None, double: bool = False, model: str = "better"):
    """Build options (sorted, so that equal specializations share one cache entry). Every
    name carries the ``BD_`` prefix."""
    opts = {} if defines is None else dict(defines)
    stray = [k for k in opts if not k.startswith("BD_")]
    if stray:
        raise ValueError(f"build options {stray}: every kernel option is named BD_<NAME>")
    if double:
        opts["BD_DOUBLE"] = None
    define = MODEL[model].define        # ValueError naming the models if unknown
    if define is not None:
        opts[define] = None
    return tuple(f"-D{k}" if v is None else f"-D{k}={v}" for k, v in sorted(opts.items()))


def get_program(rt: Runtime, name: str, options=()) -> cl.Program:
    """Build (once per runtime, source name and options) the program of ``kernels/<name>.cl``,
    with the options of ``rt``'s numerics added (``numerics.numerics_options``)."""
    options = tuple(options) + numerics_options(rt.device, rt.numerics)
    key = (id(rt.context), name, options)
    prg = PROGRAM_CACHE.get(key)
    if prg is None:
        if any(o == "-DBD_DOUBLE" for o in options) and not rt.has_fp64:
            raise DeviceError(f"{rt.describe()} has no cl_khr_fp64: float64 is not available")
        refuse_rejected(rt, name, options)
        source = kernel_source(name)
        guarded_build_check(rt, source, options, f"kernels/{name}.cl with "
                                                 f"{' '.join(options) or 'no options'}")
        try:
            prg = build_quietly(rt.context, source, options)
        except cl.RuntimeError as exc:
            raise DeviceError(f"building kernels/{name}.cl with {' '.join(options)} failed:\n"
                              f"{exc}") from exc
        PROGRAM_CACHE.put(key, prg, program_bytes(prg))
    return prg


def guarded_build_check(rt: Runtime, source: str, options, what: str) -> None:
    """Raise ``guard.BuildRefused`` where building this program crashed ``rt``'s runtime in a
    child process (tried there first, once per device and program: ``guard``); nothing in the
    probe's own child, which is the guard there."""
    if not in_probe_child():
        checked_build(rt.device, device_index(rt.device), kernels_digest(), source, options,
                      what)


def refuse_rejected(rt: Runtime, name: str, options) -> None:
    """A DeviceError where the device's probe rejected this configuration (its runtime crashed
    or failed building or running it): building it here could take the process down."""
    known = known_verdict(rt.device)
    if known is None:
        return
    config = config_name(name, options)
    result = known.result(config)
    if result is not None and not result.ok:
        raise DeviceError(f"kernels/{name}.cl as {config} failed this device's probe on "
                          f"{rt.describe()} ({result.reason}); not built here (`bdipole-cl "
                          f"devices` lists what works)")


def real_dtype(double: bool):
    return np.dtype(np.float64 if double else np.float32)


def program_count() -> int:
    """Programs built and kept in this process."""
    return len(PROGRAM_CACHE)
