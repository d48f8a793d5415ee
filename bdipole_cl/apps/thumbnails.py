"""The thumbnails' numbers (applications): blocks averaged down, the scale of a group of
channels (linear or log), values mapped onto it, sRGB encoding for display (``preview``
draws them)."""
from __future__ import annotations

import numpy as np

#: positive values spanning more than this many decades are shown on a log scale
LOG_DECADES = 2.0
#: longest side of a thumbnail, texels (larger images are averaged down in blocks)
THUMB = 192


def shrink(px, longest=THUMB):
    """Average ``px`` down in square blocks so its longest side is at most ``longest``: the
    image's last rows and columns repeated to whole blocks (a strip 300 x 1 is one column of
    blocks, not none; no edge texel is dropped). A block with a texel that is not finite is
    not finite (``thumbnail`` shows it)."""
    k = int(np.ceil(max(px.shape[:2]) / longest))
    if k <= 1:
        return px
    h, w = -(-px.shape[0] // k) * k, -(-px.shape[1] // k) * k
    whole = np.pad(px, ((0, h - px.shape[0]), (0, w - px.shape[1]), (0, 0)), mode="edge")
    return whole.reshape(h // k, k, w // k, k, -1).mean(axis=(1, 3))


def srgb_encode(x):
    """Linear [0, 1] -> sRGB-encoded [0, 1] (IEC 61966-2-1), for display."""
    x = np.clip(x, 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)


def group_scale(values, may_log=True):
    """(log?, vmin, vmax) of a group's finite values: log when the middle 90% of its positive
    values spans more than LOG_DECADES decades (a few outliers do not make a scale log),
    between the smallest positive value and the largest; (False, nan, nan) where no value is
    finite (no range is made up: the caption says so)."""
    finite = values[np.isfinite(values)]
    if finite.size == 0:
        return False, float("nan"), float("nan")
    pos = finite[finite > 0]
    spread = np.log10(np.percentile(pos, 95) / np.percentile(pos, 5)) if pos.size else 0.0
    if may_log and finite.min() >= 0 and spread > LOG_DECADES:
        return True, float(pos.min()), float(pos.max())
    return False, float(finite.min()), float(finite.max())


#: texels (thumbnail blocks) holding a value that is not finite are drawn in this colour
NOT_FINITE_RGB = (1.0, 0.0, 1.0)


def normalise(values, log, vmin, vmax):
    """Values -> [0, 1] on the group's scale (0 for texels at or below the log range)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        if log:
            t = (np.log10(np.maximum(values, vmin)) - np.log10(vmin)) / np.log10(vmax / vmin)
            t = np.where(values > 0, t, 0.0)
        else:
            # a constant group is shown mid-grey (its caption says it is constant)
            t = (values - vmin) / (vmax - vmin) if vmax > vmin else np.full_like(values, 0.5)
    return np.clip(np.nan_to_num(t, nan=0.0), 0.0, 1.0)


def finite_spread(channel) -> bool:
    """Whether a channel's finite values are not all one value (False where none is)."""
    finite = np.isfinite(channel)
    if not finite.any():
        return False
    return bool(np.min(channel, where=finite, initial=np.inf)
                != np.max(channel, where=finite, initial=-np.inf))
