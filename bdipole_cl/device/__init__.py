"""The device layer: OpenCL runtimes found and probed (``runtime``, ``icd``), kernel sources,
build options and programs (``programs``), and the host/kernel parameter layout (``layout``).

Imports only the physics layer (and the foundation: errors, caches)."""
from .programs import build_options, get_program, kernel_source, real_dtype
from .runtime import (REMEDIES, DeviceError, DeviceState, Runtime, device_has_fp64, get_runtime,
                      survey, use_device, working_runtimes)

__all__ = ["REMEDIES", "DeviceError", "DeviceState", "Runtime", "build_options",
           "device_has_fp64", "get_program", "get_runtime", "kernel_source", "real_dtype",
           "survey", "use_device", "working_runtimes"]
