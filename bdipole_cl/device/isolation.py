"""Kernel probes in a child process, and their verdicts cached on disk (the device layer).

A runtime's compiler can crash inside the process that builds (PoCL's LLVM on a Zen 4 dies
with SIGSEGV or an abort building 16-float vectors), and nothing in-process survives that. So
a device's probe runs in a child process (``children``): ``python -m PROBE_MODULE`` first
checks the vector ABI (``VECTOR_ABI``: whether the compiler passes 16- and 8-float vectors to
its built-ins as they take them; where it does not, nothing that wide is built), then builds,
asks the binaries of, runs and checks every kernel configuration the library may pick on that
device (each width of the vectorised kernels, the blur kernels, float64 where the device
claims it), then times the widths and the blur's methods; it prints one JSON line as it
begins and one as it ends each configuration, and one as it begins each timing run. When the
child dies, the configuration it was in (building, running or timing it) is rejected with the
signal or the runtime's last words, and a new child goes on with the rest; one that dies after
its last configuration (at the runtime's teardown) leaves an ``exit`` result. The verdict is
cached per device identity (platform, device, driver) and kernel digest in the user's cache
folder, so the probe costs seconds once per device and driver, not per process. Programs the
probe did not build (a job's own constants and options) are built first in a child too
(``guard``).

A configuration's name is ``config_name(source, options)``: the kernel file's name, then
``/w<BD_WIDTH>`` and ``/f64`` where those options are given. ``programs.get_program`` refuses
to build a configuration the verdict rejected, so no caller (a forced width included) can
take the process down on a known crash.

``FAULT_VARIABLE`` makes the child fail one configuration on purpose (tests): ``NAME=segv``
(killed by SIGSEGV), ``NAME=abort:TEXT`` (TEXT on stderr, then exit status 1), ``NAME=hang``,
``NAME=kill`` (SIGKILL, as from outside: such a verdict is not cached); several with ``;``.
NAME is a configuration, or a timed workload as ``time:NAME``.

A verdict that says more of the moment than of the device (the probe's process failed outside
any kernel, or was killed by SIGKILL) serves its process only and is not cached; the child ends
with its parent (``children.die_with``), so a killed caller leaves no probe building on.
"""
from __future__ import annotations

import contextlib
import dataclasses
import functools
import hashlib
import importlib.util
import json
import logging
import os
import re
import sys
import tempfile
import threading
from dataclasses import dataclass
from pathlib import Path

from ..caches import user_cache_dir
from ..durable import durable_replace
from ..version import __version__
from .children import TIMED_OUT, Child, death

#: the module the child runs (the operations layer's checks: started by name, not imported)
PROBE_MODULE = "bdipole_cl.ops.kernel_checks"
#: raised whenever what a check does, or the verdict file's fields, change meaning
PROBE_FORMAT = 2
#: fails one configuration of the child on purpose: tests only (module docstring)
FAULT_VARIABLE = "BDIPOLE_CL_PROBE_FAULT"
#: seconds one configuration may take (a PoCL build of the largest blur kernel takes ~20 s
#: on a loaded 2-core machine); past it the child is killed and the configuration rejected
CONFIG_TIMEOUT_S = 240.0
#: seconds a child may take to start and list its configurations (imports, the ICD loader)
START_TIMEOUT_S = 120.0

log = logging.getLogger("bdipole_cl")

#: the configurations of the default inversion kernel: a device works when one of them does
ESSENTIAL = "invert_table"
#: a child killed by SIGKILL was killed from outside (the OOM killer, an operator): a verdict
#: holding it is not cached
KILLED = "SIGKILL"
#: seconds after which a configuration still building is said (once) on stderr
SLOW_NOTE_S = 30.0
#: what re-probes a device (its verdict removed)
REPROBE = "`bdipole-cl cache --clear` probes again"
#: the result of a child that died after its last configuration (at its runtime's teardown,
#: as PoCL does with "still have references to IRs" after building a broken program)
EXIT = "exit"
#: the probe's first check (``ops.kernel_checks.vector_abi_check``): ``vector_abi/w<N>`` fails
#: where the device's compiler passes N-float vectors to its built-ins otherwise than they take
#: them (PoCL's LLVM 14 calls a Zen 4 'znver3', without AVX-512, but loads its AVX-512 built-in
#: library): no configuration of N lanes or more is built there
VECTOR_ABI = "vector_abi"
#: the vector widths (floats) the probe checks the ABI of, widest first
VECTOR_ABI_WIDTHS = (16, 8)


@dataclass(frozen=True)
class ConfigResult:
    """One kernel configuration on one device: whether it built, ran and computed right, and
    its timing workload's best time (seconds; None where it has none)."""

    name: str
    ok: bool
    reason: str = ""
    seconds: float | None = None


@dataclass(frozen=True)
class Verdict:
    """Every probed configuration of one device."""

    device: str                         # the device, described
    results: tuple = ()                 # ConfigResult, in the probe's order
    error: str = ""                     # the probe itself failed (no child could start)
    cached: bool = False                # read from the cache file

    @property
    def works(self) -> bool:
        """The device is usable: its default inversion kernel works at some width (every
        other configuration is optional: what it rejected is never built)."""
        return not self.error and any(r.ok for r in self.results
                                      if r.name.startswith(ESSENTIAL + "/"))

    @property
    def reason(self) -> str:
        """"" where the device works, else one line saying why not."""
        if self.works:
            return ""
        if self.error:
            return self.error
        essential = [r for r in self.results if r.name.startswith(ESSENTIAL + "/")]
        if not essential:
            return "the probe ran no kernel"
        first = essential[0]
        return (f"the default inversion kernel fails at every width ({first.name}: "
                f"{first.reason})")

    @property
    def transient(self) -> bool:
        """Whether it says more of this moment than of the device (the probe's process
        failed outside any kernel, or was killed from outside): not cached."""
        return bool(self.error) or any(not r.ok and KILLED in r.reason for r in self.results)

    def result(self, name: str) -> ConfigResult | None:
        return next((r for r in self.results if r.name == name), None)

    def passed(self, name: str) -> bool | None:
        """Whether configuration ``name`` passed (None: not probed)."""
        r = self.result(name)
        return None if r is None else r.ok

    def rejected(self) -> tuple:
        return tuple(r for r in self.results if not r.ok)

    @property
    def vector_cap(self) -> int:
        """The widest vector (floats) that the device's kernels may use: half the narrowest
        width whose ABI check failed (``VECTOR_ABI``), else 16, OpenCL's widest."""
        return vector_cap({r.name for r in self.results if not r.ok})

    def describe_rejected(self) -> str:
        """"" or '2 configurations rejected: a (reason); b (reason)'."""
        bad = self.rejected()
        if not bad:
            return ""
        items = "; ".join(f"{r.name} ({r.reason})" for r in bad)
        return f"{len(bad)} configuration{'s' if len(bad) > 1 else ''} rejected: {items}"


def vector_cap(failed) -> int:
    """The widest usable vector (floats) given the names of the failed configurations."""
    bad = [w for w in VECTOR_ABI_WIDTHS if f"{VECTOR_ABI}/w{w}" in failed]
    return min(bad) // 2 if bad else max(VECTOR_ABI_WIDTHS)


def config_name(source: str, options=()) -> str:
    """The probe's name for kernels/<source>.cl built with ``options`` (-D strings)."""
    name = source
    for opt in options:
        if opt.startswith("-DBD_WIDTH="):
            name += f"/w{opt.split('=', 1)[1]}"
    if "-DBD_DOUBLE" in options:
        name += "/f64"
    return name


# {{{ identity and cache

def identity(device) -> dict:
    """What makes a device's verdict its own: platform, device and driver as the runtime
    reports them (a new driver is a new compiler)."""
    p = device.platform
    return {"platform": p.name.strip(), "platform_version": p.version.strip(),
            "vendor": device.vendor.strip(), "device": device.name.strip(),
            "driver": device.driver_version.strip(), "version": device.version.strip()}


@functools.lru_cache(maxsize=None)
def checks_digest() -> str:
    """A digest of the checks' own source (PROBE_MODULE's file, found without importing it):
    a changed check is a new verdict."""
    spec = importlib.util.find_spec(PROBE_MODULE)
    try:
        return hashlib.sha256(Path(spec.origin).read_bytes()).hexdigest()[:16]
    except (AttributeError, TypeError, OSError):
        return ""


#: tests only: a clang target feature (``-avx512f``) that every PoCL build hands its front end,
#: to make on any AVX-512 CPU the vector ABI mismatch PoCL makes on a Zen 4 (docs/runtimes.md
#: "Vector widths"); it follows a define and a tab, which PoCL's option check lets through
TARGET_FEATURE_VARIABLE = "BDIPOLE_CL_TARGET_FEATURE"


def probe_faults() -> str:
    """The simulated faults of the probe's child (FAULT_VARIABLE without the guarded builds'
    ``build:`` ones): a verdict made under them is not the device's."""
    return ";".join(item for item in os.environ.get(FAULT_VARIABLE, "").split(";")
                    if item and not item.startswith("build:"))


#: pyopencl's variable of build options added to every program it builds
BUILD_OPTIONS_VARIABLE = "PYOPENCL_BUILD_OPTIONS"


def verdict_key(device, kernels_digest: str) -> str:
    """The cache key: the device's identity, the kernels, the checks and this library's
    version; the build options pyopencl adds to every program (``PYOPENCL_BUILD_OPTIONS``:
    a kernel built with -cl-fast-relaxed-math fails checks it passes without); the simulated
    faults and target feature (tests): what is found under them is not the device's, and the
    guarded builds' records beside it are kept apart too."""
    text = json.dumps([identity(device), kernels_digest, checks_digest(), __version__,
                       PROBE_FORMAT, probe_faults(),
                       os.environ.get(TARGET_FEATURE_VARIABLE, ""),
                       os.environ.get(BUILD_OPTIONS_VARIABLE, "")], sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:20]


#: the verdicts' folder in the user's cache folder, and their file names (a key's 20 hex digits)
VERDICT_FOLDER = "probes"
#: (a verdict, and the lock of the process probing it)
VERDICT_NAME = re.compile(r"^[0-9a-f]{20}\.(json|lock)$")
#: the folder of a device's guarded builds' records beside its verdict (``guard``)
BUILDS_NAME = re.compile(r"^[0-9a-f]{20}\.builds$")


def verdict_dir() -> Path:
    return user_cache_dir() / VERDICT_FOLDER


def verdict_path(device, kernels_digest: str) -> Path:
    return verdict_dir() / f"{verdict_key(device, kernels_digest)}.json"


def read_verdict(path: Path) -> Verdict | None:
    """The verdict stored at ``path``; None where there is none or it cannot be read."""
    try:
        raw = json.loads(path.read_text())
        results = tuple(ConfigResult(str(r["name"]), _strict_bool(r["ok"]),
                                     str(r.get("reason", "")),
                                     None if r.get("seconds") is None else float(r["seconds"]))
                        for r in raw["results"])
        return Verdict(str(raw["device"]), results, str(raw.get("error", "")), cached=True)
    except (OSError, ValueError, KeyError, TypeError):
        return None


def _strict_bool(value) -> bool:
    """A JSON true or false (a string "false" is not true: the file is not a verdict)."""
    if not isinstance(value, bool):
        raise ValueError(f"not a boolean: {value!r}")
    return value


def write_verdict(verdict: Verdict, path: Path) -> None:
    """Store ``verdict`` (temporary file, then a rename: readers see the old or the new)."""
    raw = {"device": verdict.device, "error": verdict.error,
           "results": [{"name": r.name, "ok": r.ok, "reason": r.reason, "seconds": r.seconds}
                       for r in verdict.results]}
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".probe-", suffix=".tmp")
    with os.fdopen(fd, "w") as f:
        json.dump(raw, f, indent=1)
    durable_replace(tmp, path)

# }}}


# {{{ the child

@dataclass
class _Run:
    """What one child reported before it ended."""

    current: str | None = None          # the configuration it was in (checking or timing it)
    finished: bool = False              # it said "done"
    timed_out: bool = False
    timing: bool = False                # ``current`` is being timed (its check had passed)
    error: str = ""                     # it could not open the device


def _next(child: Child, timeout: float, current: str | None, describe: str):
    """The child's next line within ``timeout`` seconds (TIMED_OUT after), saying once on
    stderr when a configuration takes over SLOW_NOTE_S."""
    if current is None or timeout <= SLOW_NOTE_S:
        return child.line(timeout)
    msg = child.line(SLOW_NOTE_S)
    if msg is not TIMED_OUT:
        return msg
    print(f"bdipole-cl: probing {describe}: {current} has taken {SLOW_NOTE_S:.0f} s; waiting "
          f"up to {timeout:.0f} s", file=sys.stderr, flush=True)
    return child.line(timeout - SLOW_NOTE_S)


def _read(child: Child, results: dict, describe: str = "") -> _Run:
    """Read ``child``'s lines into ``results`` until it ends, says done, or times out."""
    run, timeout = _Run(), START_TIMEOUT_S
    while True:
        msg = _next(child, timeout, run.current, describe)
        if msg is None or msg is TIMED_OUT:
            run.timed_out = msg is TIMED_OUT
            return run
        timeout = CONFIG_TIMEOUT_S
        if "begin" in msg:
            run.current, run.timing = str(msg["begin"]), False
        elif "end" in msg:
            r = ConfigResult(str(msg["end"]), bool(msg["ok"]), str(msg.get("reason", "")))
            results[r.name] = r
            run.current = None
        elif "run" in msg:                      # a workload's timing run begins
            run.current, run.timing = str(msg["run"]), True
        elif "time" in msg:                     # a width's, or a workload's of its own
            name = str(msg["time"])
            r = results.get(name, ConfigResult(name, True))
            results[name] = dataclasses.replace(r, seconds=float(msg["seconds"]))
        elif msg.get("done"):
            run.finished = True
            return run
        elif "error" in msg:
            run.error = str(msg["error"])
            return run


def _probe_args(device_index: str, results: dict) -> list:
    """The child's arguments: the device, and what earlier children already decided (skipped;
    those that passed are timed)."""
    args = ["--device", device_index]
    if results:
        args += ["--skip", ",".join(results),
                 "--passed", ",".join(n for n, r in results.items() if r.ok)]
    return args


def run_probe(device_index: str, description: str) -> Verdict:
    """Probe the device ``device_index`` ("P:D") in child processes: every configuration's
    result, one that killed its child (building, running or timing it) rejected and the rest
    probed by a new child. An interrupt (or any error here) kills the child and propagates:
    nothing is cached."""
    results: dict = {}
    for _attempt in range(64):                 # more than there are configurations
        child = Child(PROBE_MODULE, _probe_args(device_index, results))
        try:
            run = _read(child, results, description)
        except BaseException:
            child.finish(kill=True)
            raise
        rc, err = child.finish(kill=run.timed_out or not run.finished)
        if run.error:
            return Verdict(description, tuple(results.values()), run.error)
        if run.finished:
            if rc != 0:          # after every configuration: at its runtime's teardown
                results[EXIT] = ConfigResult(EXIT, False, death(rc, err))
            return Verdict(description, tuple(results.values()))
        if run.current is None:                 # died between configurations, or at start
            why = (f"timed out after {START_TIMEOUT_S:.0f} s" if run.timed_out
                   else death(rc, err))
            return Verdict(description, tuple(results.values()),
                           f"the kernel probe's process failed outside any kernel ({why})")
        how = (f"timed out after {CONFIG_TIMEOUT_S:.0f} s" if run.timed_out
               else death(rc, err))
        results[run.current] = ConfigResult(run.current, False,
                                            f"{how} (timing it)" if run.timing else how)
    return Verdict(description, tuple(results.values()), "the kernel probe did not finish")

# }}}


_lock = threading.Lock()
_verdicts: dict = {}              # verdict key -> Verdict (this process, wherever the cache
#                                   folder points: a device's verdict is the device's)


@contextlib.contextmanager
def _probing(path: Path, describe: str):
    """Hold ``path``'s probe lock (an flock on a file beside it) while this process probes,
    so that processes starting together (a test run's workers, a farm's tasks) probe a device
    once and the others read its verdict (saying that they wait). Without fcntl or a
    writable cache: no lock."""
    try:
        import fcntl
        path.parent.mkdir(parents=True, exist_ok=True)
        handle = open(path.with_suffix(".lock"), "a")
    except (ImportError, OSError):
        yield
        return
    with handle:                                # the lock goes with the file's closing
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            print(f"bdipole-cl: waiting for another process probing {describe} (it holds "
                  f"{handle.name})", file=sys.stderr, flush=True)
            fcntl.flock(handle, fcntl.LOCK_EX)
        yield


def lock_in_use(lock: Path) -> bool:
    """Whether a process holds the probe lock ``lock`` now (``cache --clear`` leaves it)."""
    try:
        import fcntl
        with open(lock, "a") as handle:
            fcntl.flock(handle, fcntl.LOCK_SH | fcntl.LOCK_NB)
    except BlockingIOError:
        return True
    except (ImportError, OSError):
        return False
    return False


def device_verdict(device, device_index: str, kernels_digest: str, describe: str) -> Verdict:
    """The device's verdict: this process's, else the cached one, else probed now (seconds
    to a minute, once per device, driver and kernels; one process at a time) and cached.
    Says on stderr that it is probing, and what it rejected when it probes."""
    key = verdict_key(device, kernels_digest)
    path = verdict_path(device, kernels_digest)
    with _lock:
        hit = _verdicts.get(key) or read_verdict(path)
        if hit is None:
            with _probing(path, describe):
                hit = read_verdict(path) or _probe_and_cache(path, device_index, describe)
        _verdicts[key] = hit
    return hit


def _probe_and_cache(path: Path, device_index: str, describe: str) -> Verdict:
    print(f"bdipole-cl: probing {describe}: building its kernels once (cached in "
          f"{verdict_dir()})", file=sys.stderr, flush=True)
    verdict = run_probe(device_index, describe)
    if verdict.works and verdict.rejected():
        log.warning("%s: %s; the library uses the configurations that passed "
                    "(`bdipole-cl devices` lists them; %s)", describe,
                    verdict.describe_rejected(), REPROBE)
    if verdict.transient:               # this moment's, not the device's: next time
        log.warning("%s: the probe was disturbed (%s); its verdict serves this process "
                    "only", describe, verdict.error or KILLED)
    else:
        try:
            write_verdict(verdict, path)
        except OSError as exc:          # an unwritable cache: probed again next time
            log.warning("the probe's verdict for %s could not be cached: %s", describe, exc)
    return verdict


def cached_verdict(device, kernels_digest: str) -> Verdict | None:
    """This process's verdict of ``device``, else the cache file's, else None (no probe)."""
    key = verdict_key(device, kernels_digest)
    with _lock:
        hit = _verdicts.get(key)
        if hit is None:
            hit = read_verdict(verdict_path(device, kernels_digest))
            if hit is not None:
                _verdicts[key] = hit
        return hit


def forget_verdicts() -> None:
    """Drop this process's verdicts (the cache files stay): tests."""
    with _lock:
        _verdicts.clear()
