"""Images: reading and writing bands of OpenImageIO files, channels and colour (I/O layer).

* Pixels are read as float32 (``Reader``), respecting the data window, scanline or tiled.
* Channels are classified by name (``classify_channels``): only colour is ever inverted.
* Integer-encoded (8/16-bit) colour is decoded to linear through OpenImageIO's colour
  conversion: ``colorspace="auto"`` takes the space the file declares (``oiio:ColorSpace``),
  else sRGB for 8-bit and linear for 16-bit; a named space overrides it for integer files.
  Float/half files are taken as linear. Decoded values are clamped to [0, 1] (the conversion's
  own overshoot, e.g. 1.0000241 for sRGB white).
* Outputs are OpenEXR (``check_output_format``), written band by band into a temporary file
  beside the target and renamed when it reads back as written (``Writer``, ``verify``); every
  value is finite in the output's format or its texel is invalid (``verify.finite_texels``).
* Inputs: regular files only; colour with alpha is read unassociated (as painted, never
  premultiplied); tiled and mip-mapped files are read at level 0 in tile-aligned bands;
  multi-part and deep files, and L/a/b channels, are refused by name.
"""
from __future__ import annotations

import os
import stat
import threading
from pathlib import Path

import numpy as np
import OpenImageIO as oiio

from .verify import BandDigests, WriteCheckError, finite_texels, read_back, read_rows_of


class TextureError(RuntimeError):
    """A file that cannot be processed; the message names the file and the reason."""


class Cancelled(TextureError):
    """The batch was stopped (SIGINT/SIGTERM) before this file was complete."""


def check_output_format(path):
    """Outputs are OpenEXR: only EXR holds float/half values in any number of named channels
    (``sigma_a.R``, ...). Any other extension would drop channels or quantise: refused."""
    suffix = Path(path).suffix.lower()
    if suffix != ".exr":
        raise ValueError(f"{path}: output must be an OpenEXR file (.exr), got "
                           f"'{suffix or 'no extension'}': other formats would drop channels or "
                           f"quantise the float values")


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


#: channel name sets that are colour models other than linear RGB: never read as R, G, B, A
NOT_RGB = ({"L", "a", "b"},)


class Reader:
    """One image file open for band reads (scanline or tiled), float32 out: the first part,
    mip level 0; multi-part and deep files are refused by name."""

    def __init__(self, path, what):
        self.path = path
        self.inp = None
        check_regular_file(path, what)
        self.inp = oiio.ImageInput.open(str(path), open_config())
        if self.inp is None:
            raise TextureError(f"{path}: cannot read {what}: {oiio.geterror() or 'unknown error'}")
        self.spec = self.inp.spec()
        self.lock = threading.Lock()
        problem = None
        if self.spec.deep:
            problem = (f"{path}: a deep image ({what}): deep (per-sample) data is not a "
                       f"texture; flatten it first (oiiotool {path} --flatten -o flat.exr)")
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
        colour, alpha, _ = classify_channels(names, self.spec.alpha_channel)
        if not colour:
            raise TextureError(f"{self.path}: no colour channel among "
                               f"{', '.join(names)} (colour is R, G, B or Y, "
                               f"or a single channel that is not alpha)")
        return colour, alpha

    def read_band(self, y0, y1):
        s = self.spec
        with self.lock:
            px = read_rows_of(self.inp, s, y0, y1, oiio.FLOAT)
        if px is None:
            why = self.inp.geterror() or oiio.geterror() or "missing or corrupt data"
            raise TextureError(f"{self.path}: read of rows {y0}..{y1} failed: {why}")
        return np.asarray(px, dtype=np.float32).reshape(y1 - y0, s.width, s.nchannels)

    def close(self):
        if self.inp is not None:
            self.inp.close()
            self.inp = None


def invalid_texels(exc, path, x, y, channel, rows=""):
    """TextureError for an InvalidInputError ``exc`` whose first texel is at image
    coordinates (x, y) (data window included), channel ``channel``."""
    return TextureError(f"{path}: {exc.count} invalid {exc.name} texel(s) ({exc.why}){rows}; "
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


#: input attributes never copied to an output: its own encoding, and what describes the input's
#: pixels rather than the output's (mip levels, texture wrap and per-image statistics)
SKIP_ATTRIBS = ("compression", "oiio:ColorSpace", "oiio:BitsPerSample", "oiio:UnassociatedAlpha",
                 "oiio:Gamma", "openexr:lineOrder", "PixelAspectRatio", "oiio:miplevels",
                 "oiio:subimages", "oiio:ConstantColor", "oiio:AverageColor", "oiio:SHA-1",
                 "textureformat", "wrapmodes", "fovcot", "openexr:levelmode",
                 "openexr:roundingmode", "smcube", "name", "type", "version", "chunkCount")


def output_spec(in_spec, channel_names, alpha_index, half, params):
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
    spec.attribute("oiio:ColorSpace", "lin_rec709_scene")
    for key, value in params.items():
        spec.attribute(f"bdipole:{key}", str(value))
    return spec


def partial_files(path) -> list:
    """Temporary files a Writer of ``path`` leaves only if its process is killed mid-write."""
    path = Path(path)
    return sorted(path.parent.glob(f".{path.stem}.partial-*{path.suffix}"))


def remove_partial_files(path) -> int:
    """Remove what killed writers of ``path`` left (the one process that writes ``path`` calls
    this before it starts: outputs never collide, so no live writer owns them)."""
    n = 0
    for p in partial_files(path):
        try:
            p.unlink()
            n += 1
        except FileNotFoundError:
            pass
    return n


class Writer:
    """An EXR written band by band into a temporary file, renamed by ``commit`` once it reads
    back as written (``verify``). Every band is made storable first (``finite_texels``, by
    ``on_invalid``); ``invalid`` counts the texels that were not."""

    def __init__(self, path, spec, on_invalid="raise"):
        self.path = Path(path)
        self.tmp = self.path.with_name(f".{self.path.stem}.partial-{os.getpid()}"
                                       f"-{threading.get_ident()}{self.path.suffix}")
        self.spec = spec
        self.on_invalid = on_invalid
        self.half = spec.format == oiio.TypeDesc("half")
        self.digests = BandDigests(self.half)
        self.invalid = 0
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
            raise TextureError(f"{self.path}: write of rows {y0}..{y1} failed: "
                               f"{self.out.geterror()}")
        self.digests.add(y0, y1, pixels)

    def commit(self):
        ok = self.out.close()
        self.out = None
        if not ok:
            self._remove_tmp()
            raise TextureError(f"{self.path}: closing the output failed: {oiio.geterror()}")
        try:
            read_back(self.tmp, self.digests, str(self.path), list(self.spec.channelnames))
        except WriteCheckError as exc:
            self._remove_tmp()
            raise TextureError(str(exc)) from None
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


def is_integer(spec):
    return spec.format.basetype in (oiio.UINT8, oiio.INT8, oiio.UINT16, oiio.INT16, oiio.UINT32,
                                    oiio.INT32)


LINEAR_NAMES = {"linear", "lin_rec709_scene", "lin_rec709", "scene_linear", "raw",
                 "linear rec.709 (srgb)"}


def source_colorspace(spec, colorspace="auto"):
    """The colour space integer-encoded albedo is decoded from, or None for linear data."""
    if not is_integer(spec):
        return None
    if colorspace == "auto":
        declared = spec.getattribute("oiio:ColorSpace")
        if declared:
            colorspace = declared
        else:
            colorspace = "sRGB" if spec.format.size() == 1 else "linear"
    return None if str(colorspace).lower() in LINEAR_NAMES else colorspace


def check_colorspace(colorspace):
    """A ``colorspace`` option OpenImageIO can decode from (a 1-texel conversion), else
    ValueError naming the known spaces."""
    if colorspace == "auto" or str(colorspace).lower() in LINEAR_NAMES:
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


def read_rows(reader, idx):
    """Rows ``idx`` (-1: zeros) of an open image, reading each contiguous run once."""
    spec = reader.spec
    out = np.zeros((len(idx), spec.width, spec.nchannels), np.float32)
    valid = np.flatnonzero(idx >= 0)
    if valid.size:
        lo, hi = int(idx[valid].min()), int(idx[valid].max()) + 1
        if hi - lo <= 2 * len(idx):
            block = reader.read_band(lo, hi)
            out[valid] = block[idx[valid] - lo]
        else:                                   # wrap halos: the two ends separately
            for j in valid:
                out[j] = reader.read_band(int(idx[j]), int(idx[j]) + 1)[0]
    return out


def read_parameter_texture(path, what, colour=False, colorspace="auto"):
    """A parameter texture (albedo, mfp, alpha', sigma_t') as HxWxC float32, alpha dropped;
    ``colour``: integer-encoded files are decoded to linear (albedo), else read as data."""
    reader = Reader(path, what)
    try:
        cols, _ = reader.channels()
        px = reader.read_band(0, reader.spec.height)[..., cols]
        space = source_colorspace(reader.spec, colorspace) if colour else None
        return to_linear(px, space) if space is not None else px
    finally:
        reader.close()
