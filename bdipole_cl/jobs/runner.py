"""The one job runner: ``run_job(job, runtime)`` runs a ``job.Job`` of any kind and returns
its FileResult; a failing job is a result, never an exception, so a bad file never stops the
others. The CLI's batches, the scene bake and the Dask workers all call it."""
from __future__ import annotations

import threading

from ..device import get_runtime
from .blur_file import run_blur
from .invert_file import run_invert
from .job import Job
from .results import FileResult
from .scene_records import run_constant
from .stretch_file import run_stretch

#: the function that runs each kind of job (job.JOB_KINDS)
RUNNERS = {"invert": run_invert, "blur": run_blur, "constant": run_constant,
           "stretch": run_stretch}
#: serialises the device work of jobs run at once in one process (their I/O overlaps)
DEVICE_LOCK = threading.Lock()


def run_job(job: Job, runtime=None, *, cancel=None, lock=None, progress=None) -> FileResult:
    """Run ``job`` on ``runtime`` (None: the default device). ``cancel``: a threading.Event
    that stops it at its next band (its temporary output removed, status "cancelled");
    ``lock``: held around device work (default: this process's DEVICE_LOCK); ``progress``:
    a tqdm bar advanced by texels."""
    if cancel is not None and cancel.is_set():
        return FileResult(job.source, job.output, status="cancelled",
                          error="interrupted before it started")
    return RUNNERS[job.kind](job, get_runtime(runtime), cancel=cancel,
                             lock=lock if lock is not None else DEVICE_LOCK, progress=progress)
