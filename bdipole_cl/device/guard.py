"""Programs built first in a child process (the device layer): a runtime's compiler crash on a
program costs that program, never the user's process.

The probe (``isolation``) builds and runs each kernel family at each width, but jobs build
specialisations it never saw: their constants, outputs and checks compiled in. So the first
build of each program on a device (its exact source and options) happens first in a child
process, ``python -m bdipole_cl.device.build_child`` (one per device and process, kept for
the next build): it builds the program, asks for its binaries (PoCL generates machine code then) and
creates every kernel. Where the child survives, the program is built here, from the runtime's
caches the child warmed (PoCL's kernel cache, pyopencl's binaries); where it dies or hangs, the
program is refused with ``BuildRefused``, one line naming how, and the caller falls back (a
narrower width: ``ops.widths.built_at_width``) or fails its job. What each build did is kept
beside the device's verdict (``<verdict>.builds/``: a file per program, ``.ok`` or ``.bad``
with the reason), so each program is tried in a child once per device, driver and kernels.

A compile error is no crash: the child says it survived, and the build here raises pyopencl's
error with the log as before. The probe's own child builds unguarded (it is the guard there).
"""
from __future__ import annotations

import hashlib
import json
import logging
import os
import tempfile
import threading
from dataclasses import dataclass
from pathlib import Path

from ..durable import durable_replace
from .children import TIMED_OUT, Child, death
from .isolation import CONFIG_TIMEOUT_S, KILLED, START_TIMEOUT_S, verdict_path
from .runtime import DeviceError

log = logging.getLogger("bdipole_cl")

#: the module the guard's child runs (``build_child``: imported by nothing, so that ``-m`` runs
#: it fresh)
GUARD_MODULE = "bdipole_cl.device.build_child"
#: a build record's name: 24 hex digits of the program's digest, then its outcome
RECORD_SUFFIXES = (".ok", ".bad")


class BuildRefused(DeviceError):
    """A program whose build crashed (or hung) a runtime in the guard's child: not built here."""


@dataclass(frozen=True)
class Outcome:
    """What building one program did in the child: survived, or how it died."""

    ok: bool
    reason: str = ""


def program_digest(source: str, options) -> str:
    """The program's identity: its source and options."""
    h = hashlib.sha256(source.encode())
    for opt in options:
        h.update(b"\0" + str(opt).encode())
    return h.hexdigest()[:24]


def records_dir(device, kernels_digest: str) -> Path:
    """The device's build records, beside its verdict (the same key: device, driver,
    kernels, checks and version)."""
    return verdict_path(device, kernels_digest).with_suffix(".builds")


def read_record(folder: Path, digest: str) -> Outcome | None:
    if (folder / f"{digest}.ok").is_file():
        return Outcome(True)
    try:
        return Outcome(False, json.loads((folder / f"{digest}.bad").read_text())["reason"])
    except (OSError, ValueError, KeyError, TypeError):
        return None


def write_record(folder: Path, digest: str, outcome: Outcome) -> None:
    """Keep ``outcome`` (temporary file, then a rename); an unwritable cache costs only the
    next process a child build."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=folder, prefix=".build-", suffix=".tmp")
        with os.fdopen(fd, "w") as f:
            if not outcome.ok:
                json.dump({"reason": outcome.reason}, f)
        durable_replace(tmp, folder / f"{digest}{'.ok' if outcome.ok else '.bad'}")
    except OSError as exc:
        log.debug("build record not kept in %s: %s", folder, exc)


class _Guard:
    """One device's child, started on the first build that needs it and kept."""

    def __init__(self, device_index: str):
        self.device_index = device_index
        self.child: Child | None = None
        self.lock = threading.Lock()

    def try_build(self, source: str, options) -> Outcome:
        with self.lock:
            if self.child is None or not self.child.alive():
                self.child = Child(GUARD_MODULE, ["--device", self.device_index], requests=True)
                if not self._ready():
                    return Outcome(True, "unguarded")
            if not self.child.send({"source": source, "options": list(options)}):
                return self._died(kill=True)
            try:
                msg = self._answer()
            except BaseException:            # an interrupt: the child goes with it
                self._died(kill=True)
                raise
            if msg is TIMED_OUT:
                return self._died(kill=True, how=f"timed out after {CONFIG_TIMEOUT_S:.0f} s")
            if msg is None:
                return self._died()
            return Outcome(True)

    def _ready(self) -> bool:
        """Whether the child opened its device; where it cannot start at all (no Python, no
        device there), builds go unguarded, said once."""
        msg = self.child.line(START_TIMEOUT_S)
        if isinstance(msg, dict) and msg.get("ready"):
            return True
        rc, err = self.child.finish(kill=True)
        self.child = None
        log.warning("the guarded builds' child process could not start (%s); programs are built "
                    "unguarded in this process", msg.get("error") if isinstance(msg, dict)
                    and msg.get("error") else death(rc, err))
        return False

    def _answer(self):
        while True:
            msg = self.child.line(CONFIG_TIMEOUT_S)
            if msg is TIMED_OUT or msg is None or "built" in msg:
                return msg

    def _died(self, kill=False, how="") -> Outcome:
        rc, err = self.child.finish(kill=kill)
        self.child = None
        return Outcome(False, how or death(rc, err))


_lock = threading.Lock()
_guards: dict = {}                 # device int_ptr -> _Guard
_outcomes: dict = {}               # (device int_ptr, digest) -> Outcome (this process)


def guard_for(device, device_index: str) -> _Guard:
    with _lock:
        return _guards.setdefault(device.int_ptr, _Guard(device_index))


def checked_build(device, device_index: str, kernels_digest: str, source: str, options,
                  what: str) -> None:
    """Return where building ``source`` with ``options`` on ``device`` is known not to crash
    (this process's record, the disk's, or the guard's child building it now); raise
    BuildRefused naming ``what`` and how the child died where it is not."""
    digest = program_digest(source, options)
    key = (device.int_ptr, digest)
    with _lock:
        outcome = _outcomes.get(key)
    if outcome is None:
        folder = records_dir(device, kernels_digest)
        outcome = read_record(folder, digest)
        if outcome is None:
            outcome = guard_for(device, device_index).try_build(source, options)
            if outcome.reason != "unguarded" and KILLED not in outcome.reason:
                write_record(folder, digest, outcome)      # a kill from outside: next time
        with _lock:
            _outcomes[key] = outcome
    if not outcome.ok:
        raise BuildRefused(f"{what}: building it crashed this device's runtime in a child "
                           f"process ({outcome.reason}); not built here (`bdipole-cl cache "
                           f"--clear` tries again)")


def forget_outcomes() -> None:
    """Drop this process's records (the disk's stay) and end its children, so that the next
    build starts one in the environment as it is now: tests."""
    with _lock:
        _outcomes.clear()
        guards = list(_guards.values())
        _guards.clear()
    for g in guards:
        with g.lock:
            if g.child is not None:
                g.child.finish(kill=True)
                g.child = None
