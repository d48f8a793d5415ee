"""Texture outputs (I/O layer): a finished EXR made into a renderer-ready texture, tiled and
mip-mapped as ``maketx`` makes it, by OpenImageIO's ``make_texture``, and verified.

``images.Writer`` calls ``build_texture`` on its verified temporary file when an output is a
texture (``--texture``, ``texture = true``). The texture keeps the channel names, the pixel
type (half stays half), and every header entry of the plain output (``bdipole:*``, colour,
the source's metadata) except those a texture build rewrites (``TEXTURE_REWRITES``); its
level 0 is the plain output bit for bit. A data window smaller than the display window is
filled out to it with 0 (a texture spans its display window), by a copy: maketx's own fill
resamples (changes values by ~1e-7); one reaching outside it is refused (``window_problem``:
its texels would be lost).
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

from .oiio_text import oiio_error


class TextureBuildError(RuntimeError):
    """A texture that could not be made, or that does not verify (the message says how)."""


@dataclass(frozen=True)
class TextureOptions:
    """A renderer-ready output: ``tile`` x ``tile`` tiles, a full mip chain of
    ``mip_filter``-downsampled halvings down to 1x1, ``compression``, and the wrap mode it
    declares for lookups beyond its edges (``wrap``: OpenImageIO's "black", "clamp",
    "periodic" or "mirror"; a blur's follows its border rule, ``Border.texture_wrap``)."""

    tile: int = 64
    mip_filter: str = "box"
    compression: str = "zip"
    wrap: str = "black"


def texture_options(texture) -> TextureOptions | None:
    """``texture=`` of the entry points: True (the defaults), False/None, or TextureOptions."""
    if texture is None or texture is False:
        return None
    if texture is True:
        return TextureOptions()
    if isinstance(texture, TextureOptions):
        return texture
    raise TypeError(f"texture={texture!r}: expected True, False or a TextureOptions")


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
    total, w, h = 0, spec.full_width, spec.full_height
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
    config = oiio.ImageSpec()
    config.tile_width = config.tile_height = options.tile
    config.attribute("compression", options.compression)
    config.attribute("maketx:filtername", options.mip_filter)
    config.attribute("wrapmodes", f"{options.wrap},{options.wrap}")
    config.set_format(spec.format)
    full = oiio.ImageBufAlgo.crop(src, src.roi_full)
    if full.has_error:
        raise TextureBuildError(f"making the texture failed: {oiio_error(full)}")
    why = _make_texture(full, texture, config, cancelled)
    if why is not None:
        raise TextureBuildError(f"making the texture failed: {why}")
    problems = texture_problems(spec, px, texture, options)
    if problems:
        raise TextureBuildError(f"the texture does not verify: {'; '.join(problems)}")


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


def _make_texture(full, texture, config, cancelled) -> str | None:
    """OpenImageIO's make_texture of ``full`` to ``texture`` on a daemon thread (it releases
    the GIL), waited for in steps of 0.1 s so that ``cancelled()`` is heard: then the build is
    waited for ABANDON_WAIT more, left to its thread (``ABANDONED``: the process ends it),
    and its files are removed. None if it was made, else why not (OpenImageIO keeps an
    error per thread: it is read on the build's own, one line)."""
    result = []

    def build():
        made = oiio.ImageBufAlgo.make_texture(oiio.MakeTxTexture, full, str(texture), config)
        result.append(None if made else oiio_error() or "unknown error")
    worker = threading.Thread(target=build, daemon=True, name="bdipole-maketx")
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
    """(level 0's spec, mip levels, level 0's pixels, the problems of the smaller levels: one
    that does not read, or holds a value that is not finite) of a texture, read afresh
    (ImageInput: no image cache). OpenImageIO's mip filter sums before it divides, so finite
    values above ~FLT_MAX / 4 make infinite ones in the levels below."""
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise TextureBuildError(f"the texture cannot be read back: {oiio_error()}")
    try:
        got = inp.spec()
        px = inp.read_image(0, 0, 0, got.nchannels, oiio.FLOAT)
        levels, problems, overflowed = 1, [], {}
        while inp.seek_subimage(0, levels):
            level = inp.read_image(0, levels, 0, inp.spec().nchannels, oiio.FLOAT)
            if level is None:
                problems.append(f"mip level {levels} does not read")
            elif not np.all(np.isfinite(level)):
                overflowed[levels] = int(np.count_nonzero(~np.isfinite(level)))
            levels += 1
    finally:
        inp.close()
    if overflowed:
        problems.append(f"mip levels {', '.join(map(str, overflowed))} hold "
                        f"{sum(overflowed.values())} values that are not finite (the mip "
                        f"filter overflows on values above "
                        f"{np.finfo(np.float32).max / 4:.2g}: write without --texture)")
    if px is None:
        raise TextureBuildError("the texture's level 0 cannot be read back")
    return got, levels, np.asarray(px, np.float32).reshape(got.height, got.width, -1), problems


def texture_problems(want, px, texture, options) -> list:
    """What is wrong with ``texture`` as the texture of the plain output (``want``, ``px``):
    tiles, mip chain, channels and pixel type, header, level 0 (empty when it verifies)."""
    got, levels, level0, problems = _read_texture(texture)
    expected = mip_levels(want.full_width, want.full_height)
    if (got.tile_width, got.tile_height) != (options.tile, options.tile):
        problems.append(f"tiles {got.tile_width}x{got.tile_height}")
    if levels != expected:
        problems.append(f"{levels} mip levels, not {expected}")
    if tuple(got.channelnames) != tuple(want.channelnames) or got.format != want.format:
        problems.append(f"channels {', '.join(got.channelnames)} ({got.format})")
    lost = [a.name for a in want.extra_attribs
            if a.name not in TEXTURE_REWRITES and got.getattribute(a.name) != a.value]
    if lost:
        problems.append(f"header {', '.join(lost)} lost")
    y0, x0 = want.y - got.y, want.x - got.x          # the plain output's data window in it
    window = level0[y0:y0 + want.height, x0:x0 + want.width]
    if not problems and not np.array_equal(window, px, equal_nan=True):
        problems.append("level 0 differs from the plain output")
    return problems
