"""Images: reading and writing bands of OpenImageIO files, channels and colour (I/O layer).

* Pixels are read as float32 (``Reader``), respecting the data window, scanline or tiled.
* Channels are classified by name (``classify_channels``): only colour is ever inverted.
* Colour (albedo, irradiance) is converted into the working space by ``colour`` (OpenColorIO
  through OpenImageIO); parameter textures that are not colour (mfp, masks) are read as data.
  Outputs are tagged as being in the working space (``output_spec``).
* Outputs are OpenEXR (``check_output_format``), written band by band into a temporary file
  beside the target and renamed when it reads back as written (``Writer``, ``verify``); every
  value is finite in the output's format or its texel is invalid (``verify.finite_texels``).
* Inputs: regular files only; colour with alpha is read unassociated (as painted, never
  premultiplied); tiled and mip-mapped files are read at level 0 in tile-aligned bands;
  multi-part and deep files, and L/a/b channels, are refused by name.
* Texture outputs (``mipmaps.TextureOptions``): the verified EXR made tiled and mip-mapped by
  OpenImageIO's ``make_texture``, channels, header and pixel type kept, level 0 verified equal
  to it (``Writer``).
"""
from __future__ import annotations

import os
import shutil
import stat
import threading
from pathlib import Path

import numpy as np
import OpenImageIO as oiio

from .mipmaps import (TextureBuildCancelled, TextureBuildError, build_texture,
                      texture_options, window_problem)
from .verify import (BandDigests, WriteCheckError, finite_texels, read_back,  # noqa: F401
                     read_rows, read_rows_of)
from .channels import (ALPHA_NAMES, COLOUR_NAMES, GREY_NAMES, NOT_RGB,  # noqa: F401
                       classify_channels, role_missing, role_refused)
from .colour import COLOUR_ATTRIBS, colour_path, tag_data, tag_output
from .oiio_text import oiio_error
from .partials import remove_partial_files
from ..durable import durable_replace
from ..errors import one_line
from ..signals import STOP
from ..version import __version__


class TextureError(RuntimeError):
    """A file that cannot be processed; the message names the file and the reason, on one
    line (OpenImageIO's errors can hold several: ``errors.one_line``)."""

    def __init__(self, message=""):
        super().__init__(one_line(message))


class Cancelled(TextureError):
    """The batch was stopped (SIGINT/SIGTERM) before this file was complete."""


#: texture extensions that are TIFF underneath (maketx's .tx): refused, with the reason
TIFF_TEXTURES = (".tx", ".tif", ".tiff")


def check_output_format(path):
    """Outputs are OpenEXR: only EXR holds float/half values in any number of named channels
    (``sigma_a.R``, ...). Any other extension would drop channels or quantise: refused, and a
    ``.tx``/TIFF texture with its own reason (texture outputs are tiled, mip-mapped EXRs); an
    empty path is named as such."""
    if not str(path).strip():
        raise ValueError(f"output {str(path)!r}: an empty path; name an .exr file")
    suffix = Path(path).suffix.lower()
    if suffix in TIFF_TEXTURES:
        raise ValueError(f"{path}: output must be an OpenEXR file (.exr): a {suffix} (TIFF) "
                         f"texture drops the channel names (sigma_a.R, ...); an .exr output "
                         f"with --texture / texture = true is a tiled, mip-mapped texture")
    if suffix != ".exr":
        raise ValueError(f"{path}: output must be an OpenEXR file (.exr), got "
                           f"'{suffix or 'no extension'}': other formats would drop channels or "
                           f"quantise the float values")


def open_config():
    """How every input is opened: colour with alpha as painted (unassociated, never
    premultiplied on read: no texel changes by its alpha)."""
    cfg = oiio.ImageSpec()
    cfg.attribute("oiio:UnassociatedAlpha", 1)
    return cfg


def is_regular_file(path) -> bool:
    """``path`` is a regular file (opening anything else may block: a FIFO waits forever)."""
    try:
        return stat.S_ISREG(os.stat(path).st_mode)
    except OSError:
        return False


def oiio_path(path) -> str:
    """``path``, or a TextureError naming it (caf\\xe9.exr) if OpenImageIO cannot take it: a
    name that is not UTF-8."""
    try:
        return str(path).encode("utf-8") and str(path)
    except UnicodeEncodeError:
        shown = str(path).encode("utf-8", "surrogateescape").decode("utf-8", "backslashreplace")
        raise TextureError(f"{shown}: a file name that is not UTF-8, which OpenImageIO cannot "
                           f"open: rename it (convmv -f latin1 -t utf8)") from None


def image_header(path):
    """The ImageSpec of the image file at ``path`` (its first part), None when it is not a
    readable regular file (never opened then: a FIFO would block) or has a name OpenImageIO
    cannot take."""
    try:
        inp = oiio.ImageInput.open(oiio_path(path)) if is_regular_file(path) else None
    except TextureError:
        inp = None
    if inp is None:
        oiio_error()                     # taken: OpenImageIO prints a pending one at exit
        return None
    try:
        return inp.spec()
    finally:
        inp.close()


def texel_count(path) -> int:
    """Width x height of an image file, 0 when it is not a readable regular file (a progress
    bar's total: the job itself reports why it cannot read it)."""
    spec = image_header(path)
    return 0 if spec is None else spec.width * spec.height


def check_regular_file(path, what):
    """TextureError unless ``path`` is a regular file (a FIFO or device would block or never
    end)."""
    try:
        st = os.stat(path)
    except FileNotFoundError:
        raise TextureError(f"{path}: no such file ({what})") from None
    except OSError as exc:
        raise TextureError(f"{path}: cannot read {what}: {exc.strerror}") from None
    if stat.S_ISDIR(st.st_mode):
        raise TextureError(f"{path}: is a directory, not an image ({what})")
    if not stat.S_ISREG(st.st_mode):
        raise TextureError(f"{path}: is not a regular file (a FIFO, socket or device); "
                           f"give an image file ({what})")


def _part_names(inp):
    names, n = [], 0
    while inp.seek_subimage(n, 0):
        names.append(inp.spec().getattribute("name") or
                     inp.spec().getattribute("oiio:subimagename") or f"#{n}")
        n += 1
    inp.seek_subimage(0, 0)
    return names


def integer_channels(spec) -> list:
    """Names of the channels stored as 32-bit integers (an EXR's UINT: object IDs, counts),
    which OpenImageIO would scale by 1 / (2^32 - 1) as if they were a normalized colour."""
    formats = list(spec.channelformats) or [spec.format] * spec.nchannels
    return [str(n) for n, f in zip(spec.channelnames, formats)
            if f.basetype in (oiio.UINT, oiio.INT)]


class Reader:
    """One image file open for band reads (scanline or tiled), float32 out: the first part,
    mip level 0; multi-part and deep files are refused by name. ``role``: the input it is
    read as (``channels.ROLE_LAYER``: albedo, mfp, alpha, sigma_t), which picks the layer of
    an output of ours that holds it; ``layer``: the one asked for (a material's)."""

    def __init__(self, path, what, role=None, layer=None):
        self.path, self.what, self.role, self.layer = path, what, role, layer
        self.inp = None
        check_regular_file(path, what)
        self.inp = oiio.ImageInput.open(oiio_path(path), open_config())
        if self.inp is None:
            raise TextureError(f"{path}: cannot read {what}: {oiio_error() or 'unknown error'}")
        self.spec = self.inp.spec()
        self.lock = threading.Lock()
        problem = None
        if self.spec.deep:
            problem = (f"{path}: a deep image ({what}): deep (per-sample) data is not a "
                       f"texture; flatten it first (oiiotool {path} --flatten -o flat.exr)")
        elif integer_channels(self.spec):
            problem = (f"{path}: channels {', '.join(integer_channels(self.spec))} ({what}) "
                       f"are 32-bit integers (IDs or counts), not texture values: write them "
                       f"as half or float")
        elif role_refused(self.spec, role, what):
            problem = f"{path}: {role_refused(self.spec, role, what)}"
        else:
            parts = _part_names(self.inp)
            if len(parts) > 1:
                problem = (f"{path}: {len(parts)} parts ({', '.join(parts)}) ({what}): only "
                           f"single-part files are read, so no part is dropped silently; "
                           f"write each part to its own file (oiiotool --subimage)")
        if problem:
            self.close()
            raise TextureError(problem)

    def channels(self):
        """Indices of the colour channels and of the alpha channel (or -1), by
        ``classify_channels``; a file with no colour channel is a TextureError."""
        names = self.spec.channelnames
        short = {str(n).rsplit(".", 1)[-1] for n in names}
        for model in NOT_RGB:
            if model <= short:
                raise TextureError(f"{self.path}: channels {', '.join(names)} are "
                                   f"{'/'.join(sorted(model))} colour, not linear RGB: "
                                   f"convert to R, G, B first")
        colour, alpha, _ = classify_channels(names, self.spec.alpha_channel, self.role,
                                             self.layer)
        if not colour and self.layer is not None:
            raise TextureError(f"{self.path}: no colour channel in layer {self.layer!r} "
                               f"({self.what}; its channels: {', '.join(names)})")
        if not colour and role_missing(names, self.role):
            raise TextureError(f"{self.path}: {role_missing(names, self.role)} ({self.what})")
        if not colour:
            raise TextureError(f"{self.path}: no colour channel among "
                               f"{', '.join(names)} (colour is R, G, B or Y, a Y not in a "
                               f"vector's X, Y, Z; or a single channel that is not alpha)")
        return colour, alpha

    def colour(self, colorspace="auto", working=None):
        """The file's ColourPath into the working space ``working`` (``colour.colour_path``);
        a declaration the config cannot follow is a TextureError."""
        colour, _ = self.channels()
        try:
            return colour_path(self.spec, self.path, colorspace, working,
                               [self.spec.channelnames[c] for c in colour])
        except ValueError as exc:
            raise TextureError(str(exc)) from None

    def read_band(self, y0, y1):
        s = self.spec
        with self.lock:
            px = read_rows_of(self.inp, s, y0, y1, oiio.FLOAT)
        if px is None:
            why = oiio_error(self.inp) or "missing or corrupt data"
            raise TextureError(f"{self.path}: read of rows {y0}..{y1 - 1} failed: {why}")
        return np.asarray(px, dtype=np.float32).reshape(y1 - y0, s.width, s.nchannels)

    def close(self):
        if self.inp is not None:
            self.inp.close()
            self.inp = None


def invalid_texels(exc, path, x, y, channel, rows=""):
    """TextureError for an InvalidInputError ``exc`` whose first texel is at image
    coordinates (x, y) (data window included), channel ``channel``."""
    return TextureError(f"{path}: {exc.count} invalid {exc.name} value(s) ({exc.why}){rows}; "
                        f"first at x={x}, y={y}, channel {channel}: {float(exc.first_value):g} "
                        f"(--on-invalid clamp / on_invalid='clamp' clamps them)")


def check_same_window(spec, other, path, role, other_path):
    """TextureError unless ``other`` (the ``role`` texture) covers the same pixels as
    ``spec`` (the albedo or irradiance): texels are combined by pixel coordinates."""
    a = (spec.x, spec.y, spec.width, spec.height)
    b = (other.x, other.y, other.width, other.height)
    if a != b:
        raise TextureError(f"{path}: {role} {other_path} covers x {b[0]}..{b[0] + b[2] - 1}, "
                           f"y {b[1]}..{b[1] + b[3] - 1} ({b[2]}x{b[3]}); this file x "
                           f"{a[0]}..{a[0] + a[2] - 1}, y {a[1]}..{a[1] + a[3] - 1} "
                           f"({a[2]}x{a[3]}): data windows and resolutions must match")


#: input attributes never copied to an output: its own encoding, its colour tags (the output
#: is tagged with the working space), and what describes the input's pixels rather than the
#: output's (mip levels, texture wrap and per-image statistics)
SKIP_ATTRIBS = ("compression", "oiio:BitsPerSample", "oiio:UnassociatedAlpha",
                "openexr:lineOrder", "PixelAspectRatio", "oiio:miplevels",
                "oiio:subimages", "oiio:ConstantColor", "oiio:AverageColor", "oiio:SHA-1",
                "textureformat", "wrapmodes", "fovcot", "openexr:levelmode",
                "openexr:roundingmode", "smcube", "name", "type", "version",
                "chunkCount") + COLOUR_ATTRIBS


#: an output's Software header: the name, then the version
SOFTWARE = "bdipole_cl"


def output_spec(in_spec, channel_names, alpha_index, half, params, *, working, data=False):
    """The ImageSpec of an output of ``in_spec``'s size and window: ``channel_names``, float or
    half, the input's metadata but not its colour tags, tagged as in the WorkingSpace
    ``working`` (``data``: numbers that are not colour, tagged as the config's data space,
    the working space named in ``bdipole:working_space``), and ``params`` as ``bdipole:*``
    attributes, ``bdipole:version`` always and Software (the marks of this tool's outputs:
    ``io.collisions.ours``)."""
    spec = oiio.ImageSpec(in_spec.width, in_spec.height, len(channel_names),
                          "half" if half else "float")
    spec.x, spec.y, spec.z = in_spec.x, in_spec.y, in_spec.z
    spec.full_x, spec.full_y = in_spec.full_x, in_spec.full_y
    spec.full_width, spec.full_height = in_spec.full_width, in_spec.full_height
    spec.tile_width, spec.tile_height = in_spec.tile_width, in_spec.tile_height
    spec.channelnames = tuple(channel_names)
    spec.alpha_channel = alpha_index
    for attr in in_spec.extra_attribs:
        if attr.name in SKIP_ATTRIBS or attr.name.startswith(("bdipole:", "png:", "tiff:",
                                                               "jpeg:")):
            continue
        try:
            spec.attribute(attr.name, attr.type, attr.value)
        except Exception:  # an attribute type the Python binding cannot copy: leave it out
            pass
    spec.attribute("compression", "zip")
    # who wrote it: an image tool that edits the output writes its own (oiiotool does), so an
    # edited copy is not taken for this tool's output (``collisions.ours``)
    spec.attribute("Software", f"{SOFTWARE} {__version__}")
    if data:
        tag_data(spec, working.config)
        params = {"working_space": working.name, **params}
    else:
        tag_output(spec, working)
    for key, value in {"version": __version__, **params}.items():
        spec.attribute(f"bdipole:{key}", header_text(value))
    return spec


def header_text(value) -> str:
    """A parameter as an output's header holds it: numbers as '1.2,0.6,0.3' (a tuple, list or
    array alike; one value alone), anything else as its text."""
    if isinstance(value, (tuple, list, np.ndarray)):
        values = np.ravel(np.asarray(value, dtype=object))
        return ",".join(header_text(v) for v in values)
    if isinstance(value, (float, np.floating)):
        return f"{float(value):.10g}"
    return str(value)


#: below this many free bytes a failed write names the disk's free space as its likely cause
LOW_SPACE = 64 << 20


def low_space(path) -> str:
    """"; the disk has only N free" where ``path``'s disk is (nearly) full, else "": a library's
    "write failed" then says why."""
    try:
        free = shutil.disk_usage(Path(path).parent).free
    except OSError:
        return ""
    return f" (the disk has only {free / 2**20:.1f} MiB free)" if free < LOW_SPACE else ""


def check_texture_window(output, spec):
    """TextureError where an image of ``spec`` cannot be the texture ``output`` (a data window
    reaching outside its display window: ``mipmaps.window_problem``), before any work."""
    why = window_problem(spec)
    if why:
        raise TextureError(f"{output}: cannot be a texture (--texture / texture = true): {why}")


class Writer:
    """An EXR written band by band into a temporary file, renamed by ``commit`` once it reads
    back as written (``verify``). Every band is made storable first (``finite_texels``, by
    ``on_invalid``); ``invalid`` counts the texels that were not.

    ``texture`` (True or a TextureOptions): the verified temporary file is made into a tiled,
    mip-mapped texture beside it (``mipmaps.build_texture``), verified against it, and that is
    renamed; ``cancel`` (threading.Event, else the process's stop request) set by then, or
    during the build, discards both (the build runs on a thread of its own, waited for in
    steps of 0.1 s: ``mipmaps.build_texture``)."""

    def __init__(self, path, spec, on_invalid="raise", texture=None, cancel=None):
        self.path = Path(oiio_path(path))
        remove_partial_files(self.path)   # a stopped or killed earlier run's (``partials``)
        self.tmp = self.path.with_name(f".{self.path.stem}.partial-{os.getpid()}"
                                       f"-{threading.get_ident()}{self.path.suffix}")
        self.spec = spec
        self.on_invalid = on_invalid
        self.half = spec.format == oiio.TypeDesc("half")
        self.digests = BandDigests(self.half)
        self.invalid = 0
        self.texture = texture_options(texture)
        if self.texture is not None:      # the mark of this tool's textures (collisions.ours)
            check_texture_window(path, spec)      # before any band is computed
            spec.attribute("bdipole:texture", self.texture.describe())
        self.cancel = cancel
        self.out = oiio.ImageOutput.create(str(self.tmp))
        if self.out is None:
            raise TextureError(f"{path}: cannot create output: {oiio_error()}")
        if not self.out.open(str(self.tmp), spec):
            err = oiio_error(self.out)
            self.out = None
            self._remove_tmp()
            raise TextureError(f"{path}: cannot write output: {err}")

    @property
    def clamped(self) -> dict:
        """{what: count} of the values that could not be stored and were clamped
        (``on_invalid="clamp"``): "half range" in a half output, else "not finite"."""
        return {("half range" if self.half else "not finite"): self.invalid} if self.invalid \
            else {}

    def write_band(self, y0, y1, pixels):
        s = self.spec
        try:
            pixels, n = finite_texels(pixels, self.half, self.on_invalid, self.path,
                                      s.channelnames, s.x, s.y + y0)
        except WriteCheckError as exc:
            raise TextureError(str(exc)) from None
        self.invalid += n
        pixels = np.ascontiguousarray(pixels, dtype=np.float32)
        if s.tile_width:
            ok = self.out.write_tiles(s.x, s.x + s.width, s.y + y0, s.y + y1, s.z,
                                      s.z + max(s.depth, 1), pixels)
        else:
            ok = self.out.write_scanlines(s.y + y0, s.y + y1, s.z, pixels)
        if not ok:
            raise TextureError(f"{self.path}: write of rows {y0}..{y1 - 1} failed: "
                               f"{oiio_error(self.out)}{low_space(self.path)}")
        self.digests.add(y0, y1, pixels)

    def commit(self, check=None):
        """Close, verify and put the output in place. ``check`` (a callable that raises a
        TextureError, e.g. ``freshness.InputGuard.check``) runs last, after every write of
        the file to be renamed (so an input changed after it is older than the output's
        time, never newer), and a raise discards it."""
        ok = self.out.close()
        self.out = None
        if not ok:
            self._remove_tmp()
            raise TextureError(f"{self.path}: closing the output failed: {oiio_error()}"
                               f"{low_space(self.path)}")
        try:
            read_back(self.tmp, self.digests, str(self.path), list(self.spec.channelnames))
        except WriteCheckError as exc:
            self._remove_tmp()
            raise TextureError(str(exc)) from None
        if self.texture is not None:
            self._commit_texture(check)
            return
        if check is not None:
            try:
                check()
            except TextureError:
                self._remove_tmp()
                raise
        durable_replace(self.tmp, self.path)

    def _commit_texture(self, check=None):
        tex = self.tmp.with_name(f"{self.tmp.stem}.tx{self.tmp.suffix}")
        try:
            spec, px = read_whole(self.tmp, "plain output")
            try:
                build_texture(spec, px, tex, self.texture, (self.cancel or STOP).is_set)
            except TextureBuildCancelled:
                raise Cancelled(f"{self.path}: interrupted; nothing written") from None
            except TextureBuildError as exc:
                raise TextureError(f"{self.path}: {exc}") from None
            if self.cancel is not None and self.cancel.is_set():
                raise Cancelled(f"{self.path}: interrupted; nothing written")
            if check is not None:
                check()
            durable_replace(tex, self.path)
        finally:
            for p in (tex, self.tmp):
                try:
                    p.unlink()
                except FileNotFoundError:
                    pass

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


def read_parameter_texture(path, what, colour=False, colorspace="auto", working=None,
                           role=None, layer=None):
    """A parameter texture (albedo, mfp, alpha', sigma_t') as HxWxC float32, alpha dropped;
    ``colour`` (albedo): converted from its space (``colorspace``, else as the file declares)
    into the working space ``working``; else read as data, as it is. ``role``, ``layer``: as
    ``Reader``'s (an output of ours read by its layer; a material's layer)."""
    reader = Reader(path, what, role, layer)
    try:
        cols, _ = reader.channels()
        px = reader.read_band(0, reader.spec.height)[..., cols]
        if not colour:
            return px
        route = reader.colour(colorspace, working)
        return route.convert(px, [reader.spec.channelnames[c] for c in cols])
    finally:
        reader.close()


def read_whole(path, what):
    """(spec, pixels HxWxC float32) of an image through ``Reader``: no image cache, so a file
    rewritten under the same name is read afresh."""
    reader = Reader(path, what)
    try:
        return reader.spec, reader.read_band(0, reader.spec.height)
    finally:
        reader.close()
