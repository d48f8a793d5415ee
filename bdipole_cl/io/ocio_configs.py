"""OpenColorIO configs loaded once per process, and their processors (I/O layer): what
``colour`` converts with. OpenImageIO's ColorConfig of a name (names, aliases, interop IDs),
OpenColorIO's own Config (roles, identification), and a CPU processor per (config, source,
target, environment context)."""
from __future__ import annotations

import os
import threading

import OpenImageIO as oiio
import PyOpenColorIO as ocio

from .oiio_text import oiio_error

#: OpenColorIO's OPTIMIZATION_LOSSLESS (OpenColorTypes.h): no fast pow/log/exp approximations
if not os.environ.get("OCIO_OPTIMIZATION_FLAGS", "").strip():   # OCIO reads "" as unset
    os.environ["OCIO_OPTIMIZATION_FLAGS"] = "0x89c3fc3"

_configs: dict = {}
_lock = threading.Lock()


def oiio_config(name) -> "oiio.ColorConfig":
    """OpenImageIO's ColorConfig of ``name``, loaded once (ValueError if it cannot be)."""
    with _lock:
        cfg = _configs.get(name)
        if cfg is None:
            cfg = oiio.ColorConfig(name)
            err = oiio_error(cfg)
            if err or cfg.configname() != name:
                raise ValueError(f"OCIO config {name!r} cannot be used: "
                                 f"{' '.join((err or 'not found').split())}")
            _configs[name] = cfg
        return cfg


_pyocio_configs: dict = {}


def ocio_config(name):
    """OpenColorIO's own Config of ``name`` (roles, identification, processors), loaded once."""
    with _lock:
        cfg = _pyocio_configs.get(name)
        if cfg is None:
            cfg = _pyocio_configs[name] = ocio.Config.CreateFromFile(name)
        return cfg


_processors: dict = {}


def environment_context(config) -> "ocio.Context":
    """A new context of ``config`` with the environment as it is now, as loading the config
    afresh would give (OpenImageIO's colorconvert by name): its declared variables from the
    environment, else their defaults; every environment variable when it declares none. The
    config's own context is shared and loads the environment only once (never overwriting)."""
    base = config.getCurrentContext()
    if base.getEnvironmentMode() == ocio.ENV_ENVIRONMENT_LOAD_ALL:
        variables = dict(os.environ)
    else:
        variables = {n: os.environ.get(n, config.getEnvironmentVarDefault(n))
                     for n in config.getEnvironmentVarNames()}
    return ocio.Context(workingDir=base.getWorkingDir(), searchPaths=list(base.getSearchPaths()),
                        stringVars=variables, environmentMode=base.getEnvironmentMode())


def processor(name, source, target):
    """The CPU processor of ``source`` -> ``target`` in config ``name`` under the context of
    the environment now ($SHOT in a LUT path...), made once per context. Not OpenImageIO's
    colorconvert on its default config: that config is made from $OCIO at its first use, and
    reading it from Python (``ColorConfig.default_colorconfig``, OpenImageIO 3.2) moves it out
    of the process, so that its readers and writers afterwards name spaces through whatever
    $OCIO then names; by name it would load the config each call (30 ms).
    ``getDefaultCPUProcessor`` honours OCIO_OPTIMIZATION_FLAGS (lossless, above)."""
    config = ocio_config(name)
    context = environment_context(config)
    key = (name, source, target, context.getCacheID())
    with _lock:
        cpu = _processors.get(key)
    if cpu is None:
        cpu = config.getProcessor(context, source, target).getDefaultCPUProcessor()
        with _lock:
            cpu = _processors.setdefault(key, cpu)
    return cpu


def reset_config_cache() -> None:
    """Forget loaded configs (a config file edited in place is read again)."""
    with _lock:
        _configs.clear()
        _pyocio_configs.clear()
        _processors.clear()
