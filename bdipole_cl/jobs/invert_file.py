"""One inversion job: an albedo texture (+ an mfp texture or constants, + a mask) in, a
scattering-coefficient EXR out, streamed in bands of rows (a multiple of the tile height for
tiled files) so that memory stays bounded by ``max_memory``; the next band is read and the
last one written in helper threads while the device works on the current one. The output is written to a
temporary file, verified and renamed when complete (``io.images.Writer``), so an interrupted
or failed job leaves nothing half-written.

Output channels are named ``<output>.<channel>`` (``sigma_a.R``), float or half, the albedo's
size, data window and tiling, its metadata kept, and the parameters written as ``bdipole:*``
attributes; mfp textures are data (no colour conversion), values times ``mfp_scale``.
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InvalidInputError, check_policy, find_invalid
from ..io.freshness import InputGuard
from ..io.channels import short_name
from ..io.images import (Cancelled, Reader, TextureError, Writer, check_same_window,
                         classify_channels, invalid_texels, output_spec)
from ..ops.bands import band_rows
from ..ops.invert import InversionPlan, check_mfp_kind
from ..version import __version__
from .pipeline import stream_bands
from .results import FileResult

#: the mfp convention each kind writes to an output's header
MFP_CONVENTIONS = {"diffuse": "ld = 1/mu_tr (Jensen/Hery)",
                   "extinction": "1/sigma_t' (medium mean free path)"}


def per_channel(values, ncolor, what, path):
    """One value (also given as several equal ones), or one per colour channel (a TextureError
    naming the file if neither)."""
    if len(set(values)) == 1:
        return tuple(values[:1]) * ncolor
    if len(values) != ncolor:
        raise TextureError(f"{path}: {what} has {len(values)} values but the albedo has "
                           f"{ncolor} colour channels")
    return tuple(values)


@dataclass
class InvertInputs:
    """The open readers of one inversion job and what they decide: the albedo's colour and
    alpha channels, the mfp texture's channels (or the constants), the mask's source."""

    albedo: Reader
    colour: list
    alpha: int                       # the albedo's alpha channel (-1: none)
    names: list                      # colour channel names
    mfp: Reader | None
    mfp_channels: list | None
    mfp_const: np.ndarray | None     # per channel, scaled (no mfp texture)
    mask: Reader | None
    keep_alpha: bool                 # the alpha channel is carried to the output

    def read(self, band, work):
        """Rows [y0, y1) of (albedo, mfp texture or None, mask or None)."""
        y0, y1 = band
        a = self.albedo.read_band(y0, y1)
        m = self.mfp.read_band(y0, y1) if self.mfp is not None else None
        mask = (a[..., self.alpha:self.alpha + 1] if work.mask == "alpha" else
                self.mask.read_band(y0, y1)[..., :1] if self.mask is not None else None)
        return a, m, mask


def open_inputs(job, work, readers) -> InvertInputs:
    """Open the job's albedo, mfp and mask (each appended to ``readers`` as it opens, so the
    caller closes what opened) and check they fit together."""
    what = getattr(work, "input_names", {})      # convert's: its colour and --radius
    alb = Reader(job.source, what.get("albedo", "albedo"), role="albedo",
                 layer=work.layers.get("albedo"))
    readers.append(alb)
    colour, alpha_ch = alb.channels()
    spec = alb.spec
    names = [spec.channelnames[c] for c in colour]
    mfp_reader = mfp_channels = mfp_const = mask_reader = None
    mfp_path = job.inputs.get("mfp")
    if mfp_path is not None:
        mfp_reader = Reader(mfp_path, what.get("mfp", "mfp texture"), role="mfp",
                            layer=work.layers.get("mfp"))
        readers.append(mfp_reader)
        check_same_window(spec, mfp_reader.spec, job.source, "mfp texture", mfp_path)
        mfp_channels, _ = mfp_reader.channels()
        if len(mfp_channels) not in (1, len(colour)):
            raise TextureError(f"{job.source}: mfp texture {mfp_path} has "
                               f"{len(mfp_channels)} channels; expected 1 or {len(colour)}")
    else:                        # an overflow is invalid (on_invalid: named, or clamped)
        with np.errstate(over="ignore", under="ignore"):
            mfp_const = np.array(per_channel(work.mfp, len(colour), "mfp", job.source),
                                 np.float32) * np.asarray(work.mfp_scale, np.float32)
    if work.mask == "alpha" and alpha_ch < 0:
        raise TextureError(f"{job.source}: mask = 'alpha' but the albedo has no alpha "
                           f"channel (channels {', '.join(spec.channelnames)})")
    if work.mask == "texture":
        mask_reader = Reader(job.inputs["mask"], "mask texture")
        readers.append(mask_reader)
        check_same_window(spec, mask_reader.spec, job.source, "mask", job.inputs["mask"])
    return InvertInputs(alb, colour, alpha_ch, names, mfp_reader, mfp_channels, mfp_const,
                        mask_reader, alpha_ch >= 0 and work.alpha_channel == "keep")


def output_header(job, work, etas, inp, route) -> dict:
    """The ``bdipole:*`` attributes of an inversion's output: what it was computed with."""
    return {"version": __version__, "method": work.config.describe(), "model": work.model,
            "eta": ",".join(f"{e:g}" for e in etas),
            "mfp": job.inputs.get("mfp") or ",".join(f"{m:g}" for m in inp.mfp_const),
            "mfp_scale": ",".join(f"{v:g}" for v in np.atleast_1d(work.mfp_scale)),
            "unit": work.unit, "coefficient_unit": f"1/{work.unit}", "albedo": job.source,
            **route.header("albedo"), "mfp_convention": MFP_CONVENTIONS[work.mfp_kind],
            **work.header}


def inversion_plan(work, etas, inp, runtime) -> InversionPlan:
    """The job's inversion plan on ``runtime``, made once and applied to every band
    (constants compiled into its kernel with ``specialise``)."""
    return InversionPlan(tuple(etas), work.config, outputs=work.outputs,
                         mfp_kind=check_mfp_kind(work.mfp_kind), model=work.model,
                         exact=work.exact, double=work.double, on_invalid=work.on_invalid,
                         specialise=work.specialise,
                         mfp_const=inp.mfp_const if work.specialise else None,
                         runtime=runtime)


def non_negative_albedo(albedo, on_invalid, mask=None, one_valid=False):
    """(albedo, count): a texture's albedo below 0 (outside the working space's gamut after
    the colour conversion, or painted so) is invalid: an InvalidInputError naming the first,
    or with "clamp" 0 and counted. (``invert_albedo``'s arrays map Rd <= 0 to alpha' = 0; a
    file's texel below 0 is not an albedo, and is never silently changed.) Texels where
    ``mask`` (HxWx1 or HxW, as the plan takes it) is not > 0 are neither checked nor counted,
    as the plan leaves them out; a NaN is not below 0 (the plan's own rule reports it) and
    hides no other texel. Under "raise" the error counts and names, in array order, the plan's
    invalid values too (NaN, infinite, above 1, or 1 itself unless ``one_valid``)."""
    bad = albedo < 0
    keep = True
    if mask is not None:
        keep = np.asarray(mask) > 0
        if keep.ndim == albedo.ndim - 1:
            keep = keep[..., None]
        bad &= keep
    if not bad.any():
        return albedo, 0
    if check_policy(on_invalid) == "raise":
        above = ~(albedo <= 1) if one_valid else ~(albedo < 1)
        find_invalid("albedo", albedo, bad | (above & keep),
                     f"below 0 in the working space (outside its gamut, or not an albedo), "
                     f"NaN, infinite or {'> 1' if one_valid else '>= 1'}", on_invalid,
                     texels=True)
    n = find_invalid("albedo", albedo, bad, "below 0", on_invalid, texels=True)
    return np.where(bad, albedo.dtype.type(0), albedo), n


def invert_bands(job, work, inp, route, plan, writer, result, lock, cancel, progress):
    """The band loop (``pipeline.stream_bands``: the next band read and the last written
    while one is inverted): read, convert, invert on the device, write. The band budget
    counts three bands' texels (the one read ahead, the one inverted, the one written)."""
    spec = inp.albedo.spec
    nout = len(work.outputs) * len(inp.names) + inp.keep_alpha
    per_texel = 4 * 3 * (spec.nchannels + len(inp.names) * (1 + len(work.outputs)) + nout)
    rows = band_rows(spec.height, spec.width * per_texel, work.max_memory,
                     tile_height=spec.tile_height if spec.tile_width else 0)
    scale = np.asarray(work.mfp_scale, np.float32)

    def compute(band, data):
        (y0, y1), (a, m, mask) = band, data
        albedo = route.convert(a[..., inp.colour], inp.names)
        if m is None:
            mfp = inp.mfp_const
        else:                             # an overflow is an invalid texel, named below
            with np.errstate(over="ignore", under="ignore"):
                mfp = m[..., inp.mfp_channels] * scale
        try:
            albedo, negative = non_negative_albedo(albedo, work.on_invalid, mask,
                                                   one_valid=plan.mfp_kind is None)
            with lock:
                done = plan.apply(albedo, mfp, mask)
        except InvalidInputError as exc:
            yy, xx, cc = exc.first_index
            scaled, where, channel = "", job.source, inp.names[cc]
            if exc.name == "mfp" and m is not None:     # the mfp texture's own texel, named
                ch = inp.mfp_channels[cc if len(inp.mfp_channels) > 1 else 0]
                where, channel = job.inputs["mfp"], inp.mfp.spec.channelnames[ch]
                if np.any(scale != 1):
                    scaled = (f" (the mfp texture's {float(m[yy, xx, ch]):g} x --mfp-scale "
                              f"{float(np.ravel(scale)[cc % scale.size]):g})")
            raise invalid_texels(exc, where, spec.x + xx, spec.y + y0 + yy,
                                 channel, f" in rows {y0}..{y1 - 1}{scaled}") from None
        for key, n in (("albedo", done.invalid_albedo + negative), ("mfp", done.invalid_mfp)):
            result.invalid[key] = result.invalid.get(key, 0) + n
        parts = [done.arrays[o] for o in work.outputs]
        if inp.keep_alpha:
            parts.append(a[..., inp.alpha:inp.alpha + 1])
        if cancel is not None and cancel.is_set():
            raise Cancelled(f"{job.source}: interrupted; nothing written")
        return np.concatenate(parts, axis=-1)

    def write(band, block):
        writer.write_band(*band, block)
        if progress is not None:
            progress.update((band[1] - band[0]) * spec.width)

    stream_bands([(y, min(y + rows, spec.height)) for y in range(0, spec.height, rows)],
                 lambda band: inp.read(band, work), compute, write)


class JobFiles:
    """A file job's open readers and its writer, and how the job ends (``run_invert``,
    ``convert_file.run_convert``): used as ``with JobFiles(job, result) as files``, an error
    of the job's files (cancelled, a texture error, OSError, ValueError) becomes the result's,
    the writer not committed (``files.writer`` still set) is aborted, the readers closed and
    the time taken recorded."""

    def __init__(self, job, result: FileResult):
        self.job, self.result = job, result
        self.readers: list = []
        self.writer = None

    def __enter__(self):
        self._t0 = time.perf_counter()
        return self

    def __exit__(self, kind, exc, tb):
        result = self.result
        if isinstance(exc, Cancelled):
            result.status, result.error = "cancelled", str(exc)
        elif isinstance(exc, TextureError):
            result.error = str(exc)
        elif isinstance(exc, (OSError, ValueError)):
            result.error = f"{self.job.source}: {exc}"
        if self.writer is not None:
            self.writer.abort()
        for r in self.readers:
            r.close()
        result.seconds = time.perf_counter() - self._t0
        return isinstance(exc, (Cancelled, TextureError, OSError, ValueError))


def run_invert(job, runtime, *, cancel=None, lock, progress=None) -> FileResult:
    """Run one inversion job (``runner.run_job``): its FileResult."""
    work = job.work
    result = FileResult(job.source, job.output)
    guard = InputGuard(job.inputs, job.identities)    # before the first read
    with JobFiles(job, result) as files:
        inp = open_inputs(job, work, files.readers)
        spec = inp.albedo.spec
        _, _, other = classify_channels(spec.channelnames, spec.alpha_channel, "albedo",
                                        work.layers.get("albedo"))
        if other:
            result.notes.append("not colour, left out: "
                                + ", ".join(spec.channelnames[c] for c in other))
        etas = per_channel(work.eta, len(inp.names), "eta", job.source)
        route = inp.albedo.colour(work.colorspace, work.working)
        result.colour = route.describe()
        out_names = [f"{o}.{short_name(n)}" for o in work.outputs for n in inp.names]
        if inp.keep_alpha:
            out_names.append(spec.channelnames[inp.alpha])
        out_spec = output_spec(spec, out_names, len(out_names) - 1 if inp.keep_alpha else -1,
                               work.half, output_header(job, work, etas, inp, route),
                               working=route.working)
        Path(job.output).parent.mkdir(parents=True, exist_ok=True)
        files.writer = writer = Writer(job.output, out_spec, work.on_invalid,
                                       texture=work.texture, cancel=cancel)
        with lock:
            plan = inversion_plan(work, etas, inp, runtime)
        invert_bands(job, work, inp, route, plan, writer, result, lock, cancel, progress)
        result.invalid.update(writer.clamped)
        writer.commit(check=guard.check)
        files.writer = None
        result.status = "ok"
        result.texels = spec.width * spec.height
    return result
