"""A scene's statistics pass (the jobs layer): each albedo file read once, in bands of rows,
into the working space, for its Rd range and masked fraction; and the smallest monotone table
that meets a material's tol on that range (``bdipole_cl.jobs.scene`` plans with these)."""
from __future__ import annotations

import numpy as np

from ..caches import ByteCache
from ..io.images import (Reader, TextureError, check_same_window, classify_channels,
                         read_parameter_texture)
from ..methods.registry import MethodConfig
from ..ops.bands import band_rows
from ..ops.invert import InversionKernel
from ..physics import reference as ref
from ..physics import tables

#: table sizes tried for a scene's albedo range, smallest first
TABLE_SIZES = (8, 16, 32, 64, 128, 256)
#: albedos checked in the range when choosing a table size
RANGE_SWEEP = 4000
#: host bytes one job's bands may take (``bdipole-cl plan/bake --max-memory``)
DEFAULT_MEMORY = 256 << 20


def read_albedo(path, mask_mode, mask_path, colorspace, working, layer=None):
    """One read of an albedo file: (colour texels HxWxC in the working space ``working``, the
    mask as booleans or None, colour channel names, alpha name or None, other channel names,
    its ColourPath). ``mask_mode``: None, "alpha" (the file's alpha) or a texture
    (``mask_path``, its first channel; masks are data, never converted); ``layer``: the
    EXR layer read (None: ``channels.classify_channels``' rule)."""
    r = Reader(path, "albedo", role="albedo", layer=layer)
    try:
        spec = r.spec
        colour, alpha = r.channels()
        route = r.colour(colorspace, working)
        px = r.read_band(0, spec.height)
    finally:
        r.close()
    _, _, other = classify_channels(spec.channelnames, spec.alpha_channel, "albedo", layer)
    keep = None
    if mask_mode == "alpha":
        if alpha < 0:
            raise TextureError(f"{path}: mask = 'alpha' but the albedo has no alpha channel")
        keep = px[..., alpha] > 0
    elif mask_mode:
        keep = read_parameter_texture(mask_path, "mask")[..., 0] > 0
    names = [spec.channelnames[c] for c in colour]
    return (route.convert(px[..., colour], names), keep, names,
            spec.channelnames[alpha] if alpha >= 0 else None,
            [spec.channelnames[c] for c in other], route)


def albedo_stats(path, mask_mode, mask_path, colorspace, working, max_memory=DEFAULT_MEMORY,
                 layer=None):
    """(colour channel names, alpha name, other names, Rd range of unmasked texels, masked
    fraction, ColourPath) of an albedo file: the statistics pass, in the working space,
    streamed in bands of rows."""
    readers = [Reader(path, "albedo", role="albedo", layer=layer)]
    try:
        spec = readers[0].spec
        colour, alpha = readers[0].channels()
        route = readers[0].colour(colorspace, working)
        if mask_mode == "alpha" and alpha < 0:
            raise TextureError(f"{path}: mask = 'alpha' but the albedo has no alpha channel")
        if mask_mode and mask_mode != "alpha":
            readers.append(Reader(mask_path, "mask"))
            check_same_window(spec, readers[1].spec, path, "mask", mask_path)
        colour_names = [spec.channelnames[c] for c in colour]
        rows = band_rows(spec.height, spec.width * (spec.nchannels + 2) * 4 * 3, max_memory,
                         tile_height=spec.tile_height if spec.tile_width else 0)
        lo, hi, kept = np.inf, -np.inf, 0
        for y0 in range(0, spec.height, rows):
            y1 = min(y0 + rows, spec.height)
            px = readers[0].read_band(y0, y1)
            keep = (px[..., alpha] > 0 if mask_mode == "alpha" else
                    readers[1].read_band(y0, y1)[..., 0] > 0 if mask_mode else
                    np.ones(px.shape[:2], bool))
            vals = route.convert(px[..., colour], colour_names)[keep]
            vals = vals[np.isfinite(vals)]
            kept += int(np.count_nonzero(keep))
            if vals.size:
                lo, hi = min(lo, float(vals.min())), max(hi, float(vals.max()))
    finally:
        for r in readers:
            r.close()
    _, _, other = classify_channels(spec.channelnames, spec.alpha_channel, "albedo", layer)
    names = spec.channelnames
    return (colour_names, names[alpha] if alpha >= 0 else None,
            [names[c] for c in other], (lo, hi) if lo <= hi else None,
            1.0 - kept / max(spec.width * spec.height, 1), route)


#: table sizes chosen per (etas, albedo range, tol, model, exact): a few bytes each
_size_cache = ByteCache("scene table sizes", 1 << 20)


def table_for_range(etas, rd_range, tol, model, exact, device):
    """The smallest monotone table meeting tol (max relative rho error) on float32 albedos of
    ``rd_range`` at every eta; (size, measured error)."""
    lo, hi = max(rd_range[0], 1e-7), min(rd_range[1], float(np.nextafter(np.float32(1), 0)))
    key = (tuple(etas), float(np.float32(lo)), float(np.float32(hi)), tol, model, exact)
    hit = _size_cache.get(key)
    if hit is not None:
        return hit
    rd = np.unique(np.float32(np.concatenate([np.geomspace(lo, max(hi, lo), RANGE_SWEEP),
                                              np.linspace(lo, hi, RANGE_SWEEP)])))
    wants = {e: ref.invert_rd_rho(rd.astype(np.float64), e, exact, model)[1] for e in etas}
    choice = (TABLE_SIZES[-1], None)
    for n in TABLE_SIZES:
        if not all(tables.table_is_monotone(e, n, exact, model) for e in etas):
            continue
        err = 0.0
        for e in etas:
            k = InversionKernel((e,), MethodConfig("table", table_size=n), model=model,
                                exact=exact, runtime=device)
            rho = k.run(rd, None, ("rho",))["rho"]
            err = max(err, float(np.max(np.abs(rho / wants[e] - 1.0))))
        if err <= tol:
            choice = (n, err)
            break
    return _size_cache.put(key, choice)
