"""Bands of rows: the one band-size rule and the one band loop (operations layer).

Huge images are processed in bands of rows so that memory stays bounded. A band that feeds a
blur carries a halo of ``halo`` rows above and below, taken by the border rule, so that every
texel an interior kernel reaches is present and the result equals the whole-image result.
The in-memory blurs and the file-to-file batches all cut their bands here.
"""
from __future__ import annotations

import numbers

import numpy as np


def band_rows(height: int, per_row_bytes: float, max_memory=None, halo: int = 0,
              tile_height: int = 0) -> int:
    """Rows per band: what ``max_memory`` bytes hold at ``per_row_bytes`` a row (the caller's
    working-set estimate for one row), less the two halos; at least 1; a multiple of
    ``tile_height`` for tiled files (whole tiles are read); all rows without a budget."""
    if max_memory is None or max_memory == float("inf"):
        return height
    if isinstance(max_memory, bool) or not isinstance(max_memory, numbers.Real) \
            or not max_memory > 0:
        raise ValueError(f"max_memory={max_memory!r}: expected a number of bytes > 0 "
                         f"(or None: no budget)")
    rows = max(1, int(max_memory // max(per_row_bytes, 1)) - 2 * halo)
    if tile_height:
        rows = max(tile_height, rows - rows % tile_height)
    return min(rows, height) if height else rows


def halo_rows(y0: int, y1: int, halo: int, height: int, border: str = "zero") -> np.ndarray:
    """Source rows of band [y0, y1) with ``halo`` rows each side, by the border rule: clamped,
    wrapped, or -1 (zeros) outside the image for ``zero``."""
    rows = np.arange(y0 - halo, y1 + halo)
    if border == "clamp":
        return np.clip(rows, 0, height - 1)
    if border == "wrap":
        return rows % height
    return np.where((rows >= 0) & (rows < height), rows, -1)


def bands(height: int, rows: int, halo: int = 0, border: str = "zero"):
    """The band loop: (y0, y1, source row indices with halos) for each band, top to bottom."""
    for y0 in range(0, height, max(1, rows)):
        y1 = min(y0 + rows, height)
        yield y0, y1, halo_rows(y0, y1, halo, height, border)


def gather_rows(image: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """Rows ``idx`` of an in-memory image, zeros where ``idx`` is -1."""
    return np.where((idx >= 0)[:, None, None], image[np.maximum(idx, 0)],
                    np.zeros((), image.dtype))
