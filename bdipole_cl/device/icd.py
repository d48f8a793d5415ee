"""OpenCL runtimes installed into the Python environment, made visible to the ICD loader.

pyopencl's wheel ships the ocl-icd loader and finds its own PoCL by itself. Intel's CPU runtime
from PyPI (``intel-opencl-rt``) is different: its wheel puts ``libintelocl.so`` in the
environment's ``lib/`` and an ``etc/OpenCL/vendors/intel-cpu.icd`` whose path is a build-time
placeholder, so the loader never finds it. ``register_environment_runtimes`` fixes that
without any variable set by the user:

- it writes a vendors directory holding every ``.icd`` the loader would have read anyway (the
  user's ``OCL_ICD_VENDORS`` if set, else ``/etc/OpenCL/vendors``) plus one naming the absolute
  path of the environment's ``libintelocl.so``, and points ``OCL_ICD_VENDORS`` at it;
- it preloads the runtime's support libraries (``libimf``, ``libintlc``, ``libirng``,
  ``libsvml``) from the same ``lib/``, globally, so that the runtime and the code it compiles
  resolve them whatever the loader's search path.

It must run before the first platform query of the process (``bdipole_cl.device`` calls it on
import, before importing pyopencl). ``PYOPENCL_CTX`` is untouched and still selects among all.
Set ``BDIPOLE_CL_ENV_RUNTIMES=0`` to leave the loader exactly as the user configured it.

The folder may be removed while processes use it (``bdipole-cl cache --clear`` in another
shell). ocl-icd reads ``OCL_ICD_VENDORS`` at the first platform query and takes a path that is
not a folder for one library, which hides every runtime, PoCL's too. So ``ensure_registered``
writes the folder again just before that query, and the processes this one starts (Dask
workers, probes) register again from the user's own setting, which ``BEFORE`` carries.
"""
from __future__ import annotations

import ctypes
import hashlib
import os
import re
import site
import sys
from dataclasses import dataclass
from pathlib import Path

from ..caches import user_cache_dir
from .cache_home import private_folder, temporary_folder

#: the ICD library of Intel's CPU runtime, as the ``intel-opencl-rt`` wheel installs it
INTEL_ICD_LIBRARY = "libintelocl.so"
#: its support libraries (``intel-cmplr-lib-rt``), preloaded with RTLD_GLOBAL
INTEL_SUPPORT_LIBRARIES = ("libimf.so", "libintlc.so.5", "libirng.so", "libsvml.so")
SYSTEM_VENDORS = Path("/etc/OpenCL/vendors")
SWITCH = "BDIPOLE_CL_ENV_RUNTIMES"
#: the user's own ``OCL_ICD_VENDORS`` ('' where unset), set beside a registration
BEFORE = "BDIPOLE_CL_OCL_ICD_VENDORS_BEFORE"
#: a registration's folder: ``icd-`` and 16 hex digits (``vendors_directory``)
ICD_NAME = re.compile(r"^icd-[0-9a-f]{16}$")


@dataclass(frozen=True)
class EnvironmentRuntime:
    """One runtime found in the environment and how it was registered."""

    name: str
    library: Path
    registered: bool
    note: str = ""


_registered: list[EnvironmentRuntime] | None = None
#: this process's registration: the folder ``OCL_ICD_VENDORS`` names and what it holds
_registration: tuple[Path, dict[str, str]] | None = None


def environment_lib_dirs() -> list[Path]:
    """Where pip puts a wheel's ``data/lib`` files: the environment's prefix, then the user's
    base (``pip install --user``)."""
    dirs = [Path(sys.prefix) / "lib"]
    user = site.getuserbase()
    if user:
        dirs.append(Path(user) / "lib")
    return [d for d in dict.fromkeys(dirs) if d.is_dir()]


def find_intel_runtime(lib_dirs=None) -> Path | None:
    """``libintelocl.so`` of the environment, or None."""
    for d in environment_lib_dirs() if lib_dirs is None else lib_dirs:
        candidate = Path(d) / INTEL_ICD_LIBRARY
        if candidate.is_file():
            return candidate.resolve()
    return None


def existing_icd_entries(vendors: str | None) -> dict[str, str]:
    """The ``.icd`` files the loader would read on its own: {file name: content}.

    ``vendors`` is ``OCL_ICD_VENDORS`` as the user set it (a directory, an ``.icd`` file or a
    library path; ocl-icd accepts all three), or None for the system directory."""
    if vendors:
        path = Path(vendors)
        if path.is_dir():
            files = sorted(path.glob("*.icd"))
        elif path.suffix == ".icd" and path.is_file():
            files = [path]
        else:                                   # a library named directly
            return {f"user-{path.name}.icd": str(path) + "\n"}
    else:
        files = sorted(SYSTEM_VENDORS.glob("*.icd")) if SYSTEM_VENDORS.is_dir() else []
    entries = {}
    for f in files:
        try:
            entries[f.name] = f.read_text()
        except OSError:
            continue
    return entries


def users_vendors() -> str | None:
    """``OCL_ICD_VENDORS`` as the user set it. Where it names a registration folder inherited
    from a parent process, the value that parent found (``BEFORE``): the folder may be gone,
    and registering from it would nest one registration in another."""
    current = os.environ.get("OCL_ICD_VENDORS")
    if current and BEFORE in os.environ and ICD_NAME.match(Path(current).name):
        return os.environ[BEFORE] or None
    return current


def restore_users_vendors() -> None:
    """The loader as the user configured it, where a parent's registration was inherited
    (``SWITCH`` at 0 in a process started by one that registered)."""
    before = users_vendors()
    if before is None:
        os.environ.pop("OCL_ICD_VENDORS", None)
    else:
        os.environ["OCL_ICD_VENDORS"] = before


def vendors_roots() -> tuple[Path, Path | None]:
    """Where vendors directories (``icd-*``) are written: the user's cache, else a folder of
    this user's in the temporary directory (None where there is no temporary folder)."""
    temporary = temporary_folder()
    return user_cache_dir(), temporary and temporary / f"bdipole_cl-{os.getuid()}"


def vendors_directory(entries: dict[str, str]) -> Path:
    """A directory holding exactly ``entries``, named by their content so that processes with
    the same set share it; written atomically (each file via a temporary name)."""
    digest = hashlib.sha256(repr(sorted(entries.items())).encode()).hexdigest()[:16]
    own, temporary = vendors_roots()
    tried = []
    for root in (own, temporary):
        if root is None:
            continue
        tried.append(str(root))
        if root == temporary and not private_folder(root):
            tried[-1] += " (not a folder of this user's that only it can write)"
            continue                # another user's, at a known name: its .icd would load
        target = root / f"icd-{digest}"
        try:
            target.mkdir(parents=True, exist_ok=True)
            for name, content in entries.items():
                dest = target / name
                if not dest.is_file() or dest.read_text() != content:
                    tmp = target / f".{name}.{os.getpid()}.tmp"
                    tmp.write_text(content)
                    os.replace(tmp, dest)
            return target
        except OSError:
            continue
    raise OSError(f"no writable directory for the OpenCL vendors list (tried "
                  f"{', '.join(tried) or 'none'})")


def _preload(lib_dir: Path) -> list[str]:
    missing = []
    for name in INTEL_SUPPORT_LIBRARIES:
        path = lib_dir / name
        try:
            ctypes.CDLL(str(path), mode=ctypes.RTLD_GLOBAL)
        except OSError:
            missing.append(name)
    return missing


def register_environment_runtimes() -> list[EnvironmentRuntime]:
    """Register the environment's OpenCL runtimes with the ICD loader (once per process)."""
    global _registered, _registration
    if _registered is not None:
        return _registered
    _registered = []
    if os.environ.get(SWITCH, "1") == "0":
        restore_users_vendors()
        return _registered
    library = find_intel_runtime()
    if library is None:
        return _registered
    before = users_vendors()
    entries = existing_icd_entries(before)
    if any(Path(c.strip()).name == INTEL_ICD_LIBRARY for c in entries.values()):
        _registered.append(EnvironmentRuntime("Intel CPU runtime", library, False,
                                              "already registered by the system"))
        return _registered
    missing = _preload(library.parent)
    entries["bdipole_cl-intel-cpu.icd"] = f"{library}\n"
    try:
        directory = vendors_directory(entries)
    except OSError as exc:
        _registered.append(EnvironmentRuntime("Intel CPU runtime", library, False, str(exc)))
        return _registered
    _registration = directory, entries
    os.environ[BEFORE] = before or ""
    os.environ["OCL_ICD_VENDORS"] = str(directory)
    note = f"support libraries not found: {', '.join(missing)}" if missing else ""
    _registered.append(EnvironmentRuntime("Intel CPU runtime", library, True, note))
    return _registered


def ensure_registered() -> None:
    """Write this process's registration folder again where it was removed since (called just
    before a platform query; the loader reads the folder at the first one)."""
    global _registration
    if _registration is None:
        return
    directory, entries = _registration
    if os.environ.get("OCL_ICD_VENDORS") != str(directory):
        return                                  # the user pointed the loader elsewhere
    if all((directory / name).is_file() for name in entries):
        return
    try:
        directory = vendors_directory(entries)      # the other root, where this one is gone
    except OSError:
        return                      # no writable folder: the query reports what it finds
    _registration = directory, entries
    os.environ["OCL_ICD_VENDORS"] = str(directory)
