"""Beyond one machine: scene bakes, texture batches and huge blurs on a Dask cluster.

``cluster.connect("local:N")`` starts a LocalCluster of N worker processes (one thread each);
``cluster.connect("tcp://host:8786")`` joins a running scheduler (``cluster``: connecting,
sending jobs with absolute paths, gathering, stopping). Jobs are plain functions of picklable
data (file paths, dataclasses): each worker process opens its own OpenCL device once
(``device``: a spec string such as ``"intel"``, or None for the automatic choice, which
honours ``PYOPENCL_CTX``) and builds its kernels once; nothing OpenCL crosses processes.
Workers read inputs and write outputs themselves, so storage must be shared; writes stay
atomic (temporary file + rename), and a job that Dask reruns after a worker died first removes
what the dead writer left.

Lazy arrays: ``invert_albedo`` and ``albedo_to_coefficients`` map a dask array's blocks;
``blur`` uses ``map_overlap`` with a depth of the truncation radius the plan picks and the
boundary of ``border`` (clamp: nearest, zero: 0, wrap: periodic), so that it equals ``blur``
on the whole array.
"""
from __future__ import annotations

import glob
import os
import re
import shutil
import tempfile
import uuid
from pathlib import Path

import numpy as np
import OpenImageIO as oiio

from .device import get_runtime
from .io.collisions import Claim, check_claim
from .io.colour import resolve_working_space
from .io.images import (Cancelled, Reader, TextureError, Writer, check_texture_window,
                        read_rows)
from .io.freshness import InputChanged, InputGuard
from .io.partials import remove_partial_files
from .io.mipmaps import texture_options
from .io.verify import file_identity
from .jobs import runner
from .jobs.blur_file import (FILE_ROW_FLOATS, blurred_band, exitance_writer, file_plan,
                              located, report_clamped)
from .jobs.job import Job
from .jobs.results import BatchReport, FileResult
from .jobs.scene import Plan, not_run, scene_job
from .jobs.scene_stats import DEFAULT_MEMORY
from .jobs.scene_finish import finish_bake
from .jobs.scene_stretch import blocked, with_maps_header
from .ops import invert as ops_invert
from .ops.bands import band_rows, bands, halo_rows
from .ops.host_arrays import texel_broadcast
from .ops.blur import Scattering, plan_blur
from .ops.blur.params import checked_irradiance
from .ops.blur.planning import BlurAccuracyWarning
from .errors import InvalidInputError, moved_by, warnings_naming
from .signals import STOP
from .cluster import (RETRIES, absolute, counted, gather_results, not_finished, progress_bar,
                      task_key)

# {{{ scenes

@counted
def run_on_worker(job: Job, device=None) -> FileResult:
    """One job on a worker: ``runner.run_job`` on the worker's own device (opened once per
    process), after removing what a writer that died there before left of its output."""
    if job.kind != "constant":
        remove_partial_files(job.output)
    return runner.run_job(job, get_runtime(device))   # the process's one device lock


def bake_on_cluster(plan: Plan, client, *, device=None, progress=True,
                    run=run_on_worker, max_memory=DEFAULT_MEMORY) -> BatchReport:
    """``Plan.run`` with the jobs on the cluster (up-to-date checks already done by the plan,
    in this process, before anything is sent): each planned job's ``scene_job`` is mapped
    over by ``run`` (the runner); a blur that reads the stretch maps a stretch job of this
    bake makes starts when that job has finished (``run_after``)."""
    results, futures, made = {}, {}, {}   # made: stretch output -> its job's future
    before = {i: file_identity(j.output) for i, j in enumerate(plan.jobs) if j.output}
    run_id = uuid.uuid4().hex[:12]       # a run's own task keys: never an earlier run's results
    for i, job in enumerate(plan.jobs):
        if STOP.is_set():                # a stop request: nothing more is sent
            break
        results[i] = not_run(job)
        if results[i] is None:
            del results[i]
            work = absolute(scene_job(job, plan.scene, max_memory, pending=set(made)))
            needs = made.get(work.inputs.get("stretch")) if job.kind == "blur" else None
            fut = client.submit(*((run_after, run, work, device, needs) if needs is not None
                                  else (run, work, device)), pure=False, retries=RETRIES,
                                key=task_key("bake", i, job.kind, job.name, job.udim, run_id))
            futures[fut] = i
            if job.kind == "stretch":
                made[work.output] = fut
    bar = progress_bar(len(futures), "bake", progress)
    try:
        results.update(gather_results(client, futures, lambda i, exc: FileResult(
            plan.jobs[i].source, plan.jobs[i].output, error=f"{plan.jobs[i].source}: {exc}"),
            bar))
    finally:
        if bar is not None:
            bar.close()
    for job in plan.jobs:
        if job.output and job.kind != "constant":
            remove_partial_files(job.output)
    return finish_bake(plan, [results.get(i) or not_finished(j.source, j.output, before.get(i))
                              for i, j in enumerate(plan.jobs)])

def run_after(run, job: Job, device, needed: FileResult) -> FileResult:
    """``run(job, device)`` once the stretch job whose maps ``job`` reads has finished (Dask
    passes its FileResult, ``needed``): where it made none, ``job`` fails, named, and reads
    nothing (``scene_stretch.blocked``)."""
    return (blocked(job, {job.inputs.get("stretch"): needed})
            or run(with_maps_header(job), device))


def not_started(plan: Plan, why: str) -> BatchReport:
    """The report of a bake whose cluster did not start (``cluster.ClusterStartError``):
    every job that was to run fails, named with ``why``; the rest as the plan has them."""
    return finish_bake(plan, [not_run(j) or FileResult(j.source, j.output,
                                                       error=f"{j.source}: not run: {why}")
                              for j in plan.jobs])

# }}}


# {{{ texture batches (bdipole-cl invert)

def file_runner(client, *, device=None, progress=True):
    """A ``run_files`` for ``process_textures``: each job a task on the cluster."""
    def run(jobs):
        run_id = uuid.uuid4().hex[:12]
        before = [file_identity(job.output) for job in jobs]
        futures = {client.submit(run_on_worker, absolute(job), device, pure=False,
                                 retries=RETRIES,
                                 key=task_key("invert", i, Path(job.source).name, run_id)): i
                   for i, job in enumerate(jobs)}
        bar = progress_bar(len(futures), "invert", progress)
        try:
            results = gather_results(client, futures, lambda i, exc: FileResult(
                jobs[i].source, jobs[i].output, error=f"{jobs[i].source}: {exc}"), bar)
        finally:
            if bar is not None:
                bar.close()
        for job in jobs:
            remove_partial_files(job.output)
        return [results.get(i) or not_finished(j.source, j.output, before[i])
                for i, j in enumerate(jobs)]
    return run

def not_started_runner(why: str):
    """A ``run_files`` for a batch whose cluster did not start: each job fails, named."""
    def run(jobs):
        return [FileResult(j.source, j.output, error=f"{j.source}: not run: {why}")
                for j in jobs]
    return run

# }}}


# {{{ huge file-to-file blurs

@counted
def blur_band_task(path, band_path, y0, y1, plan, colorspace, working, device=None,
                   identity=None):
    """A cluster task: rows [y0, y1) of the blurred image (``blur_file``'s own band step,
    ``blurred_band``, with the plan made once by the client), written to ``band_path``.
    Returns (band_path, the irradiance values of its rows clamped by kind), or the
    TextureError naming an invalid texel where it is in the image, or the InputChanged of an
    irradiance whose identity is not ``identity`` (the client's, as it first read it) before
    or after the rows are read (returned, not raised: the same input would fail every
    retry)."""
    remove_partial_files(band_path)
    plan = plan.on(get_runtime(device))
    guard = InputGuard({"irradiance": path}, {"irradiance": identity} if identity else None)
    reader = None
    try:
        guard.check()
        reader = Reader(path, "irradiance", role="irradiance")
        spec = reader.spec
        colour, alpha = reader.channels()
        route = reader.colour(colorspace, working)
        idx = halo_rows(y0, y1, plan.halo, spec.height, plan.border)
        px = read_rows(reader, idx)
        guard.check()
    except InputChanged as exc:
        return exc
    finally:
        if reader is not None:
            reader.close()
    counts = {}
    names = [spec.channelnames[c] for c in colour]
    try:
        with warnings_naming(path, BlurAccuracyWarning):
            out, _ = blurred_band(plan, px, colour, alpha, names, route, idx, None, y0, y1,
                                  counts=counts)
    except InvalidInputError as exc:
        return located(exc, path, {}, spec, idx, names)
    band = oiio.ImageSpec(spec.width, y1 - y0, out.shape[-1], "float")
    writer = Writer(band_path, band)
    try:
        writer.write_band(0, y1 - y0, out)
        writer.commit()
    except Exception:
        writer.abort()
        raise
    return band_path, counts


def band_folder_prefix(output) -> str:
    return f".{Path(output).stem}.bands-"


def remove_band_folders(output) -> int:
    """Remove the band folders a cluster blur of ``output`` left when its process was killed
    (the one process that writes ``output`` calls this first: outputs never collide)."""
    prefix = band_folder_prefix(output)        # matched literally (an output named m[1]),
    name = re.compile(re.escape(prefix) + r"[A-Za-z0-9_]+")    # mkdtemp's characters after
    stale = [p for p in Path(output).parent.glob(glob.escape(prefix) + "*")    # it (no dot:
             if p.is_dir() and name.fullmatch(p.name)]     # not .m.bands-x.bands-... of m.bands-x)
    for folder in stale:
        shutil.rmtree(folder, ignore_errors=True)
    return len(stale)


def blur_file_on_cluster(path, output, client, *, colorspace="auto", working_space=None,
                         half=False, max_memory=256 << 20, device=None, progress=True,
                         texture=False, force=False, clamped=None, identities=None,
                         **kwargs):
    """``blur_file`` with its bands as tasks: each worker reads its rows and the halo of the
    truncation radius from ``path``, blurs them within ``max_memory`` bytes, and writes them
    to a band file; this process then streams the bands into ``output`` (one band in memory
    at a time) and removes them. Constant parameters only (a texture-varying plan is global).
    ``clamped``: as ``blur_file``'s; ``identities``: the irradiance's as first read
    (``freshness.input_identities``; default: now): each band and the output check it, and an
    irradiance changed before the output is in place fails the blur, nothing written.
    Returns the number of bands."""
    from .io.images import check_output_format
    check_output_format(output)
    check_claim(Claim(str(path), str(output), {"irradiance": str(path)}), force)
    scattering, options = Scattering.split(kwargs)
    if scattering.textured:
        raise ValueError("a blur on a cluster takes constant parameters (one value or one per "
                         "channel); with parameter textures, blur in one process")
    guard = InputGuard({"irradiance": os.path.abspath(path)}, identities)
    reader = Reader(path, "irradiance", role="irradiance")
    try:
        spec = reader.spec
        colour, alpha = reader.channels()
        route = reader.colour(colorspace, resolve_working_space(working_space))
    finally:
        reader.close()
    if texture_options(texture) is not None:
        check_texture_window(output, spec)   # before any band is sent
    plan = file_plan(path, spec, [spec.channelnames[c] for c in colour], scattering,
                     dict(options, device=device), {})
    halo = plan.halo
    rows = band_rows(spec.height, spec.width * spec.nchannels * 4 * FILE_ROW_FLOATS,
                     max_memory, halo=halo)
    path, output = os.path.abspath(path), os.path.abspath(output)   # the workers' folder is
    remove_band_folders(output)         # not ours; what a run of this output killed mid-way left
    Path(output).parent.mkdir(parents=True, exist_ok=True)
    work = Path(tempfile.mkdtemp(prefix=band_folder_prefix(output), dir=Path(output).parent))
    try:
        futures, run_id = {}, uuid.uuid4().hex[:12]
        for k, (y0, y1, _) in enumerate(bands(spec.height, rows)):
            fut = client.submit(blur_band_task, str(path), str(work / f"band{k:05d}.exr"), y0,
                                y1, plan, colorspace, route.working, device,
                                guard.before["irradiance"], pure=False,
                                retries=RETRIES,
                                key=task_key("blur-band", k, Path(path).name, run_id))
            futures[fut] = (k, y0, y1)
        bar = progress_bar(len(futures), "blur bands", progress)
        done = gather_results(client, futures, lambda i, why: RuntimeError(why), bar)
        if bar is not None:
            bar.close()
        if STOP.is_set() or len(done) < len(futures):
            raise Cancelled(f"{path}: interrupted; nothing written")
        failed = [done[key] for key in sorted(done) if isinstance(done[key], Exception)]
        if failed:
            if isinstance(failed[0], TextureError):      # an input's texel, named already
                raise failed[0]                            # (in every band whose halo has it)
            raise TextureError(f"{path}: {len(failed)} band(s) failed: {failed[0]}")
        writer = exitance_writer(path, output, spec, colour, alpha, route, plan, half=half,
                                 texture=texture)
        counts = dict(plan.invalid)
        for _, band_counts in done.values():
            for kind, n in band_counts.items():
                counts[kind] = counts.get(kind, 0) + n
        try:
            for (k, y0, y1) in sorted(done):       # one band in memory at a time
                r = Reader(done[(k, y0, y1)][0], "band")
                try:
                    writer.write_band(y0, y1, r.read_band(0, y1 - y0))
                finally:
                    r.close()
            writer.commit(check=guard.check)
        except Exception:
            writer.abort()
            raise
        report_clamped(writer, output, clamped, counts)
        return len(futures)
    finally:
        shutil.rmtree(work, ignore_errors=True)

# }}}


# {{{ lazy arrays

def block_origin(block_info) -> tuple:
    """The index of a block's first element in its array (map_blocks' ``block_info``)."""
    return tuple(start for start, _ in block_info[0]["array-location"])


def _stacked(fn, dtype=np.float32):
    """A block function returning its outputs stacked on a new last axis, in ``dtype``; an
    invalid value named where it is in the whole array, not in its block."""
    def block(*arrays, block_info=None):
        try:
            outs = fn(*arrays)
        except InvalidInputError as exc:
            raise (moved_by(exc, block_origin(block_info)) if block_info else exc) from None
        outs = outs if isinstance(outs, tuple) else (outs,)
        return np.stack([np.asarray(o, dtype) for o in outs], axis=-1)
    return block


def output_dtype(kw):
    """The lazy inversions' output dtype: the in-memory one's (float64 with ``double=True``)."""
    return np.dtype(np.float64 if kw.get("double") else np.float32)


def whole_channels(rd, eta):
    """``rd`` with its channels (last axis) in one chunk where ``eta`` has one value per
    channel: each block then holds every channel its etas are for."""
    return rd.rechunk({rd.ndim - 1: -1}) if np.size(eta) > 1 and rd.ndim else rd


def invert_albedo(rd, eta, method="table", *, return_rho=False, device=None, **kw):
    """``bdipole_cl.invert_albedo`` over a dask array's blocks (lazy)."""
    def fn(block):
        return ops_invert.invert_albedo(block, eta, method, return_rho=return_rho,
                                        device=device, **kw)
    rd, dtype = whole_channels(rd, eta), output_dtype(kw)
    out = rd.map_blocks(_stacked(fn, dtype), dtype=dtype, new_axis=rd.ndim,
                        chunks=rd.chunks + ((2 if return_rho else 1,),))
    return (out[..., 0], out[..., 1]) if return_rho else out[..., 0]


def albedo_to_coefficients(rd, mfp, eta, method="table", *, outputs=("sigma_a", "sigma_s"),
                           device=None, **kw):
    """``bdipole_cl.albedo_to_coefficients`` over dask arrays' blocks (lazy); ``mfp`` a
    constant, per-channel tuple, or an array of rd's shape (a dask array of its chunks) or of
    its shape without the channel axis (one mfp per texel for every channel)."""
    import dask.array as da

    def fn(block, mfp_block):
        return ops_invert.albedo_to_coefficients(block, mfp_block, eta, method,
                                                 outputs=outputs, device=device, **kw)
    rd, dtype = whole_channels(rd, eta), output_dtype(kw)
    mfp_arr = mfp if isinstance(mfp, da.Array) else np.asarray(mfp, np.float32)
    if not (isinstance(mfp_arr, da.Array) and mfp_arr.shape == rd.shape):
        _, mfp_arr = texel_broadcast(rd, mfp_arr)
        # chunked as rd along its axes, one chunk along those it is broadcast over
        chunks = tuple(c if n > 1 else (1,) for c, n in
                       zip(rd.chunks[rd.ndim - mfp_arr.ndim:], mfp_arr.shape))
        mfp_arr = (mfp_arr.rechunk(chunks) if isinstance(mfp_arr, da.Array)
                   else da.from_array(mfp_arr, chunks=chunks))
        mfp_arr = da.broadcast_to(mfp_arr, rd.shape, chunks=rd.chunks)
    if isinstance(mfp_arr, da.Array) and mfp_arr.chunks != rd.chunks:
        mfp_arr = mfp_arr.rechunk(rd.chunks)
    out = da.map_blocks(_stacked(fn, dtype), rd, mfp_arr, dtype=dtype,
                        new_axis=rd.ndim, chunks=rd.chunks + ((len(outputs),),))
    result = tuple(out[..., i] for i in range(len(outputs)))
    return result if len(result) > 1 else result[0]


BOUNDARIES = {"clamp": "nearest", "zero": 0, "wrap": "periodic"}


def blur(irradiance, *, border="clamp", device=None, stretch=None, charts="clamp", **kwargs):
    """``bdipole_cl.blur`` of an HxW or HxWxC dask array (lazy), constant parameters: each
    block with an overlap of the plan's truncation radius, the image's edges by ``border``.
    With ``stretch`` (and ``charts``), as ``bdipole_cl.blur`` takes them: the blur in surface
    distance (``stretched_blur``)."""
    scattering, options = Scattering.split(kwargs)
    if stretch is not None and not scattering.textured:
        return stretched_blur(irradiance, scattering, stretch, charts=charts, border=border,
                              device=device, **options)
    if scattering.textured:
        raise ValueError("bdipole_cl.dask.blur takes constant parameters (one value or one "
                         "per channel)")
    arr = irradiance if irradiance.ndim == 3 else irradiance[..., None]
    arr = arr.rechunk({2: -1})
    plan = plan_blur(arr.shape, scattering, border=border, device=device, **options)
    k = plan.halo

    def checked(block, block_info=None):  # before the overlap: a bad texel named in place
        try:
            return checked_irradiance(block, plan.on_invalid)
        except InvalidInputError as exc:
            raise moved_by(exc, block_origin(block_info)) from None

    def fn(block):                     # the one plan, its device bound once per process
        return plan.on(device).apply_band(np.ascontiguousarray(block, np.float32))[0]

    def whole(block):                  # the image in one block: the border rule applied there
        return plan.on(device).apply(block)[0]
    if k >= min(arr.shape[:2]):        # no overlap of k texels fits: an image that small is
        out = arr.rechunk({0: -1, 1: -1}).map_blocks(whole, dtype=np.float32)   # one block
        return out if irradiance.ndim == 3 else out[..., 0]
    # chunks thinner than the radius are merged by dask (allow_rechunk) so that every block's
    # overlap holds all the texels its kernels reach
    arr = arr.map_blocks(checked, dtype=np.float32)
    out = arr.map_overlap(fn, depth={0: k, 1: k, 2: 0}, boundary=BOUNDARIES[border],
                          dtype=np.float32, allow_rechunk=True)
    return out if irradiance.ndim == 3 else out[..., 0]



def channel_keywords(scattering: Scattering, c: int) -> dict:
    """``blur``'s parameter keywords of channel ``c`` alone (a constant per channel sliced;
    one value for every channel kept)."""
    return {k: (v if np.size(v) == 1 else np.asarray(v).ravel()[c])
            for k, v in scattering.keywords().items() if v is not None}


def stretched_blur(irradiance, scattering, stretch, *, charts="clamp", border="clamp",
                   device=None, **options):
    """``blur`` with a stretch: one task per channel over the whole image (the stretched blur
    reads every texel of it at once: its basis blurs are FFTs of the image's chart windows, so
    no band with a halo makes it); channels are blurred apart in it too, each with its own
    plan. The stretch is checked against the image's size here, before any task; the result
    comes chunked as the input."""
    from .ops.blur import blur as blur_image
    from .ops.blur.stretched import as_stretch
    arr = irradiance if irradiance.ndim == 3 else irradiance[..., None]
    s = as_stretch(stretch, arr.shape)

    def channel(block, block_info=None):
        c = block_info[0]["chunk-location"][2]
        out = blur_image(np.ascontiguousarray(block, np.float32), stretch=s, charts=charts,
                         border=border, device=device, **channel_keywords(scattering, c),
                         **options)
        return out.reshape(block.shape)
    out = arr.rechunk({0: -1, 1: -1, 2: 1}).map_blocks(channel, dtype=np.float32)
    out = out.rechunk(arr.chunks)
    return out if irradiance.ndim == 3 else out[..., 0]

# }}}
