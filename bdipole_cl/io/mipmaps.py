"""Texture outputs (I/O layer): a finished EXR made into a renderer-ready texture, tiled and
mip-mapped as ``maketx``/``txmake`` make one, and verified as a renderer reads it.

``images.Writer`` calls ``build_texture`` on its verified temporary file when an output is a
texture (``--texture``, ``texture = true``). The texture keeps the channel names, the pixel
type (half stays half), and every header entry of the plain output (``bdipole:*``, colour,
the source's metadata) except those a texture build rewrites (``TEXTURE_REWRITES``); its
level 0 is the plain output bit for bit (unless resized to powers of two, ``resize``). Each
smaller level is its parent averaged over each texel's exact footprint (``area_resample``: at
odd sizes a texel covers fractions of its parent's, so each level keeps its parent's mean,
within ``mean_bound``; OpenImageIO's maketx filter samples instead: a 100x37 texture's 1x1
level was 11% off its mean). The wrap mode a lookup beyond the edges uses is written in the
file; ``clamp`` by default, so that no seam appears at a tile's edge (``black`` read a
constant texture 50% low there). A data window smaller than the display window is filled out
to it with 0 (a texture spans its display window); one reaching outside it is refused
(``window_problem``: its texels would be lost). docs/textures.md has the rules.
"""
from __future__ import annotations

import glob
import math
import shutil
import threading
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import OpenImageIO as oiio

from ..methods.registry import TEXTURE_RESIZE, TEXTURE_WRAP
from .oiio_text import oiio_error


class TextureBuildError(RuntimeError):
    """A texture that could not be made, or that does not verify (the message says how)."""


TEXTURE_WRAPS = TEXTURE_WRAP.names
TEXTURE_RESIZES = TEXTURE_RESIZE.names
#: largest tile side accepted (OpenEXR takes any; renderers use 16..256)
MAX_TILE = 4096


@dataclass(frozen=True)
class TextureOptions:
    """A renderer-ready output: ``tile`` x ``tile`` tiles, a full mip chain of area-averaged
    halvings down to 1x1 (``mip_filter``: "box", each texel's exact footprint),
    ``compression``, the wrap mode it declares for lookups beyond its edges (``wrap``, one of
    TEXTURE_WRAPS; None: "clamp", or for a blur what its border rule saw,
    ``Border.texture_wrap``) and the power-of-two resizing of level 0 (``resize``)."""

    tile: int = 64
    mip_filter: str = "box"
    compression: str = "zip"
    wrap: str | None = None
    resize: str = "none"

    def __post_init__(self):
        check_texture_option("wrap", self.wrap)
        check_texture_option("resize", self.resize)
        check_texture_option("tile", self.tile)
        if self.mip_filter != "box":              # the one filter that keeps every mean
            raise ValueError(f"texture mip_filter={self.mip_filter!r}: expected box (the "
                             f"area average, docs/textures.md)")

    @property
    def wrap_mode(self) -> str:
        return self.wrap or "clamp"

    def describe(self) -> str:
        return (f"tiles {self.tile}, {self.mip_filter} mips, {self.compression}, wrap "
                f"{self.wrap_mode}, resize {self.resize}")


def check_texture_option(name, value):
    """ValueError (one line) unless ``value`` is allowed for texture option ``name``."""
    if name == "wrap" and value is not None:
        TEXTURE_WRAP[value]                  # ValueError listing the choices
    if name == "resize":
        TEXTURE_RESIZE[value]
    if name == "tile" and (isinstance(value, bool) or not isinstance(value, int)
                           or not 1 <= value <= MAX_TILE):
        raise ValueError(f"texture tile={value!r}: expected a whole number of texels in "
                         f"1..{MAX_TILE} (maketx's default is 64)")
    if name not in ("wrap", "resize", "tile"):
        raise ValueError(f"texture option {name!r}: expected wrap, tile or resize")


def texture_options(texture) -> TextureOptions | None:
    """``texture=`` of the entry points: True (the defaults), False/None, or TextureOptions."""
    if texture is None or texture is False:
        return None
    if texture is True:
        return TextureOptions()
    if isinstance(texture, TextureOptions):
        return texture
    raise TypeError(f"texture={texture!r}: expected True, False or a TextureOptions")


def resized(width, height, resize: str) -> tuple:
    """Level 0's (width, height) under ``resize`` (TEXTURE_RESIZES)."""
    def one(n):
        if resize == "none":
            return n
        lo = 1 << (n.bit_length() - 1)
        hi = lo if lo == n else lo * 2
        if resize == "up":
            return hi
        if resize == "down":
            return lo
        return hi if hi - n <= n - lo else lo
    return one(int(width)), one(int(height))


def mip_levels(width, height) -> int:
    """Levels of a full mip chain: halvings (rounded down, at least 1) down to 1x1."""
    return 1 + int(math.floor(math.log2(max(width, height, 1))))


#: header entries a texture build rewrites (its own layout, time and path); every other entry
#: of the plain output must come through unchanged
TEXTURE_REWRITES = ("oiio:RowsPerChunk", "oiio:SourcePath", "DateTime", "openexr:lineOrder",
                    "oiio:subimages")


class TextureBuildCancelled(TextureBuildError):
    """A texture build abandoned because ``cancelled()`` said so (a signal)."""


def texture_bytes(spec, options: TextureOptions) -> int:
    """An upper bound on the texture's size: every mip level uncompressed, in whole tiles
    (zip never stores a chunk larger than uncompressed), plus 64 KiB for headers and offsets."""
    total = 0
    w, h = resized(spec.full_width, spec.full_height, options.resize)
    for _ in range(mip_levels(w, h)):
        tiles = -(-w // options.tile) * -(-h // options.tile)
        total += tiles * options.tile ** 2 * spec.nchannels * spec.format.size()
        w, h = max(w // 2, 1), max(h // 2, 1)
    return total + (1 << 16)


def size_text(n) -> str:
    """A byte count in KiB below 1 MiB (2 significant figures at least), else MiB."""
    return f"{n / 2**10:.1f} KiB" if n < 2**20 else f"{n / 2**20:.2f} MiB"


def window_problem(spec) -> str | None:
    """Why an image of ``spec`` cannot be a texture (one line), else None: a texture spans its
    display window, so a data window reaching outside it would lose those texels."""
    inside = (spec.x >= spec.full_x and spec.y >= spec.full_y
              and spec.x + spec.width <= spec.full_x + spec.full_width
              and spec.y + spec.height <= spec.full_y + spec.full_height)
    if inside:
        return None
    return (f"its data window ({spec.width}x{spec.height} at {spec.x},{spec.y}) reaches "
            f"outside its display window ({spec.full_width}x{spec.full_height} at "
            f"{spec.full_x},{spec.full_y}); a texture spans its display window, so those "
            f"texels would be lost: write a plain output, or widen the display window "
            f"(oiiotool IN --fullpixels -o OUT)")


def check_space(spec, texture, options: TextureOptions):
    """TextureBuildError where the texture's disk has less free space than ``texture_bytes``:
    OpenImageIO's texture build can hang on a full disk rather than fail."""
    need = texture_bytes(spec, options)
    free = shutil.disk_usage(Path(texture).parent).free
    if free < need:
        raise TextureBuildError(f"not enough space for the texture: it needs up to "
                                f"{size_text(need)}, {size_text(free)} are free")


def build_texture(spec, px, texture, options: TextureOptions, cancelled=None):
    """Write the texture of the plain output (its ``spec`` and pixels ``px``, HxWxC float32 of
    its data window) to ``texture``, and verify it (``texture_problems``). The build runs on a
    thread of its own, ``cancelled()`` (a stop request) asked every 0.1 s: then it is
    abandoned (TextureBuildCancelled), its files removed."""
    why = window_problem(spec)
    if why:
        raise TextureBuildError(f"cannot be a texture: {why}")
    check_space(spec, texture, options)
    src = oiio.ImageBuf(spec)                     # its pixel type (half stays half), header
    src.set_pixels(src.roi, np.ascontiguousarray(px, np.float32))
    full = oiio.ImageBufAlgo.crop(src, src.roi_full)
    if full.has_error:
        raise TextureBuildError(f"making the texture failed: {oiio_error(full)}")
    level0 = np.asarray(full.get_pixels(oiio.FLOAT), np.float32).reshape(
        spec.full_height, spec.full_width, spec.nchannels)
    why = _on_thread(lambda: write_levels(mip_chain(level0, spec, options), texture, spec,
                                          options), texture, cancelled)
    if why is not None:
        raise TextureBuildError(f"making the texture failed: {why}")
    problems = texture_problems(spec, px, texture, options)
    if problems:
        raise TextureBuildError(f"the texture does not verify: {'; '.join(problems)}")


def stored(px, spec) -> np.ndarray:
    """``px`` as the file stores it (half: rounded to half; float32: as it is), float32."""
    if spec.format == oiio.TypeDesc("half"):
        return px.astype(np.float16).astype(np.float32)
    return px.astype(np.float32)


def _footprints(n: int, m: int):
    """(index (m, K), weight (m, K)) of an area resampling of ``n`` texels to ``m``: texel i
    of the result covers [i n/m, (i+1) n/m) of the source, each source texel weighted by the
    fraction of it covered, divided by n/m. Each row of weights sums to 1 and each source
    texel's weights to m/n: the mean is kept exactly (docs/textures.md)."""
    lo = np.arange(m, dtype=np.float64) * n / m
    hi = np.arange(1, m + 1, dtype=np.float64) * n / m
    k = int(np.ceil(n / m)) + 1
    j = np.floor(lo).astype(np.int64)[:, None] + np.arange(k)[None, :]
    cover = np.clip(np.minimum(hi[:, None], j + 1) - np.maximum(lo[:, None], j), 0.0, None)
    j = np.where(cover > 0, np.minimum(j, n - 1), j[:, :1])  # unused slots: a texel in it
    return j, cover / (n / m)


def area_resample(px, height: int, width: int) -> np.ndarray:
    """``px`` (HxWxC) averaged over each texel's footprint (``_footprints``) to
    ``height`` x ``width``, in float64 by bands of rows (no overflow: each texel is a
    convex combination of its parent's), float32."""
    jy, wy = _footprints(px.shape[0], height)
    jx, wx = _footprints(px.shape[1], width)
    out = np.empty((height, width, px.shape[2]), np.float32)
    band = max(1, (1 << 21) // max(1, px.shape[1] * px.shape[2] * jy.shape[1]))
    for a in range(0, height, band):
        b = min(a + band, height)
        rows = px[jy[a:b]].astype(np.float64)                   # (rows, K, W, C)
        col = np.einsum("rk,rkwc->rwc", wy[a:b], rows)
        out[a:b] = np.einsum("xk,rxkc->rxc", wx, col[:, jx, :])
    return out


def mip_chain(level0, spec, options: TextureOptions) -> list:
    """Level 0 (resized by ``options.resize``) and its halvings (rounded down, at least 1)
    to 1x1, each ``area_resample``d from its parent as stored (half: rounded)."""
    h, w = level0.shape[:2]
    rw, rh = resized(w, h, options.resize)
    levels = [stored(area_resample(level0, rh, rw) if (rw, rh) != (w, h) else level0, spec)]
    while levels[-1].shape[:2] != (1, 1):
        ph, pw = levels[-1].shape[:2]
        levels.append(stored(area_resample(levels[-1], max(ph // 2, 1), max(pw // 2, 1)),
                             spec))
    return levels


def level_spec(spec, level: int, px, options: TextureOptions):
    """The spec of mip level ``level`` (pixels ``px``): the plain output's header, tiled,
    its own size (level 0 keeps the display window's origin)."""
    out = oiio.ImageSpec(spec)
    out.width = out.full_width = px.shape[1]
    out.height = out.full_height = px.shape[0]
    out.x = out.full_x = spec.full_x if level == 0 else 0
    out.y = out.full_y = spec.full_y if level == 0 else 0
    out.tile_width = out.tile_height = options.tile
    out.attribute("compression", options.compression)
    out.attribute("textureformat", "Plain Texture")      # OpenEXR: a MIP-mapped file
    out.attribute("wrapmodes", f"{options.wrap_mode},{options.wrap_mode}")
    return out


def write_levels(levels, texture, spec, options: TextureOptions) -> str | None:
    """Write ``levels`` (``mip_chain``) as one tiled, MIP-mapped OpenEXR; None if written,
    else why not (one line)."""
    out = oiio.ImageOutput.create(str(texture))
    if out is None:
        return oiio_error() or "no OpenEXR writer"
    try:
        for k, px in enumerate(levels):
            if not out.open(str(texture), level_spec(spec, k, px, options),
                            "Create" if k == 0 else "AppendMIPLevel"):
                return oiio_error(out)
            if not out.write_image(np.ascontiguousarray(px)):
                return oiio_error(out)
    finally:
        closed = out.close()
    return None if closed else (oiio_error(out) or "closing the texture failed")


#: (thread, texture path) of the texture builds abandoned on a stop request
ABANDONED = []
#: how long an abandoned build is waited for (s): a build that is not hung ends by then, and
#: its files are removed then; a hung one (a full disk) is left to the process's end
ABANDON_WAIT = 2.0


def builds_running() -> bool:
    """Whether an abandoned texture build still runs (its files removed once more first): a
    process must then end without Python's interpreter teardown (``os._exit``), which would
    pull OpenImageIO out from under it (a crash instead of the signal's exit status)."""
    running = False
    for worker, texture in ABANDONED:
        _remove_build(texture)
        running = running or worker.is_alive()
    return running


def _remove_build(texture):
    for p in [Path(texture), *build_files(texture)]:
        p.unlink(missing_ok=True)


def _on_thread(build, texture, cancelled) -> str | None:
    """``build()`` (None when made, else why not) on a daemon thread, waited for in steps of
    0.1 s so that ``cancelled()`` is heard: then the build is waited for ABANDON_WAIT more,
    left to its thread (``ABANDONED``: the process ends it), and its files are removed.
    OpenImageIO keeps an error per thread: it is read on the build's own, one line."""
    result = []

    def run():
        try:
            result.append(build())
        except (OSError, ValueError, MemoryError) as exc:
            result.append(str(exc) or type(exc).__name__)
    worker = threading.Thread(target=run, daemon=True, name="bdipole-texture")
    worker.start()
    while worker.is_alive():
        worker.join(0.1)
        if worker.is_alive() and cancelled is not None and cancelled():
            worker.join(ABANDON_WAIT)
            ABANDONED.append((worker, texture))
            _remove_build(texture)
            raise TextureBuildCancelled("interrupted during the texture build")
    return result[0] if result else "the build ended without a result"


def build_files(texture) -> list:
    """The temporary files OpenImageIO's texture build writes beside ``texture``:
    ``{stem}.{hex}.temp{suffix}`` (OpenImageIO 3), ``{name}.{hex}.temp`` (earlier)."""
    texture = Path(texture)
    found = set(texture.parent.glob(f"{glob.escape(texture.name)}.*.temp*"))
    found |= set(texture.parent.glob(f"{glob.escape(texture.stem)}.*.temp"
                                     f"{glob.escape(texture.suffix)}"))
    return sorted(found)


def _read_texture(path):
    """(level 0's spec, every level's pixels, the problems of the smaller levels: one that
    does not read, or holds a value that is not finite) of a texture, read afresh
    (ImageInput: no image cache)."""
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise TextureBuildError(f"the texture cannot be read back: {oiio_error()}")
    try:
        got = inp.spec()
        px = inp.read_image(0, 0, 0, got.nchannels, oiio.FLOAT)
        if px is None:
            raise TextureBuildError("the texture's level 0 cannot be read back")
        levels, problems, overflowed = [np.asarray(px, np.float32).reshape(
            got.height, got.width, -1)], [], {}
        while inp.seek_subimage(0, len(levels)):
            s = inp.spec()
            level = inp.read_image(0, len(levels), 0, s.nchannels, oiio.FLOAT)
            if level is None:
                problems.append(f"mip level {len(levels)} does not read")
                break
            level = np.asarray(level, np.float32).reshape(s.height, s.width, -1)
            if not np.all(np.isfinite(level)):
                overflowed[len(levels)] = int(np.count_nonzero(~np.isfinite(level)))
            levels.append(level)
    finally:
        inp.close()
    if overflowed:
        problems.append(f"mip levels {', '.join(map(str, overflowed))} hold "
                        f"{sum(overflowed.values())} values that are not finite")
    return got, levels, problems


def mean_bound(parent, half: bool) -> np.ndarray:
    """How far (per channel) a level's mean may be from its parent's: each texel is a convex
    combination of the parent's (float64, error ~1e-16) rounded once to the stored type
    (relative u = 2^-24 float, 2^-11 half; half's subnormals 2^-25 absolute), so the mean
    moves by at most u * mean(|parent|) (+ the subnormal step)."""
    u, sub = (2.0 ** -11, 2.0 ** -25) if half else (2.0 ** -24, 2.0 ** -149)
    return (u + 1e-12) * np.mean(np.abs(parent.astype(np.float64)), axis=(0, 1)) + sub


def level_means(levels) -> list:
    """Each level's mean per channel (float64)."""
    return [np.mean(v.astype(np.float64), axis=(0, 1)) for v in levels]


def texture_problems(want, px, texture, options) -> list:
    """What is wrong with ``texture`` as the texture of the plain output (``want``, ``px``):
    tiles, wrap, mip chain, channels and pixel type, header, level 0 (bit for bit, or the
    plain output resized), each level's mean against its parent's (``mean_bound``); empty
    when it verifies."""
    got, levels, problems = _read_texture(texture)
    full = np.zeros((want.full_height, want.full_width, px.shape[2]), np.float32)
    full[want.y - want.full_y:want.y - want.full_y + want.height,
         want.x - want.full_x:want.x - want.full_x + want.width] = px
    size = resized(want.full_width, want.full_height, options.resize)
    expected = mip_levels(*size)
    if (got.tile_width, got.tile_height) != (options.tile, options.tile):
        problems.append(f"tiles {got.tile_width}x{got.tile_height}")
    if got.getattribute("wrapmodes") != f"{options.wrap_mode},{options.wrap_mode}":
        problems.append(f"wrap modes {got.getattribute('wrapmodes')}")
    if len(levels) != expected:
        problems.append(f"{len(levels)} mip levels, not {expected}")
    if tuple(got.channelnames) != tuple(want.channelnames) or got.format != want.format:
        problems.append(f"channels {', '.join(got.channelnames)} ({got.format})")
    lost = [a.name for a in want.extra_attribs
            if a.name not in TEXTURE_REWRITES and got.getattribute(a.name) != a.value]
    if lost:
        problems.append(f"header {', '.join(lost)} lost")
    if problems:
        return problems
    half = want.format == oiio.TypeDesc("half")
    first = full if size == (full.shape[1], full.shape[0]) else \
        stored(area_resample(full, size[1], size[0]), want)
    if not np.array_equal(levels[0], first, equal_nan=True):
        return ["level 0 differs from the plain output"
                + (f" resized to {size[0]}x{size[1]}" if first is not full else "")]
    means = level_means(levels)
    for k in range(1, len(levels)):
        off = np.abs(means[k] - means[k - 1])
        if np.any(off > mean_bound(levels[k - 1], half)):
            problems.append(f"mip level {k} ({levels[k].shape[1]}x{levels[k].shape[0]}) "
                            f"mean {means[k].max():.7g} is {off.max():.3g} from its parent's")
            break
    return problems


def scene_texture(entry) -> TextureOptions | None:
    """The texture options of a merged entry: ``texture = true`` and the ``texture_wrap``,
    ``texture_tile``, ``texture_resize`` keys (each implies a texture, as its CLI option
    does), else None."""
    chosen = {k[len("texture_"):]: entry[k] for k in TEXTURE_KEYS
              if entry.get(k) is not None}
    if not entry.get("texture") and not chosen:
        return None
    return TextureOptions(**{k: TEXTURE_WRAP.canonical(v) if k == "wrap" else
                             TEXTURE_RESIZE.canonical(v) if k == "resize" else v
                             for k, v in chosen.items()})


#: the scene keys of a texture's options (CLI: --texture-wrap, --texture-tile, ...)
TEXTURE_KEYS = ("texture_wrap", "texture_tile", "texture_resize")
