"""Texture batches: albedo (+ mfp) textures in, scattering-coefficient EXRs out.

``process_textures`` is ``bdipole-cl invert``: it expands the inputs (globs, UDIM and UV-tile
patterns) into one inversion ``Job`` per file, checks every job's output against every input
of the run, and runs the jobs with ``runner.run_job`` (``jobs`` at a time, or on a cluster
through ``run_files``). What one job does is ``invert_file``. A failing file is reported
(path and reason) and the batch goes on.
"""
from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import fields, replace

import numpy as np

from ..device import get_runtime
from ..errors import check_policy
from ..io import tiles
from ..io.collisions import Claim, collisions
from ..io.freshness import params_digest
from ..io.colour import check_colorspace, resolve_working_space
from ..io.images import TextureError, check_output_format, image_header, texel_count
from ..io.mipmaps import texture_options
from ..io.patterns import (companion_path, expand_inputs, stem, unmatched_pattern,  # noqa: F401
                           written_by_us)
from ..io.verify import is_complete
from ..methods.choice import DeviceKey, device_auto_note, resolve_method
from ..methods.registry import ALPHA_CHANNEL
from ..ops.invert import InversionPlan, check_mfp_kind
from ..physics.models import MODEL
from . import runner
from .job import InvertWork, Job
from .results import BatchReport, FileResult

DEFAULT_OUTPUT = "{dir}/{stem}.bdipole.exr"


def job_claims(jobs):
    """The ``collisions.Claim`` of each job: its output and every input by role."""
    return [Claim(j.source, j.output, j.inputs) for j in jobs]


def parse_constant(value, what):
    """A float, a per-channel tuple, or a comma-separated string of them, or None (a path)."""
    if isinstance(value, (int, float)):
        return (float(value),)
    if isinstance(value, (tuple, list)) and all(isinstance(v, (int, float)) for v in value):
        return tuple(float(v) for v in value)
    if isinstance(value, str):
        try:
            return tuple(float(v) for v in value.split(","))
        except ValueError:
            return None
    raise TypeError(f"{what}: expected a number, per-channel numbers or a path, got {value!r}")


def check_scaled_mfp(mfp, scale):
    """A ValueError naming both values where a constant mfp (``parse_constant``'s, or None)
    times ``mfp_scale`` (both checked on their own) leaves the range every kernel can take
    (``params.CONSTANT_RULES``): it would fail every texel of every file (unless they are
    clamped: ``on_invalid="clamp"``)."""
    from ..ops.blur.params import scaled_mfp_problem
    why = scaled_mfp_problem(mfp, scale) if mfp else None
    if why:
        raise ValueError(why)


def work_digest(work: InvertWork) -> str:
    """The digest of everything an inversion's output depends on but its inputs' content
    (what ``--skip-existing`` compares with the output's ``bdipole:params_digest``): every
    field of its work but the band budget and the header."""
    return params_digest({f.name: getattr(work, f.name) for f in fields(work)
                          if f.name not in ("max_memory", "header")})


def made_with(output, digest) -> bool:
    """The output's header records the settings' digest ``digest`` (``work_digest``)."""
    spec = image_header(output)
    return spec is not None and spec.getattribute("bdipole:params_digest") == digest


def newer_than_inputs(output, inputs):
    """``--skip-existing``: the output is complete (every pixel reads) and newer than every
    input's last change, content (mtime) or inode (ctime: which ``touch -r`` cannot restore)."""
    try:
        t = os.stat(output).st_mtime_ns
    except OSError:
        return False
    for p in inputs:
        if p and os.path.exists(p) and last_change(p) > t:
            return False
    return is_complete(output)


def last_change(path) -> int:
    """The latest change (ns) of a file as reached through ``path``: its content or inode, and
    every symbolic link met on the way (a "latest" link re-pointed at an older version is a new
    input, though the file it names is older than the output)."""
    st = os.stat(path)
    times = [st.st_mtime_ns, st.st_ctime_ns]
    parts = os.path.abspath(path).split(os.sep)
    for k in range(2, len(parts) + 1):
        link, hops = os.sep.join(parts[:k]), 0
        while os.path.islink(link) and hops < 40:     # a chain of links, each re-pointable
            lst = os.lstat(link)
            times += [lst.st_mtime_ns, lst.st_ctime_ns]
            link, hops = os.path.join(os.path.dirname(link), os.readlink(link)), hops + 1
    return max(times)


def process_textures(inputs, *, mfp=1.0, eta=1.4, output=DEFAULT_OUTPUT,
                     outputs=("sigma_a", "sigma_s"), method="table", model="better",
                     exact=False, half=False, colorspace="auto", working_space=None, alpha="keep",
                     on_invalid="raise", max_memory=256 << 20, jobs=1, skip_existing=False,
                     unit="mm", mfp_scale=1.0, progress=False, device=None, cancel=None,
                     double=False, run_files=None, mfp_kind="diffuse", texture=False,
                     force=False, **knobs) -> BatchReport:
    """Invert albedo textures into scattering-coefficient EXRs (the ``bdipole-cl invert`` job).

    Parameters
    ----------
    inputs : str or sequence of str
        Albedo files, globs or tile patterns (``diffuse.<UDIM>.exr``, ``diffuse_<UVTILE>.exr``:
        ``bdipole_cl.io.tiles``).
    mfp : float, sequence of float, or str
        Mean free path ld = 1/mu_tr (docs/model.md "Mean free path"): a constant (one or per
        channel, also as
        ``"1,0.5,0.25"``) or a texture path/pattern (``{stem}``, ``{dir}``, ``<UDIM>``).
    mfp_kind : {"diffuse", "extinction"}
        What the mfp is: ld = 1/mu_tr (default), or the medium's mean free path 1/sigma_t'
        (``albedo_to_coefficients``).
    eta : float or sequence of float
        Relative index of refraction, one or per colour channel.
    output : str
        Output path pattern (``{dir}``, ``{stem}``, ``{name}``, ``{udim}``, a tile token; the
        output's token may differ from the input's: tiles are converted).
    outputs : sequence of str
        Channel groups to write, from alpha, rho, sigma_a, sigma_s, sigma_t.
    method, model, exact, double, **knobs
        As for ``invert_albedo`` (``double``: computed in float64; written as float or half).
    half : bool
        Write half floats instead of float.
    texture : bool or TextureOptions
        Tiled (64x64), mip-mapped EXRs (``mipmaps``; the image is held whole for the mips).
    colorspace, working_space : str
        The albedo files' colour space ("auto": as each declares, else 8-bit sRGB, 16-bit and
        float in the working space) and the space they are inverted in and outputs are
        tagged with (None: ``$OCIO``'s scene_linear, else lin_rec709_scene); docs/colour.md.
    alpha : {"keep", "drop"}
        What to do with an alpha channel (never inverted).
    on_invalid : {"raise", "clamp"}
        Invalid texels fail the file (reported with texel coordinates) or are clamped
        (counted in the summary); see ``albedo_to_coefficients``.
    max_memory : int
        Host bytes one file's bands may take (bounds memory for huge textures).
    jobs : int
        Files processed at once (I/O of one overlaps the device work of another).
    skip_existing : bool
        Skip files whose output is newer than all their inputs and was made with the same
        settings (its ``bdipole:params_digest``: ``work_digest``).
    unit : str
        Length unit of the mfp (coefficients are per this unit); written to the header.
    mfp_scale : float
        Multiplies mfp values (constants and textures).
    progress : bool
        Show a tqdm progress bar (texels).
    device : None, str, pyopencl.Device or Runtime
        Where to run (``bdipole_cl.device``); every file of the batch uses this one device.
    run_files : callable or None
        ``run_files(jobs) -> [FileResult]`` runs the jobs elsewhere (a cluster:
        ``bdipole_cl.dask.file_runner``); by default they run here, ``jobs`` at a time.
    cancel : threading.Event or None
        When set (the CLI sets it on SIGINT/SIGTERM), files stop at their next band: their
        temporary files are removed, finished files stay, and they are reported "cancelled".
    force : bool
        Replace existing outputs this tool did not write (else such a file fails its row:
        ``io.collisions.foreign``).
    """
    check_output_format(output)
    working = resolve_working_space(working_space)
    check_colorspace(colorspace, working.config)
    if isinstance(inputs, (str, os.PathLike)):
        inputs = [inputs]
    alpha = ALPHA_CHANNEL.canonical(alpha)
    model = MODEL.canonical(model)
    rt = get_runtime(device)
    key = DeviceKey.of(rt.device) if method == "auto" else None
    config = resolve_method(method, double=double, device_key=key, **knobs)
    if method == "auto" and progress:
        print(f"method='auto': using {config.describe()} ({device_auto_note(key)})")
    constant_mfp = parse_constant(mfp, "mfp")
    if on_invalid != "clamp":          # clamp: each texel's, clamped and counted
        check_scaled_mfp(constant_mfp, float(mfp_scale))
    work = InvertWork(
        eta=tuple(np.atleast_1d(np.asarray(eta, np.float64)).tolist()),
        mfp=constant_mfp, mfp_scale=float(mfp_scale), config=config,
        model=model, exact=exact, half=half, colorspace=colorspace, working=working,
        alpha_channel=alpha, on_invalid=check_policy(on_invalid), max_memory=int(max_memory),
        outputs=tuple(outputs), unit=unit, double=bool(double),
        mfp_kind=check_mfp_kind(mfp_kind), texture=texture_options(texture))
    work = replace(work, header={"params_digest": work_digest(work)})
    InversionPlan((work.eta[0],), config, outputs=work.outputs, mfp_kind=work.mfp_kind,
                  model=model, exact=exact, on_invalid=work.on_invalid,
                  runtime=rt)                           # fail fast on bad settings
    files = expand_inputs(inputs)
    jobs_list, skip, results = batch_jobs(files, work, output, mfp, skip_existing)
    clashes = collisions(job_claims(jobs_list), force)  # skipped jobs' inputs are inputs too
    for j, s, clash in zip(jobs_list, skip, clashes):
        if clash:
            results.append(FileResult(j.source, j.output, error=clash))
        elif s:
            results.append(FileResult(j.source, j.output, status="skipped"))
    jobs_list = [j for j, s, clash in zip(jobs_list, skip, clashes) if not clash and not s]
    bar = texel_bar(jobs_list, "invert") if progress else None
    try:
        if run_files is not None:
            results += run_files(jobs_list)
        else:
            with ThreadPoolExecutor(max(1, int(jobs))) as pool:
                results += list(pool.map(lambda j: runner.run_job(j, rt, cancel=cancel,
                                                                  progress=bar), jobs_list))
    finally:
        if bar is not None:
            bar.close()
    order = {p: i for i, (p, _) in enumerate(files)}
    results.sort(key=lambda r: order.get(r.path, len(order)))
    return BatchReport(results)


def batch_jobs(files, work, output, mfp, skip_existing):
    """One inversion Job per (file, tile) of ``files`` (``expand_inputs``), whether each is up
    to date (``--skip-existing``), and the results of files that cannot be jobs."""
    jobs_list, skip, results = [], [], []
    for path, tile in files:
        if tiles.is_pattern(path) and not os.path.exists(path):
            results.append(FileResult(path, error=unmatched_pattern(path)))
            continue
        try:
            out = companion_path(output, path, tile)
            mfp_path = None if work.mfp is not None else companion_path(mfp, path, tile)
        except (TextureError, tiles.TileError) as exc:
            results.append(FileResult(path, error=str(exc)))
            continue
        inputs = {"albedo": path} | ({"mfp": mfp_path} if mfp_path else {})
        jobs_list.append(Job("invert", path, out, inputs, work, tile.label if tile else None))
        skip.append(skip_existing and newer_than_inputs(out, [path, mfp_path])
                    and made_with(out, work.header["params_digest"]))
    return jobs_list, skip, results


def texel_bar(jobs_list, desc):
    """A tqdm bar over the texels of the jobs' sources."""
    from tqdm import tqdm
    return tqdm(total=sum(texel_count(j.source) for j in jobs_list), unit="texel",
                unit_scale=True, desc=desc)
