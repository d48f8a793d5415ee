"""Blur jobs: an irradiance image in, an exitance EXR out (``bdipole-cl blur``, a scene's
blurs), planned once (``ops.blur.plan_blur``) and applied in bands of rows with the plan's
halo; ``run_blur`` is the runner of blur jobs (``runner.run_job``)."""
from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from ..device import get_runtime
from ..errors import InvalidInputError, warn_caller, warnings_naming
from ..io.channels import classify_channels
from ..io.collisions import Claim, check_claim
from ..io.colour import resolve_working_space
from ..io.freshness import InputGuard
from ..io.images import (Cancelled, Reader, TextureError, Writer, check_output_format,
                         check_same_window, image_header, invalid_texels, output_spec,
                         read_parameter_texture, read_rows)
from ..io.mipmaps import texture_options
from ..methods.registry import BORDER
from ..ops.bands import band_rows, bands
from ..ops.blur import BlurPlan, Scattering, plan_blur
from ..ops.blur.params import add_count, checked_irradiance
from ..ops.blur.planning import BlurAccuracyWarning, worse
from ..ops.invert import invert_albedo
from ..signals import Stopped
from .pipeline import stream_bands
from .results import FileResult
from .scene_stats import read_albedo
from .stretch_file import scene_stretch

#: working set per row of a streamed band, in floats per texel and channel of the file: the
#: band as read, the colour planes, the blur's own working set (``constant_row_bytes``, which
#: counts float64 FFT copies; the float32 FFT needs half) and the output with alpha, and the
#: band read ahead and the one being written (``pipeline.BANDS_IN_FLIGHT``) in what the
#: float32 FFT leaves. Measured: a 4096^2 RGB blur at --max-memory 64M peaks 65-70 MB above
#: the process's own (a 64-row image's) peak
FILE_ROW_FLOATS = 10


def located(exc, path, sources, spec, idx, names=None):
    """An InvalidInputError of one band as a TextureError naming the file it comes from and
    the texel in image coordinates: irradiance rows through the band's row indices ``idx``
    (the halo included), parameter textures (whole images) as they are, data window added;
    the channel by its name in ``names`` (the irradiance's colour channels, which each
    parameter's channel serves), as ``invert`` names it."""
    yy, xx, cc = exc.first_index
    row = int(idx[yy]) if exc.name == "irradiance" else yy
    role = exc.name if exc.name in sources else exc.name.rstrip("'")
    where = sources.get(role, path)
    names = (texture_channel_names(where, role) or names) if where != path else names
    channel = names[min(cc, len(names) - 1)] if names and cc >= 0 else cc
    return invalid_texels(exc, where, spec.x + xx, spec.y + row, channel)


def texture_channel_names(path, role=None) -> list | None:
    """The colour channels' names of a parameter texture file read as ``role`` (a one-channel
    map serves every channel: its one name), None where ``path`` is no image file."""
    header = image_header(path) if isinstance(path, (str, Path)) else None
    if header is None:
        return None
    colour, _, _ = classify_channels(header.channelnames, header.alpha_channel, role)
    return [header.channelnames[c] for c in colour] or None


def file_plan(path, spec, names, scattering, options, sources) -> BlurPlan:
    """The plan of a file's blur (``names``: its colour channels'), made once for all its
    bands (a parameter texture's bad texel named in the file it comes from); its accuracy
    warnings name the file (``warnings_naming``)."""
    try:
        with warnings_naming(path, BlurAccuracyWarning):
            return plan_blur((spec.height, spec.width, len(names)), scattering, **options)
    except InvalidInputError as exc:
        raise located(exc, path, sources, spec, np.arange(spec.height), names) from None


def blurred_band(plan, px, colour, alpha_ch, names, route, idx, mask, y0, y1,
                 max_memory=None, counts=None):
    """Rows [y0, y1) of the output from the band ``px`` read at rows ``idx`` (the halo
    included): the colour channels converted into the working space, masked texels unlit
    (whatever they hold: a NaN there is no error), blurred by ``plan`` (a texture-varying plan
    reads its whole image at once: no halo); bands with no light are not blurred (0); then
    the alpha channel ``alpha_ch`` (if >= 0) as read. (output, BlurInfo or None).
    ``counts``: a dict that gets the irradiance values of rows [y0, y1) that the plan's
    ``on_invalid="clamp"`` makes unlit (NaN, infinite), under "irradiance" (the halo's rows
    are some other band's)."""
    k = plan.halo if len(idx) > y1 - y0 else 0
    e = route.convert(px[..., colour], names)
    if mask is not None:
        keep = (np.asarray(mask)[np.maximum(idx, 0)] > 0) & (idx >= 0)[:, None]
        e = np.where(keep[..., None], e, np.float32(0))
    if plan.on_invalid == "clamp":
        own = e[k:k + y1 - y0]
        add_count(counts, "irradiance", own.size - np.count_nonzero(np.isfinite(own)))
    if not np.any(e):                   # no light reaches this band: nothing to blur
        out, info = np.zeros((y1 - y0, px.shape[1], len(colour)), np.float32), None
    else:
        try:
            if plan.textured:
                out, info = plan.apply(e, max_memory)
            else:
                out, info = plan.apply_band(checked_irradiance(e, plan.on_invalid), idx)
        except InvalidInputError as exc:
            if exc.name == "irradiance":
                check_band_rows(e, idx)     # counted once per image row, not per halo copy
            raise
        out = out[k:k + y1 - y0]
        if mask is not None:
            out = out * (np.asarray(mask)[y0:y1] > 0)[..., None]
    if alpha_ch >= 0:
        out = np.concatenate([out, px[k:k + y1 - y0, :, alpha_ch:alpha_ch + 1]], axis=-1)
    return out, info


def check_band_rows(e, idx):
    """A band's irradiance ``e`` read at image rows ``idx`` (its halo
    included: the border rule repeats rows, an edge row up to the halo's height) checked once
    per image row: an InvalidInputError counts each bad value once, its first row given as a
    row of ``e`` (``located`` maps it through ``idx``)."""
    real = np.flatnonzero(idx >= 0)
    _, first = np.unique(idx[real], return_index=True)
    rows = real[np.sort(first)]
    try:
        checked_irradiance(e[rows], "raise")
    except InvalidInputError as exc:
        yy, xx, cc = exc.first_index
        raise exc.with_(first_index=(int(rows[yy]), xx, cc)) from None


def exitance_writer(path, output, spec, colour, alpha_ch, route, plan, *, half=False,
                    header=None, texture=False, cancel=None) -> Writer:
    """The writer of a blur's output: the irradiance's colour channels (then its alpha), the
    parameters and the methods used as ``bdipole:*`` attributes, tagged with the working
    space. The one output layout of the file blur and of its cluster form."""
    names = [spec.channelnames[c] for c in colour]
    if alpha_ch >= 0:
        names.append(spec.channelnames[alpha_ch])
    meta = plan.scattering.header() | {"tol": plan.tol, "border": plan.border}
    meta["methods"] = ",".join(planned_methods(plan))
    meta.update(header or {})
    meta["source"] = str(path)
    meta["layer"] = "exitance"      # what the file holds (``channels.held_layer``)
    meta.update(route.header("irradiance"))
    Path(output).parent.mkdir(parents=True, exist_ok=True)
    options = texture_options(texture)   # a texture wraps as the blur's border did, unless
    if options is not None and options.wrap is None:         # the user chose a wrap mode
        options = replace(options, wrap=BORDER[plan.border].texture_wrap)
    return Writer(output, output_spec(spec, names, len(names) - 1 if alpha_ch >= 0 else -1,
                                      half, meta, working=route.working),
                  plan.on_invalid, texture=options, cancel=cancel)


def planned_methods(plan):
    """Each channel's method and radius, as the plan decided them (before any band runs)."""
    if plan.textured:
        return [f"{c.method}(r={c.radius})" for c in plan.textured_info.channels]
    return [f"{p.method}(r={p.kernel.radius})" for p in plan.channels]


def blur_file(path, output, *, colorspace="auto", working_space=None, half=False,
              max_memory=256 << 20, sources=None, cancel=None, mask=None, header=None,
              progress=None, texture=False, albedo=None, mfp=None, eta=1.4, texel_size=1.0,
              alpha=None, sigma_t=None, device=None, force=False, clamped=None, guard=None,
              stretch=None, **options):
    """Blur an irradiance image file into an EXR, streamed in bands of rows with a halo of the
    truncation radius (memory bounded by ``max_memory``). The irradiance is converted from
    ``colorspace`` (else as the file declares, as in ``process_textures``) into
    ``working_space``, the space the albedo/mfp parameters are in (arrays and constants are
    taken as being in it; ``read_parameter_texture(..., colour=True)`` converts an albedo
    file), and the output is tagged with it. Alpha is copied through. The parameters
    (``albedo`` ... ``sigma_t``, ``alpha`` being alpha') and ``options`` (tol, method, border,
    exact, on_invalid) are ``blur``'s; the plan is made once for every band.

    ``sources``: {parameter name: file} of parameter textures given as arrays, so that errors
    name the file they come from and ``output`` never overwrites one of them. ``cancel``
    (threading.Event): when set, the next band raises Cancelled and the temporary output is
    removed. ``mask`` (HxW, the image's size): texels where it is 0 give no light and get no
    exitance (written as 0); bands whose halo'd irradiance is all 0 are not blurred at all.
    ``header``: more ``bdipole:*`` attributes for the output. ``progress``: a tqdm bar
    advanced by texels. ``texture`` (True or a TextureOptions): a tiled, mip-mapped EXR
    (``images.Writer``). ``force``: replace an existing ``output`` this tool did not write
    (``io.collisions.foreign``). ``clamped``: a dict that gets, under ``on_invalid="clamp"``,
    the invalid values clamped by kind: the irradiance's and the parameter textures'
    (``BlurInfo.invalid``) and the output values that could not be stored
    (``images.Writer.clamped``); without it they are warned of. ``guard``: the
    ``freshness.InputGuard`` of the job's inputs as first read (default: the irradiance and
    ``sources`` as of this call): an input changed before the output is in place fails it,
    nothing written. Returns the BlurInfo (None when every band was skipped)."""
    check_output_format(output)
    sources = dict(sources or {})
    check_claim(Claim(str(path), str(output), {"irradiance": str(path), **sources}), force)
    scattering = Scattering(albedo, mfp, eta, texel_size, alpha, sigma_t, stretch)
    guard = guard or InputGuard({"irradiance": path, **sources})
    reader = Reader(path, "irradiance", role="irradiance")
    writer = None
    try:
        spec = reader.spec
        colour, alpha_ch = reader.channels()
        route = reader.colour(colorspace, resolve_working_space(working_space))
        names = [spec.channelnames[c] for c in colour]
        _, _, other = classify_channels(spec.channelnames, spec.alpha_channel)
        if other:                     # as ``invert`` says it: a channel is never lost unsaid
            warn_caller(f"{path}: not colour, left out: "
                        f"{', '.join(spec.channelnames[c] for c in other)}")
        plan = file_plan(path, spec, names, scattering,
                         dict(options, device=get_runtime(device)), sources)
        if plan.textured:
            # parameter textures: one global plan, so the whole image is read and the plan
            # bands it itself within max_memory (its halo follows that plan)
            k, rows = 0, spec.height
        else:
            k = plan.halo
            rows = band_rows(spec.height, spec.width * spec.nchannels * 4 * FILE_ROW_FLOATS,
                             max_memory, halo=k, tile_height=spec.tile_height)
        state = {"info": None, "writer": None}
        counts = dict(plan.invalid)         # the parameter textures' values clamped

        def compute(band, px):
            y0, y1, idx = band
            if cancel is not None and cancel.is_set():
                raise Cancelled(f"{path}: interrupted; nothing written")
            try:
                with warnings_naming(path, BlurAccuracyWarning):
                    out, band_info = blurred_band(plan, px, colour, alpha_ch, names, route,
                                                  idx, mask, y0, y1, max_memory, counts)
            except InvalidInputError as exc:
                raise located(exc, path, sources, spec, idx, names) from None
            state["info"] = worse(state["info"], band_info)
            if state["writer"] is None:
                state["writer"] = exitance_writer(path, output, spec, colour, alpha_ch, route,
                                                  plan, half=half, header=header,
                                                  texture=texture, cancel=cancel)
            return out

        def write(band, block):
            y0, y1, _ = band
            state["writer"].write_band(y0, y1, block)
            if progress is not None:
                progress.update((y1 - y0) * spec.width)

        try:
            stream_bands(bands(spec.height, rows, k, plan.border),
                         lambda band: read_rows(reader, band[2]), compute, write)
        finally:
            writer, info = state["writer"], state["info"]
        writer.commit(check=guard.check)
        report_clamped(writer, output, clamped, counts)
        writer = None
        return info if info is None else replace(info, invalid=counts)
    except Stopped:
        raise Cancelled(f"{path}: interrupted; nothing written") from None
    except (OSError, ValueError) as exc:
        where = sources.get(getattr(exc, "name", None), path)
        raise TextureError(f"{where}: {exc}") from exc
    except Warning as exc:             # an accuracy warning the user's filter makes an error:
        raise TextureError(f"{exc} (a warning made an error by the warnings filter)") from exc
    finally:
        if writer is not None:
            writer.abort()
        reader.close()


def report_clamped(writer, output, clamped, inputs=None):
    """The invalid input values clamped (``inputs``, by kind) and the writer's clamped values
    into ``clamped`` (a dict), or a warning naming the output where the caller keeps no
    count: a clamped value is never silent."""
    given = {**(inputs or {}), **writer.clamped}
    counts = {k: given[k] for k in sorted(given, key=count_order) if given[k]}
    if clamped is not None:
        clamped.update(counts)
    elif counts:
        warn_caller(f"{output}: {clamped_text(counts)}")


#: the order invalid counts are said in: the irradiance, the parameters, then the output's
COUNT_ORDER = ("irradiance", "albedo", "mfp", "alpha", "sigma_t")


def count_order(kind) -> int:
    return COUNT_ORDER.index(kind) if kind in COUNT_ORDER else len(COUNT_ORDER)


def clamped_text(counts) -> str:
    """Clamped-value counts ({what: n}) as words: "invalid values clamped: irradiance 2, half
    range 5" ("" if none)."""
    parts = [f"{k} {n}" for k, n in counts.items() if n]
    return "invalid values clamped: " + ", ".join(parts) if parts else ""


def masked_parameter(values, keep):
    """Parameter maps with masked texels set to a valid value of the unmasked ones (their own
    parameters are never used: their exitance is 0), so they neither fail the checks nor widen
    the plan's range."""
    if keep is None or not keep.any():
        return values
    fill = np.nanmin(np.where(keep[..., None], values, np.nan), axis=(0, 1))
    return np.where(keep[..., None], values, fill)


def check_windows(job):
    """The blur's parameter textures cover the irradiance's pixels (TextureError if not); the
    irradiance's texel count."""
    r = Reader(job.source, "irradiance", role="irradiance")
    try:
        for role, p in job.inputs.items():
            if role != "irradiance":
                other = Reader(p, role, role=role)
                try:
                    check_same_window(r.spec, other.spec, job.source, role, p)
                finally:
                    other.close()
        return r.spec.width * r.spec.height
    finally:
        r.close()


def material_scattering(job, runtime):
    """A scene blur's parameters from its material (``BlurWork.material``): the albedo file
    read into the working space, the mfp texture or constants, masked texels filled; an
    extinction mfp as alpha' and sigma_t' = 1/mfp; the job's "stretch" maps, if any, in the
    material's unit. (Scattering, mask or None, header)."""
    w, m = job.work, job.work.material
    albedo, keep, *_, route = read_albedo(job.inputs["albedo"], w.mask, job.inputs.get("mask"),
                                          m.colorspace, w.working, m.albedo_layer)
    mfp = (read_parameter_texture(job.inputs["mfp"], "mfp", role="mfp", layer=m.mfp_layer)
           if "mfp" in job.inputs else np.asarray(m.mfp)) * np.asarray(m.mfp_scale, np.float32)
    albedo = masked_parameter(albedo, keep)
    if np.ndim(mfp) >= 2:
        mfp = masked_parameter(mfp, keep)
    # a stretch job's maps, or the user's, in the material's unit (the mfp's)
    stretch = scene_stretch(job.inputs["stretch"], m.unit) if "stretch" in job.inputs else None
    texel = 1.0 if w.texel_size is None else w.texel_size    # (unused with a stretch)
    if m.mfp_kind == "diffuse":
        scattering = Scattering(albedo, mfp, m.eta, texel, stretch=stretch)
    else:
        alpha_prime = invert_albedo(albedo, m.eta if len(m.eta) > 1 else m.eta[0],
                                    exact=m.exact, model=m.model, device=runtime)
        scattering = Scattering(None, None, m.eta, texel, alpha_prime, 1.0 / mfp, stretch)
    return scattering, keep, route.header("albedo")


def run_blur(job, runtime, *, cancel=None, lock=None, progress=None) -> FileResult:
    """Run one blur job (``runner.run_job``): its FileResult (``info``: the BlurInfo)."""
    w = job.work
    result = FileResult(job.source, job.output)
    t0 = time.perf_counter()
    guard = InputGuard(job.inputs, job.identities)     # before the first read
    try:
        keep, header = None, dict(w.header)
        texels = check_windows(job)     # parameter textures meet the irradiance texel by texel
        if w.material is not None:
            result.colour = "irradiance " + colour_of(job.source, "irradiance", w.colorspace,
                                                      w.working)
            scattering, keep, albedo_header = material_scattering(job, runtime)
            header |= albedo_header
        else:
            scattering = w.scattering
        sources = {k: v for k, v in job.inputs.items() if k != "irradiance" and k != "mask"}
        result.info = blur_file(
            job.source, job.output, half=w.half, sources=sources, cancel=cancel, mask=keep,
            header=header, colorspace=w.colorspace, working_space=w.working,
            albedo=scattering.albedo, mfp=scattering.mfp, eta=scattering.eta,
            texel_size=scattering.texel_size, alpha=scattering.alpha_prime,
            sigma_t=scattering.sigma_t, tol=w.tol, method=w.method, border=w.border,
            on_invalid=w.on_invalid, exact=w.exact, device=runtime, max_memory=w.max_memory,
            texture=w.texture, progress=progress, clamped=result.invalid,
            stretch=scattering.stretch, charts=w.charts,
            force=True,      # its claim was checked where the job was made, with the run's force
            guard=guard)
        result.status = "ok"
        result.texels = texels
    except Cancelled as exc:
        result.status, result.error = "cancelled", str(exc)
    except (TextureError, OSError, ValueError) as exc:
        result.error = str(exc)
    result.seconds = time.perf_counter() - t0
    return result


def colour_of(path, role, colorspace, working, layer=None) -> str:
    """The colour path of one file (its ``layer``) into ``working``, described
    (``ColourPath.describe``)."""
    r = Reader(path, role, role=role, layer=layer)
    try:
        return r.colour(colorspace, working).describe()
    finally:
        r.close()
