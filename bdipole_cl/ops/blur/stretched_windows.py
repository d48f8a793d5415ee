"""The stretched blur's windows (docs/stretch.md "Chart borders", "Bands"): the parts of the
image blurred on their own, each with its own plan. Without charts one window, the image, with
the blur's border rule; with charts kept apart, one per UV chart: its bounding box, the texels
it writes (its chart's, gutters included) and where each of its texels' irradiance comes from
(the chart's own texels; beyond them, by the chart border rule, the nearest covered texel or 0).
A window is blurred in bands of rows with a halo (``band_sources``), as ``BlurPlan`` bands an
image."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...signals import check_stop
from ..bands import halo_rows


@dataclass(frozen=True)
class Window:
    """A part of an H x W image blurred on its own: rows x cols of the image, the texels it
    writes (``output``: a mask of the box, None: all), where each of its texels' irradiance
    comes from (``source``: flat image indices, None: the texel itself; ``keep``: False where
    it is 0) and the border rule beyond its box (``border``: ``BORDER``'s)."""

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
            flat = e2d.ravel()
            src = np.where(self.keep[rows], flat[self.source[rows]], np.float32(0))
        return np.where((idx >= 0)[:, None], src, np.float32(0)).astype(np.float32,
                                                                         copy=False)

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


def chart_windows(chart, covered, shape, mode) -> tuple:
    """The Windows of the charts of a map (``chart``: each texel's chart, gutters the nearest
    chart's; ``covered``: the texels a triangle covers, None: all) kept apart by ``mode``
    (``methods.registry.CHART_BORDER``, not "none"): "clamp" continues each chart beyond its
    covered texels by the nearest one (its box's border rule clamp), "zero" by 0."""
    from scipy.ndimage import distance_transform_edt, find_objects
    h, w = shape[:2]
    covered = covered if covered is not None else np.ones((h, w), bool)
    _, labels = np.unique(chart, return_inverse=True)
    labels = labels.reshape(chart.shape) + 1
    out = []
    for k, box in enumerate(find_objects(labels)):
        if box is None:
            continue
        check_stop()
        rows, cols = box
        output = labels[box] == k + 1
        own = output & covered[box]
        if not own.any():
            own = output
        if mode == "clamp":
            iy, ix = distance_transform_edt(~own, return_distances=False, return_indices=True)
            source = (iy + rows.start) * w + (ix + cols.start)
            keep = np.ones(own.shape, bool)
        else:
            yy, xx = np.mgrid[rows, cols]
            source, keep = yy * w + xx, own
        out.append(Window(rows, cols, "clamp" if mode == "clamp" else "zero", output,
                          source.astype(np.int64), keep))
    return tuple(out)
