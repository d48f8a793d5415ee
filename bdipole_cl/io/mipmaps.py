"""Texture outputs (I/O layer): a finished EXR made into a renderer-ready texture, tiled and
mip-mapped as ``maketx`` makes it, by OpenImageIO's ``make_texture``, and verified.

``images.Writer`` calls ``build_texture`` on its verified temporary file when an output is a
texture (``--texture``, ``texture = true``). The texture keeps the channel names, the pixel
type (half stays half), and every header entry of the plain output (``bdipole:*``, colour,
the source's metadata) except those a texture build rewrites (``TEXTURE_REWRITES``); its
level 0 is the plain output bit for bit. A data window smaller than the display window is
filled out to it with 0 (a texture spans its display window), by a copy: maketx's own fill
resamples (changes values by ~1e-7).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import OpenImageIO as oiio


class TextureBuildError(RuntimeError):
    """A texture that could not be made, or that does not verify (the message says how)."""


@dataclass(frozen=True)
class TextureOptions:
    """A renderer-ready output: ``tile`` x ``tile`` tiles, a full mip chain of
    ``mip_filter``-downsampled halvings down to 1x1, ``compression``."""

    tile: int = 64
    mip_filter: str = "box"
    compression: str = "zip"


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


def build_texture(spec, px, texture, options: TextureOptions):
    """Write the texture of the plain output (its ``spec`` and pixels ``px``, HxWxC float32 of
    its data window) to ``texture``, and verify it (``texture_problems``)."""
    src = oiio.ImageBuf(spec)                     # its pixel type (half stays half), header
    src.set_pixels(src.roi, np.ascontiguousarray(px, np.float32))
    config = oiio.ImageSpec()
    config.tile_width = config.tile_height = options.tile
    config.attribute("compression", options.compression)
    config.attribute("maketx:filtername", options.mip_filter)
    config.set_format(spec.format)
    full = oiio.ImageBufAlgo.crop(src, src.roi_full)
    if full.has_error or not oiio.ImageBufAlgo.make_texture(oiio.MakeTxTexture, full,
                                                            str(texture), config):
        raise TextureBuildError(f"making the texture failed: "
                                f"{full.geterror() or oiio.geterror()}")
    problems = texture_problems(spec, px, texture, options)
    if problems:
        raise TextureBuildError(f"the texture does not verify: {'; '.join(problems)}")


def _read_texture(path):
    """(level 0's spec, mip levels, level 0's pixels) of a texture, read afresh (ImageInput:
    no image cache)."""
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise TextureBuildError(f"the texture cannot be read back: {oiio.geterror()}")
    try:
        got = inp.spec()
        levels = 1
        while inp.seek_subimage(0, levels):
            levels += 1
        inp.seek_subimage(0, 0)
        px = inp.read_image(0, 0, 0, got.nchannels, oiio.FLOAT)
    finally:
        inp.close()
    if px is None:
        raise TextureBuildError("the texture's level 0 cannot be read back")
    return got, levels, np.asarray(px, np.float32).reshape(got.height, got.width, -1)


def texture_problems(want, px, texture, options) -> list:
    """What is wrong with ``texture`` as the texture of the plain output (``want``, ``px``):
    tiles, mip chain, channels and pixel type, header, level 0 (empty when it verifies)."""
    got, levels, level0 = _read_texture(texture)
    expected = mip_levels(want.full_width, want.full_height)
    problems = []
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
