"""A writable cache home for the OpenCL stack, where the user's cannot be written.

pyopencl keeps its compiled programs, and pytools its kernel invokers, under
``$XDG_CACHE_HOME`` (else ``~/.cache``). Where that folder cannot be made or written (a render
node's read-only or missing home), neither falls back: pyopencl 2026.1 raises a ``KeyError``
on every program build and pytools an ``OSError`` on every kernel call, so no device works.
``ensure_writable_cache_home`` runs before pyopencl is imported: where the cache home is not
writable it points ``XDG_CACHE_HOME`` at a folder of this user's in the temporary folder, for
this process and those it starts, and warns once naming both.
"""
from __future__ import annotations

import os
import tempfile
import warnings
from pathlib import Path

from ..caches import cache_home

#: the fallback's name in the temporary folder, beside the runtime registration's fallback
FALLBACK_NAME = "bdipole_cl-{uid}-cache"


def writable(folder: Path) -> bool:
    """Whether ``folder`` exists or can be made, and files can be made in it."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError:
        return False
    return os.access(folder, os.W_OK | os.X_OK)


def ensure_writable_cache_home() -> Path | None:
    """Point ``XDG_CACHE_HOME`` at the fallback where the cache home is not writable; the
    fallback, or None where nothing changed (or no fallback is writable either)."""
    home = cache_home()
    if writable(home):
        return None
    fallback = Path(tempfile.gettempdir()) / FALLBACK_NAME.format(uid=os.getuid())
    if not writable(fallback):
        return None
    os.environ["XDG_CACHE_HOME"] = str(fallback)
    warnings.warn(f"the cache folder {home} cannot be written: the OpenCL compilers' caches "
                  f"and bdipole_cl's are kept in {fallback} (set XDG_CACHE_HOME to keep them "
                  f"elsewhere)", RuntimeWarning, stacklevel=2)
    return fallback
