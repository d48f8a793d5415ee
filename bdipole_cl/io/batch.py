"""Texture batches: albedo (+ mfp) textures in, scattering-coefficient EXRs out.

``process_textures`` is the engine of ``bdipole-cl invert``. Per input file it streams bands of
scanlines (a multiple of the tile height for tiled files) so memory stays bounded by
``max_memory`` whatever the resolution; the next band is read in a helper thread while the
device works on the current one. Outputs are written to a temporary file beside the target and
renamed when complete, so an interrupted or failed file leaves nothing half-written. A failing
file is reported (path and reason) and the batch goes on.

Images are read and written by ``images`` (conventions there); mfp textures are data (no
colour conversion), values times ``mfp_scale``, in ``unit``. Output channels are named
``<output>.<channel>`` (``sigma_a.R``), float or half, zip compression, same size, data window
and tiling as the albedo, its metadata kept, and the parameters used written as ``bdipole:*``
attributes.
"""
from __future__ import annotations

import os
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import OpenImageIO as oiio

from ..device import Runtime, get_runtime
from ..errors import InvalidInputError, check_policy
from ..methods.choice import DeviceKey, device_auto_note, resolve_method
from ..methods.registry import MethodConfig
from ..ops.bands import band_rows
from ..ops.invert import CoefficientMapper, check_mfp_kind
from ..version import __version__
from . import tiles
from .collisions import Claim, collisions
from .colour import WorkingSpace, check_colorspace, resolve_working_space
from .images import (Cancelled, Reader, TextureError, Writer, check_output_format,
                     check_same_window, classify_channels, invalid_texels, is_regular_file,
                     output_spec)
from .mipmaps import TextureOptions, texture_options
from .patterns import companion_path, expand_inputs, stem, written_by_us  # noqa: F401
from .verify import is_complete


DEFAULT_OUTPUT = "{dir}/{stem}.bdipole.exr"


def job_claims(jobs):
    """The ``collisions.Claim`` of each job: its output and its albedo, mfp and mask."""
    return [Claim(j.path, j.output, {"albedo": j.path, "mfp": j.mfp_path, "mask": j.mask_path})
            for j in jobs]


@dataclass
class FileResult:
    path: str
    output: str | None = None
    status: str = "failed"            # ok | failed | skipped | cancelled
    error: str | None = None
    texels: int = 0
    seconds: float = 0.0
    invalid: dict = field(default_factory=dict)
    notes: list = field(default_factory=list)       # e.g. channels left out
    colour: str | None = None                       # its colour path (ColourPath.describe)
    values: dict = field(default_factory=dict)      # a constant material's coefficients

    @property
    def mtexel_per_s(self):
        return self.texels / self.seconds / 1e6 if self.seconds > 0 else 0.0


@dataclass
class BatchReport:
    results: list

    @property
    def ok(self):
        return all(r.status in ("ok", "skipped") for r in self.results)

    @property
    def exit_code(self):
        return 0 if self.ok else 1

    def summary(self):
        rows = [("file", "status", "texels", "Mtexel/s", "invalid", "output / reason")]
        for r in self.results:
            inv = ", ".join(f"{k} {v}" for k, v in r.invalid.items() if v) or "0"
            rows.append((r.path, r.status, f"{r.texels}", f"{r.mtexel_per_s:.3g}", inv,
                         r.error if r.status in ("failed", "cancelled") else
                         (r.output or "") + "".join(f" ({n})" for n in r.notes)))
        widths = [max(len(row[i]) for row in rows) for i in range(5)]
        lines = []
        for row, r in zip(rows, [None] + self.results):
            lines.append("  ".join(c.ljust(w) for c, w in zip(row[:5], widths)) + "  " + row[5])
            if r is not None and r.colour:
                lines.append(f"  colour: {r.colour}")
        done = sum(r.status == "ok" for r in self.results)
        failed = sum(r.status == "failed" for r in self.results)
        skipped = sum(r.status == "skipped" for r in self.results)
        cancelled = sum(r.status == "cancelled" for r in self.results)
        lines.append(f"{done} done, {failed} failed, {skipped} skipped"
                     + (f", {cancelled} cancelled" if cancelled else ""))
        return "\n".join(lines)


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


def per_channel(values, ncolor, what, path):
    if len(values) == 1:
        return values * ncolor
    if len(values) != ncolor:
        raise TextureError(f"{path}: {what} has {len(values)} values but the albedo has "
                           f"{ncolor} colour channels")
    return tuple(values)


@dataclass
class Job:
    path: str
    udim: str | None                      # the tile's label (tiles.Tile.label), or None
    output: str
    mfp_path: str | None
    mask_path: str | None = None          # settings.mask == "texture": this file's mask
    skip: bool = False                    # up to date (--skip-existing): not run


@dataclass(frozen=True)
class BatchSettings:
    """What every file of a batch is processed with (``process_textures``' arguments)."""

    eta: tuple
    mfp: tuple | None            # constants per channel, or None: a texture per file
    mfp_scale: float | tuple     # one factor, or one per channel
    config: MethodConfig
    model: str
    exact: bool
    half: bool
    colorspace: str
    alpha: str                   # keep | drop
    on_invalid: str              # raise | clamp
    max_memory: int
    outputs: tuple
    unit: str
    runtime: Runtime
    double: bool = False
    cancel: object = None        # threading.Event or None
    mask: str | None = None      # None, "alpha" (the albedo's alpha) or "texture" (Job.mask_path)
    bake: bool = False           # a kernel specialised for the batch (constants compiled in)
    header: dict = field(default_factory=dict)   # more bdipole:* attributes for the outputs
    working: WorkingSpace | None = None          # None: the default working space
    mfp_kind: str = "diffuse"    # ops.invert.MFP_KINDS: ld = 1/mu_tr, or 1/sigma_t'
    texture: TextureOptions | None = None        # tiled, mip-mapped outputs (images.Writer)


#: the mfp convention each kind writes to an output's header
MFP_CONVENTIONS = {"diffuse": "ld = 1/mu_tr (Jensen/Hery)",
                   "extinction": "1/sigma_t' (medium mean free path)"}


def process_file(job, settings, device_lock, progress):
    result = FileResult(job.path, job.output)
    t0 = time.perf_counter()
    readers, writer = [], None
    if settings.cancel is not None and settings.cancel.is_set():
        result.status, result.error = "cancelled", "interrupted before it started"
        return result
    try:
        alb = Reader(job.path, "albedo")
        readers.append(alb)
        colour, alpha_ch = alb.channels()
        ncolor = len(colour)
        spec = alb.spec
        _, _, other = classify_channels(spec.channelnames, spec.alpha_channel)
        if other:
            result.notes.append("not colour, left out: "
                                + ", ".join(spec.channelnames[c] for c in other))
        names = [spec.channelnames[c] for c in colour]
        etas = per_channel(settings.eta, ncolor, "eta", job.path)
        mfp_reader = None
        if job.mfp_path is not None:
            mfp_reader = Reader(job.mfp_path, "mfp texture")
            readers.append(mfp_reader)
            check_same_window(spec, mfp_reader.spec, job.path, "mfp texture", job.mfp_path)
            mfp_colour, _ = mfp_reader.channels()
            if len(mfp_colour) not in (1, ncolor):
                raise TextureError(f"{job.path}: mfp texture {job.mfp_path} has "
                                   f"{len(mfp_colour)} channels; expected 1 or {ncolor}")
            mfp_const = None
        else:
            mfp_const = np.array(per_channel(settings.mfp, ncolor, "mfp", job.path),
                                 np.float32) * np.asarray(settings.mfp_scale, np.float32)
        route = alb.colour(settings.colorspace, settings.working)
        result.colour = route.describe()
        keep_alpha = alpha_ch >= 0 and settings.alpha == "keep"
        outputs = settings.outputs
        out_names = [f"{o}.{n}" for o in outputs for n in names]
        if keep_alpha:
            out_names.append(spec.channelnames[alpha_ch])
        params = {"version": __version__, "method": settings.config.describe(),
                  "model": settings.model, "eta": ",".join(f"{e:g}" for e in etas),
                  "mfp": job.mfp_path or ",".join(f"{m:g}" for m in mfp_const),
                  "mfp_scale": ",".join(f"{v:g}" for v in np.atleast_1d(settings.mfp_scale)),
                  "unit": settings.unit,
                  "coefficient_unit": f"1/{settings.unit}",
                  "albedo": job.path, **route.header("albedo"),
                  "mfp_convention": MFP_CONVENTIONS[settings.mfp_kind], **settings.header}
        mask_reader = None
        if settings.mask == "alpha" and alpha_ch < 0:
            raise TextureError(f"{job.path}: mask = 'alpha' but the albedo has no alpha "
                               f"channel (channels {', '.join(spec.channelnames)})")
        if settings.mask == "texture":
            mask_reader = Reader(job.mask_path, "mask texture")
            readers.append(mask_reader)
            check_same_window(spec, mask_reader.spec, job.path, "mask", job.mask_path)
        out_spec = output_spec(spec, out_names, len(out_names) - 1 if keep_alpha else -1,
                                settings.half, params, working=route.working)
        Path(job.output).parent.mkdir(parents=True, exist_ok=True)
        writer = Writer(job.output, out_spec, settings.on_invalid, texture=settings.texture,
                        cancel=settings.cancel)
        with device_lock:
            mapper = CoefficientMapper(tuple(etas), settings.config, outputs=outputs,
                                       model=settings.model, exact=settings.exact,
                                       on_invalid=settings.on_invalid,
                                       device=settings.runtime, double=settings.double,
                                       bake=settings.bake, mfp_kind=settings.mfp_kind,
                                       mfp_const=mfp_const if settings.bake else None)
        per_texel = 4 * 3 * (spec.nchannels + ncolor * (1 + len(outputs)) + len(out_names))
        rows = band_rows(spec.height, spec.width * per_texel, settings.max_memory,
                         tile_height=spec.tile_height if spec.tile_width else 0)
        bands = [(y, min(y + rows, spec.height)) for y in range(0, spec.height, rows)]

        def read(band):
            y0, y1 = band
            a = alb.read_band(y0, y1)
            m = mfp_reader.read_band(y0, y1) if mfp_reader is not None else None
            mask = (a[..., alpha_ch:alpha_ch + 1] if settings.mask == "alpha" else
                    mask_reader.read_band(y0, y1)[..., :1] if mask_reader is not None else None)
            return a, m, mask

        with ThreadPoolExecutor(1) as prefetch:
            pending = prefetch.submit(read, bands[0]) if bands else None
            for k, (y0, y1) in enumerate(bands):
                a, m, mask = pending.result()
                if k + 1 < len(bands):
                    pending = prefetch.submit(read, bands[k + 1])
                albedo = route.convert(a[..., colour], names)
                if m is None:
                    mfp = mfp_const
                else:
                    mfp = m[..., mfp_colour] * np.asarray(settings.mfp_scale, np.float32)
                try:
                    with device_lock:
                        outs, counts = mapper(albedo, mfp, mask)
                except InvalidInputError as exc:
                    yy, xx, cc = exc.first_index
                    raise invalid_texels(exc, job.path, spec.x + xx, spec.y + y0 + yy,
                                         names[cc], f" in rows {y0}..{y1 - 1}") from None
                for key, n in counts.items():
                    result.invalid[key] = result.invalid.get(key, 0) + n
                parts = [outs[o] for o in outputs]
                if keep_alpha:
                    parts.append(a[..., alpha_ch:alpha_ch + 1])
                block = np.concatenate(parts, axis=-1)
                cancel = settings.cancel
                if cancel is not None and cancel.is_set():
                    raise Cancelled(f"{job.path}: interrupted; nothing written")
                writer.write_band(y0, y1, block)
                if progress is not None:
                    progress.update((y1 - y0) * spec.width)
        if writer.invalid:
            result.invalid["half range" if settings.half else "not finite"] = writer.invalid
        writer.commit()
        writer = None
        result.status = "ok"
        result.texels = spec.width * spec.height
    except Cancelled as exc:
        result.status = "cancelled"
        result.error = str(exc)
    except TextureError as exc:
        result.error = str(exc)
    except (OSError, ValueError) as exc:
        result.error = f"{job.path}: {exc}"
    finally:
        if writer is not None:
            writer.abort()
        for r in readers:
            r.close()
        result.seconds = time.perf_counter() - t0
    return result


def newer_than_inputs(output, inputs):
    """``--skip-existing``: the output is complete (every pixel reads) and newer than every
    input's last change, content (mtime) or inode (ctime: which ``touch -r`` cannot restore)."""
    try:
        t = os.stat(output).st_mtime_ns
    except OSError:
        return False
    for p in inputs:
        if p and os.path.exists(p):
            st = os.stat(p)
            if max(st.st_mtime_ns, st.st_ctime_ns) > t:
                return False
    return is_complete(output)


def process_textures(inputs, *, mfp=1.0, eta=1.4, output=DEFAULT_OUTPUT,
                     outputs=("sigma_a", "sigma_s"), method="table", model="better",
                     exact=False, half=False, colorspace="auto", working_space=None, alpha="keep",
                     on_invalid="raise", max_memory=256 << 20, jobs=1, skip_existing=False,
                     unit="mm", mfp_scale=1.0, progress=False, device=None, cancel=None,
                     double=False, run_files=None, mfp_kind="diffuse", texture=False,
                     **knobs) -> BatchReport:
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
        tagged with (None: ``$OCIO``'s scene_linear, else lin_rec709_scene); README: Colour.
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
        Skip files whose output is newer than all their inputs.
    unit : str
        Length unit of the mfp (coefficients are per this unit); written to the header.
    mfp_scale : float
        Multiplies mfp values (constants and textures).
    progress : bool
        Show a tqdm progress bar (texels).
    device : None, str, pyopencl.Device or Runtime
        Where to run (``bdipole_cl.device``); every file of the batch uses this one device.
    run_files : callable or None
        ``run_files(jobs, settings) -> [FileResult]`` runs the files elsewhere (a cluster:
        ``bdipole_cl.dask.file_runner``); by default they run here, ``jobs`` at a time.
    cancel : threading.Event or None
        When set (the CLI sets it on SIGINT/SIGTERM), files stop at their next band: their
        temporary files are removed, finished files stay, and they are reported "cancelled".
    """
    check_output_format(output)
    working = resolve_working_space(working_space)
    check_colorspace(colorspace, working.config)
    if isinstance(inputs, (str, os.PathLike)):
        inputs = [inputs]
    if alpha not in ("keep", "drop"):
        raise ValueError(f"alpha={alpha!r}: expected 'keep' or 'drop'")
    key = DeviceKey.of(get_runtime(device).device) if method == "auto" else None
    config = resolve_method(method, double=double, device_key=key, **knobs)
    if method == "auto" and progress:
        print(f"method='auto': using {config.describe()} ({device_auto_note(key)})")
    settings = BatchSettings(
        eta=tuple(np.atleast_1d(np.asarray(eta, np.float64)).tolist()),
        mfp=parse_constant(mfp, "mfp"), mfp_scale=float(mfp_scale), config=config,
        model=model, exact=exact, half=half, colorspace=colorspace, working=working,
        alpha=alpha, on_invalid=check_policy(on_invalid), max_memory=int(max_memory),
        outputs=tuple(outputs), unit=unit, runtime=get_runtime(device), double=bool(double),
        cancel=cancel, mfp_kind=check_mfp_kind(mfp_kind), texture=texture_options(texture))
    CoefficientMapper((settings.eta[0],), config, outputs=settings.outputs, model=model,
                      exact=exact, on_invalid=on_invalid,
                      device=settings.runtime)  # fail fast on bad settings
    jobs_list, results = [], []
    files = expand_inputs(inputs)
    for path, tile in files:
        if tiles.is_pattern(path) and not os.path.exists(path):
            conv = tiles.token_of(path)
            results.append(FileResult(path, error=f"{path}: no file matches this pattern"
                                      + (f" ({conv.token} names tiles as {conv.convention})"
                                         if conv else "")))
            continue
        try:
            out = companion_path(output, path, tile)
            mfp_path = None if settings.mfp is not None else companion_path(mfp, path, tile)
        except (TextureError, tiles.TileError) as exc:
            results.append(FileResult(path, error=str(exc)))
            continue
        job = Job(path, tile.label if tile else None, out, mfp_path)
        job.skip = skip_existing and os.path.exists(path) and newer_than_inputs(out, [path,
                                                                                   mfp_path])
        jobs_list.append(job)
    clashes = collisions(job_claims(jobs_list))     # skipped jobs' inputs are inputs too
    for j, clash in zip(jobs_list, clashes):
        if clash:
            results.append(FileResult(j.path, j.output, error=clash))
        elif j.skip:
            results.append(FileResult(j.path, j.output, status="skipped"))
    jobs_list = [j for j, clash in zip(jobs_list, clashes) if not clash and not j.skip]
    bar = None
    if progress:
        from tqdm import tqdm
        total = 0
        for j in jobs_list:
            inp = oiio.ImageInput.open(j.path) if is_regular_file(j.path) else None
            if inp is not None:
                total += inp.spec().width * inp.spec().height
                inp.close()
        bar = tqdm(total=total, unit="texel", unit_scale=True, desc="invert")
    lock = threading.Lock()
    try:
        if run_files is not None:
            results += run_files(jobs_list, settings)
        else:
            with ThreadPoolExecutor(max(1, int(jobs))) as pool:
                results += list(pool.map(lambda j: process_file(j, settings, lock, bar),
                                         jobs_list))
    finally:
        if bar is not None:
            bar.close()
    order = {p: i for i, (p, _) in enumerate(files)}
    results.sort(key=lambda r: order.get(r.path, len(order)))
    return BatchReport(results)
