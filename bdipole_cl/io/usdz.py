"""Textures packaged inside a ``.usdz`` (a zip archive whose files are stored uncompressed, so
that a renderer maps them in place): USD names one as ``/path/asset.usdz[tex/a.exr]``, which no
image reader opens. A bake reads it from a copy in the user's cache, extracted once per
package content (its path, size, modification time and inode key the folder): the package is
never written, and a changed package is extracted anew, so its materials rebake.
"""
from __future__ import annotations

import hashlib
import os
import re
import tempfile
import zipfile

from ..caches import user_cache_dir
from ..durable import durable_replace
from . import tiles

#: the folder of the user's cache (``caches.user_cache_dir``) that holds extracted packages,
#: one subfolder per package content, named by EXTRACTED_NAME
EXTRACTED_FOLDER = "usdz"
EXTRACTED_NAME = re.compile(r"^[0-9a-f]{20}$")

#: ``package.usdz[member]``: a file inside a package, as USD's resolver names it
PACKAGED = re.compile(r"^(?P<package>.+?\.usdz)\[(?P<member>.+)\]$", re.IGNORECASE)


def is_packaged(path: str) -> bool:
    return PACKAGED.match(str(path)) is not None


def in_package(layer_path: str) -> bool:
    """Whether a layer's real path is a package (its root layer) or a layer inside one."""
    return str(layer_path).lower().endswith(".usdz") or is_packaged(layer_path)


def anchored(layer_path: str, path: str) -> str:
    """Relative asset ``path`` (a <UDIM> pattern, which USD's resolver leaves as it is) of a
    layer in a package, as USD names a packaged file: the package's root layer sits at the
    archive's root, ``package.usdz[sub/layer.usda]`` in ``sub/``."""
    match = PACKAGED.match(str(layer_path))
    package, folder = ((match["package"], os.path.dirname(match["member"])) if match
                       else (str(layer_path), ""))
    return f"{package}[{os.path.normpath(os.path.join(folder, path))}]"


def extracted(path: str) -> str:
    """The path (or <UDIM> pattern) of packaged texture ``path`` in the cache's copy of its
    package, the member (every tile of a pattern) extracted there if not already; a
    ValueError naming the package and member where it is not in the package, is in a package
    nested in the package, or would leave the copy's folder (``..``)."""
    match = PACKAGED.match(str(path))
    package, member = match["package"], match["member"]
    if "[" in member:
        raise ValueError(f"{path}: a texture in a package inside a package: unpack the outer "
                         f"package")
    root = package_folder(package)
    with zipfile.ZipFile(package) as archive:
        names = members(archive.namelist(), member)
        if not names:
            raise ValueError(f"{package} holds no {member}")
        for name in names:
            target = os.path.normpath(os.path.join(root, name))
            if not target.startswith(root + os.sep):
                raise ValueError(f"{package}: member {name} would be written outside its "
                                 f"folder (..): not read")
            if not os.path.isfile(target):
                extract(archive, name, target)
    copy = os.path.join(root, member)
    ORIGINS[copy] = str(path)
    return copy


#: {a copy's path (or pattern): the packaged path it was extracted from}, of this process:
#: what a bake writes names the package's member (``origin``), never the user's cache
ORIGINS = {}


def origin(path: str) -> str | None:
    """The packaged path (``package.usdz[member]``) a cache copy was extracted from, else
    None."""
    return ORIGINS.get(str(path))


def package_folder(package: str) -> str:
    """The cache folder of this content of ``package``."""
    st = os.stat(package)
    key = f"{os.path.realpath(package)}\0{st.st_size}\0{st.st_mtime_ns}\0{st.st_ino}"
    digest = hashlib.sha256(key.encode()).hexdigest()[:20]
    return os.path.join(str(user_cache_dir()), EXTRACTED_FOLDER, digest)


def members(names, member: str) -> list:
    """The archive's names that ``member`` names: itself, or where it is a tile pattern
    (``tex/a.<UDIM>.exr``) every name that fills it."""
    if tiles.token_of(member) is None:
        return [n for n in names if n == member]
    return [n for n in names if tiles.match(member, n) is not None]


def extract(archive, name: str, target: str):
    """Member ``name`` written at ``target`` (temporary file + durable rename: a copy is whole
    or absent, whatever stops the bake)."""
    os.makedirs(os.path.dirname(target), exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=os.path.dirname(target), prefix=".extract-")
    try:
        with os.fdopen(fd, "wb") as out, archive.open(name) as src:
            while chunk := src.read(1 << 20):
                out.write(chunk)
        durable_replace(tmp, target)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
