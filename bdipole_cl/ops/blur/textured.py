"""Texture-varying blur applied: per channel a TexturedPlan (``textured_plan``), the basis
blurs (host FFT, or the separable OpenCL kernels for ``gaussians``), and the per-texel gather
of their weights on the device (kernels/blur_textured.cl)."""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ...device.transfer import aligned_empty
from ...errors import warn_caller
from ...methods.registry import TEXTURED_BLUR_METHODS
from ...signals import check_stop
from .dispatch import DeviceBlur, device_weight_planes, gather_exitance
from .fft import (FFT32_ROUNDOFF, FFT32_ROUNDOFF_ULPS, ROUNDOFF_ULPS, basis_blurs,
                  channel_extremes, fft_shape, settle_floor, settled, summed_roundoff)
from .params import MapRanges, texel_parameters
from .planning import BlurAccuracyWarning, BlurInfo, ChannelInfo, separable_roundoff
from .near_field import DEFAULT_GATHER_COSTS, near_cells
from .textured_plan import (RD_MAX, RD_MIN, MapExtremes, TexturedPlan, map_extremes,
                            parameter_ranges, shape_clamp_error)
from .textured_plan_files import plan_for_ranges


def textured_method(method) -> str:
    """The method a texture-varying blur runs for ``method`` (auto: the host FFT of the SVD
    basis)."""
    if method not in TEXTURED_BLUR_METHODS:
        raise ValueError(f"method={method!r} needs constant parameters; with texture-varying "
                         f"parameters use one of {TEXTURED_BLUR_METHODS}")
    return "fft" if method == "auto" else method


class TexturedChannel(NamedTuple):
    """One channel of a texture-varying blur: its plan, float32 Rd and ld maps, and their
    extremes."""

    plan: TexturedPlan
    rd: np.ndarray
    ld: np.ndarray
    extremes: MapExtremes


def textured_plans(shape, *, tol, exact=False, eta=1.4, method="auto", on_invalid="raise",
                   costs=DEFAULT_GATHER_COSTS, counts=None, **physical):
    """Per channel a TexturedChannel (plan, Rd map, ld map, extremes) for an HxWxC image, for
    ``method`` (its basis: separable Gaussians for ``gaussians``, else eigen-kernels). Each
    channel has the plan of its own ranges (a union over channels would need more basis
    kernels per channel; the kernels' spectra are cheap, so sharing them saves little), its
    near field chosen for gather costs ``costs`` (the device's: ``dispatch.gather_costs``).
    ``counts``: a dict that gets the parameter values clamped (``on_invalid="clamp"``), by
    kind."""
    basis = "gaussians" if textured_method(method) == "gaussians" else "svd"
    etas = np.broadcast_to(np.atleast_1d(np.asarray(eta, np.float64)), (shape[2],)) \
        if np.ndim(eta) <= 1 and np.size(eta) in (1, shape[2]) else None
    if etas is None:
        raise ValueError(f"eta must be one value or one per channel (constant over the texture); "
                         f"got shape {np.shape(eta)}")
    out, ld_maps, ranges = [], {}, MapRanges()
    for c in range(shape[2]):
        rd, ld = texel_parameters(shape, c, eta=float(etas[c]), exact=exact,
                                  on_invalid=on_invalid, ld_maps=ld_maps, ranges=ranges,
                                  counts=counts, **physical)
        ext = map_extremes(rd, ld, ranges)
        out.append(TexturedChannel(plan_for_ranges(*parameter_ranges(ext), float(etas[c]),
                                                   float(tol), exact, basis, costs=costs),
                                   rd, ld, ext))
    return out


def blur_band(e, plans, rows, method, border, kernels, ranges=None):
    """Blur one image or band (rows: the rows of the parameter maps it covers) with the
    plan's device kernels (``dispatch.BlurKernels``). ``ranges``: a list that gets each
    channel's (min, max) irradiance."""
    ranges = [] if ranges is None else ranges
    h, w, _ = e.shape
    rt = kernels.rt
    if method == "gaussians":
        device = DeviceBlur(e, kernels)
        for c, (plan, rd, ld, _) in enumerate(plans):
            device.run_textured(c, plan, device_weight_planes(plan, rd[rows], ld[rows], rt))
        out = device.result()
        lows, highs = channel_extremes(e)
        for c, (_, rd, _, _) in enumerate(plans):
            ranges.append((float(lows[c]), float(highs[c])))
            settled(out[..., c], e[..., c], rd[rows], e_range=ranges[-1])
        return out
    out = host_array(e.shape)
    planes = None          # the basis blurs, (G, H, FFT width), reused across channels
    for c, (plan, rd, ld, _) in enumerate(plans):
        check_stop()
        shape = fft_shape((h, w), plan.radius)
        if planes is None or planes.shape != (len(plan.kernels), h, shape[1]):
            planes = host_array((len(plan.kernels), h, shape[1]))
        padded, e_range, dtype, unit = basis_blurs(e, c, plan, border, planes)
        ranges.append((e_range[0] / unit, e_range[1] / unit))
        ulps = FFT32_ROUNDOFF_ULPS if dtype == np.float32 else ROUNDOFF_ULPS
        gather_exitance(out, c, plan, rd[rows], ld[rows], planes, padded, plan.radius, rt,
                        settle_floor(e_range, ulps))
        if unit != 1.0:                # back from the HDR unit: exact, a power of two (whose
            view = out[..., c]         # inverse, up to 2^128, float32 need not hold)
            np.ldexp(view, -int(np.log2(unit)), out=view)
    return out


def host_array(shape):
    """An uninitialised float32 array on the device-alignment boundary, so that a CPU
    runtime reads and writes it in place (an unaligned host pointer is copied whole, in and
    out: ``device.transfer``)."""
    return aligned_empty(int(np.prod(shape)), np.float32).reshape(shape)


def textured_row_bytes(width, nchan, radius, nbasis) -> int:
    """Working set per band row (of width ~ w + 2K): input, output, parameter maps, and per
    basis kernel its spectrum, product spectrum (complex) and blurred plane (or weight plane)."""
    return (width + 2 * radius) * 4 * (4 * nchan + 4 * nbasis + 6)


def textured_info(plans, method, exact) -> BlurInfo:
    """What a texture-varying blur does per channel, its error bound with the shape clamp's
    (the truncation's tol plus the basis's measured kernel error, each <= tol by design: up
    to 2 tol, reported). Where the basis could not fit the kernels within tol (separable
    Gaussians at MAX_BASIS: 7e-3 at tol 1e-4), BlurAccuracyWarning says so."""
    for c, (p, _, _, _) in enumerate(plans):
        kernel_error = max(p.fit_error, p.interp_error)
        if kernel_error > p.truncation_tol:
            warn_caller(BlurAccuracyWarning(
                f"channel {c}: the {p.basis} basis fits the texture's kernels within "
                f"{kernel_error:.2e}, not tol {p.truncation_tol:g}: error bound "
                f"{p.error_bound:.2e}" + ("; method='fft' fits them within tol"
                                          if p.basis == "gaussians" else "")))
    return BlurInfo(tuple(
        ChannelInfo(c, f"{method} (texture-varying, {len(p.kernels)} {p.basis} basis kernels"
                       + (f", near field {p.near} with {len(p.near_values)} kernels"
                          if p.near >= 0 else "") + ")",
                    p.radius, p.error_bound + clamp_bound(c, p, ext, exact) + roundoff(p),
                    fit_error=p.fit_error, interp_error=p.interp_error,
                    nodes=int(np.prod(p.table.shape[:2])))
        for c, (p, _, _, ext) in enumerate(plans)))


def roundoff(plan) -> float:
    """The texture-varying blur's round-off relative to max|E| * Rd(x): separable Gaussians,
    their row and column sums (``planning.separable_roundoff``); eigen-kernels, the float32
    basis blurs' (FFT32_ROUNDOFF, the constant FFT's model) and the gather's float32 sums of
    its near cells, near kernels and table weights."""
    if plan.basis == "gaussians":
        return separable_roundoff([(len(taps) - 1) // 2 for taps in plan.kernels])
    terms = near_cells(plan.near) + len(plan.kernels) + len(plan.near_values)
    return FFT32_ROUNDOFF + summed_roundoff(terms)


def clamp_bound(c, plan, ext, exact) -> float:
    """What the albedo shape clamp adds to channel c's bound; warned of when it is not 0."""
    err = shape_clamp_error(plan, ext, exact)
    if err > 0:
        warn_caller(BlurAccuracyWarning(
            f"channel {c}: albedo texels outside [{RD_MIN:g}, 1 - {1 - RD_MAX:.0e}] take the "
            f"kernel shape of the bound: error bound + {err:.2e}"))
    return err
