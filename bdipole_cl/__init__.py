"""bdipole_cl: the Better Dipole (d'Eon 2012) and its texture-mapping inversion (Hery, Pixar
TM 12-11) as OpenCL batch kernels with a thin NumPy host layer.

Layers, each importing only those below it (README "Layout"):

    applications   apps/      cli, report, crosscheck, demo, benchmark
    I/O            io/        images, texture batches, file-to-file blur
    operations     ops/       invert, physics_eval, bands, blur/
    method choice  methods/   registry of methods and knobs, measured choice data
    device         device/    runtimes and probing, programs, kernel sources, parameter layout
    physics        physics/   reference (float64 truth), tables
    foundation                errors (invalid input, on_invalid), caches

Float64 reference of every function: ``bdipole_cl.reference``.
"""
from .caches import clear_caches  # noqa: E402
from .device import DeviceError, DeviceState, Runtime, get_runtime, survey, use_device  # noqa: E402
from .errors import POLICIES, InvalidInputError  # noqa: E402
from .methods.registry import METHODS, MethodConfig  # noqa: E402
from .ops.blur import BlurInfo, ChannelInfo, blur  # noqa: E402
from .ops.invert import OUTPUTS, albedo_to_coefficients, invert_albedo  # noqa: E402
from .physics import reference  # noqa: E402
from .version import __version__  # noqa: E402

__all__ = [
    "METHODS", "OUTPUTS", "POLICIES", "BlurInfo", "ChannelInfo", "DeviceError", "DeviceState",
    "InvalidInputError", "MethodConfig", "Runtime", "albedo_to_coefficients", "blur",
    "clear_caches", "get_runtime", "invert_albedo", "reference", "survey", "use_device",
    "__version__",
]
