"""The stretched blur applied (docs/stretch.md): per channel a StretchedPlan
(``stretched_plan``), per UV chart a window of the image whose irradiance is the chart's own
(``ChartWindow``: other charts left out, the chart continued beyond its edge by its nearest
texel, or 0), the basis blurs of each window by the host FFT (``fft.basis_blurs``) and the
per-texel gather on the device (kernels/blur_stretched.cl)."""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
import pyopencl as cl

from ...device import build_options, get_program, get_runtime
from ...errors import check_policy
from ...methods.registry import BORDER, CHART_BORDER
from ...physics import reference as ref
from ...signals import check_stop
from .dispatch import host_buffer, read_back
from .fft import FFT32_ROUNDOFF, basis_blurs, fft_shape, settle_floor, summed_roundoff, \
    FFT32_ROUNDOFF_ULPS, ROUNDOFF_ULPS, value_range
from .params import MapRanges, checked_irradiance, texel_parameters
from .planning import BlurAccuracyWarning, BlurInfo, ChannelInfo
from .stretched_plan import (StretchedPlan, coefficients, node_kernel, stretched_plan,
                             transformed)
from .textured import host_array
from .textured_plan import RD_MAX, RD_MIN
from .weights import EXACT_CELLS, unfold_quadrant


@dataclass(frozen=True)
class Stretch:
    """Per texel the surface length of one texel step along u (``su``) and along v (``sv``),
    HxW, in the mfp's unit; optionally the UV chart of each texel (``chart``, int; gutters:
    the nearest chart's) and which texels a triangle covers (``covered``); the largest shear
    |cos| between the surface's u and v directions (``max_shear``, for the bound)."""

    su: np.ndarray
    sv: np.ndarray
    chart: np.ndarray | None = None
    covered: np.ndarray | None = None
    max_shear: float = 0.0
    unit: str = ""


def as_stretch(value, shape) -> Stretch:
    """A Stretch of an HxW image from a Stretch, an ``ops.stretch.StretchTile`` (or anything
    with ``su``, ``sv``: its chart, covered and max_shear too), an (su, sv) pair or an HxWx2
    array; ValueError naming the first texel whose length is not finite and > 0."""
    if isinstance(value, Stretch):
        s = value
    elif hasattr(value, "su") and hasattr(value, "sv"):
        s = Stretch(value.su, value.sv, getattr(value, "chart", None),
                    getattr(value, "covered", None), float(getattr(value, "max_shear", 0.0)),
                    getattr(value, "unit", ""))
    elif isinstance(value, (tuple, list)) and len(value) == 2:
        s = Stretch(np.asarray(value[0]), np.asarray(value[1]))
    else:
        a = np.asarray(value)
        if a.ndim != 3 or a.shape[2] != 2:
            raise ValueError(f"stretch: expected (su, sv) maps or an HxWx2 array; got shape "
                             f"{a.shape}")
        s = Stretch(a[..., 0], a[..., 1])
    h, w = shape[:2]
    maps = {}
    for name in ("su", "sv"):
        m = np.ascontiguousarray(getattr(s, name), np.float32)
        if m.shape != (h, w):
            raise ValueError(f"stretch {name} has shape {m.shape}; expected ({h}, {w}) to "
                             f"match the irradiance")
        bad = ~(np.isfinite(m) & (m > 0))
        if bad.any():
            y, x = np.unravel_index(int(np.flatnonzero(bad)[0]), bad.shape)
            raise ValueError(f"stretch {name} at x={x}, y={y}: {m[y, x]!r}: a texel step's "
                             f"surface length must be finite and > 0 ({int(bad.sum())} "
                             f"texel(s) so)")
        maps[name] = m
    chart = None if s.chart is None else np.asarray(s.chart).astype(np.int64)
    if chart is not None and chart.shape != (h, w):
        raise ValueError(f"stretch chart map has shape {chart.shape}; expected ({h}, {w})")
    covered = None if s.covered is None else np.asarray(s.covered, bool)
    return Stretch(maps["su"], maps["sv"], chart, covered, float(s.max_shear), s.unit)


@dataclass(frozen=True)
class ChartWindow:
    """One chart's part of the image: ``rows`` x ``cols``, the texels it writes (``output``:
    its chart's), and where each of its texels' irradiance comes from (``source``: flat image
    indices; ``keep``: False where it is 0)."""

    rows: slice
    cols: slice
    output: np.ndarray
    source: np.ndarray
    keep: np.ndarray


def chart_windows(stretch: Stretch, shape, mode) -> tuple:
    """The ChartWindows of ``mode`` (``methods.registry.CHART_BORDER``); () for "none" or a
    stretch without charts (one window: the image, with the plan's border rule)."""
    from scipy.ndimage import distance_transform_edt, find_objects
    if mode == "none" or stretch.chart is None:
        return ()
    h, w = shape[:2]
    chart = stretch.chart
    covered = stretch.covered if stretch.covered is not None else np.ones((h, w), bool)
    ids, labels = np.unique(chart, return_inverse=True)
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
        yy, xx = np.mgrid[rows, cols]
        if mode == "clamp":
            iy, ix = distance_transform_edt(~own, return_distances=False, return_indices=True)
            source = (iy + rows.start) * w + (ix + cols.start)
            keep = np.ones(own.shape, bool)
        else:
            source, keep = yy * w + xx, own
        out.append(ChartWindow(rows, cols, output, source.astype(np.int64), keep))
    return tuple(out)


class StretchedChannel:
    """One channel: its plan and float32 Rd, l_u, l_v maps (diffusion lengths in texels)."""

    def __init__(self, plan, rd, lu, lv):
        self.plan, self.rd, self.lu, self.lv = plan, rd, lu, lv


def channel_maps(shape, c, stretch, physical, eta, exact, on_invalid, counts, ranges):
    """(Rd, l_u, l_v) float32 maps of channel c: Rd and ld (the mfp's unit) as the
    texture-varying blur makes them, divided by the texel lengths."""
    rd, ld = texel_parameters(shape, c, eta=eta, exact=exact, on_invalid=on_invalid,
                              ranges=ranges, counts=counts, **{**physical, "texel_size": 1.0})
    return rd, (ld / stretch.su).astype(np.float32), (ld / stretch.sv).astype(np.float32)


def map_ranges(rd, lu, lv):
    """((lo, hi) of logit Rd, ln l_u, ln l_v) over the maps (Rd's lit texels only)."""
    lo, hi = value_range(rd)
    if lo <= 0 < hi:
        lo = np.min(rd, where=rd > 0, initial=np.inf)
    t_rd = transformed([float(lo), float(hi)], [1.0, 1.0], [1.0, 1.0])[0]
    out = [(float(t_rd[0]), float(t_rd[1]))]
    for m in (lu, lv):
        a, b = value_range(m)
        out.append((float(np.log(a)), float(np.log(b))))
    return tuple(out)


def shear_error(plan: StretchedPlan, ranges, max_shear, exact=False) -> float:
    """The L1 distance (of the normalized kernel) between the axis-aligned kernel the blur
    uses and the kernel of the surface's true metric, whose u and v directions meet at an
    angle of cosine ``max_shear``, at the corners of the range (docs/stretch.md "Shear":
    measured, as the interpolation error is, not proven): 0 without shear."""
    if max_shear <= 0:
        return 0.0
    worst = 0.0
    corners = [sorted({lo, hi}) for lo, hi in ranges]
    for t_rd in corners[0]:
        for t_u in corners[1]:
            for t_v in corners[2]:
                check_stop()
                rd = float(np.clip(1.0 / (1.0 + np.exp(-t_rd)), RD_MIN, RD_MAX))
                lu, lv = float(np.exp(t_u)), float(np.exp(t_v))
                aligned = unfold_quadrant(node_kernel(rd, lu, lv, plan.eta, plan.radius,
                                                      exact))
                worst = max(worst, float(np.abs(sheared_kernel(rd, lu, lv, max_shear,
                                                               plan.eta, plan.radius, exact)
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
    """The float32 basis blurs' round-off and the gather's sums (as ``textured.roundoff``)."""
    return FFT32_ROUNDOFF + summed_roundoff(len(plan.kernels) + 8)


@dataclass(eq=False)
class StretchedBlurPlan:
    """A stretched blur, decided once (``plan_stretched``): per channel a StretchedPlan and its
    maps, the chart windows; apply it to the whole image (it reads every texel at once, as
    the texture-varying blur: ``textured`` is True for the file blur's sake)."""

    scattering: object
    shape: tuple
    tol: float
    border: str
    charts: str
    on_invalid: str
    channels: tuple
    windows: tuple
    textured_info: BlurInfo
    invalid: dict = field(default_factory=dict)
    runtime: object = field(default=None, repr=False)
    method: str = "fft"
    exact: bool = False
    halo: int = 0
    textured: bool = True

    @property
    def nchan(self) -> int:
        return self.shape[2]

    def on(self, device=None):
        self.runtime = get_runtime(device)
        return self

    def __getstate__(self):
        return {**self.__dict__, "runtime": None}

    def apply(self, irradiance, max_memory=None):
        """(M, BlurInfo) of the whole image (``max_memory`` is not used: the windows' FFTs
        read the whole image)."""
        counts = dict(self.invalid)
        e = checked_irradiance(irradiance, self.on_invalid, counts)
        out, info = self.apply_checked(e)
        out = out[..., 0] if np.ndim(irradiance) == 2 else out
        return out, replace(info, invalid=counts)

    def apply_checked(self, e, max_memory=None):
        if e.shape != tuple(self.shape):
            raise ValueError(f"irradiance has shape {e.shape}; the plan is for {self.shape}")
        rt = self.runtime = get_runtime(self.runtime)
        out = np.zeros(e.shape, np.float32)
        windows = self.windows or (None,)
        for c, ch in enumerate(self.channels):
            for win in windows:
                check_stop()
                blur_window(out, e, c, ch, win, self.border if win is None else
                            ("clamp" if self.charts == "clamp" else "zero"), rt)
        return out, self.textured_info

    def apply_band(self, e, rows=None):
        return self.apply_checked(e)


def blur_window(out, e, c, ch, win, border, rt):
    """out[..., c] over one chart window (None: the whole image) from its own irradiance."""
    plan = ch.plan
    if win is None:
        rows, cols = slice(0, e.shape[0]), slice(0, e.shape[1])
        src = e[..., c:c + 1]
    else:
        rows, cols = win.rows, win.cols
        flat = e[..., c].ravel()
        src = np.where(win.keep, flat[win.source], np.float32(0))[..., None]
    h, w = src.shape[:2]
    shape = fft_shape((h, w), plan.radius)
    planes = host_array((max(len(plan.kernels), 1), h, shape[1]))
    _, e_range, dtype, unit = basis_blurs(np.ascontiguousarray(src, np.float32), 0, plan,
                                          border, planes)
    ulps = FFT32_ROUNDOFF_ULPS if dtype == np.float32 else ROUNDOFF_ULPS
    res = np.empty((h, w), np.float32)
    gather(res, plan, ch.rd[rows, cols], ch.lu[rows, cols], ch.lv[rows, cols], planes,
           rt, settle_floor(e_range, ulps))
    if unit != 1.0:
        np.ldexp(res, -int(np.log2(unit)), out=res)
    view = out[rows, cols, c]
    if win is None:
        view[...] = res
    else:
        np.copyto(view, res, where=win.output)


def gather(res, plan, rd, lu, lv, planes, rt, settle):
    """res = the stretched gather (kernels/blur_stretched.cl) of one window on ``rt``."""
    h, w = res.shape
    mf = cl.mem_flags
    g = len(plan.kernels)
    fine = np.ascontiguousarray(plan.fine, np.float32)
    # over the host arrays (zero-copy on a CPU device: the planes are G images)
    bufs = [host_buffer(rt, np.ascontiguousarray(a, np.float32), mf.READ_ONLY)
            for a in (rd, lu, lv, fine, planes)]
    dst = host_buffer(rt, res, mf.READ_WRITE)
    (s0, o0), (s1, o1), (s2, o2) = plan.axis_maps()
    n0, n1, n2 = fine.shape[:3]
    scale, nonneg = settle
    kernel = cl.Kernel(get_program(rt, "blur_stretched", build_options({"BD_NBASIS": g})),
                       "gather_stretched")
    kernel(rt.queue, (w, h), None, *bufs, dst, np.int32(w), np.int32(h),
           np.int32(planes.shape[2]), np.int32(planes.shape[1] * planes.shape[2]),
           np.int32(plan.radius), np.int32(n0), np.int32(n1), np.int32(n2),
           np.float32(RD_MIN), np.float32(RD_MAX), s0, o0, s1, o1, s2, o2,
           np.float32(scale), np.int32(bool(nonneg)))
    read_back(rt, dst, res)


def plan_stretched(shape, scattering, stretch, *, tol=1e-3, border="clamp", charts="clamp",
                   exact=False, on_invalid="raise", device=None) -> StretchedBlurPlan:
    """The StretchedBlurPlan of an irradiance of ``shape`` (H, W, C) under ``scattering``
    (``plan.Scattering``: albedo and mfp, or alpha' and sigma_t', in the stretch's unit;
    its texel_size is not used) with ``stretch`` (``as_stretch``), chart borders by
    ``charts`` (``methods.registry.CHART_BORDER``)."""
    import warnings
    BORDER[border], CHART_BORDER[charts]
    check_policy(on_invalid)
    if not 0 < tol < 1:
        raise ValueError(f"tol={tol!r}: expected 0 < tol < 1")
    s = as_stretch(stretch, shape)
    physical = {k: v for k, v in scattering.keywords().items() if k not in ("eta",)}
    etas = np.broadcast_to(np.atleast_1d(np.asarray(scattering.eta, np.float64)), (shape[2],))
    counts, ranges_kept, chans, infos = {}, MapRanges(), [], []
    for c in range(shape[2]):
        rd, lu, lv = channel_maps(shape, c, s, physical, float(etas[c]), exact, on_invalid,
                                  counts, ranges_kept)
        ranges = map_ranges(rd, lu, lv)
        plan = stretched_plan(ranges, float(etas[c]), float(tol), exact)
        shear = shear_error(plan, ranges, s.max_shear, exact)
        bound = plan.error_bound + shear + roundoff(plan)
        if max(plan.fit_error, plan.interp_error) > tol or shear > tol:
            warnings.warn(BlurAccuracyWarning(
                f"channel {c}: stretched blur error bound {bound:.2e} (basis {plan.fit_error:.1e}"
                f", interpolation {plan.interp_error:.1e}, shear {shear:.1e} at |cos| "
                f"{s.max_shear:.3f})"), stacklevel=3)
        chans.append(StretchedChannel(plan, rd, lu, lv))
        infos.append(ChannelInfo(c, f"fft (stretched, {len(plan.kernels)} eigen-kernels"
                                    f"{', shear %.1e' % shear if shear else ''})",
                                 plan.radius, bound, fit_error=plan.fit_error,
                                 interp_error=plan.interp_error, nodes=plan.nodes))
    windows = chart_windows(s, shape, charts)
    return StretchedBlurPlan(scattering, tuple(shape), float(tol), border, charts, on_invalid,
                             tuple(chans), windows, BlurInfo(tuple(infos)), counts,
                             get_runtime(device), exact=exact)
