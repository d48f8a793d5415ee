"""Constant-parameter blur planning: per channel, which method and kernel, and why (``auto``);
the typed record of what a blur did (``BlurInfo``); and one image (or band) blurred by its plans.
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from ...methods.choice import AUTO_DIRECT_MAX_RADIUS, auto_blur_config
from ...signals import check_stop
from .dispatch import DeviceBlur
from .fft import fft_blur_channel
from .fit import fit_gaussians
from .params import channel_parameters
from .weights import ChannelKernel, channel_kernel


class BlurAccuracyWarning(UserWarning):
    """A blur's error bound exceeds the tol it was asked for (the ``gaussians`` fit of a
    near-delta kernel, say); BlurInfo's ``error_bound`` says by how much."""


@dataclass(frozen=True)
class AutoPick:
    """Why ``method="auto"`` chose a channel's configuration."""

    rule: str                          # "measured" or "radius" (no measured one meets tol)
    truncation_tol: float
    measured_error: float | None = None
    measured_ms: float | None = None
    workload_radius: int | None = None


@dataclass(frozen=True)
class ChannelInfo:
    """What ``blur`` did in one channel. ``error_bound`` bounds |M - exact| / (max E * Rd):
    the truncation tol for exact weights, plus the fit's L1 error for gaussians, or the
    measured kernel error of a texture-varying plan."""

    channel: int
    method: str
    radius: int                        # texels
    error_bound: float
    rd: float | None = None            # constant parameters: the channel's Rd
    auto: AutoPick | None = None
    fit_error: float | None = None     # texture-varying: max L1 error of the nodes in the basis
    interp_error: float | None = None  # texture-varying: max L1 error at the check points
    nodes: int | None = None           # texture-varying: lattice nodes


@dataclass(frozen=True)
class BlurInfo:
    """What ``blur`` did, per channel."""

    channels: tuple


@dataclass(frozen=True)
class ChannelPlan:
    """One channel's blur: the method, its exact kernel, and the auto record (if auto)."""

    method: str
    kernel: ChannelKernel
    auto: AutoPick | None = None


def constant_row_bytes(width: int, nchan: int) -> int:
    """Working set per image row of a constant-parameter blur: input, output, a temporary and
    the FFT's float64 copies (``bands.band_rows`` takes it)."""
    return width * nchan * 4 * 8


def auto_choice(ck, alpha, sigma_t, eta, tol, exact) -> ChannelPlan:
    """``method="auto"``: the cheapest configuration measured by ``bdipole-cl report`` whose
    max error (relative to max(E) * Rd) is <= tol, on the workload of the nearest radius; without
    data, ``direct`` up to AUTO_DIRECT_MAX_RADIUS and ``fft`` above, at truncation tol."""
    choice = auto_blur_config(ck.radius, tol)
    if choice is None:
        method = "direct" if ck.radius <= AUTO_DIRECT_MAX_RADIUS else "fft"
        return ChannelPlan(method, ck, AutoPick("radius", tol))
    if choice.tol != tol:
        ck = channel_kernel(alpha, sigma_t, eta, choice.tol, exact)
    return ChannelPlan(choice.method, ck, AutoPick("measured", choice.tol, choice.max_error,
                                                   choice.median_s * 1e3, choice.radius))


def plan_channel(method, alpha, sigma_t, eta, tol, exact) -> ChannelPlan:
    ck = channel_kernel(alpha, sigma_t, eta, tol, exact)
    if method == "auto":
        return auto_choice(ck, alpha, sigma_t, eta, tol, exact)
    return ChannelPlan(method, ck)


def channel_plans(nchan, *, method, tol, exact, **physical):
    """Per-channel parameters and ChannelPlans: the one place that decides each channel's
    kernel, and so the halo of banded blurs."""
    params = channel_parameters(nchan, exact=exact, **physical)
    return params, [plan_channel(method, a, st, et, tol, exact) for a, st, et in params]


def halo_of(plans) -> int:
    """The rows a band needs above and below: the largest kernel radius of its plans."""
    return max(p.kernel.radius for p in plans)


def blur_whole(e, params, plans, border, exact, rt):
    """One in-memory image (or band with its halo), its channel plans resolved: (M, BlurInfo)."""
    device = None
    fft_out = {}
    info = []
    for c, ((a, st, et), plan) in enumerate(zip(params, plans)):
        check_stop()
        ck = plan.kernel
        if plan.method in ("direct", "gaussians") and device is None:
            device = DeviceBlur(e, border, rt)
        if plan.method == "direct":
            device.run_direct(c, ck)
            bound = ck.tol
        elif plan.method == "gaussians":
            fit = fit_gaussians(a, st, et, ck.tol, exact)
            device.run_gaussians(c, fit)
            bound = ck.tol + fit.l1_error
            if fit.l1_error > ck.tol:
                warnings.warn(BlurAccuracyWarning(
                    f"channel {c}: the gaussians fit of this kernel (radius {ck.radius}, "
                    f"albedo {ck.rd:.3g}) has L1 error {fit.l1_error:.2e} > tol {ck.tol:g}; "
                    f"energy is kept, the shape is not: use method='direct' or 'fft' for the "
                    f"exact kernel"), stacklevel=4)
        else:
            fft_out[c] = fft_blur_channel(e[..., c], ck.weights, border)
            bound = ck.tol
        if plan.auto is not None and plan.auto.measured_error is not None:
            bound = max(bound, plan.auto.measured_error)
        info.append(ChannelInfo(c, plan.method, ck.radius, bound, rd=ck.rd, auto=plan.auto))
    out = device.result() if device is not None else np.empty_like(e)
    for c, v in fft_out.items():
        out[..., c] = v
    return out, BlurInfo(tuple(info))
