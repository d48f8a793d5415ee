"""bdipole_cl: the Better Dipole (d'Eon 2012) and its texture-mapping inversion (Hery, Pixar
TM 12-11) as OpenCL batch kernels with a thin NumPy host layer.

Float64 reference of every function: ``bdipole_cl.reference``.
"""
from . import reference
from .device import DeviceError, DeviceState, Runtime, get_runtime, survey, use_device
from .invert import (METHODS, InvalidInputError, MethodConfig, albedo_to_coefficients,
                     invert_albedo)

__version__ = "0.1.0"

__all__ = [
    "METHODS", "DeviceError", "DeviceState", "InvalidInputError", "MethodConfig", "Runtime",
    "albedo_to_coefficients", "get_runtime", "invert_albedo", "reference", "survey",
    "use_device",
]
