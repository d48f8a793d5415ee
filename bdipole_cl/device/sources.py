"""Where the kernel sources are, and their digest (the device layer's foundation: imported by
``programs`` and ``runtime`` alike)."""
from __future__ import annotations

import functools
import hashlib
from pathlib import Path

from . import layout

#: The header every kernel source is joined behind.
HEADER = "bdipole.h"


class KernelSourcesMissing(RuntimeError):
    """The kernel sources are not where the package expects them."""


def kernel_dir() -> Path:
    """``bdipole_cl/kernels`` in an installed wheel, else the source tree's ``kernels``."""
    package = Path(__file__).resolve().parent.parent
    for candidate in (package / "kernels", package.parent / "kernels"):
        if (candidate / HEADER).is_file():
            return candidate
    raise KernelSourcesMissing(f"kernel sources not found next to {package} (looked for "
                               f"{HEADER})")


@functools.lru_cache(maxsize=None)
def kernels_digest() -> str:
    """A digest of every kernel source (kernels/*.cl and *.h) and the generated layout: what a
    device's measured kernel shapes (``report --calibrate``'s widths and costs) were measured
    with, so that a later version's kernels do not run on shapes measured for other code."""
    d = kernel_dir()
    h = hashlib.sha256(layout.header().encode())
    for path in sorted(d.glob("*.cl")) + sorted(d.glob("*.h")):
        h.update(b"\0" + path.name.encode() + b"\0" + path.read_bytes())
    return h.hexdigest()[:16]


