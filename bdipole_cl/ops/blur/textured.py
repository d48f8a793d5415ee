"""Texture-varying blur applied: per channel a TexturedPlan (``textured_plan``), the basis
blurs (host FFT, or the separable OpenCL kernels for ``gaussians``), and the per-texel gather
of their weights on the device (kernels/blur_textured.cl)."""
from __future__ import annotations

import warnings

import numpy as np

from ...methods.registry import TEXTURED_BLUR_METHODS
from ...signals import check_stop
from ..bands import band_rows, bands, gather_rows
from .dispatch import DeviceBlur, gather_exitance, weight_planes
from .fft import FFT32_ROUNDOFF_ULPS, basis_blurs, cached_spectra, fft_shape, settled
from .params import texel_parameters
from .planning import BlurAccuracyWarning, BlurInfo, ChannelInfo
from .textured_plan import (RD_MAX, RD_MIN, parameter_ranges, plan_for_ranges,
                            shape_clamp_error)


def textured_plans(shape, *, tol, exact=False, eta=1.4, basis="svd", on_invalid="raise",
                   **physical):
    """Per channel: (TexturedPlan, Rd map, ld map) for an HxWxC image. Each channel has the plan
    of its own ranges (a union over channels would need more basis kernels per channel; the
    kernels' spectra are cheap, so sharing them saves little)."""
    etas = np.broadcast_to(np.atleast_1d(np.asarray(eta, np.float64)), (shape[2],)) \
        if np.ndim(eta) <= 1 and np.size(eta) in (1, shape[2]) else None
    if etas is None:
        raise ValueError(f"eta must be one value or one per channel (constant over the texture); "
                         f"got shape {np.shape(eta)}")
    out = []
    for c in range(shape[2]):
        rd, ld = texel_parameters(shape, c, eta=float(etas[c]), exact=exact,
                                  on_invalid=on_invalid, **physical)
        out.append((plan_for_ranges(*parameter_ranges(rd, ld), float(etas[c]), float(tol),
                                    exact, basis), rd, ld))
    return out


def blur_band(e, plans, rows, method, border, rt):
    """Blur one image or band (rows: the rows of the parameter maps it covers)."""
    h, w, _ = e.shape
    if method == "gaussians":
        device = DeviceBlur(e, border, rt)
        for c, (plan, rd, ld) in enumerate(plans):
            device.run_textured(c, plan, weight_planes(plan, rd[rows], ld[rows], rt))
        out = device.result()
        for c, (_, rd, _) in enumerate(plans):
            settled(out[..., c], e[..., c], rd[rows])
        return out
    out = np.empty_like(e)
    planes = None          # the basis blurs, (G, H, FFT width), reused across channels
    for c, (plan, rd, ld) in enumerate(plans):
        check_stop()
        shape = fft_shape((h, w), plan.radius)
        kspec = cached_spectra(plan, shape)
        if planes is None or planes.shape != (len(kspec), h, shape[1]):
            planes = np.empty((len(kspec), h, shape[1]), np.float32)
        basis_blurs(e[..., c], plan, kspec, border, planes)
        gather_exitance(out, c, plan, rd[rows], ld[rows], planes, plan.radius, rt)
        settled(out[..., c], e[..., c], rd[rows], FFT32_ROUNDOFF_ULPS)
    return out


def textured_row_bytes(width, nchan, radius, nbasis) -> int:
    """Working set per band row (of width ~ w + 2K): input, output, parameter maps, and per
    basis kernel its spectrum, product spectrum (complex) and blurred plane (or weight plane)."""
    return (width + 2 * radius) * 4 * (4 * nchan + 4 * nbasis + 6)


def blur_textured(e, *, method, tol, border, exact, max_memory, rt, on_invalid="raise",
                  **physical):
    """``blur`` with texture-varying parameters (see ``textured_plan``): (M, BlurInfo)."""
    if method not in TEXTURED_BLUR_METHODS:
        raise ValueError(f"method={method!r} needs constant parameters; with texture-varying "
                         f"parameters use one of {TEXTURED_BLUR_METHODS}")
    used = "fft" if method == "auto" else method
    plans = textured_plans(e.shape, tol=tol, exact=exact, on_invalid=on_invalid,
                           basis="gaussians" if used == "gaussians" else "svd", **physical)
    h, w, nch = e.shape
    k = max(p[0].radius for p in plans)
    nbasis = max(len(p[0].kernels) for p in plans)
    rows = band_rows(h, textured_row_bytes(w, nch, k, nbasis), max_memory, halo=k)
    if rows >= h:
        out = blur_band(e, plans, slice(0, h), used, border, rt)
    else:
        out = np.empty_like(e)
        for y0, y1, idx in bands(h, rows, k, border):
            # the halo rows' own parameters are never used (a gather: exit texel's profile)
            res = blur_band(gather_rows(e, idx), plans, np.maximum(idx, 0), used, border, rt)
            out[y0:y1] = res[k:k + (y1 - y0)]
    info = tuple(ChannelInfo(c, f"{used} (texture-varying, {len(p.kernels)} {p.basis} basis "
                                f"kernels)", p.radius, p.error_bound + clamp_bound(c, p, rd, ld,
                                                                                   exact),
                             fit_error=p.fit_error, interp_error=p.interp_error,
                             nodes=int(np.prod(p.table.shape[:2])))
                 for c, (p, rd, ld) in enumerate(plans))
    return out, BlurInfo(info)


def clamp_bound(c, plan, rd, ld, exact) -> float:
    """What the albedo shape clamp adds to channel c's bound; warned of when it is not 0."""
    err = shape_clamp_error(plan, rd, ld, exact)
    if err > 0:
        warnings.warn(BlurAccuracyWarning(
            f"channel {c}: albedo texels outside [{RD_MIN:g}, 1 - {1 - RD_MAX:.0e}] take the "
            f"kernel shape of the bound: error bound + {err:.2e}"), stacklevel=5)
    return err
