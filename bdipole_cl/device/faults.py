"""Faults of a process's environment, told apart from the device's (the probe's verdicts
are the device's and cached; an environment's fault serves the process only)."""
from __future__ import annotations

import os

from ..caches import cache_home

#: where a check's exception says more of this process's folders than of the device: the
#: file system, and pytools' cache (pyopencl's kernel invokers)
ENVIRONMENT_MODULES = ("pytools/persistent_dict.py",)
#: pyopencl 2026.1 reads this variable unguarded when a cached build fails for any reason but
#: BUILD_PROGRAM_FAILURE: the KeyError hides the real error, its ``__context__``
PYOPENCL_CACHE_KEY = "PYOPENCL_CACHE_FAILURE_FATAL"


def underlying(exc: BaseException) -> BaseException:
    """The error pyopencl's KeyError hides, else ``exc``."""
    hiding = ((PYOPENCL_CACHE_KEY,), (PYOPENCL_CACHE_KEY.encode(),))    # os.environ's too
    while isinstance(exc, KeyError) and exc.args in hiding and exc.__context__ is not None:
        exc = exc.__context__
    return exc


def environment_fault(exc: BaseException) -> bool:
    """Whether ``exc`` is a fault of the process's environment (a cache folder it cannot
    write), which the probe must not record as the device's; an OpenCL error never is."""
    import pyopencl as cl
    exc = underlying(exc)
    if isinstance(exc, cl.Error):
        return False
    if isinstance(exc, OSError):
        return True
    return in_caches(exc)


def in_caches(exc: BaseException) -> bool:
    """Whether ``exc`` was raised in pytools' cache (its sqlite errors name no file)."""
    tb = exc.__traceback__
    while tb is not None:
        if tb.tb_frame.f_code.co_filename.replace(os.sep, "/").endswith(ENVIRONMENT_MODULES):
            return True
        tb = tb.tb_next
    return False


def fault_words(exc: BaseException) -> str:
    """One line for an environment fault, naming pytools' folder where its error does not."""
    exc = underlying(exc)
    text = " ".join(str(exc).split())[:300] or type(exc).__name__
    where = "" if isinstance(exc, OSError) or not in_caches(exc) else \
        f" in pytools' cache folder {cache_home() / 'pytools'}"
    return f"{text}{where} (a fault of this process's folders, not of the device)"
