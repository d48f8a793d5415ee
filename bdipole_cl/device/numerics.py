"""A device's float32 arithmetic, and build options that make one device's like another's (the
device layer): GPU-like numerics on the CPU runtimes, so that tests of what a GPU does run in CI
on any machine (docs/numerics.md "What a GPU does").

OpenCL lets a device flush float32 subnormals to zero (unless it reports ``CL_FP_DENORM``), and
round float32 division and sqrt within 2.5 and 3 ulp (unless a program is built with
``-cl-fp32-correctly-rounded-divide-sqrt``). NVIDIA's OpenCL does both by default; the CPU
runtimes do neither. ``NUMERICS`` names the variants: each is the ``-cl-*`` compiler options and
``-DBD_*`` defines that every program built on a ``Runtime`` carrying it gets
(``Runtime.with_numerics``, ``programs.get_program``). Intel's CPU runtime and PoCL both honour
``-cl-denorms-are-zero`` (subnormal inputs read as 0, subnormal results written as 0); neither
has an option that makes its division or sqrt less accurate (``-cl-fast-relaxed-math`` left
Intel's division within 0.55 ulp and its sqrt exact, PoCL's both exact; Intel's
``native_divide`` is 900 ulp off, beyond what OpenCL allows ``/``), so ``-DBD_INEXACT_MATH``
(kernels/bdipole.h) moves every float32 sqrt, and every division written ``BD_DIV``, by up to
2 ulps, the most OpenCL allows.
"""
from __future__ import annotations

from dataclasses import dataclass

import pyopencl as cl

from ..vocabulary import Option, Registry

#: kernels/bdipole.h's define: every float32 sqrt and BD_DIV off by up to 2 ulps, not monotone
INEXACT_MATH = "BD_INEXACT_MATH"
#: kernels/bdipole.h's define: the device's float32 sqrt is correctly rounded, used as it is
#: for the inversion's variable (else corrected to the correctly rounded one in the kernel)
DEVICE_SQRT_RN = "BD_DEVICE_SQRT_RN"


@dataclass(frozen=True)
class Numerics(Option):
    """One variant of a device's float32 arithmetic: the OpenCL ``compiler_options`` and the
    kernels' ``defines`` (BD_* names) that make it, and whether the device's sqrt may be used
    as it is where it is known to be correctly rounded (``trust_sqrt``)."""

    compiler_options: tuple = ()
    defines: tuple = ()
    trust_sqrt: bool = True


NUMERICS: Registry[Numerics] = Registry("numerics", (
    Numerics("device", "the device's own float32 arithmetic, as built without options"),
    Numerics("ftz", "float32 subnormals flushed to zero (-cl-denorms-are-zero), as NVIDIA's "
                    "OpenCL does", compiler_options=("-cl-denorms-are-zero",)),
    Numerics("inexact", "float32 sqrt and division each off by up to 2 ulps, not monotone in "
                        "their inputs (-DBD_INEXACT_MATH: OpenCL allows 3 and 2.5 ulp)",
             defines=(INEXACT_MATH,), trust_sqrt=False),
    Numerics("gpu", "both: what a GPU may do by default (the H200's OpenCL flushed "
                    "subnormals and its sqrt reversed the inversion near FLT_MIN)",
             compiler_options=("-cl-denorms-are-zero",), defines=(INEXACT_MATH,),
             trust_sqrt=False),
    Numerics("corrected", "the device's own arithmetic, its sqrt corrected in the kernels as "
                          "where it is not known to be correctly rounded (a GPU): to time that",
             trust_sqrt=False),
))
#: the numerics every Runtime has unless it asks for another
DEVICE_NUMERICS = NUMERICS["device"]


def sqrt_is_correctly_rounded(device, numerics: Numerics) -> bool:
    """Whether ``device``'s float32 sqrt, under ``numerics``, is known to be the correctly
    rounded one: on CPUs (their compilers emit the instruction set's IEEE sqrt;
    tests/test_gpu_numerics.py checks every CPU device under test), unless ``numerics`` does
    not trust it. Elsewhere the kernels correct it (kernels/bdipole.h: BD_SQRT_RN)."""
    return bool(device.type & cl.device_type.CPU) and numerics.trust_sqrt


def numerics_options(device, numerics: Numerics) -> tuple:
    """The build options every program on ``device`` gets under ``numerics``: its compiler
    options, its defines, and DEVICE_SQRT_RN where the device's sqrt may be used as it is."""
    defines = numerics.defines + ((DEVICE_SQRT_RN,) if sqrt_is_correctly_rounded(
        device, numerics) else ())
    return tuple(numerics.compiler_options) + tuple(f"-D{d}" for d in defines)
