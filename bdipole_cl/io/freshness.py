"""Is a scene output up to date? Its ``bdipole:*`` header records the parameters digest, the
library version and the input files (their quick key and their content digest); the output
itself must read completely (I/O layer).

Did an input change while a job read it? ``InputGuard`` holds each input's identity (inode,
size, content and inode change times) as of the job's first read and checks it again just
before the output is put in place: a file re-exported in place (a new inode) or overwritten
(new times) in between fails the job, named, and nothing is written (the output would hold
the old content, or rows of both, and its time would make it look newer than the input).
"""
from __future__ import annotations

import hashlib
import json
import os

from ..version import __version__
from .images import TextureError, image_header
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


def input_identity(path) -> list | None:
    """An input file's identity as of now: [inode, size, mtime, ctime] (ns), None where it
    cannot be reached (``verify.file_identity``, an output's, needs no ctime: this tool
    writes outputs by renaming). No device number: a cluster's workers see one shared file under another device
    number than this process does. ctime changes with any write or rename onto the name,
    which no user call can set back."""
    try:
        st = os.stat(path)
    except OSError:
        return None
    return [st.st_ino, st.st_size, st.st_mtime_ns, st.st_ctime_ns]


def input_identities(inputs: dict) -> dict:
    """{role: ``input_identity``} of a job's input files (role -> path)."""
    return {role: input_identity(path) for role, path in inputs.items()}


def identity_change(before, now) -> str:
    """How a file changed between two identities, in words ("" when it did not)."""
    if before == now:
        return ""
    if now is None:
        return "it is gone"
    if before is None:
        return "it appeared"
    if before[0] != now[0]:
        return "it was replaced by another file (re-exported in place)"
    if before[1] != now[1]:
        return f"its size went from {before[1]} to {now[1]} bytes"
    return "it was rewritten" if before[2] != now[2] else "its inode changed (ctime)"


class InputChanged(TextureError):
    """An input changed between a job's first and last read: nothing is written."""


class InputGuard:
    """The identities of a job's inputs (role -> path) as of its first read: ``identities``
    where the caller took them then (a scene's plan, the CLI before it reads a parameter
    texture), else now. ``check()`` raises InputChanged naming the first that differs."""

    def __init__(self, inputs: dict, identities: dict | None = None):
        self.inputs = {r: str(p) for r, p in inputs.items() if p}
        self.before = {r: (identities or {}).get(r, input_identity(p))
                       for r, p in self.inputs.items()}

    def check(self):
        for role, path in self.inputs.items():
            why = identity_change(self.before[role], input_identity(path))
            if why:
                raise InputChanged(f"{path}: the {role} changed while the job read it ({why}):"
                                   f" nothing written; run it again")
