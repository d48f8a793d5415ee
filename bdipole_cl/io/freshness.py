"""Is a scene output up to date? Its ``bdipole:*`` header records the parameters digest, the
library version and the input files (their quick key and their content digest); the output
itself must read completely (I/O layer)."""
from __future__ import annotations

import hashlib
import json
import os

import OpenImageIO as oiio

from ..version import __version__
from .verify import is_complete


def params_digest(fields: dict) -> str:
    text = json.dumps(fields, sort_keys=True, default=str)
    return hashlib.sha256(f"{__version__}\n{text}".encode()).hexdigest()[:32]


def file_stat(path) -> list:
    """The quick check's key: size, content time and inode change time. Content changed with
    the size and mtime restored (``touch -r``) still changes st_ctime, which no user call can
    set back; a changed key is not a rebuild, only a full content digest comparison."""
    st = os.stat(path)
    return [st.st_size, st.st_mtime_ns, st.st_ctime_ns]


def content_digest(paths) -> str:
    h = hashlib.blake2b(digest_size=16)
    for p in paths:
        with open(p, "rb") as f:
            for block in iter(lambda: f.read(1 << 22), b""):
                h.update(block)
    return h.hexdigest()


def header_fields(inputs: dict, digest: str) -> dict:
    """The ``bdipole:*`` attributes that make an output checkable later."""
    files = sorted(inputs.values())
    return {"version": __version__, "params_digest": digest,
            "inputs": json.dumps(inputs, sort_keys=True),
            "inputs_stat": json.dumps([file_stat(p) for p in files]),
            "inputs_digest": content_digest(files)}


def header_attribute(path, name):
    """Attribute ``name`` of the image header at ``path`` (None if it has none, or is not a
    readable regular file)."""
    if not os.path.isfile(path):
        return None
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        return None
    try:
        return inp.spec().getattribute(name)
    finally:
        inp.close()


def is_up_to_date(output, inputs: dict, digest: str) -> bool:
    if not os.path.isfile(output):       # missing, or not a regular file (never opened)
        return False
    inp = oiio.ImageInput.open(str(output))
    if inp is None:
        return False
    spec = inp.spec()
    inp.close()
    get = spec.getattribute
    if get("bdipole:params_digest") != digest or get("bdipole:version") != __version__:
        return False
    if get("bdipole:inputs") != json.dumps(inputs, sort_keys=True):
        return False
    files = sorted(inputs.values())
    try:
        same = get("bdipole:inputs_stat") == json.dumps([file_stat(p) for p in files])
        if not same and get("bdipole:inputs_digest") != content_digest(files):
            return False
    except OSError:
        return False
    return is_complete(output)           # a truncated output with an intact header is not
