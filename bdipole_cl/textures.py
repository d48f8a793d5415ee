"""Texture batches: albedo (+ mfp) textures in, scattering-coefficient EXRs out.

``process_textures`` is the engine of ``bdipole-cl invert``. Per input file it streams bands of
scanlines (a multiple of the tile height for tiled files) so memory stays bounded by
``max_memory`` whatever the resolution; the next band is read in a helper thread while the
device works on the current one. Outputs are written to a temporary file beside the target and
renamed when complete, so an interrupted or failed file leaves nothing half-written. A failing
file is reported (path and reason) and the batch goes on.

Conventions
-----------
* Pixels are read as float32. Integer-encoded (8/16-bit) albedo is decoded to linear through
  OpenImageIO's colour conversion: ``colorspace="auto"`` takes the space the file declares
  (``oiio:ColorSpace``), else sRGB for 8-bit and linear for 16-bit; a named space overrides it
  for integer files. Float/half files are taken as linear. Decoded values are clamped to
  [0, 1] (the conversion's own overshoot, e.g. 1.0000241 for sRGB white).
* The alpha channel (``spec.alpha_channel``) is never inverted: ``alpha="keep"`` copies it to
  the output, ``"drop"`` leaves it out.
* mfp textures are data: no colour conversion; values times ``mfp_scale``, in ``unit``.
* Output channels are named ``<output>.<channel>`` (``sigma_a.R``), float or half, zip
  compression, same size, data window and tiling as the albedo, its metadata kept, and the
  parameters used written as ``bdipole:*`` attributes.
"""
from __future__ import annotations

import glob
import os
import re
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import OpenImageIO as oiio

from . import __version__
from .device import get_runtime
from .invert import CoefficientMapper, InvalidInputError, resolve_method

UDIM_TOKEN = "<UDIM>"
DEFAULT_OUTPUT = "{dir}/{stem}.bdipole.exr"


class TextureError(RuntimeError):
    """A file that cannot be processed; the message names the file and the reason."""


class Cancelled(TextureError):
    """The batch was stopped (SIGINT/SIGTERM) before this file was complete."""


#: what half floats hold: larger finite values become inf, smaller nonzero ones become 0
HALF_MAX = float(np.finfo(np.float16).max)
HALF_TINY = float(np.finfo(np.float16).smallest_subnormal)


# {{{ file sets

def expand_inputs(patterns):
    """Files named by paths, globs (``textures/*.tif``) or UDIM patterns (``a.<UDIM>.exr``),
    as ``(path, udim or None)``, in order, without duplicates. A pattern matching nothing is
    kept as a path, so that it is reported as missing rather than silently skipped."""
    out, seen = [], set()
    for pattern in patterns:
        pattern = str(pattern)
        if UDIM_TOKEN in pattern:
            rx = re.compile(re.escape(pattern).replace(re.escape(UDIM_TOKEN), r"(\d{4})") + "$")
            hits = sorted(glob.glob(pattern.replace(UDIM_TOKEN, "[1-9][0-9][0-9][0-9]")))
            found = [(h, rx.search(h).group(1)) for h in hits if rx.search(h)]
        elif glob.has_magic(pattern):
            found = [(h, None) for h in sorted(glob.glob(pattern))]
        else:
            found = [(pattern, None)]
        if not found:
            found = [(pattern, None)]
        for path, udim in found:
            if path not in seen:
                seen.add(path)
                out.append((path, udim))
    return out


def _stem(path):
    """The file name without its extension: ``diffuse.1001.exr`` -> ``diffuse.1001``, so that
    the tiles of a UDIM set keep distinct names."""
    name = Path(path).name
    return name.rsplit(".", 1)[0] if "." in name else name


def check_output_format(path):
    """Outputs are OpenEXR: only EXR holds float/half values in any number of named channels
    (``sigma_a.R``, ...). Any other extension would drop channels or quantise: refused."""
    suffix = Path(path).suffix.lower()
    if suffix != ".exr":
        raise ValueError(f"{path}: output must be an OpenEXR file (.exr), got "
                           f"'{suffix or 'no extension'}': other formats would drop channels or "
                           f"quantise the float values")


def output_collisions(jobs):
    """{output: reason} for outputs that two jobs share or that are some job's input: each
    such job would overwrite another's result or a user's file."""
    def key(p):
        return os.path.realpath(p)
    inputs = {key(p) for j in jobs for p in (j.path, j.mfp_path) if p}
    writers = {}
    for j in jobs:
        writers.setdefault(key(j.output), []).append(j.path)
    bad = {}
    for j in jobs:
        k = key(j.output)
        if k in inputs:
            bad[j.output] = f"{j.path}: output {j.output} would overwrite an input"
        elif len(writers[k]) > 1:
            others = ", ".join(p for p in writers[k] if p != j.path)
            bad[j.output] = (f"{j.path}: output {j.output} is also the output of {others}: put "
                             f"<UDIM>, {{udim}}, {{stem}} or {{name}} in -o so each input has its own")
    return bad


def companion_path(pattern, path, udim):
    """Fill ``{stem}``, ``{dir}``, ``{name}``, ``{udim}`` and ``<UDIM>`` for one input file."""
    p = Path(path)
    fields = {"stem": _stem(path), "dir": str(p.parent), "name": p.name, "udim": udim or ""}
    text = str(pattern)
    if UDIM_TOKEN in text:
        if udim is None:
            raise TextureError(f"{path}: pattern {pattern!r} needs a UDIM but the input has none")
        text = text.replace(UDIM_TOKEN, udim)
    try:
        return text.format(**fields)
    except (KeyError, IndexError) as exc:
        raise TextureError(f"pattern {pattern!r}: unknown field {exc}") from exc

# }}}


# {{{ channels

COLOUR_NAMES = ("r", "g", "b", "y", "red", "green", "blue", "l", "gray", "grey")
ALPHA_NAMES = ("a", "alpha")


def classify_channels(names, alpha_channel=-1):
    """(colour, alpha, other) channel indices of a file, by name (the part after the last '.',
    case-insensitive) and the file's declared alpha channel:

    - alpha: the declared alpha channel, else the first named A or alpha;
    - colour: channels named R, G, B, Y (also red, green, blue, L, gray, grey), in file order;
    - a file whose channels have none of these names but exactly one non-alpha channel: that
      channel is grey (a 1-channel file of any name; 2 channels of which one is alpha);
    - everything else (Z, depth, masks, ...) is other: never inverted, never written.

    So 1 channel is grey; 2 are grey + alpha when one is alpha, else as named (e.g. R and G);
    4 or more are R, G, B (+ A) with any extra channels left out."""
    short = [str(n).rsplit(".", 1)[-1].strip().lower() for n in names]
    alpha = alpha_channel if 0 <= alpha_channel < len(names) else next(
        (i for i, s in enumerate(short) if s in ALPHA_NAMES), -1)
    rest = [i for i in range(len(names)) if i != alpha]
    colour = [i for i in rest if short[i] in COLOUR_NAMES]
    if not colour and len(rest) == 1:
        colour = rest
    other = [i for i in rest if i not in colour]
    return colour, alpha, other

# }}}


# {{{ reading and writing bands

class _Reader:
    """One image file open for band reads (scanline or tiled), float32 out."""

    def __init__(self, path, what):
        self.path = path
        self.inp = None
        if os.path.isdir(path):
            raise TextureError(f"{path}: is a directory, not an image ({what})")
        if not os.path.exists(path):
            raise TextureError(f"{path}: no such file ({what})")
        self.inp = oiio.ImageInput.open(str(path))
        if self.inp is None:
            raise TextureError(f"{path}: cannot read {what}: {oiio.geterror() or 'unknown error'}")
        self.spec = self.inp.spec()
        self.lock = threading.Lock()

    def channels(self):
        """Indices of the colour channels and of the alpha channel (or -1), by
        ``classify_channels``; a file with no colour channel is a TextureError."""
        colour, alpha, _ = classify_channels(self.spec.channelnames, self.spec.alpha_channel)
        if not colour:
            raise TextureError(f"{self.path}: no colour channel among "
                               f"{', '.join(self.spec.channelnames)} (colour is R, G, B or Y, "
                               f"or a single channel that is not alpha)")
        return colour, alpha

    def read_band(self, y0, y1):
        s = self.spec
        with self.lock:
            if s.tile_width:
                px = self.inp.read_tiles(0, 0, s.x, s.x + s.width, s.y + y0, s.y + y1, s.z,
                                         s.z + max(s.depth, 1), 0, s.nchannels, oiio.FLOAT)
            else:
                px = self.inp.read_scanlines(0, 0, s.y + y0, s.y + y1, s.z, 0, s.nchannels,
                                             oiio.FLOAT)
        if px is None:
            raise TextureError(f"{self.path}: read of rows {y0}..{y1} failed: "
                               f"{self.inp.geterror() or oiio.geterror()}")
        return np.asarray(px, dtype=np.float32).reshape(y1 - y0, s.width, s.nchannels)

    def close(self):
        if self.inp is not None:
            self.inp.close()
            self.inp = None


_SKIP_ATTRIBS = ("compression", "oiio:ColorSpace", "oiio:BitsPerSample", "oiio:UnassociatedAlpha",
                 "oiio:Gamma", "openexr:lineOrder", "PixelAspectRatio")


def _output_spec(in_spec, channel_names, alpha_index, half, params):
    spec = oiio.ImageSpec(in_spec.width, in_spec.height, len(channel_names),
                          "half" if half else "float")
    spec.x, spec.y, spec.z = in_spec.x, in_spec.y, in_spec.z
    spec.full_x, spec.full_y = in_spec.full_x, in_spec.full_y
    spec.full_width, spec.full_height = in_spec.full_width, in_spec.full_height
    spec.tile_width, spec.tile_height = in_spec.tile_width, in_spec.tile_height
    spec.channelnames = tuple(channel_names)
    spec.alpha_channel = alpha_index
    for attr in in_spec.extra_attribs:
        if attr.name in _SKIP_ATTRIBS or attr.name.startswith(("bdipole:", "png:", "tiff:",
                                                               "jpeg:")):
            continue
        try:
            spec.attribute(attr.name, attr.type, attr.value)
        except Exception:  # an attribute type the Python binding cannot copy: leave it out
            pass
    spec.attribute("compression", "zip")
    spec.attribute("oiio:ColorSpace", "lin_rec709_scene")
    for key, value in params.items():
        spec.attribute(f"bdipole:{key}", str(value))
    return spec


class _Writer:
    """An EXR written band by band into a temporary file, renamed by ``commit``."""

    def __init__(self, path, spec):
        self.path = Path(path)
        self.tmp = self.path.with_name(f".{self.path.stem}.partial-{os.getpid()}"
                                       f"-{threading.get_ident()}{self.path.suffix}")
        self.spec = spec
        self.out = oiio.ImageOutput.create(str(self.tmp))
        if self.out is None:
            raise TextureError(f"{path}: cannot create output: {oiio.geterror()}")
        if not self.out.open(str(self.tmp), spec):
            err = self.out.geterror() or oiio.geterror()
            self.out = None
            self._remove_tmp()
            raise TextureError(f"{path}: cannot write output: {err}")

    def write_band(self, y0, y1, pixels):
        s = self.spec
        pixels = np.ascontiguousarray(pixels, dtype=np.float32)
        if s.tile_width:
            ok = self.out.write_tiles(s.x, s.x + s.width, s.y + y0, s.y + y1, s.z,
                                      s.z + max(s.depth, 1), pixels)
        else:
            ok = self.out.write_scanlines(s.y + y0, s.y + y1, s.z, pixels)
        if not ok:
            raise TextureError(f"{self.path}: write of rows {y0}..{y1} failed: "
                               f"{self.out.geterror()}")

    def commit(self):
        ok = self.out.close()
        self.out = None
        if not ok:
            self._remove_tmp()
            raise TextureError(f"{self.path}: closing the output failed: {oiio.geterror()}")
        os.replace(self.tmp, self.path)

    def abort(self):
        if self.out is not None:
            self.out.close()
            self.out = None
        self._remove_tmp()

    def _remove_tmp(self):
        try:
            self.tmp.unlink()
        except FileNotFoundError:
            pass

# }}}


# {{{ colour

def _is_integer(spec):
    return spec.format.basetype in (oiio.UINT8, oiio.INT8, oiio.UINT16, oiio.INT16, oiio.UINT32,
                                    oiio.INT32)


_LINEAR_NAMES = {"linear", "lin_rec709_scene", "lin_rec709", "scene_linear", "raw",
                 "linear rec.709 (srgb)"}


def source_colorspace(spec, colorspace="auto"):
    """The colour space integer-encoded albedo is decoded from, or None for linear data."""
    if not _is_integer(spec):
        return None
    if colorspace == "auto":
        declared = spec.getattribute("oiio:ColorSpace")
        if declared:
            colorspace = declared
        else:
            colorspace = "sRGB" if spec.format.size() == 1 else "linear"
    return None if str(colorspace).lower() in _LINEAR_NAMES else colorspace


def check_colorspace(colorspace):
    """A ``colorspace`` option OpenImageIO can decode from (a 1-texel conversion), else
    ValueError naming the known spaces."""
    if colorspace == "auto" or str(colorspace).lower() in _LINEAR_NAMES:
        return
    try:
        to_linear(np.full((1, 1, 3), 0.5, np.float32), colorspace)
    except TextureError:
        names = ", ".join(oiio.ColorConfig().getColorSpaceNames())
        raise ValueError(f"colorspace {colorspace!r} is unknown to OpenImageIO; use auto, "
                         f"linear, sRGB or one of: {names}") from None


def to_linear(pixels, colorspace):
    """Decode (rows, width, channels) colour pixels from ``colorspace`` to linear with OIIO."""
    if colorspace is None:
        return pixels
    rows, width, nch = pixels.shape
    buf = oiio.ImageBuf(oiio.ImageSpec(width, rows, nch, "float"))
    buf.set_pixels(oiio.ROI(), np.ascontiguousarray(pixels))
    out = oiio.ImageBufAlgo.colorconvert(buf, colorspace, "linear")
    if out.has_error:
        raise TextureError(f"colour conversion from {colorspace!r} failed: {out.geterror()}")
    return np.clip(out.get_pixels(oiio.FLOAT).reshape(rows, width, nch), 0.0, 1.0)

# }}}


# {{{ the batch

def fit_half(block, on_invalid, path, names, x0, y0):
    """``block`` (rows, width, channels) made safe to store as half floats. A finite value
    above HALF_MAX would be written as inf, a nonzero one below HALF_TINY/2 as 0: both are
    invalid, and ``on_invalid`` says what happens ("raise": TextureError naming the first
    texel; "clamp": clamped into [HALF_TINY, HALF_MAX] with its sign). Returns (block, count)."""
    with np.errstate(over="ignore"):            # the overflow is what is being detected
        h = block.astype(np.float16)
    bad = (np.isfinite(block) & ~np.isfinite(h)) | ((block != 0) & (h == 0))
    n = int(np.count_nonzero(bad))
    if n == 0:
        return block, 0
    if on_invalid != "clamp":
        yy, xx, cc = (int(v) for v in np.argwhere(bad)[0])
        raise TextureError(
            f"{path}: {n} value(s) outside the half-float range [{HALF_TINY:.3g}, {HALF_MAX:g}]; "
            f"first at x={x0 + xx}, y={y0 + yy}, channel {names[cc]}: {float(block[yy, xx, cc]):g}"
            f" (write float instead of half, or clamp with --on-invalid clamp / "
            f"on_invalid='clamp')")
    return np.where(bad, np.sign(block) * np.clip(np.abs(block), HALF_TINY, HALF_MAX), block), n


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
            rows.append((r.path, r.status, f"{r.texels}", f"{r.mtexel_per_s:.1f}", inv,
                         r.error if r.status in ("failed", "cancelled") else
                         (r.output or "") + "".join(f" ({n})" for n in r.notes)))
        widths = [max(len(row[i]) for row in rows) for i in range(5)]
        lines = ["  ".join(c.ljust(w) for c, w in zip(row[:5], widths)) + "  " + row[5]
                 for row in rows]
        done = sum(r.status == "ok" for r in self.results)
        failed = sum(r.status == "failed" for r in self.results)
        skipped = sum(r.status == "skipped" for r in self.results)
        cancelled = sum(r.status == "cancelled" for r in self.results)
        lines.append(f"{done} done, {failed} failed, {skipped} skipped"
                     + (f", {cancelled} cancelled" if cancelled else ""))
        return "\n".join(lines)


def _parse_constant(value, what):
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


def _per_channel(values, ncolor, what, path):
    if len(values) == 1:
        return values * ncolor
    if len(values) != ncolor:
        raise TextureError(f"{path}: {what} has {len(values)} values but the albedo has "
                           f"{ncolor} colour channels")
    return tuple(values)


def _band_rows(spec, bytes_per_texel, max_memory):
    rows = max(1, int(max_memory // max(1, spec.width * bytes_per_texel)))
    rows = min(rows, spec.height)
    if spec.tile_width and spec.tile_height:
        th = spec.tile_height
        rows = max(th, rows - rows % th)
    return rows


@dataclass
class _Job:
    path: str
    udim: str | None
    output: str
    mfp_path: str | None


def _process_file(job, settings, device_lock, progress):
    result = FileResult(job.path, job.output)
    t0 = time.perf_counter()
    readers, writer = [], None
    try:
        alb = _Reader(job.path, "albedo")
        readers.append(alb)
        colour, alpha_ch = alb.channels()
        ncolor = len(colour)
        spec = alb.spec
        _, _, other = classify_channels(spec.channelnames, spec.alpha_channel)
        if other:
            result.notes.append("not colour, left out: "
                                + ", ".join(spec.channelnames[c] for c in other))
        names = [spec.channelnames[c] for c in colour]
        etas = _per_channel(settings["eta"], ncolor, "eta", job.path)
        mfp_reader = None
        if job.mfp_path is not None:
            mfp_reader = _Reader(job.mfp_path, "mfp texture")
            readers.append(mfp_reader)
            ms = mfp_reader.spec
            if (ms.width, ms.height) != (spec.width, spec.height):
                raise TextureError(f"{job.path}: mfp texture {job.mfp_path} is "
                                   f"{ms.width}x{ms.height}, the albedo {spec.width}x"
                                   f"{spec.height}: resolutions must match")
            mfp_colour, _ = mfp_reader.channels()
            if len(mfp_colour) not in (1, ncolor):
                raise TextureError(f"{job.path}: mfp texture {job.mfp_path} has "
                                   f"{len(mfp_colour)} channels; expected 1 or {ncolor}")
            mfp_const = None
        else:
            mfp_const = np.array(_per_channel(settings["mfp"], ncolor, "mfp", job.path),
                                 np.float32) * settings["mfp_scale"]
        from_space = source_colorspace(spec, settings["colorspace"])
        keep_alpha = alpha_ch >= 0 and settings["alpha"] == "keep"
        outputs = settings["outputs"]
        out_names = [f"{o}.{n}" for o in outputs for n in names]
        if keep_alpha:
            out_names.append(spec.channelnames[alpha_ch])
        params = {"version": __version__, "method": settings["config"].describe(),
                  "model": settings["model"], "eta": ",".join(f"{e:g}" for e in etas),
                  "mfp": job.mfp_path or ",".join(f"{m:g}" for m in mfp_const),
                  "mfp_scale": settings["mfp_scale"], "unit": settings["unit"],
                  "coefficient_unit": f"1/{settings['unit']}",
                  "albedo": job.path, "albedo_colorspace": from_space or "linear",
                  "mfp_convention": "ld = 1/mu_tr (Jensen/Hery)"}
        out_spec = _output_spec(spec, out_names, len(out_names) - 1 if keep_alpha else -1,
                                settings["half"], params)
        Path(job.output).parent.mkdir(parents=True, exist_ok=True)
        writer = _Writer(job.output, out_spec)
        with device_lock:
            mapper = CoefficientMapper(tuple(etas), settings["config"], outputs=outputs,
                                       model=settings["model"], exact=settings["exact"],
                                       on_invalid=settings["on_invalid"],
                                       device=settings["runtime"], double=settings["double"])
        per_texel = 4 * 3 * (spec.nchannels + ncolor * (1 + len(outputs)) + len(out_names))
        rows = _band_rows(spec, per_texel, settings["max_memory"])
        bands = [(y, min(y + rows, spec.height)) for y in range(0, spec.height, rows)]

        def read(band):
            y0, y1 = band
            a = alb.read_band(y0, y1)
            m = mfp_reader.read_band(y0, y1) if mfp_reader is not None else None
            return a, m

        with ThreadPoolExecutor(1) as prefetch:
            pending = prefetch.submit(read, bands[0]) if bands else None
            for k, (y0, y1) in enumerate(bands):
                a, m = pending.result()
                if k + 1 < len(bands):
                    pending = prefetch.submit(read, bands[k + 1])
                albedo = to_linear(a[..., colour], from_space)
                if m is None:
                    mfp = mfp_const
                else:
                    mfp = m[..., mfp_colour] * np.float32(settings["mfp_scale"])
                try:
                    with device_lock:
                        outs, counts = mapper(albedo, mfp)
                except InvalidInputError as exc:
                    yy, xx, cc = exc.first_index
                    raise TextureError(
                        f"{job.path}: {exc.count} invalid {exc.name} texel(s) ({exc.why}) in "
                        f"rows {y0}..{y1 - 1}; first at x={spec.x + xx}, y={spec.y + y0 + yy}, "
                        f"channel {names[cc]}: {float(exc.first_value):g} "
                        f"(--on-invalid clamp / on_invalid='clamp' clamps them)") from None
                for key, n in counts.items():
                    result.invalid[key] = result.invalid.get(key, 0) + n
                parts = [outs[o] for o in outputs]
                if keep_alpha:
                    parts.append(a[..., alpha_ch:alpha_ch + 1])
                block = np.concatenate(parts, axis=-1)
                if settings["half"]:
                    block, n = fit_half(block, settings["on_invalid"], job.path, out_names,
                                        spec.x, spec.y + y0)
                    if n:
                        result.invalid["half range"] = result.invalid.get("half range", 0) + n
                cancel = settings["cancel"]
                if cancel is not None and cancel.is_set():
                    raise Cancelled(f"{job.path}: interrupted; nothing written")
                writer.write_band(y0, y1, block)
                if progress is not None:
                    progress.update((y1 - y0) * spec.width)
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


def _newer_than_inputs(output, inputs):
    try:
        t = os.path.getmtime(output)
    except OSError:
        return False
    return all(os.path.getmtime(p) <= t for p in inputs if p and os.path.exists(p))


def process_textures(inputs, *, mfp=1.0, eta=1.4, output=DEFAULT_OUTPUT,
                     outputs=("sigma_a", "sigma_s"), method="table", model="better",
                     exact=False, half=False, colorspace="auto", alpha="keep",
                     on_invalid="raise", max_memory=256 << 20, jobs=1, skip_existing=False,
                     unit="mm", mfp_scale=1.0, progress=False, device=None, cancel=None,
                     double=False, **knobs) -> BatchReport:
    """Invert albedo textures into scattering-coefficient EXRs (the ``bdipole-cl invert`` job).

    Parameters
    ----------
    inputs : str or sequence of str
        Albedo files, globs or UDIM patterns (``diffuse.<UDIM>.exr``).
    mfp : float, sequence of float, or str
        Mean free path ld = 1/mu_tr (SPEC.md): a constant (one or per channel, also as
        ``"1,0.5,0.25"``) or a texture path/pattern (``{stem}``, ``{dir}``, ``<UDIM>``).
    eta : float or sequence of float
        Relative index of refraction, one or per colour channel.
    output : str
        Output path pattern (``{dir}``, ``{stem}``, ``{name}``, ``{udim}``, ``<UDIM>``).
    outputs : sequence of str
        Channel groups to write, from alpha, rho, sigma_a, sigma_s, sigma_t.
    method, model, exact, double, **knobs
        As for ``invert_albedo`` (``double``: computed in float64; written as float or half).
    half : bool
        Write half floats instead of float.
    colorspace : str
        Colour space of integer-encoded albedo ("auto": see the module docstring).
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
    cancel : threading.Event or None
        When set (the CLI sets it on SIGINT/SIGTERM), files stop at their next band: their
        temporary files are removed, finished files stay, and they are reported "cancelled".
    """
    check_output_format(output)
    check_colorspace(colorspace)
    if isinstance(inputs, (str, os.PathLike)):
        inputs = [inputs]
    if alpha not in ("keep", "drop"):
        raise ValueError(f"alpha={alpha!r}: expected 'keep' or 'drop'")
    config = resolve_method(method, double=double, **knobs)
    if method == "auto" and progress:
        print(f"method='auto': using {config.describe()}")
    settings = dict(eta=tuple(np.atleast_1d(np.asarray(eta, np.float64)).tolist()),
                    mfp=_parse_constant(mfp, "mfp"), mfp_scale=float(mfp_scale),
                    config=config, model=model, exact=exact, half=half,
                    colorspace=colorspace, alpha=alpha, on_invalid=on_invalid,
                    max_memory=int(max_memory), outputs=tuple(outputs), unit=unit,
                    runtime=get_runtime(device), cancel=cancel, double=bool(double))
    CoefficientMapper((settings["eta"][0],), config, outputs=settings["outputs"], model=model,
                      exact=exact, on_invalid=on_invalid,
                      device=settings["runtime"])  # fail fast on bad settings
    jobs_list, results = [], []
    files = expand_inputs(inputs)
    unmatched = {p for p, _ in files if UDIM_TOKEN in p or glob.has_magic(p)}
    for path, udim in files:
        if path in unmatched:
            results.append(FileResult(path, error=f"{path}: no file matches this pattern"
                                      + (" (a UDIM is a 4-digit tile number, 1001-9999)"
                                         if UDIM_TOKEN in path else "")))
            continue
        try:
            out = companion_path(output, path, udim)
            mfp_path = None if settings["mfp"] is not None else companion_path(mfp, path, udim)
        except TextureError as exc:
            results.append(FileResult(path, error=str(exc)))
            continue
        if skip_existing and os.path.exists(path) and _newer_than_inputs(out, [path, mfp_path]):
            results.append(FileResult(path, out, status="skipped"))
            continue
        jobs_list.append(_Job(path, udim, out, mfp_path))
    clashes = output_collisions(jobs_list)
    results += [FileResult(j.path, j.output, error=clashes[j.output])
                for j in jobs_list if j.output in clashes]
    jobs_list = [j for j in jobs_list if j.output not in clashes]
    bar = None
    if progress:
        from tqdm import tqdm
        total = 0
        for j in jobs_list:
            inp = oiio.ImageInput.open(j.path)
            if inp is not None:
                total += inp.spec().width * inp.spec().height
                inp.close()
        bar = tqdm(total=total, unit="texel", unit_scale=True, desc="invert")
    lock = threading.Lock()
    try:
        with ThreadPoolExecutor(max(1, int(jobs))) as pool:
            results += list(pool.map(lambda j: _process_file(j, settings, lock, bar), jobs_list))
    finally:
        if bar is not None:
            bar.close()
    order = {p: i for i, (p, _) in enumerate(files)}
    results.sort(key=lambda r: order.get(r.path, len(order)))
    return BatchReport(results)

# }}}
