"""Talking to a Dask cluster (the applications' layer, beside ``dask``): connecting (a local
one or a scheduler's address), sending a job with its paths absolute and a key the scheduler
can carry, gathering results as they come, and stopping: a stop request cancels what has not
started and has the workers end what they are in the middle of, cleanly, before what was
written is judged (``stop_workers``, ``not_finished``)."""
from __future__ import annotations

import functools
import logging
import os
import threading
import time
from contextlib import contextmanager
from dataclasses import replace

from .errors import one_line
from .io.verify import replaced_since
from .jobs.job import Job
from .jobs.results import FileResult
from .signals import (STOP, Stopped, clear_stop, quiet_resource_tracker, request_stop,
                      sigint_ignored_by_children)

#: a task that raised is tried again this many times (a worker that died is always replaced)
RETRIES = 2
#: what one worker process takes before any job (Python, numpy, OpenImageIO, the OpenCL
#: runtime and its compiler): a smaller --worker-memory can never run a job
MIN_WORKER_MEMORY = 384 << 20
#: seconds between checks of a stop request while waiting for the cluster
POLL = 0.25
#: seconds a run waits for a cluster without workers before failing its unfinished jobs
NO_WORKER_TIMEOUT = 60.0


class ClusterStartError(RuntimeError):
    """The cluster could not be started (a worker process ended as it started) or its
    scheduler reached: no job ran. One line (what, why, what to try); ``short``: what and why,
    for each job's row (the commands fail every job with it, named, and print their summary:
    ``dask.not_started``)."""

    def __init__(self, message, short):
        super().__init__(message)
        self.short = short


class _WorkerExits(logging.Handler):
    """The nannies' "Worker process N exited with status S" lines, kept (they log at INFO,
    which the run keeps quiet)."""

    def __init__(self):
        super().__init__(logging.INFO)
        self.lines = []

    def emit(self, record):
        text = record.getMessage()
        if "exited with status" in text:
            self.lines.append(text)


@contextmanager
def worker_exits():
    """A ``_WorkerExits`` that hears the nannies of this process while a local cluster
    starts (only them: their lines go nowhere else)."""
    log = logging.getLogger("distributed.nanny")
    handler, saved = _WorkerExits(), (log.level, log.propagate)
    log.setLevel(logging.INFO)
    log.propagate = False
    log.addHandler(handler)
    try:
        yield handler
    finally:
        log.removeHandler(handler)
        log.setLevel(saved[0])
        log.propagate = saved[1]


def start_failure(scheduler, exc, exits) -> ClusterStartError:
    """The ClusterStartError of a ``--scheduler local:N`` that did not start: the workers'
    exit statuses, what distributed said (and its cause), and what to try."""
    said = one_line(exc).rstrip(".") or type(exc).__name__
    cause = exc.__cause__ or exc.__context__
    if cause is not None and one_line(cause) and not one_line(cause).startswith(said):
        said += f" ({one_line(cause)})"
    statuses = sorted({line.rsplit(" ", 1)[-1] for line in exits})
    died = (f"a worker process exited as it started (status {', '.join(statuses)})"
            if statuses else said)
    short = f"--scheduler {scheduler}: the local cluster did not start: {died}"
    return ClusterStartError(
        f"{short}{': ' + said if statuses else ''}; no job ran: check that a worker can "
        f"start here (its memory limit, --worker-memory; its Python environment and Dask "
        f"preloads), or run without --scheduler", short)


@contextmanager
def connect(scheduler: str, *, memory_limit=None):
    """A ``distributed.Client``: ``local:N`` starts N worker processes on this machine (each
    limited to ``memory_limit`` bytes if given), anything else is a scheduler address."""
    from distributed import Client, LocalCluster
    if ":" not in scheduler:           # neither local:N nor an address (nor empty)
        raise ValueError(f"--scheduler {scheduler!r}: expected local:N (N worker processes "
                         f"here) or a scheduler address such as tcp://host:8786")
    logging.getLogger("distributed").setLevel(logging.CRITICAL)   # the run says what failed
    if scheduler.lower().startswith("local:"):
        try:
            n = int(scheduler.split(":", 1)[1])
        except ValueError:
            n = 0
        if n < 1:
            raise ValueError(f"--scheduler {scheduler!r}: expected local:N with N >= 1 workers, "
                             f"or a scheduler address such as tcp://host:8786")
        if memory_limit is not None and memory_limit < MIN_WORKER_MEMORY:
            raise ValueError(f"--worker-memory {memory_limit}: a worker needs at least "
                             f"{MIN_WORKER_MEMORY >> 20}M (its Python, OpenCL runtime and one "
                             f"band); give more, e.g. 1G")
        quiet_resource_tracker()
        try:
            with sigint_ignored_by_children(), worker_exits() as exits:
                cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                                       memory_limit=memory_limit or "auto",
                                       dashboard_address=":0", silence_logs=logging.CRITICAL)
        except Stopped:
            raise
        except Exception as exc:       # noqa: BLE001 (distributed: "Nanny failed to start")
            raise start_failure(scheduler, exc, exits.lines) from None
        try:
            with Client(cluster) as client:
                yield client
        finally:
            cluster.close()
    else:
        try:
            client = Client(scheduler)
        except (ValueError, TypeError, KeyError) as exc:   # an address distributed cannot read
            raise ValueError(f"--scheduler {scheduler!r}: not a scheduler address "
                             f"({one_line(exc)}): give tcp://host:8786 or "
                             f"local:N") from None
        except (OSError, TimeoutError) as exc:   # nothing there, or it did not answer
            short = (f"--scheduler {scheduler}: cannot reach the scheduler "
                     f"({one_line(exc) or type(exc).__name__})")
            raise ClusterStartError(f"{short}; no job ran: start it (dask scheduler) or give "
                                    f"its address, or run without --scheduler", short) \
                from None
        with client:
            yield client


def progress_bar(total, desc, enabled):
    if not enabled:
        return None
    from tqdm import tqdm
    return tqdm(total=total, desc=desc, unit="job")


def gather_results(client, futures, describe, progress=None):
    """Results of ``futures`` ({future: index}) as they complete; a task that still fails after
    its retries becomes a failed result described by ``describe(index, exc)``. A stop request
    (SIGINT/SIGTERM) cancels every unfinished task, and a cluster with no worker for
    NO_WORKER_TIMEOUT seconds fails them: both leave those indices out of the result (the
    callers report them), within a POLL of the event."""
    from distributed import wait
    results, pending = {}, set(futures)
    idle = time.monotonic()
    while pending:
        if STOP.is_set():
            client.cancel(list(pending))
            stop_workers(client)
            break
        try:
            try:
                done, pending = wait(pending, timeout=POLL, return_when="FIRST_COMPLETED")
            except TimeoutError:
                done = set()
                if client.scheduler_info().get("workers"):
                    idle = time.monotonic()
                elif time.monotonic() - idle > NO_WORKER_TIMEOUT:
                    for fut in pending:
                        results[futures[fut]] = describe(futures[fut], RuntimeError(
                            f"no worker on the cluster for {NO_WORKER_TIMEOUT:g} s; not run"))
                    client.cancel(list(pending))
                    break
        except Exception as exc:              # the scheduler lost: every job not done
            for fut in pending:                # fails, named, and the run says the rest
                results[futures[fut]] = describe(futures[fut], f"the cluster was lost "
                                                               f"({type(exc).__name__}: "
                                                               f"{one_line(exc)})")
            break
        for fut in done:
            i = futures[fut]
            try:
                results[i] = fut.result()
            except Exception as exc:  # the worker's exception, after RETRIES
                results[i] = describe(i, one_line(exc) or type(exc).__name__)
            if progress is not None:
                progress.update(1)
    return results


#: seconds a stopped run waits for the tasks its workers are in the middle of to end (each
#: ends at its next stop check: a band, a texture build's wait, ~2 s)
STOP_GRACE = 30.0


#: jobs this process (a worker) is running (``counted``): a cancelled task's thread runs on
#: until its job ends, unknown to the scheduler
_running = [0]
_running_lock = threading.Lock()


def counted(fn):
    """``fn`` (a job a worker runs), counted in ``running_jobs`` while it runs."""
    @functools.wraps(fn)
    def job(*args, **kwargs):
        with _running_lock:
            _running[0] += 1
        try:
            return fn(*args, **kwargs)
        finally:
            with _running_lock:
                _running[0] -= 1
    return job


def running_jobs() -> int:
    """How many ``counted`` jobs this process is running."""
    return _running[0]


def stop_workers(client, grace=STOP_GRACE):
    """After a stop request: the workers' own stop flag set, so that the tasks they are running
    (which a cancel does not stop) end at their next check, their temporaries removed, and
    waited for (up to ``grace`` s): only then is what was written known (``_not_finished``)
    and nothing is killed half-way through a write. The flag is cleared after: a cluster's
    long-lived workers serve later runs."""
    try:
        client.run(request_stop)
        deadline = time.monotonic() + grace
        while time.monotonic() < deadline and sum(client.run(running_jobs).values()):
            time.sleep(POLL)
        client.run(clear_stop)
    except Exception:                  # a cluster already gone: nothing runs there
        pass


def not_finished(source, output, before=None):
    """The result of a job whose task the run has no result of (cancelled by a stop): its
    output, where it is a whole image that is not the file there before the run (``before``:
    its ``file_identity`` then), was written by this run's task as the stop came (outputs are
    written whole, then renamed into place): done, said so; else cancelled, nothing
    written."""
    if output and replaced_since(output, before):
        return FileResult(source, output, status="ok",
                          notes=["finished on the cluster as the run was stopped"])
    return FileResult(source, output, status="cancelled",
                      error="interrupted: cancelled on the cluster, nothing written")



def absolute(job: Job) -> Job:
    """``job`` with every path absolute: a worker's working folder is not the command's (on a
    cluster of other hosts, or a worker started elsewhere, a relative path names another
    file: the command's checks were of these)."""
    def whole(p):
        return os.path.abspath(p) if isinstance(p, str) and p and job.kind != "constant" else p
    return replace(job, source=whole(job.source), output=whole(job.output),
                   inputs={k: whole(v) for k, v in job.inputs.items()})


def task_key(*parts) -> str:
    """A task's key from its parts, as text the scheduler can send (a file name that is not
    UTF-8 escaped: msgpack refused it, and the run lost its scheduler)."""
    text = "-".join(str(p) for p in parts)
    return text.encode("utf-8", "backslashreplace").decode("utf-8")
