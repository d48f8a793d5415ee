"""Shared test helpers. Kernel tests run once per working OpenCL device, in the manner of
pyopencl's ``ctx_factory``: the ``runtime`` fixture is parametrised over
``bdipole_cl.device.working_runtimes()`` (restrict with ``BDIPOLE_CL_TEST_DEVICES``, a comma list
of device specs such as ``intel,pocl`` or ``0:0``). Modules that reach kernels through the public
API use ``on_device``, which makes the parametrised device the default for the test."""
import os

import numpy as np
import pytest

# Tests start from OpenColorIO's built-in config, whatever the user's shell sets; those about
# a studio config set $OCIO themselves (OpenImageIO's writers name spaces through a default
# config made from $OCIO at its first use in the process: tests/test_colour.py)
os.environ.pop("OCIO", None)

import bdipole_cl  # noqa: E402
from bdipole_cl import device  # noqa: E402
from bdipole_cl import reference as ref  # noqa: E402

#: float32 unit roundoff (half an ulp of 1); tolerances below are multiples of it.
EPS32 = 2.0**-24
EPS64 = 2.0**-53


def short_id(rt):
    """A test id per device: the implementation's short name (and index if it repeats)."""
    platform = rt.device.platform.name.lower()
    return ("intel" if "intel" in platform else "pocl" if "portable" in platform
            else rt.device.name.strip().split()[0].lower())


def _test_runtimes():
    wanted = os.environ.get("BDIPOLE_CL_TEST_DEVICES")
    if wanted:
        rts = [device.get_runtime(spec.strip()) for spec in wanted.split(",") if spec.strip()]
    else:
        rts = device.working_runtimes()
    if not rts:
        # never an empty parametrisation (pytest would skip every kernel test silently)
        raise device.DeviceError("no working OpenCL device to test on; see `bdipole-cl devices`")
    return rts


RUNTIMES = _test_runtimes()
_ids = [short_id(rt) for rt in RUNTIMES]
RUNTIME_IDS = [i if _ids.count(i) == 1 else f"{i}{k}" for k, i in enumerate(_ids)]


#: modules of files, scenes and commands (I/O, colour, tiles, USD and MaterialX, records,
#: pictures): what they check does not depend on the device, so they run on the first device
#: under test only; the kernels they call are checked on every device by the kernel modules
#: and the crosscheck. (Twice over two runtimes, they were a third of a cold suite's time.)
ONE_DEVICE_MODULES = {
    "test_colour", "test_tiles", "test_texture_outputs", "test_usd_import_faults",
    "test_usd_scene", "test_scene", "test_bake_materials", "test_mtlx_scene", "test_textures",
    "test_bake_records", "test_input_changes", "test_mfp_kind", "test_jobs", "test_pictures",
    "test_invert_plan", "test_report",
}


def pytest_generate_tests(metafunc):
    if "runtime" in metafunc.fixturenames:
        one = metafunc.module.__name__.rsplit(".", 1)[-1] in ONE_DEVICE_MODULES
        metafunc.parametrize("runtime", RUNTIMES[:1] if one else RUNTIMES,
                             ids=RUNTIME_IDS[:1] if one else RUNTIME_IDS, indirect=True,
                             scope="session")


def pytest_report_header(config):
    return ["OpenCL devices under test: " + "; ".join(
        f"{i} = {rt.describe()}" for i, rt in zip(RUNTIME_IDS, RUNTIMES))]


@pytest.fixture(scope="session")
def runtime(request):
    return request.param


@pytest.fixture
def on_device(runtime):
    """The parametrised device as the process default, for code that takes ``device=None``."""
    bdipole_cl.use_device(runtime)
    return runtime


@pytest.fixture(autouse=True)
def no_stop_request_left():
    """Each test starts un-stopped: a command that a test stops with SIGINT or SIGTERM
    (``cli_main`` in this process) returns with its stop request still set, as a command
    should for its own process's end, and the next test's library calls, which no command
    clears it for, raised ``Stopped`` (which tests failed depended on how xdist shared them
    out)."""
    from bdipole_cl.signals import clear_stop
    clear_stop()
    yield
    clear_stop()


@pytest.fixture(scope="session")
def has_fp64(runtime):
    return runtime.has_fp64


def skip_if_rejected(rt, source, width=None):
    """Skip where the device's probe rejected kernels/<source>.cl at ``width``: the library
    never builds it there (building it could crash the process: bdipole_cl/device/isolation)."""
    from bdipole_cl.device.isolation import config_name
    options = () if width is None else (f"-DBD_WIDTH={width}",)
    name = config_name(source, options)
    known = device.runtime.known_verdict(rt.device)
    result = None if known is None else known.result(name)
    if result is not None and not result.ok:
        pytest.skip(f"{name} was rejected by this device's probe: {result.reason}")


def f32(x):
    """Round to float32 and back, so the float64 reference sees exactly the kernel's input."""
    return np.asarray(x, dtype=np.float32).astype(np.float64)


def stiff_albedos(n=2000):
    """Rd sweeping both stiff ends geometrically plus the middle, as float32 values."""
    return f32(np.concatenate([np.geomspace(1e-6, 0.5, n), 1.0 - np.geomspace(1e-3, 0.5, n),
                               np.linspace(1e-6, 0.999, n)]))


def rel_err(got, want):
    got = np.asarray(got, np.float64)
    want = np.asarray(want, np.float64)
    return np.abs(got - want) / np.abs(want)


__all__ = ["EPS32", "EPS64", "f32", "skip_if_rejected", "stiff_albedos", "rel_err", "ref"]
