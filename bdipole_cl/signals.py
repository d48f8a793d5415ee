"""Stop requests: SIGINT/SIGTERM obeyed within seconds everywhere (the foundation layer).

The command line installs ``install()``; the handler only sets one process-wide event. Long
work checks it between its pieces (``check_stop``: between kernel launches, chunks of rows of
one launch, host FFTs, bands, jobs, cluster waits, and in a plan's building: rows of a kernel's
weights, node fits, SVD ranks, check points) and raises ``Stopped``; the file layers turn
that into a cancelled job whose temporary file is removed. Nothing is killed half-way through a
write.
"""
from __future__ import annotations

import os
import signal
import sys
import threading
from contextlib import contextmanager

#: set by SIGINT/SIGTERM (or ``request_stop``); every long loop checks it
STOP = threading.Event()


class Stopped(Exception):
    """Work abandoned because a stop was requested (a signal)."""


def check_stop():
    """Raise Stopped if a stop was requested."""
    if STOP.is_set():
        raise Stopped("interrupted")


def request_stop():
    STOP.set()


def clear_stop():
    """Obey no earlier stop request (a long-lived cluster worker, before its next run)."""
    STOP.clear()


class SignalStop:
    """SIGINT/SIGTERM set ``STOP`` (``event``); the signal is kept for the exit code."""

    def __init__(self):
        self.event = STOP
        self.signum = None

    def install(self):
        """Obey SIGINT/SIGTERM from now on, for a command that starts un-stopped (a stop
        request of an earlier command in the same process is over)."""
        STOP.clear()
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, self._handle)
        return self

    def _handle(self, signum, frame):
        self.signum = signum
        STOP.set()

    @property
    def exit_code(self):
        return 128 + self.signum if self.signum else None


class Terminated(BaseException):
    """SIGTERM in a command that has no stop checks (``terminate_raises``): raised where the
    main thread is, as KeyboardInterrupt is for SIGINT."""

    def __init__(self, signum):
        super().__init__(f"terminated by signal {signum}")
        self.signum = signum


class terminate_raises:
    """Within it, SIGTERM raises Terminated in the main thread (the command's files are
    written whole, so an exception anywhere leaves nothing half-written); the handler before
    it is restored after."""

    def __enter__(self):
        self._previous = None              # signals are the main thread's alone: elsewhere
        if threading.current_thread() is threading.main_thread():      # it changes nothing
            self._previous = signal.signal(signal.SIGTERM, self._raise)
        return self

    @staticmethod
    def _raise(signum, frame):
        raise Terminated(signum)

    def __exit__(self, *exc):
        if self._previous is not None:
            signal.signal(signal.SIGTERM, self._previous)
        return False


class signals_deferred:
    """Within it, SIGINT and SIGTERM wait (blocked; delivered on leaving it): a short write
    that must not be cut in two (a record of what a folder holds). Elsewhere than the main
    thread, or where the platform cannot block signals, nothing changes."""

    SIGNALS = (signal.SIGINT, signal.SIGTERM)

    def __enter__(self):
        self._blocked = (threading.current_thread() is threading.main_thread()
                         and hasattr(signal, "pthread_sigmask"))
        if self._blocked:
            signal.pthread_sigmask(signal.SIG_BLOCK, self.SIGNALS)
        return self

    def __exit__(self, *exc):
        if self._blocked:
            signal.pthread_sigmask(signal.SIG_UNBLOCK, self.SIGNALS)
        return False


#: the warning filter multiprocessing's resource tracker is started with (``-W``)
RESOURCE_TRACKER_QUIET = "ignore::UserWarning:multiprocessing.resource_tracker"


def quiet_resource_tracker():
    """The resource tracker that this process's cluster starts says nothing at its end: a
    stopped command ends at once (``apps.cli.console_main``), before multiprocessing unlinks
    the cluster's semaphores, so the tracker, which unlinks them itself, would print two
    lines of "leaked semaphore objects" after the command's one. (It takes its warning
    filters from ``sys.warnoptions`` when started, as every process multiprocessing starts.)"""
    if RESOURCE_TRACKER_QUIET not in sys.warnoptions:
        sys.warnoptions.append(RESOURCE_TRACKER_QUIET)


@contextmanager
def sigint_ignored_by_children():
    """Processes started inside never see SIGINT: each is spawned with SIGINT blocked (a
    signal mask is kept across fork and exec, and nothing in a worker unblocks it), so a
    Ctrl-C, which the terminal sends to the whole process group, reaches only this process,
    which cancels the tasks and closes the cluster; a worker interrupted mid-task could leave
    that close waiting on it. Only the spawning thread blocks it, and only while it spawns:
    this process keeps its handler, so a Ctrl-C while the cluster starts stops the run (were
    SIGINT ignored here for the whole start, it would be lost). SIGTERM still stops the
    workers. Multiprocessing's spawn and forkserver start their processes through
    ``multiprocessing.util.spawnv_passfds``."""
    import multiprocessing.util as mp_util
    spawn = mp_util.spawnv_passfds

    def spawn_without_sigint(*args, **kwargs):
        mask = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
        try:
            return spawn(*args, **kwargs)
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, mask)
    mp_util.spawnv_passfds = spawn_without_sigint
    try:
        yield
    finally:
        mp_util.spawnv_passfds = spawn


#: the command's name: under it, a signal while the library loads ends the process quietly
COMMAND = "bdipole-cl"
_startup_handlers: dict = {}


def is_command(argv=None, orig_argv=None) -> bool:
    """Whether this process is the ``bdipole-cl`` command (its script, or ``python -m
    bdipole_cl``, whose ``sys.argv[0]`` is "-m" while the package loads), and not a worker
    process a command started (multiprocessing gives a spawned one the command's argv, and
    imports the command's script while its parent is not yet known: its interpreter's own
    arguments say it is a spawned child)."""
    mp = sys.modules.get("multiprocessing")
    if mp is not None and mp.parent_process() is not None:
        return False
    argv = sys.argv if argv is None else argv
    orig = getattr(sys, "orig_argv", []) if orig_argv is None else orig_argv
    if "--multiprocessing-fork" in orig or (
            mp is not None and getattr(mp.current_process(), "_inheriting", False)):
        return False
    first = argv[0] if argv else ""
    if first == "-m" or first.endswith(os.path.join("bdipole_cl", "__main__.py")):
        return any(a == "-m" and b == "bdipole_cl" for a, b in zip(orig, orig[1:]))
    return os.path.basename(first) in (COMMAND, COMMAND + ".exe")   # the console script


def quiet_startup():
    """In the ``bdipole-cl`` command (``is_command``), SIGINT or SIGTERM while the library
    loads (its imports take a few tenths of a second, before the command's own handling
    exists) ends the process with 128 + the signal and one line, not a traceback: nothing has
    been read or written yet. ``end_startup`` ends it."""
    if _startup_handlers or not is_command():
        return
    if threading.current_thread() is not threading.main_thread():
        return
    for sig in (signal.SIGINT, signal.SIGTERM):
        _startup_handlers[sig] = signal.signal(sig, _startup_exit)


def _startup_exit(signum, frame):
    sys.stderr.write(f"{COMMAND}: interrupted by signal {signum} while starting: nothing "
                     f"was read or written\n")
    raise SystemExit(128 + signum)


def end_startup():
    """After ``quiet_startup``: SIGINT raises KeyboardInterrupt (which the command reports;
    also where it was ignored when the command started, as in a shell script's background job:
    the commands that install ``SignalStop`` obey it there too) and SIGTERM has its handler from
    before."""
    while _startup_handlers:
        sig, handler = _startup_handlers.popitem()
        signal.signal(sig, signal.default_int_handler if sig == signal.SIGINT else handler)
