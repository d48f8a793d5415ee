"""bdipole_cl: the Better Dipole (d'Eon 2012) and its texture-mapping inversion (Hery, Pixar
TM 12-11) as OpenCL batch kernels with a thin NumPy host layer.

Layers, each importing only those below it (docs/layout.md):

    applications   apps/      cli, report, crosscheck, demo, benchmark; dask.py, scene.py
    jobs           jobs/      job records, the one runner, batches, file blur, scenes
    I/O            io/        images, colour, tiles, patterns, scene files (read and written)
    operations     ops/       invert, physics_eval, bands, blur/
    method choice  methods/   registry of methods and knobs, measured choice data
    device         device/    runtimes and probing, programs, kernel sources, parameter layout
    physics        physics/   reference (float64 truth), fresnel, models, tables
    foundation                errors (invalid input, on_invalid), caches, vocabulary (option
                              kinds: one registry each, docs/python.md "Vocabulary")

Float64 reference of every function: ``bdipole_cl.reference``.
"""
import importlib
import importlib.abc
import importlib.util
import sys

from .signals import quiet_startup

quiet_startup()            # in the `bdipole-cl` command: a signal while it loads, one line

#: modules importable by a public path other than their own: those that moved to ``jobs/``
#: (the job layer) by their old paths, and the float64 reference as ``bdipole_cl.reference``
MOVED_MODULES = {**{f"{__name__}.io.{name}": f"{__name__}.jobs.{name}"
                    for name in ("batch", "blur_file", "scene", "scene_records", "scene_stats")},
                 f"{__name__}.reference": f"{__name__}.physics.reference"}


class _MovedModuleFinder(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Imports ``bdipole_cl.io.batch`` (say) as the one module ``bdipole_cl.jobs.batch``."""

    def __init__(self):
        self._own_specs = {}                      # alias name: the module's own spec

    def find_spec(self, fullname, path=None, target=None):
        if fullname in MOVED_MODULES:
            return importlib.util.spec_from_loader(fullname, self)
        return None

    def create_module(self, spec):
        module = importlib.import_module(MOVED_MODULES[spec.name])
        self._own_specs[spec.name] = module.__spec__
        return module

    def exec_module(self, module):
        # the import machinery set the alias's spec: give the module back its own (keyed by
        # the alias, so that two aliases imported at once in two threads cannot swap them)
        module.__spec__ = self._own_specs.pop(module.__spec__.name)


if not any(isinstance(f, _MovedModuleFinder) for f in sys.meta_path):
    sys.meta_path.insert(0, _MovedModuleFinder())

from .caches import clear_caches
from .device import DeviceError, DeviceState, Runtime, get_runtime, survey, use_device
from .errors import POLICIES, InvalidInputError
from .methods.registry import METHODS, MethodConfig
from .ops.blur import BlurInfo, BlurPlan, ChannelInfo, Scattering, blur, plan_blur
from .ops.invert import (OUTPUTS, InversionPlan, albedo_to_coefficients, invert_albedo,
                         plan_inversion)
from .physics import reference
from .physics.conventions import CONVENTIONS
from .physics.conversion import Conversion, convert
from .physics.models import MODELS
from .version import __version__



def stretch_maps(mesh, output=None, **options):
    """The stretch maps of a USD or OBJ mesh, per UDIM tile (``io.stretch_maps.stretch_maps``:
    ``size``, ``unit``, ``time``, ``prim``, ``meters_per_unit``), written to ``output`` (a
    pattern such as ``stretch.<UDIM>.exr``) if given: [(StretchTile, path)]. A StretchTile is
    what ``blur(..., stretch=)`` takes (docs/stretch.md)."""
    from .io import stretch_maps as maps_io
    return maps_io.stretch_maps(mesh, output, **options)


__all__ = [
    "CONVENTIONS",
    "METHODS",
    "MODELS",
    "OUTPUTS",
    "POLICIES",
    "BlurInfo",
    "BlurPlan",
    "ChannelInfo",
    "Conversion",
    "DeviceError",
    "DeviceState",
    "InvalidInputError",
    "InversionPlan",
    "MethodConfig",
    "Runtime",
    "Scattering",
    "__version__",
    "albedo_to_coefficients",
    "blur",
    "clear_caches",
    "convert",
    "get_runtime",
    "invert_albedo",
    "plan_blur",
    "plan_inversion",
    "reference",
    "stretch_maps",
    "survey",
    "use_device",
]
