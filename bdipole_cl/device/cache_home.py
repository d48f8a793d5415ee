"""A writable cache home for the OpenCL stack, where the user's cannot be written.

pyopencl keeps its compiled programs, and pytools its kernel invokers, under
``$XDG_CACHE_HOME`` (else ``~/.cache``). Where that folder cannot be made or written (a render
node's read-only or missing home), neither falls back: pyopencl 2026.1 raises a ``KeyError``
on every program build and pytools an ``OSError`` on every kernel call, so no device works.
``ensure_writable_cache_home`` runs before pyopencl is imported. Where the cache home is not
writable it points ``XDG_CACHE_HOME`` at a private folder of this user's in the temporary
folder (``private_fallback``), for this process and those it starts; where none can be had, it
turns pyopencl's caches off (``PYOPENCL_NO_CACHE``). ``say_once`` warns of it at the first
device use (at import, the CLI's one-line warnings are not set up yet).
"""
from __future__ import annotations

import os
import stat
import tempfile
from pathlib import Path

from ..caches import CACHE_DIR_VARIABLE, cache_home
from ..errors import warn_caller

#: the fallback's name in the temporary folder, beside the runtime registration's fallback
FALLBACK_NAME = "bdipole_cl-{uid}-cache"
NO_CACHE = "PYOPENCL_NO_CACHE"

_note: str | None = None          # what was done, said once by ``say_once``
_moved_from: Path | None = None   # the cache home this process moved away from


def used_folders() -> tuple[str, ...]:
    """The cache home's folders the OpenCL stack writes: pyopencl's, pytools' and (unless
    ``POCL_CACHE_DIR`` moves it) PoCL's, which lists no device where it cannot make it."""
    return ("pyopencl", "pytools") + (() if os.environ.get("POCL_CACHE_DIR") else ("pocl",))


def moved_from() -> Path | None:
    """The cache home this process could not write and moved away from, or None."""
    return _moved_from


def writable(folder: Path, mode: int = 0o777) -> bool:
    """Whether ``folder`` exists or can be made (with ``mode``), and files can be made in it."""
    try:
        folder.mkdir(mode=mode, parents=True, exist_ok=True)
    except OSError:
        return False
    return os.access(folder, os.W_OK | os.X_OK)


def private(folder: Path) -> bool:
    """Whether ``folder`` is a folder (not a link) of this user's that no one else can write:
    the loader loads every ``.icd`` in a registration and pyopencl unpickles its cache, so a
    folder another user made first at a known name in ``/tmp`` must not be used."""
    try:
        info = folder.lstat()
    except OSError:
        return False
    return (stat.S_ISDIR(info.st_mode) and info.st_uid == os.getuid()
            and not info.st_mode & (stat.S_IWGRP | stat.S_IWOTH))


def private_folder(folder: Path) -> bool:
    """Make ``folder`` (mode 0700) where it is missing; whether it is then ``private``."""
    return writable(folder, 0o700) and private(folder)


def temporary_folder() -> Path | None:
    """The temporary folder (``TMPDIR``, else /tmp, ...), or None where none is usable."""
    try:
        return Path(tempfile.gettempdir())
    except OSError:
        return None


def fallback_path() -> Path | None:
    """``$TMPDIR/bdipole_cl-UID-cache``, private or not (None: no temporary folder)."""
    root = temporary_folder()
    return None if root is None else root / FALLBACK_NAME.format(uid=os.getuid())


def private_fallback() -> Path | None:
    """``fallback_path()``, where it is (or is made) a private folder, else None."""
    fallback = fallback_path()
    return fallback if fallback is not None and private_folder(fallback) else None


def turned_on(text: str | None) -> bool:
    """A variable read as pyopencl reads ``PYOPENCL_NO_CACHE`` (its ``strtobool``)."""
    return (text or "").strip().lower() in ("1", "y", "yes", "t", "true", "on")


def ensure_writable_cache_home() -> None:
    """Where the cache home is not writable: the private fallback as ``XDG_CACHE_HOME``, else
    pyopencl's caches off; a note for ``say_once`` either way."""
    global _note, _moved_from
    home = cache_home()
    if all(writable(folder) for folder in (home, *(home / name for name in used_folders()))):
        return
    fallback = private_fallback()
    if fallback is not None:
        _moved_from = home
        os.environ["XDG_CACHE_HOME"] = str(fallback)
        ours = "" if os.environ.get(CACHE_DIR_VARIABLE) else " and bdipole_cl's"
        _note = (f"the cache folder {home} (or its {', '.join(used_folders())} folder) "
                 f"cannot be written: the OpenCL compilers' caches"
                 f"{ours} are kept in {fallback} (set XDG_CACHE_HOME to keep them elsewhere)")
    elif not turned_on(os.environ.get(NO_CACHE)):    # on already: the user's, or a parent's
        os.environ[NO_CACHE] = "1"
        elsewhere = fallback_path()
        why = (f"{elsewhere} is not a folder of this user's that only it can write"
               if elsewhere else "there is no usable temporary folder")
        _note = (f"the cache folder {home} (or its {', '.join(used_folders())} folder) "
                 f"cannot be written, and {why}: pyopencl's caches are off, and OpenCL "
                 f"programs are built anew in each process (set XDG_CACHE_HOME to a writable "
                 f"folder)")


def say_once() -> None:
    """Warn of what ``ensure_writable_cache_home`` did, once a process."""
    global _note
    note, _note = _note, None
    if note:
        warn_caller(note, RuntimeWarning)
