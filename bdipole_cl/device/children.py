"""Child processes that build and run kernels where a runtime's crash cannot reach the user's
process (the device layer): started, read line by line with a timeout, and described when they
die. The probe (``isolation``) and the guarded builds (``guard``) both run their children so.

A child speaks one JSON object a line on stdout; anything else a runtime prints there is
skipped. It ends with its parent (``die_with``): a killed caller leaves nothing building.
"""
from __future__ import annotations

import json
import os
import queue
import re
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

#: ``Child.line``'s answer when nothing came in time
TIMED_OUT = object()


def signal_name(status: int) -> str:
    """'SIGSEGV' for a child that ended with status -11."""
    try:
        return signal.Signals(-status).name
    except ValueError:
        return f"signal {-status}"


def last_words(stderr_text: str) -> str:
    """The runtime's most telling line on stderr: one naming an error, else the last."""
    lines = [ln.strip() for ln in stderr_text.splitlines() if ln.strip()]
    pick = next((ln for ln in reversed(lines) if "error" in ln.lower() or "invalid" in ln.lower()
                 or "fail" in ln.lower()), lines[-1] if lines else "")
    return pick if len(pick) <= 160 else pick[:157] + "..."


def death(returncode: int, stderr_text: str) -> str:
    """How a child ended, in one line: 'crashed (SIGSEGV): <its last words>'."""
    how = (f"crashed ({signal_name(returncode)})" if returncode < 0
           else f"its process exited with status {returncode}")
    words = last_words(stderr_text)
    return f"{how}: {words}" if words else how


def child_env() -> dict:
    """A child's environment: this one, with this process's import path first on PYTHONPATH,
    so that the child imports the bdipole_cl this process runs (a checkout put on ``sys.path``
    by hand, not another installed copy)."""
    env = dict(os.environ)
    package_root = str(Path(__file__).resolve().parent.parent.parent)
    paths = [package_root] + [p for p in sys.path if p and p != package_root]
    env["PYTHONPATH"] = os.pathsep.join(paths)
    return env


class Child:
    """``python -m module args`` as a child process, its stdout read by a thread into a queue
    (so that every wait has a timeout), its stderr kept in a temporary file for its last words;
    with ``requests``, its stdin is a pipe for ``send``."""

    def __init__(self, module: str, args, requests: bool = False):
        cmd = [sys.executable, "-m", module, *args, "--parent", str(os.getpid())]
        try:
            self.err = tempfile.TemporaryFile(mode="w+")
        except OSError:             # no usable temporary folder: its last words are lost
            self.err = open(os.devnull, "w+")
        self.proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=self.err,
                                     stdin=subprocess.PIPE if requests else subprocess.DEVNULL,
                                     text=True, env=child_env(),
                                     start_new_session=True)   # a terminal's Ctrl-C is ours
        self.lines: queue.Queue = queue.Queue()
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self):
        for text in self.proc.stdout:
            self.lines.put(text)
        self.proc.stdout.close()            # at its end: not left to the collector to close
        self.lines.put(None)

    def send(self, msg: dict) -> bool:
        """Write one request line; False where the child has gone."""
        try:
            self.proc.stdin.write(json.dumps(msg) + "\n")
            self.proc.stdin.flush()
            return True
        except (BrokenPipeError, OSError, ValueError):
            return False

    def alive(self) -> bool:
        return self.proc.poll() is None

    def line(self, timeout: float):
        """The next JSON line ({} for a line that is not JSON), None at the end of output,
        or TIMED_OUT after ``timeout`` seconds."""
        try:
            text = self.lines.get(timeout=timeout)
        except queue.Empty:
            return TIMED_OUT
        if text is None:
            return None
        try:
            msg = json.loads(text)
        except ValueError:
            return {}                       # a runtime's own chatter on stdout: skipped
        return msg if isinstance(msg, dict) else {}

    def finish(self, kill=False) -> tuple:
        """(returncode, stderr text) once the child has ended (killed first if ``kill``)."""
        if kill and self.proc.poll() is None:
            self.proc.kill()
        if self.proc.stdin is not None:
            try:
                self.proc.stdin.close()     # a serving child ends at the end of its input
            except OSError:
                pass
        try:
            rc = self.proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            rc = self.proc.wait()
        self.err.seek(0)
        text = self.err.read()
        self.err.close()
        return rc, text


def die_with(parent: int):
    """End this process when ``parent`` ends (a child whose caller was killed must not build
    on for ever): Linux's PR_SET_PDEATHSIG, else a thread watching the parent's pid."""
    import ctypes
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        PR_SET_PDEATHSIG = 1
        libc.prctl(PR_SET_PDEATHSIG, signal.SIGKILL)
    except (OSError, AttributeError):
        pass

    def watch():
        while os.getppid() == parent:
            time.sleep(1.0)
        os._exit(3)
    threading.Thread(target=watch, daemon=True).start()
    if os.getppid() != parent:            # it ended before the above took hold
        os._exit(3)


def emit(msg: dict):
    """One JSON line on stdout, flushed (the child's side)."""
    print(json.dumps(msg), flush=True)


#: one simulated fault: ``TARGET=segv|kill|hang|abort:TEXT|raise:TEXT`` (TARGET may hold '='
#: itself)
FAULT_ITEM = re.compile(r"^(.*)=(segv|kill|hang|abort:.*|raise:.*)$", re.S)


def inject_fault(spec: str, matches) -> None:
    """Fail this process as the first item of ``spec`` (``;``-separated ``FAULT_ITEM``s, the
    tests' simulated faults) whose target ``matches``: killed by SIGSEGV (the default action:
    a runtime may handle it), TEXT on stderr then exit status 1, SIGKILL (as the OOM killer or
    an operator would), a hang, or an OSError saying TEXT (``raise:TEXT``)."""
    for item in filter(None, spec.split(";")):
        found = FAULT_ITEM.match(item)
        if found is None or not matches(found.group(1)):
            continue
        what = found.group(2)
        if what == "segv":
            signal.signal(signal.SIGSEGV, signal.SIG_DFL)
            os.kill(os.getpid(), signal.SIGSEGV)
        elif what.startswith("abort:"):
            print(what[len("abort:"):], file=sys.stderr, flush=True)
            os._exit(1)
        elif what == "kill":
            os.kill(os.getpid(), signal.SIGKILL)
        elif what == "hang":
            time.sleep(3600)
        elif what.startswith("raise:"):          # as an unwritable cache folder does
            raise OSError(what[len("raise:"):])
