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
    name = Path(path).name
    return name.split(".")[0] if "." in name else name


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


# {{{ reading and writing bands

class _Reader:
    """One image file open for band reads (scanline or tiled), float32 out."""

    def __init__(self, path, what):
        self.path = path
        self.inp = oiio.ImageInput.open(str(path))
        if self.inp is None:
            raise TextureError(f"{path}: cannot read {what}: {oiio.geterror() or 'unknown error'}")
        self.spec = self.inp.spec()
        self.lock = threading.Lock()

    def channels(self):
        """Indices of the colour (non-alpha) channels and of the alpha channel (or -1)."""
        a = self.spec.alpha_channel
        return [c for c in range(self.spec.nchannels) if c != a], a

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

@dataclass
class FileResult:
    path: str
    output: str | None = None
    status: str = "failed"            # ok | failed | skipped
    error: str | None = None
    texels: int = 0
    seconds: float = 0.0
    invalid: dict = field(default_factory=dict)

    @property
    def mtexel_per_s(self):
        return self.texels / self.seconds / 1e6 if self.seconds > 0 else 0.0


@dataclass
class BatchReport:
    results: list

    @property
    def ok(self):
        return all(r.status != "failed" for r in self.results)

    @property
    def exit_code(self):
        return 0 if self.ok else 1

    def summary(self):
        rows = [("file", "status", "texels", "Mtexel/s", "invalid", "output / reason")]
        for r in self.results:
            inv = ", ".join(f"{k} {v}" for k, v in r.invalid.items() if v) or "0"
            rows.append((r.path, r.status, f"{r.texels}", f"{r.mtexel_per_s:.1f}", inv,
                         r.error if r.status == "failed" else (r.output or "")))
        widths = [max(len(row[i]) for row in rows) for i in range(5)]
        lines = ["  ".join(c.ljust(w) for c, w in zip(row[:5], widths)) + "  " + row[5]
                 for row in rows]
        done = sum(r.status == "ok" for r in self.results)
        failed = sum(r.status == "failed" for r in self.results)
        skipped = sum(r.status == "skipped" for r in self.results)
        lines.append(f"{done} done, {failed} failed, {skipped} skipped")
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
        if ncolor == 0:
            raise TextureError(f"{job.path}: no colour channel (only alpha)")
        spec = alb.spec
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
                                       device=settings["runtime"])
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
                        f"channel {names[cc]}: {exc.first_value!r} "
                        f"(on_invalid='clamp' clamps them)") from None
                for key, n in counts.items():
                    result.invalid[key] = result.invalid.get(key, 0) + n
                parts = [outs[o] for o in outputs]
                if keep_alpha:
                    parts.append(a[..., alpha_ch:alpha_ch + 1])
                writer.write_band(y0, y1, np.concatenate(parts, axis=-1))
                if progress is not None:
                    progress.update((y1 - y0) * spec.width)
        writer.commit()
        writer = None
        result.status = "ok"
        result.texels = spec.width * spec.height
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
                     unit="mm", mfp_scale=1.0, progress=False, device=None,
                     **knobs) -> BatchReport:
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
    method, model, exact, **knobs
        As for ``invert_albedo``.
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
    """
    if isinstance(inputs, (str, os.PathLike)):
        inputs = [inputs]
    if alpha not in ("keep", "drop"):
        raise ValueError(f"alpha={alpha!r}: expected 'keep' or 'drop'")
    config = resolve_method(method, **knobs)
    if method == "auto" and progress:
        print(f"method='auto': using {config.describe()}")
    settings = dict(eta=tuple(np.atleast_1d(np.asarray(eta, np.float64)).tolist()),
                    mfp=_parse_constant(mfp, "mfp"), mfp_scale=float(mfp_scale),
                    config=config, model=model, exact=exact, half=half,
                    colorspace=colorspace, alpha=alpha, on_invalid=on_invalid,
                    max_memory=int(max_memory), outputs=tuple(outputs), unit=unit,
                    runtime=get_runtime(device))
    CoefficientMapper((settings["eta"][0],), config, outputs=settings["outputs"], model=model,
                      exact=exact, on_invalid=on_invalid,
                      device=settings["runtime"])  # fail fast on bad settings
    jobs_list, results = [], []
    files = expand_inputs(inputs)
    for path, udim in files:
        try:
            out = companion_path(output, path, udim)
            mfp_path = None if settings["mfp"] is not None else companion_path(mfp, path, udim)
        except TextureError as exc:
            results.append(FileResult(path, error=str(exc)))
            continue
        if os.path.abspath(out) in (os.path.abspath(path), os.path.abspath(mfp_path or "")):
            results.append(FileResult(path, out, error=f"{path}: output {out} would overwrite "
                                                         "an input"))
            continue
        if skip_existing and os.path.exists(path) and _newer_than_inputs(out, [path, mfp_path]):
            results.append(FileResult(path, out, status="skipped"))
            continue
        jobs_list.append(_Job(path, udim, out, mfp_path))
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
