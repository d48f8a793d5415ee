"""The stretched blur applied (docs/stretch.md): the image's windows (``stretched_windows``:
the image, or per UV chart the chart's own irradiance, other charts left out, the chart
continued beyond its edge by its nearest texel or 0), per channel and window a StretchedPlan
of the window's ranges, shared by windows of overlapping ranges (``stretched_plan``,
``shared_ranges``), each window blurred in bands of rows with a
halo (``max_memory``): the basis blurs by the host FFT and the per-texel gather on the device
(``stretched_gather``, kernels/blur_stretched.cl), or both on the device where the FFT engine
is the device (``stretched_device``, ``widths.fft_engine``)."""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from ...caches import ByteCache
from ...device import get_runtime
from ...device.transfer import is_device_array
from ...errors import check_policy, warn_caller
from ...methods.registry import BORDER, CHART_BORDER
from ...physics import reference as ref
from ...signals import check_stop
from ..bands import band_rows
from ..widths import fft_engine
from .dispatch import gather_costs
from .fft import (FFT32_ROUNDOFF, PIECE_ROWS, channel_extremes, in_row_blocks, peaks_of,
                  summed_roundoff)
from .near_field import near_cells
from .params import MapRanges, checked_irradiance, texel_parameters
from .planning import (BlurAccuracyWarning, BlurInfo, ChannelInfo, lit_floor, peak_exponents,
                       signed_irradiance_bound, with_output_floor)
from .stretched_device import blur_band_device
from .stretched_gather import blur_band
from .stretched_plan import (StretchedPlan, coefficients, lattice_variables, node_kernel,
                             shared_ranges, stretched_plan)
from .stretched_windows import Window, chart_windows, whole_image
from .textured import host_array, textured_row_bytes
from .textured_plan import RD_MAX, RD_MIN
from .weights import EXACT_CELLS, unfold_quadrant
@dataclass(frozen=True)
class Stretch:
    """Per texel the surface length of one texel step along u (``su``) and along v (``sv``),
    HxW, in the mfp's unit; optionally the UV chart of each texel (``chart``, int; gutters:
    the nearest chart's) and which texels a triangle covers (``covered``); the largest shear
    |cos| between the surface's u and v directions (``max_shear``, for the bound) and where
    it is (``max_shear_at``: (x, y), None where not known)."""

    su: np.ndarray
    sv: np.ndarray
    chart: np.ndarray | None = None
    covered: np.ndarray | None = None
    max_shear: float = 0.0
    unit: str = ""
    max_shear_at: tuple | None = None


def as_stretch(value, shape) -> Stretch:
    """A Stretch of an HxW image from a Stretch, an ``ops.stretch.StretchTile`` (or anything
    with ``su``, ``sv``: its chart, covered and max_shear too), an (su, sv) pair or an HxWx2
    array (host or pyopencl arrays); ValueError naming the first texel whose length is not
    finite and > 0 in float32, a map of another shape, or chart ids that are not integers."""
    if isinstance(value, Stretch):
        s = value
    elif hasattr(value, "su") and hasattr(value, "sv"):
        s = Stretch(value.su, value.sv, getattr(value, "chart", None),
                    getattr(value, "covered", None), float(getattr(value, "max_shear", 0.0)),
                    getattr(value, "unit", ""), getattr(value, "max_shear_texel", None))
    elif isinstance(value, (tuple, list)) and len(value) == 2:
        s = Stretch(host_map(value[0]), host_map(value[1]))
    else:
        a = host_map(value)
        if a.ndim != 3 or a.shape[2] != 2:
            raise ValueError(f"stretch: expected (su, sv) maps or an HxWx2 array; got shape "
                             f"{a.shape}")
        s = Stretch(a[..., 0], a[..., 1])
    h, w = shape[:2]
    maps = {name: checked_lengths(name, host_map(getattr(s, name)), (h, w))
            for name in ("su", "sv")}
    chart = None if s.chart is None else checked_charts(host_map(s.chart), (h, w))
    covered = None if s.covered is None else host_map(s.covered).astype(bool, copy=False)
    if covered is not None and covered.shape != (h, w):
        raise ValueError(f"stretch covered map has shape {covered.shape}; expected ({h}, {w})")
    return Stretch(maps["su"], maps["sv"], chart, covered, float(s.max_shear), s.unit,
                   s.max_shear_at)


def host_map(value):
    """A map as a host array (a pyopencl array read back)."""
    return np.asarray(value.get() if is_device_array(value) else value)


def checked_lengths(name, given, shape):
    """Map ``given`` (su or sv) as C-contiguous float32 of ``shape``; ValueError naming the
    first texel whose length, as given or in float32, is not finite and > 0."""
    if given.shape != shape:
        raise ValueError(f"stretch {name} has shape {given.shape}; expected {shape} to match "
                         f"the irradiance")
    m = np.ascontiguousarray(given, np.float32)
    bad = ~(np.isfinite(m) & (m > 0))
    if bad.any():
        y, x = np.unravel_index(int(np.flatnonzero(bad)[0]), bad.shape)
        was = given[y, x]
        why = (f"{float(was)!r} is {'below' if 0 < was else 'above'} float32's range"
               if np.isfinite(was) and was > 0 else f"{float(was)!r}")
        raise ValueError(f"stretch {name} at x={x}, y={y}: {why}: a texel step's surface "
                         f"length must be finite and > 0 in float32 ({int(bad.sum())} "
                         f"texel(s) so)")
    return m


def checked_charts(chart, shape):
    """Chart ids of ``shape`` as integers; ValueError naming the first texel whose id is not
    a whole number (a float map's ids are not cast: 0.5 and 0.7 are not one chart)."""
    if chart.shape != shape:
        raise ValueError(f"stretch chart map has shape {chart.shape}; expected {shape}")
    if chart.dtype.kind in "iu":
        return chart
    if chart.dtype.kind == "b":
        return chart.astype(np.int64)
    whole = np.isfinite(chart) & (chart == np.round(chart)) & (np.abs(chart) < 2.0 ** 53)
    if not whole.all():
        y, x = np.unravel_index(int(np.flatnonzero(~whole)[0]), whole.shape)
        raise ValueError(f"stretch chart map at x={x}, y={y}: {float(chart[y, x])!r}: chart "
                         f"ids are whole numbers")
    return chart.astype(np.int64)


class WindowChannel:
    """One channel of one window: its plan and its (Rd, l_u, l_v) maps over the window's box
    (float32, diffusion lengths in texels, aligned: the gather reads them in place)."""

    def __init__(self, plan: StretchedPlan, maps):
        self.plan, self.maps = plan, maps


def channel_maps(shape, c, stretch, physical, eta, exact, on_invalid, counts, ranges):
    """(Rd, l_u, l_v) float32 maps of channel c (aligned: the gather reads them in place): Rd
    and ld (the mfp's unit) as the texture-varying blur makes them (``texel_parameters``: Rd an
    aligned float32 map, read only), ld divided by the texel lengths."""
    rd, ld = texel_parameters(shape, c, eta=eta, exact=exact, on_invalid=on_invalid,
                              ranges=ranges, counts=counts, **{**physical, "texel_size": 1.0})
    lu, lv = host_array(shape[:2]), host_array(shape[:2])

    def rows(r0, r1):                  # in row blocks on the FFT threads (NumPy's divisions
        for length, step in ((lu, stretch.su), (lv, stretch.sv)):      # release the GIL)
            np.divide(ld[r0:r1], step[r0:r1], out=length[r0:r1], dtype=np.float32,
                      casting="unsafe")
    in_row_blocks(rows, shape[0])
    return rd, lu, lv


def map_ranges(rd, lu, lv, own=None):
    """((lo, hi) of logit Rd, ln l, s) over the texels of HxW maps rd, l_u, l_v (those where
    ``own`` is True, None: all; Rd's lit texels only: Rd = 0 gives 0 whatever its kernel's
    shape), l = sqrt(l_u l_v) and s = ln(l_u / l_v) (``stretched_plan.lattice_variables``).
    The logarithms are taken of the extremes of l_u l_v and l_u / l_v (float64: no overflow;
    ln is monotonic), not of every texel: one read of the maps, piece by piece in row blocks
    on the FFT threads (``lattice_extremes``)."""
    lo, lit, hi, area, aspect = lattice_extremes(rd, lu, lv, own)
    if lo <= 0 < hi:
        lo = lit
    t_rd = lattice_variables([float(lo), float(hi)], 1.0, 1.0)[0]
    ln_l = 0.5 * np.log(np.asarray(area, np.float64))
    s = np.log(np.asarray(aspect, np.float64))
    return ((float(t_rd[0]), float(t_rd[1])), (float(ln_l[0]), float(ln_l[1])),
            (float(s[0]), float(s[1])))


def lattice_extremes(rd, lu, lv, own=None):
    """(min Rd, min lit Rd, max Rd, (min, max) l_u l_v, (min, max) l_u / l_v) over the
    texels of HxW maps where ``own`` (None: all), NaN where one is NaN."""
    inf = np.inf

    def block(r0, r1):
        lows, highs = np.full(4, inf), np.full(3, -inf)
        for p in range(r0, r1, PIECE_ROWS):
            q = min(p + PIECE_ROWS, r1)
            r, u, v = rd[p:q], lu[p:q], lv[p:q]
            m = True if own is None else own[p:q]
            area = np.multiply(u, v, dtype=np.float64)
            aspect = np.divide(u, v, dtype=np.float64)
            lows = np.minimum(lows, [np.min(x, where=w, initial=inf) for x, w in
                                     ((r, m), (r, (r > 0) & m), (area, m), (aspect, m))])
            highs = np.maximum(highs, [np.max(x, where=m, initial=-inf)
                                       for x in (r, area, aspect)])
        return np.concatenate([lows, highs])
    parts = np.array(in_row_blocks(block, rd.shape[0]))
    lows, highs = parts[:, :4].min(axis=0), parts[:, 4:].max(axis=0)
    return lows[0], lows[1], highs[0], (lows[2], highs[1]), (lows[3], highs[2])


def window_maps(maps, window: Window):
    """The (Rd, l_u, l_v) maps over a window's box, aligned copies (the gather reads them in
    place), and the ranges of its texels' (``map_ranges`` over the texels it writes)."""
    if window.output is None and (window.height, window.width) == maps[0].shape:
        return tuple(maps), map_ranges(*maps)   # the image: its maps, already aligned
    crop = []
    for m in maps:
        box = host_array((window.height, window.width))
        box[...] = m[window.rows, window.cols]
        crop.append(box)
    return tuple(crop), map_ranges(*crop, own=window.output)


def shear_error(plan: StretchedPlan, ranges, max_shear, exact=False) -> float:
    """The L1 distance (of the normalized kernel) between the axis-aligned kernel the blur
    uses and the kernel of the surface's true metric, whose u and v directions meet at an
    angle of cosine ``max_shear``, at the corners of the range (docs/stretch.md "Shear":
    measured, as the interpolation error is, not proven): 0 without shear."""
    if max_shear <= 0:
        return 0.0
    return _shear_error(tuple(ranges), plan.eta, plan.radius, float(max_shear), exact)


#: the shear's errors, kept across calls by (ranges, eta, radius, |cos|): each is 8 kernels
#: integrated by quadrature, ~0.1 s
SHEAR_ERRORS = ByteCache("stretched blur shear errors", 1 << 20)


@SHEAR_ERRORS.memoize
def _shear_error(ranges, eta, radius, max_shear, exact) -> float:
    worst = 0.0
    corners = [sorted({lo, hi}) for lo, hi in ranges]
    for t_rd in corners[0]:
        for ln_l in corners[1]:
            for t_s in corners[2]:
                check_stop()
                rd = float(np.clip(1.0 / (1.0 + np.exp(-t_rd)), RD_MIN, RD_MAX))
                lu, lv = float(np.exp(ln_l + 0.5 * t_s)), float(np.exp(ln_l - 0.5 * t_s))
                aligned = unfold_quadrant(node_kernel(rd, lu, lv, eta, radius, exact))
                worst = max(worst, float(np.abs(sheared_kernel(rd, lu, lv, max_shear, eta,
                                                               radius, exact)
                                                - aligned).sum()))
    return worst


#: sub-cells per texel side of the sheared kernel's quadrature within EXACT_CELLS of the centre
#: (the profile's peak is sharp there), GL nodes per sub-cell side
SHEAR_SUBCELLS, SHEAR_NODES = 8, 4


def sheared_kernel(rd, lu, lv, cos_shear, eta, k, exact=False):
    """The (2k+1)^2 kernel of R at surface distance ``sqrt(x^2 + 2 c x y + y^2)``, x = du /
    l_u, y = dv / l_v, c = ``cos_shear`` (the area element scaled by sqrt(1 - c^2)), each cell
    integrated by a product Gauss-Legendre rule (finer near the centre), normalized to 1."""
    alpha, st = coefficients(rd, eta, exact)
    su, sv = 1.0 / lu, 1.0 / lv
    out = np.zeros((2 * k + 1, 2 * k + 1))
    offs = np.arange(-k, k + 1, dtype=np.float64)
    for sub, nodes, near in ((1, 5, False), (SHEAR_SUBCELLS, SHEAR_NODES, True)):
        x, wq = np.polynomial.legendre.leggauss(nodes)
        pts = ((np.arange(sub)[:, None] + 0.5 * (x[None, :] + 1.0)) / sub - 0.5).ravel()
        wts = np.tile(0.5 * wq / sub, sub)
        sel = np.abs(offs) <= EXACT_CELLS if near else np.ones(len(offs), bool)
        rows = offs[sel]
        for i0 in range(0, len(rows), 32):
            check_stop()
            yv = sv * (rows[i0:i0 + 32, None, None, None] + pts[None, None, :, None])
            xu = su * (offs[None, :, None, None] + pts[None, None, None, :])
            r = np.sqrt(np.maximum(xu * xu + 2.0 * cos_shear * xu * yv + yv * yv, 0.0))
            val = np.einsum("ijab,a,b->ij", ref.profile(r, alpha, st, eta, exact), wts, wts)
            block = out[np.flatnonzero(sel)[i0:i0 + 32]]
            if near:
                cols = np.abs(offs) <= EXACT_CELLS
                block[:, cols] = val[:, cols]
            else:
                block[...] = val
            out[np.flatnonzero(sel)[i0:i0 + 32]] = block
    return out / out.sum()


def roundoff(plan) -> float:
    """The float32 basis blurs' round-off and the gather's sums of its near cells, near
    kernels and basis weights (as ``textured.roundoff``)."""
    return FFT32_ROUNDOFF + summed_roundoff(near_cells(plan.near) + len(plan.kernels)
                                            + len(plan.near_values))


def near_words(plan) -> str:
    """A plan's near field in words: its radius and its classes (``stretched_plan``'s near
    kernels)."""
    if plan.near < 0:
        return ""
    return f", near field {plan.near} ({counted(len(plan.near_values), 'class', 'classes')})"


def counted(n, one, many) -> str:
    """n with its noun: "1 class", "4 classes"."""
    return f"{n} {one if n == 1 else many}"


def describe(plans) -> str:
    """A channel's method: its windows' plans (eigen-kernels and near field), each distinct
    plan once with the number of charts that share it."""
    distinct = list({id(p): p for p in plans}.values())
    parts = [counted(len(p.kernels), "eigen-kernel", "eigen-kernels") + near_words(p)
             for p in distinct]
    if len(plans) == 1:
        return parts[0]
    if 1 < len(distinct) < len(plans):
        counts = [sum(q is p for q in plans) for p in distinct]
        parts = [f"{words} ({counted(n, 'chart', 'charts')})"
                 for words, n in zip(parts, counts)]
    return f"{len(plans)} charts: " + "; ".join(parts)


@dataclass(eq=False)
class StretchedBlurPlan:
    """A stretched blur, decided once (``plan_stretched``): its windows (the image, or one per
    chart) and per channel and window a StretchedPlan and its maps. ``apply`` blurs each
    window in bands of rows within ``max_memory`` (their halo the window's largest radius), so
    a band's result is the whole image's, up to the float32 FFT's round-off. ``textured`` is
    True for the file blur's sake: it reads the whole image and lets the plan band it."""

    scattering: object
    shape: tuple
    tol: float
    border: str
    charts: str
    on_invalid: str
    windows: tuple               # stretched_windows.Window
    channels: tuple              # per channel, per window: WindowChannel
    textured_info: BlurInfo
    invalid: dict = field(default_factory=dict)
    runtime: object = field(default=None, repr=False)
    method: str = "fft"
    exact: bool = False
    halo: int = 0
    textured: bool = True
    rd_floor: tuple = ()         # per channel the smallest lit Rd (``planning.lit_floor``)

    @property
    def nchan(self) -> int:
        return self.shape[2]

    def on(self, device=None):
        self.runtime = get_runtime(device)
        return self

    def __getstate__(self):
        return {**self.__dict__, "runtime": None}

    def apply(self, irradiance, max_memory=None):
        """(M, BlurInfo) of the whole image, each window in bands of rows within
        ``max_memory`` bytes (None: whole)."""
        counts = dict(self.invalid)
        e = checked_irradiance(irradiance, self.on_invalid, counts)
        out, info = self.apply_checked(e, max_memory)
        out = out[..., 0] if np.ndim(irradiance) == 2 else out
        return out, replace(info, invalid=counts)

    def apply_checked(self, e, max_memory=None):
        """``apply`` of a checked irradiance. A channel whose peak is far from 1 is blurred at
        a peak in [0.5, 1) and scaled back, its bound taking float32's absolute floor, as the
        plain blur's (``planning.peak_exponents``, ``with_output_floor``)."""
        if e.shape != tuple(self.shape):
            raise ValueError(f"irradiance has shape {e.shape}; the plan is for {self.shape}")
        rt = self.runtime = get_runtime(self.runtime)
        lo, hi = channel_extremes(e)              # one pass: the peaks and the signs
        peaks = peaks_of(lo, hi)
        shifts = peak_exponents(e, peaks)
        scaled = np.ldexp(e, -shifts).astype(np.float32) if shifts.any() else e
        out = np.zeros(e.shape, np.float32)
        for c, per_window in enumerate(self.channels):
            e2d = np.ascontiguousarray(scaled[..., c])
            for win, wch in zip(self.windows, per_window):
                blur_window(out[..., c], e2d, win, wch, max_memory, rt)
        info = self.signed_info(lo, hi)
        if not shifts.any():
            return out, info
        out = np.ldexp(out, shifts).astype(np.float32)   # one rounding, where it is subnormal
        return out, with_output_floor(info, peaks, self.rd_floor, self.tol)

    def signed_info(self, lo, hi) -> BlurInfo:
        """The plan's BlurInfo, each channel whose irradiance spans ``lo`` < 0 < ``hi`` taking
        the truncation's tol once more (``planning.signed_irradiance_bound``, as every blur)."""
        chans = list(self.textured_info.channels)
        for c in range(len(chans)):
            if lo[c] < 0 < hi[c]:
                chans[c] = signed_irradiance_bound(chans[c], self.tol, self.tol)
        return BlurInfo(tuple(chans))

    def apply_band(self, e, rows=None):
        return self.apply_checked(e)


def window_row_bytes(win: Window, plan: StretchedPlan) -> int:
    """A window's working set per band row: its basis blurs' (as ``textured_row_bytes``)."""
    return textured_row_bytes(win.width, 1, plan.radius, max(len(plan.kernels), 1))


def blur_window(out2d, e2d, win: Window, wch: WindowChannel, max_memory, rt):
    """out2d's texels that ``win`` writes = the stretched blur of its irradiance (from
    ``e2d``), in bands of rows within ``max_memory``: on the device end to end where the FFT
    engine is the device (``stretched_device``), else the basis blurs by the host FFT."""
    plan = wch.plan
    on_device = fft_engine(rt) == "device"
    halo = plan.radius
    rows = band_rows(win.height, window_row_bytes(win, plan), max_memory, halo=halo)
    writes = win.writes()
    for y0, y1, idx in win.bands(rows, halo):
        check_stop()
        src = win.band_irradiance(e2d, idx)
        # the band's own rows follow its halo's: rows [halo, halo + y1 - y0) of src
        res = (blur_band_device(src, plan, wch.maps, y0, win.border, halo, y1 - y0, rt)
               if on_device else None)
        if res is None:                # the host engine, or float64 transforms without fp64
            res = blur_band(src, plan, wch.maps, y0, win.border, halo, y1 - y0, rt)
        view = out2d[win.rows.start + y0:win.rows.start + y1, win.cols]
        np.copyto(view, res, where=writes[y0:y1])


def shear_words(max_shear, at) -> str:
    """The shear a bound was taken at, in words: its |cos| and, where known, its texel."""
    return f"|cos| {max_shear:.3f}" + (f" at texel x={at[0]}, y={at[1]}" if at else "")


def channel_plans(maps, windows, eta, tol, exact, costs, max_shear, shear_at=None, c=0):
    """Per window a WindowChannel of one channel's (Rd, l_u, l_v) ``maps``, the windows of
    overlapping ranges sharing a plan (``stretched_plan.shared_ranges``; where the union is
    past the radius or the planning memory a window alone is not, its own), and the channel's
    ChannelInfo fields: the worst plan's (bound, fit error, interpolation error, nodes), the
    shear's error, warned of (once a plan) where a kernel error exceeds tol."""
    crops, ranges = zip(*(window_maps(maps, win) for win in windows))
    shared = shared_ranges(ranges, [int(win.writes().sum()) for win in windows], tol)
    plans, refused = {}, {}

    def plan_of(box):
        if box in refused:
            raise refused[box]
        if box not in plans:
            try:
                plans[box] = stretched_plan(box, float(eta), float(tol), exact, costs=costs)
            except ValueError as exc:              # past the radius or the planning memory
                refused[box] = exc
                raise
        return plans[box]
    chosen = []
    for own, box in zip(ranges, shared):
        try:
            chosen.append(plan_of(box))
        except ValueError:
            if box == own:
                raise
            chosen.append(plan_of(own))           # the union refused: the window's own plan
    worst = None
    for box, plan in plans.items():               # each one some window's
        shear = shear_error(plan, box, max_shear, exact)
        bound = plan.error_bound + shear + roundoff(plan)
        if max(plan.fit_error, plan.interp_error) > tol or shear > tol:
            warn_caller(BlurAccuracyWarning(
                f"channel {c}: stretched blur error bound {bound:.2e} (basis "
                f"{plan.fit_error:.1e}, "
                f"interpolation {plan.interp_error:.1e}, shear {shear:.1e} at "
                f"{shear_words(max_shear, shear_at)})"))
        if worst is None or bound > worst[0]:
            worst = (bound, plan, shear)
    return tuple(WindowChannel(plan, crop) for plan, crop in zip(chosen, crops)), worst


def plan_stretched(shape, scattering, stretch, *, tol=1e-3, border="clamp", charts="clamp",
                   exact=False, on_invalid="raise", device=None) -> StretchedBlurPlan:
    """The StretchedBlurPlan of an irradiance of ``shape`` (H, W, C) under ``scattering``
    (``plan.Scattering``: albedo and mfp, or alpha' and sigma_t', in the stretch's unit;
    its texel_size is not used) with ``stretch`` (``as_stretch``), chart borders by
    ``charts`` (``methods.registry.CHART_BORDER``): per channel and window a plan of the
    window's own ranges or of a group of windows' (``stretched_plan.shared_ranges``), its
    near field chosen for the device's gather costs."""
    BORDER[border], CHART_BORDER[charts]
    check_policy(on_invalid)
    if not 0 < tol < 1:
        raise ValueError(f"tol={tol!r}: expected 0 < tol < 1")
    s = as_stretch(stretch, shape)
    rt = get_runtime(device)
    physical = {k: v for k, v in scattering.keywords().items() if k not in ("eta",)}
    etas = np.broadcast_to(np.atleast_1d(np.asarray(scattering.eta, np.float64)), (shape[2],))
    windows = (chart_windows(s.chart, s.covered, shape, charts)
               if charts != "none" and s.chart is not None else ())
    windows = windows or (whole_image(shape, border),)
    counts, ranges_kept, chans, infos, rd_floor = {}, MapRanges(), [], [], []
    for c in range(shape[2]):
        maps = channel_maps(shape, c, s, physical, float(etas[c]), exact, on_invalid, counts,
                            ranges_kept)
        rd_floor.append(lit_floor(maps[0]))
        per_window, (bound, plan, shear) = channel_plans(maps, windows, etas[c], tol, exact,
                                                         gather_costs(rt), s.max_shear,
                                                         s.max_shear_at, c)
        chans.append(per_window)
        infos.append(ChannelInfo(c, f"fft (stretched, {describe([w.plan for w in per_window])}"
                                    f"{', shear %.1e' % shear if shear else ''})",
                                 max(w.plan.radius for w in per_window), bound,
                                 fit_error=plan.fit_error, interp_error=plan.interp_error,
                                 nodes=plan.nodes))
    halo = max(w.plan.radius for ch in chans for w in ch)
    return StretchedBlurPlan(scattering, tuple(shape), float(tol), border, charts, on_invalid,
                             windows, tuple(chans), BlurInfo(tuple(infos)), counts, rt,
                             exact=exact, halo=halo, rd_floor=tuple(rd_floor))
