"""The stretched blur's windows (docs/stretch.md "Chart borders", "Bands"): the parts of the
image blurred on their own (their plans: ``stretched_plan.shared_ranges``). Without charts one
window, the image, with the blur's border rule; with charts kept apart, one per UV chart: its
bounding box, the texels it writes (its chart's, gutters included) and where each of its
texels' irradiance comes from (the chart's own texels; beyond them, by the chart border rule,
the nearest covered texel or 0). A window is blurred in bands of rows with a halo
(``band_sources``), as ``BlurPlan`` bands an image."""
from __future__ import annotations

import hashlib
from dataclasses import dataclass

import numpy as np

from ...caches import ByteCache
from ...signals import check_stop
from ..bands import halo_rows


@dataclass(frozen=True)
class Window:
    """A part of an H x W image blurred on its own: rows x cols of the image, the texels it
    writes (``output``: a mask of the box, None: all), where each of its texels' irradiance
    comes from (``source``: flat image indices, None: the texel itself; ``keep``: False where
    it is 0, None: nowhere) and the border rule beyond its box (``border``: ``BORDER``'s)."""

    rows: slice
    cols: slice
    border: str
    output: np.ndarray | None = None
    source: np.ndarray | None = None
    keep: np.ndarray | None = None

    @property
    def height(self) -> int:
        return self.rows.stop - self.rows.start

    @property
    def width(self) -> int:
        return self.cols.stop - self.cols.start

    def writes(self):
        """The mask of the box's texels this window writes (all, without charts)."""
        return (np.ones((self.height, self.width), bool) if self.output is None
                else self.output)

    def band_irradiance(self, e2d, idx):
        """The window's irradiance (len(idx) x width, float32) at its rows ``idx`` (relative
        to the box, -1: a row of zeros, by ``bands.halo_rows``) of channel ``e2d`` (H x W)."""
        rows = np.maximum(idx, 0)
        if self.source is None:
            src = e2d[self.rows.start + rows, self.cols]
        else:
            src = e2d.ravel().take(self.source[rows])
        if self.keep is not None:
            src = np.where(self.keep[rows], src, np.float32(0))
        src[idx < 0] = 0
        return src.astype(np.float32, copy=False)

    def bands(self, rows, halo):
        """(y0, y1, idx) per band of ``rows`` rows of the box (``bands.bands``): its rows
        [y0, y1) and their source rows with ``halo`` rows each side by the window's border
        rule (relative to the box; -1: zeros)."""
        for y0 in range(0, self.height, max(1, rows)):
            y1 = min(y0 + rows, self.height)
            yield y0, y1, halo_rows(y0, y1, halo, self.height, self.border)


def whole_image(shape, border) -> Window:
    """The one window of a blur without charts: the image, with its border rule."""
    return Window(slice(0, shape[0]), slice(0, shape[1]), border)


#: the windows of the stretch maps' charts, kept across calls by the maps' contents (a blur
#: of many irradiance maps over one UV layout makes them once: the nearest covered texel of
#: every gutter texel is a distance transform of the image)
WINDOWS = ByteCache("stretched blur chart windows", 256 << 20)


def chart_windows(chart, covered, shape, mode) -> tuple:
    """The Windows of the charts of a map (``chart``: each texel's chart, gutters the nearest
    chart's; ``covered``: the texels a triangle covers, None: all) kept apart by ``mode``
    (``methods.registry.CHART_BORDER``, not "none"): "clamp" continues each chart beyond its
    covered texels by the nearest one (its box's border rule clamp), "zero" by 0. Made once
    per contents of the maps (``WINDOWS``)."""
    chart = np.ascontiguousarray(chart)
    covered = None if covered is None else np.ascontiguousarray(covered, bool)
    digest = hashlib.sha1(memoryview(chart).cast("B"))
    if covered is not None:
        digest.update(memoryview(covered).cast("B"))
    key = (tuple(shape[:2]), mode, str(chart.dtype), covered is None, digest.hexdigest())
    hit = WINDOWS.get(key)
    if hit is None:
        hit = _chart_windows(chart, covered, shape, mode)
        WINDOWS.put(key, hit, sum(a.nbytes for win in hit for a in (win.output, win.source,
                                                                     win.keep)
                                  if a is not None))
    return hit


def chart_labels(chart):
    """Labels 1..n of the n chart ids of map ``chart`` (in the ids' order)."""
    if chart.dtype.kind in "iu" and chart.size:
        lo, hi = int(chart.min()), int(chart.max())
        if hi - lo < (1 << 20):        # ids within a small span: a lookup, not a sort
            present = np.zeros(hi - lo + 1, bool)
            present[chart.ravel() - lo] = True
            lut = np.cumsum(present).astype(np.int32)
            return lut[chart - lo]
    _, labels = np.unique(chart, return_inverse=True)
    return labels.reshape(chart.shape).astype(np.int32) + 1


def _chart_windows(chart, covered, shape, mode) -> tuple:
    from scipy.ndimage import distance_transform_edt, find_objects
    h, w = shape[:2]
    labels = chart_labels(chart)
    out = []
    for k, box in enumerate(find_objects(labels)):
        if box is None:
            continue
        check_stop()
        rows, cols = box
        output = labels[box] == k + 1
        own = output if covered is None else output & covered[box]
        if not own.any():
            own = output
        source = keep = None
        if mode != "clamp":
            keep = own
        elif not own.all():            # the nearest covered texel of each other one
            iy, ix = distance_transform_edt(~own, return_distances=False, return_indices=True)
            source = ((iy + rows.start) * w + (ix + cols.start)).astype(np.int64)
        out.append(Window(rows, cols, "clamp" if mode == "clamp" else "zero", output,
                          source, keep))
    return tuple(out)
