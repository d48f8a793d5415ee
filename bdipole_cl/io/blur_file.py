"""File-to-file blur (``bdipole-cl blur``): an irradiance image in, an exitance EXR out, in
bands of rows with a halo of the truncation radius (I/O layer)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..device import get_runtime
from ..ops.bands import band_rows, bands
from ..ops.blur import PARAM_KEYS, blur, is_textured
from ..ops.blur.planning import channel_plans, halo_of
from ..errors import InvalidInputError
from ..signals import Stopped
from .collisions import Claim, check_claim
from .colour import resolve_working_space
from .images import (Cancelled, Reader, TextureError, Writer, check_output_format,
                     invalid_texels, output_spec, read_rows)

#: working set per row of a streamed band, in floats per texel and channel of the file: the
#: band as read, the colour planes, the blur's own working set (``constant_row_bytes``) and
#: the output with alpha
FILE_ROW_FLOATS = 10


def located(exc, path, sources, spec, idx):
    """An InvalidInputError of one band as a TextureError naming the file it comes from and
    the texel in image coordinates: irradiance rows through the band's row indices ``idx``
    (the halo included), parameter textures (whole images) as they are, data window added."""
    yy, xx, cc = exc.first_index
    row = int(idx[yy]) if exc.name == "irradiance" else yy
    where = sources.get(exc.name, sources.get(exc.name.rstrip("'"), path))
    return invalid_texels(exc, where, spec.x + xx, spec.y + row, cc)


def blur_file(path, output, *, colorspace="auto", working_space=None, half=False,
              max_memory=256 << 20, sources=None, cancel=None, mask=None, header=None,
              progress=None, texture=False, **kwargs):
    """Blur an irradiance image file into an EXR, streamed in bands of rows with a halo of the
    truncation radius (memory bounded by ``max_memory``). The irradiance is converted from
    ``colorspace`` (else as the file declares, as in ``process_textures``) into
    ``working_space``, the space the albedo/mfp parameters are in (arrays and constants are
    taken as being in it; ``read_parameter_texture(..., colour=True)`` converts an albedo
    file), and the output is tagged with it. Alpha is copied through. ``kwargs`` are
    ``blur``'s.

    ``sources``: {parameter name: file} of parameter textures given as arrays, so that errors
    name the file they come from and ``output`` never overwrites one of them. ``cancel``
    (threading.Event): when set, the next band raises Cancelled and the temporary output is
    removed. ``mask`` (HxW, the image's size): texels where it is 0 give no light and get no
    exitance (written as 0); bands whose halo'd irradiance is all 0 are not blurred at all.
    ``header``: more ``bdipole:*`` attributes for the output. ``progress``: a tqdm bar
    advanced by texels. ``texture`` (True or a TextureOptions): a tiled, mip-mapped EXR
    (``images.Writer``). Returns the BlurInfo (None when every band was skipped)."""
    check_output_format(output)
    sources = dict(sources or {})
    check_claim(Claim(str(path), str(output), {"irradiance": str(path), **sources}))
    reader = Reader(path, "irradiance")
    writer = None
    try:
        spec = reader.spec
        colour, alpha_ch = reader.channels()
        route = reader.colour(colorspace, resolve_working_space(working_space))
        border = kwargs.get("border", "clamp")
        kwargs["device"] = get_runtime(kwargs.get("device"))   # resolved once for all bands
        physical = {key: kwargs[key] for key in PARAM_KEYS if key in kwargs}
        if is_textured(**physical):
            # parameter textures: one global plan, so the whole image is read and ``blur``
            # bands it internally (its halo follows that plan)
            k, rows = 0, spec.height
            kwargs["max_memory"] = max_memory
        else:
            # the halo follows each channel's plan (auto may pick a tighter truncation than tol)
            _, plans = channel_plans(len(colour), method=kwargs.get("method", "auto"),
                                     tol=kwargs.get("tol", 1e-3),
                                     exact=kwargs.get("exact", False), **physical)
            k = halo_of(plans)
            rows = band_rows(spec.height, spec.width * spec.nchannels * 4 * FILE_ROW_FLOATS,
                             max_memory, halo=k, tile_height=spec.tile_height)
        names = [spec.channelnames[c] for c in colour]
        if alpha_ch >= 0:
            names.append(spec.channelnames[alpha_ch])
        info = None
        for y0, y1, idx in bands(spec.height, rows, k, border):
            if cancel is not None and cancel.is_set():
                raise Cancelled(f"{path}: interrupted; nothing written")
            px = read_rows(reader, idx)
            e = px[..., colour]
            e = route.convert(e, names[:len(colour)])
            if mask is not None:
                e = e * (np.asarray(mask)[np.maximum(idx, 0)] > 0)[..., None] \
                    * (idx >= 0)[:, None, None]
            if np.any(e):
                try:
                    out, info = blur(e, return_info=True, **kwargs)
                except InvalidInputError as exc:
                    raise located(exc, path, sources, spec, idx) from None
                out = out[k:k + y1 - y0]
                if mask is not None:
                    out = out * (np.asarray(mask)[y0:y1] > 0)[..., None]
            else:                               # no light reaches this band: nothing to blur
                out = np.zeros((y1 - y0, spec.width, len(colour)), np.float32)
            parts = [out]
            if alpha_ch >= 0:
                parts.append(px[k:k + y1 - y0, :, alpha_ch:alpha_ch + 1])
            if writer is None:
                meta = {key: (v if np.ndim(v) < 2 else "texture")
                        for key, v in kwargs.items() if key in PARAM_KEYS + ("tol", "border")}
                if info is not None:
                    meta["methods"] = ",".join(f"{c.method}(r={c.radius})"
                                               for c in info.channels)
                meta.update(header or {})
                meta["source"] = str(path)
                meta.update(route.header("irradiance"))
                Path(output).parent.mkdir(parents=True, exist_ok=True)
                writer = Writer(output, output_spec(
                    spec, names, len(names) - 1 if alpha_ch >= 0 else -1, half, meta,
                    working=route.working), kwargs.get("on_invalid", "raise"),
                    texture=texture, cancel=cancel)
            writer.write_band(y0, y1, np.concatenate(parts, axis=-1))
            if progress is not None:
                progress.update((y1 - y0) * spec.width)
        writer.commit()
        writer = None
        return info
    except Stopped:
        raise Cancelled(f"{path}: interrupted; nothing written") from None
    except (OSError, ValueError) as exc:
        where = sources.get(getattr(exc, "name", None), path)
        raise TextureError(f"{where}: {exc}") from exc
    finally:
        if writer is not None:
            writer.abort()
        reader.close()
