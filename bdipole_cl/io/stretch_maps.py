"""Stretch maps as files: one EXR per UDIM tile, written through ``images.Writer`` (temp file,
read back, rename), declared as data, the unit and what each channel is in ``bdipole:*``
attributes; and read back as the blur's ``ops.blur.stretched.Stretch`` (docs/stretch.md
"Files").

Channels: ``stretch.u`` and ``stretch.v`` (the surface length of one texel step along u and
along v, in ``bdipole:stretch_unit``), and ``chart``: the UV chart of the texel plus one where a
triangle covers it, minus that where it is a gutter texel given its nearest chart (so that a
blur keeps charts apart, ``--charts``), exact in float32 up to 2^24 charts.
"""
from __future__ import annotations

import os
import re

import numpy as np
import OpenImageIO as oiio

from ..ops.blur.stretched import Stretch
from ..ops.stretch import StretchTile, stretch_tiles
from ..version import __version__
from .colour import data_space
from .images import SOFTWARE, Reader, TextureError, Writer, check_output_format, header_text
from .mesh import read_meshes
from .scene_file import UNIT_METERS
from .tiles import Tile, fill, has_tokens

CHANNELS = ("stretch.u", "stretch.v", "chart")


def chart_channel(tile: StretchTile) -> np.ndarray:
    """The ``chart`` channel: chart + 1 where covered, -(chart + 1) in the gutters."""
    code = tile.chart.astype(np.float32) + 1
    return np.where(tile.covered, code, -code).astype(np.float32)


def shear_texel_text(texel) -> str:
    """The ``bdipole:stretch_max_shear_texel`` attribute: "x y", or "" (no shear)."""
    return "" if texel is None else f"{texel[0]} {texel[1]}"


def shear_texel_of(text, shape):
    """(x, y) of a ``bdipole:stretch_max_shear_texel`` attribute of a map of ``shape`` (H,
    W), or None (none, a file written before it was recorded, or not a texel of the map)."""
    found = re.fullmatch(r"([0-9]+) ([0-9]+)", text or "")
    if found is None:
        return None
    x, y = int(found[1]), int(found[2])
    return (x, y) if x < shape[1] and y < shape[0] else None


def tile_spec(tile: StretchTile, source, meters_per_unit, header=None) -> oiio.ImageSpec:
    h, w = tile.su.shape
    spec = oiio.ImageSpec(w, h, len(CHANNELS), "float")
    spec.channelnames = CHANNELS
    spec.attribute("compression", "zip")
    spec.attribute("Software", f"{SOFTWARE} {__version__}")
    spec.attribute("oiio:ColorSpace", data_space())
    attrs = {"version": __version__, "stretch_unit": tile.unit, "stretch_source": source,
             "stretch_udim": tile.udim, "stretch_max_shear": float(tile.max_shear),
             "stretch_max_shear_texel": shear_texel_text(tile.max_shear_texel),
             "stretch_meters_per_unit": meters_per_unit,
             "stretch_degenerate_triangles": tile.degenerate,
             "stretch_flipped_triangles": tile.flipped,
             "stretch_channels": "stretch.u, stretch.v: surface length of one texel step "
                                 "along u, v; chart: chart+1 covered, -(chart+1) gutter"}
    attrs.update(header or {})
    for key, value in attrs.items():
        spec.attribute(f"bdipole:{key}", header_text(value))
    return spec


def write_tile(tile: StretchTile, path, source="", meters_per_unit=1.0, header=None,
               check=None):
    """One tile's EXR at ``path`` (verified, renamed into place); ``header``: more
    ``bdipole:*`` attributes (a scene's up-to-date key); ``check``: called just before the
    rename (an input that changed raises: nothing written). Its folder is made where it is
    missing, as every output's is."""
    check_output_format(path)
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    px = np.stack([tile.su, tile.sv, chart_channel(tile)], axis=-1).astype(np.float32)
    writer = Writer(path, tile_spec(tile, source, meters_per_unit, header))
    try:
        writer.write_band(0, px.shape[0], px)
        writer.commit(check=check)
    except BaseException:
        writer.abort()
        raise


def tile_path(pattern, tile: StretchTile, single: bool) -> str:
    """The output of a tile: ``pattern`` with its tile token filled; one without tokens only
    for a single tile (a StretchError-like ValueError otherwise)."""
    if has_tokens(pattern):
        return fill(pattern, Tile(*tile.tile), pattern)
    if not single:
        raise ValueError(f"{pattern}: the mesh covers several UDIM tiles; name the output "
                         f"with a tile token (stretch.<UDIM>.exr)")
    return str(pattern)


def stretch_maps(path, output=None, *, size=1024, unit="mm", time=None, prim=None,
                 meters_per_unit=None) -> list:
    """The StretchTiles of a mesh file (USD or OBJ; ``io.mesh.read_meshes``) at ``size``
    texels a tile (an int or (H, W)), lengths in ``unit`` (a name of ``scene_file.UNIT_METERS``,
    the scene files' units),
    at ``time``; with ``output`` (a pattern such as ``stretch.<UDIM>.exr``) each written there.
    Returns [(StretchTile, written path or None)]."""
    if unit not in UNIT_METERS:
        raise ValueError(f"unit={unit!r}: expected one of {', '.join(UNIT_METERS)}")
    meshes = read_meshes(path, time=time, prim_path=prim, meters_per_unit=meters_per_unit)
    tiles = stretch_tiles(meshes, size, UNIT_METERS[unit], unit)
    out = []
    for t in tiles:
        target = None if output is None else tile_path(output, t, len(tiles) == 1)
        if target is not None:
            write_tile(t, target, str(path), meshes[0].meters_per_unit)
        out.append((t, target))
    return out


def read_stretch(path) -> Stretch:
    """The Stretch of a stretch map EXR this tool wrote (its chart channel, unit and shear);
    TextureError naming the file where it is not one."""
    reader = Reader(path, "stretch map")
    try:
        spec = reader.spec
        names = list(spec.channelnames)
        if not set(CHANNELS[:2]) <= set(names):
            raise TextureError(f"{path}: not a stretch map (channels {', '.join(names)}; "
                               f"expected {', '.join(CHANNELS)}: bdipole-cl stretch writes it)")
        px = reader.read_band(0, spec.height)
        unit = spec.get_string_attribute("bdipole:stretch_unit", "")
        shear = float(spec.get_string_attribute("bdipole:stretch_max_shear", "0") or 0)
        shear_at = shear_texel_of(spec.get_string_attribute(
            "bdipole:stretch_max_shear_texel", ""), (spec.height, spec.width))
    finally:
        reader.close()
    for channel in CHANNELS:
        if channel in names:
            check_channel(path, channel, px[..., names.index(channel)])
    chart = covered = None
    if "chart" in names:
        code = px[..., names.index("chart")]
        chart = (np.abs(code) - 1).astype(np.int64)
        covered = code > 0
    return Stretch(px[..., names.index(CHANNELS[0])], px[..., names.index(CHANNELS[1])], chart,
                   covered, shear, unit, shear_at)


def check_channel(path, channel, values):
    """TextureError naming the file, channel and first texel where a stretch map's lengths
    are not finite and > 0, or its chart codes (chart + 1, negative where not covered) are not
    whole numbers."""
    if channel == "chart":
        ok = np.isfinite(values) & (values == np.round(values))
        want = "a whole number (chart + 1, negative where not covered)"
    else:
        ok = np.isfinite(values) & (values > 0)
        want = "a surface length, finite and > 0"
    if not ok.all():
        y, x = np.unravel_index(int(np.flatnonzero(~ok)[0]), ok.shape)
        raise TextureError(f"{path}: {channel} at x={x}, y={y}: {float(values[y, x])!r}: "
                           f"expected {want} ({int((~ok).sum())} texel(s) so)")
