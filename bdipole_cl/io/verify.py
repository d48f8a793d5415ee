"""What is written is what was meant: finite values, read back before the rename, complete on
the next run's up-to-date check (I/O layer; ``images.Writer`` calls it for every band).

* ``finite_texels``: every value a band stores is finite in the file's format (float: finite;
  half: finite, at most ``HALF_MAX``, and a nonzero value not flushed to 0). A texel with any
  other value is invalid: with ``on_invalid="raise"`` the write fails naming the first one
  (x, y in image coordinates, data window included); with ``"clamp"`` only that texel's bad
  values are replaced (NaN by 0, an infinite or too large value by the format's largest with
  its sign, a too small half by the smallest half subnormal with its sign) and the texel is
  counted. Nothing else in the band changes.
* ``BandDigests`` / ``read_back``: each band's bytes, as the file's format holds them, are
  digested while they are written; after the file is closed it is read back band by band and
  every digest must match, else the job fails (a full disk, a short write, a file size limit).
* ``is_complete``: an existing output can be trusted (by a re-run's up-to-date check) only if
  every pixel reads back: a file truncated with an intact header is not complete.
"""
from __future__ import annotations

import hashlib
import os
import stat

import numpy as np
import OpenImageIO as oiio

from .oiio_text import oiio_error

#: what half floats hold: larger finite values become inf, smaller nonzero ones become 0
HALF_MAX = float(np.finfo(np.float16).max)
HALF_TINY = float(np.finfo(np.float16).smallest_subnormal)
FLOAT_MAX = float(np.finfo(np.float32).max)


class WriteCheckError(RuntimeError):
    """Values a file cannot store, or a file that did not read back as written."""


def _stored(block, half):
    with np.errstate(over="ignore", invalid="ignore"):   # the overflow is what is detected
        return block.astype(np.float16 if half else np.float32)


def invalid_values(block, half):
    """Boolean array: values of ``block`` (rows, width, channels) that the format would not
    store as a finite number equal in kind (overflow to inf, flush of a nonzero to 0)."""
    stored = _stored(block, half)
    bad = ~np.isfinite(stored)
    if half:
        bad |= (block != 0) & (stored == 0)
    return bad


def finite_texels(block, half, on_invalid, where, names, x0, y0):
    """``block`` made storable; returns (block, the invalid values' count: channel values, as
    every invalid count). ``where`` names the file, ``names`` the channels, (x0, y0) the image
    coordinates of ``block[0, 0]``."""
    block = np.asarray(block, np.float32)
    bad = invalid_values(block, half)
    n = int(np.count_nonzero(bad))
    if n == 0:
        return block, 0
    if on_invalid != "clamp":
        yy, xx, cc = (int(v) for v in np.argwhere(bad)[0])
        what = (f"outside the half-float range [{HALF_TINY:.3g}, {HALF_MAX:g}] or not finite"
                if half else "that are not finite")
        raise WriteCheckError(
            f"{where}: {n} value(s) {what}; first at x={x0 + xx}, y={y0 + yy}, "
            f"channel {names[cc]}: {float(block[yy, xx, cc]):g} (--on-invalid clamp / "
            f"on_invalid='clamp' clamps them"
            + ("; or write float instead of half)" if half else ")"))
    top = HALF_MAX if half else FLOAT_MAX
    fixed = np.where(np.isnan(block), 0.0, np.sign(block) * np.clip(
        np.abs(block), HALF_TINY if half else 0.0, top)).astype(np.float32)
    return np.where(bad, fixed, block), n


class BandDigests:
    """Digests of the bands a Writer stored, in the file's own format, to compare on read."""

    def __init__(self, half):
        self.half = half
        self.bands = []                  # (y0, y1, digest)

    def add(self, y0, y1, block):
        self.bands.append((y0, y1, _digest(_stored(block, self.half))))


def _digest(array):
    return hashlib.blake2b(np.ascontiguousarray(array).tobytes(), digest_size=16).digest()


def read_rows_of(inp, spec, y0, y1, fmt, miplevel=0):
    """Rows [y0, y1) (0-based in the data window) of an open file (of its mip level
    ``miplevel``, whose spec ``spec`` is), any layout."""
    ya, yb = spec.y + y0, spec.y + y1
    if spec.tile_width:
        th = spec.tile_height
        ta = spec.y + (y0 // th) * th
        tb = min(spec.y + -(-y1 // th) * th, spec.y + spec.height)
        px = inp.read_tiles(0, miplevel, spec.x, spec.x + spec.width, ta, tb, spec.z,
                            spec.z + max(spec.depth, 1), 0, spec.nchannels, fmt)
        if px is None:
            return None
        px = np.asarray(px).reshape(tb - ta, spec.width, spec.nchannels)
        return px[ya - ta:yb - ta]
    px = inp.read_scanlines(0, miplevel, ya, yb, spec.z, 0, spec.nchannels, fmt)
    return None if px is None else np.asarray(px).reshape(y1 - y0, spec.width, spec.nchannels)


def read_back(path, digests: BandDigests, what, names):
    """WriteCheckError unless ``path`` reads back exactly as ``digests`` recorded (channels
    ``names`` in the order written; EXR stores them sorted by name)."""
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise WriteCheckError(f"{what}: the written file does not read back: "
                              f"{oiio_error() or 'unknown error'}")
    try:
        spec = inp.spec()
        fmt = oiio.HALF if digests.half else oiio.FLOAT
        stored = list(spec.channelnames)
        if sorted(stored) != sorted(names):
            raise WriteCheckError(f"{what}: the written file has channels {', '.join(stored)}, "
                                  f"not {', '.join(names)}")
        order = [stored.index(n) for n in names]
        for y0, y1, want in digests.bands:
            px = read_rows_of(inp, spec, y0, y1, fmt)
            px = None if px is None else px[..., order]
            if px is None or _digest(px.astype(np.float16 if digests.half else np.float32,
                                               copy=False)) != want:
                why = (oiio_error(inp) or "missing or corrupt data") if px is None else \
                    "the values differ from those written"
                raise WriteCheckError(f"{what}: rows {y0}..{y1 - 1} of the written file do not "
                                      f"read back ({why}); nothing written (disk full or a "
                                      f"file size limit?)")
    finally:
        inp.close()


def file_identity(path):
    """(inode, mtime ns, size) of ``path``, or None where there is none: what tells a file
    replaced since (this tool writes by renaming a new file into place) without a clock."""
    try:
        st = os.stat(path)
    except OSError:
        return None
    return st.st_ino, st.st_mtime_ns, st.st_size


def replaced_since(path, before) -> bool:
    """``path`` is a whole image file (``is_complete``) that is not the one ``before`` (its
    ``file_identity`` then) named: written since."""
    now = file_identity(path)
    return now is not None and now != before and is_complete(path)


def is_complete(path, rows=64) -> bool:
    """Every pixel of the image file ``path`` reads, of every mip level of a texture (``rows``
    rows at a time); a path that is not a regular file is not (and is never opened: a FIFO
    would block)."""
    try:
        if not stat.S_ISREG(os.stat(path).st_mode):
            return False
    except OSError:
        return False
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        return False
    try:
        if inp.spec().deep:
            return False
        level = 0
        while level == 0 or inp.seek_subimage(0, level):
            spec = inp.spec()
            step = max(rows, spec.tile_height or 1)
            for y0 in range(0, spec.height, step):
                if read_rows_of(inp, spec, y0, min(y0 + step, spec.height), oiio.FLOAT,
                                level) is None:
                    return False
            level += 1
        return True
    finally:
        inp.close()


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
