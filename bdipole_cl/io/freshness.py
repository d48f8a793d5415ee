"""Is a scene output up to date? Its ``bdipole:*`` header records the parameters digest, the
library version and the input files (their quick key and their content digest); the output
itself must read completely (I/O layer)."""
from __future__ import annotations

import hashlib
import json
import os

from ..version import __version__
from .images import image_header
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


def is_up_to_date(output, inputs: dict, digest: str) -> bool:
    spec = image_header(output)          # None: missing, unreadable, or not a regular file
    if spec is None:
        return False
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
