"""Constant-parameter blur planning: per channel, which method and kernel, and why (``auto``);
the typed record of what a blur did (``BlurInfo``); and one image (or band) blurred by its plans.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from ...device import get_runtime
from ...device.runtime import device_kind
from ...errors import warn_caller
from ...methods.choice import (AUTO_DIRECT_MAX_RADIUS, ChoiceData, DeviceKey, auto_blur_config,
                               choice_for, rescaled_blur)
from ..widths import blur_timings, fft_engine, passes
from ...signals import check_stop
from .dispatch import DeviceBlur
from .fft import (channel_extremes, channel_peaks, fft_blur_channels, fft_bound, fft_dtype,
                  settled, summed_roundoff)
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
    data: str = ""                     # which choice data decided (ChoiceSource.describe)


@dataclass(frozen=True)
class AutoData:
    """The choice data ``auto`` decides from on one device, and the methods it may pick: on
    a device that is not a CPU, data measured elsewhere (a CPU's) say nothing of its speed,
    so ``auto`` keeps to the methods that run on it (not the host FFT)."""

    data: ChoiceData
    source: str
    methods: tuple | None              # None: every measured method


#: the device kernel each blur method runs (the host FFT runs none): a method whose kernel the
#: device's probe rejected is never picked by ``auto``
METHOD_KERNELS = {"direct": "blur_direct", "gaussians": "blur_separable"}


def auto_data(rt=None) -> AutoData:
    """The AutoData of ``rt``'s device (None: the default device): data measured on another
    device have their blur timings rescaled by this device's probe (``probed_blur_data``);
    methods whose kernels the probe rejected are left out, and without the probe's timings,
    on a device that is not a CPU, the FFT where it would run on the host."""
    rt = get_runtime(rt)
    data, source = choice_for(DeviceKey.of(rt.device))
    described = source.describe()
    usable = tuple(m for m in ("direct", "gaussians", "fft")
                   if m not in METHOD_KERNELS or passes(rt, METHOD_KERNELS[m]))
    methods = None if len(usable) == 3 else usable
    if not source.this_device:
        probed = probed_blur_data(rt, data)
        if probed is not None:
            return AutoData(probed, described + "; blur timings rescaled by this device's "
                                                "probe", methods)
    if not source.this_device and device_kind(rt.device) != "cpu" and fft_engine(rt) == "host":
        methods = tuple(m for m in ("direct", "gaussians") if m in usable)
    return AutoData(data, described, methods)


def probed_blur_data(rt, data: ChoiceData) -> ChoiceData | None:
    """``data`` with the blur timings this device's probe measured (``ops.kernel_checks``'
    blur timings), or None where it has none for every (method, radius)."""
    return rescaled_blur(data, blur_timings(rt))


@dataclass(frozen=True)
class ChannelInfo:
    """What ``blur`` did in one channel. ``error_bound`` bounds ``|M - exact| / (max E * Rd)``:
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
    """What ``blur`` did, per channel, and the invalid input values it clamped
    (``on_invalid="clamp"``), by kind: {"irradiance": n, "albedo": n, ...}."""

    channels: tuple
    invalid: dict = field(default_factory=dict)


def worse(a: BlurInfo | None, b: BlurInfo | None) -> BlurInfo | None:
    """The BlurInfo of two bands of one image: per channel the one of the larger bound."""
    if a is None or b is None:
        return a or b
    return BlurInfo(tuple(x if x.error_bound >= y.error_bound else y
                          for x, y in zip(a.channels, b.channels)))


def signed_irradiance_bound(info: ChannelInfo, truncated: float, tol: float) -> ChannelInfo:
    """``info`` for an irradiance of both signs: the renormalized truncation's error, at most
    t max|E| Rd when E >= 0 (the kept weights' excess and the dropped tail have the same
    sign of error and it is their larger), is up to 2 t max|E| Rd when they can have opposite
    signs (docs/model.md "Blur error bound"): the bound takes ``truncated`` (t) once more, and
    a bound above tol is warned of."""
    bound = info.error_bound + truncated
    if bound > tol:
        warn_caller(BlurAccuracyWarning(
            f"channel {info.channel}: the irradiance has both signs: the kernel truncation's "
            f"error can add up from both: error bound {bound:.2e} > tol {tol:g}"))
    return replace(info, error_bound=bound)


@dataclass(frozen=True)
class ChannelPlan:
    """One channel's blur: the method, its exact kernel, the tol asked for, and the auto record
    (if auto)."""

    method: str
    kernel: ChannelKernel
    auto: AutoPick | None = None
    tol: float | None = None           # the error bound asked for (None: the kernel's tol)

    @property
    def asked_tol(self) -> float:
        """The error bound asked for: ``tol``, else the kernel's truncation tol."""
        return self.tol if self.tol is not None else self.kernel.tol


def constant_row_bytes(width: int, nchan: int) -> int:
    """Working set per image row of a constant-parameter blur: input, output, a temporary and
    the FFT's float64 copies (``bands.band_rows`` takes it)."""
    return width * nchan * 4 * 8


#: ``direct``'s round-off relative to max|E| * Rd (kernels/blur_direct.cl): each row of a
#: block is a float32 sum of <= 33 taps, the rows added by Neumaier's compensated sum (2 U32)
DIRECT_ROUNDOFF = summed_roundoff(33 + 2)


def separable_roundoff(radii) -> float:
    """A separable Gaussians blur's round-off relative to max|E| * Rd (kernels/
    blur_separable.cl): per Gaussian a row sum and a column sum of 2r + 1 taps each, its
    weighted result added into the exitance (one more per Gaussian)."""
    return summed_roundoff(2 * (2 * max(radii, default=0) + 1) + len(radii))


#: ``gaussians``: the share of tol its truncation takes; the fit's L1 error gets the rest, so
#: that truncation + fit (the bound, docs/model.md "Blur error bound") is <= tol
GAUSSIANS_TRUNCATION_SHARE = 0.5


def truncation_tol(method, tol) -> float:
    """The truncation tolerance of a method asked for error bound ``tol``."""
    return tol * GAUSSIANS_TRUNCATION_SHARE if method == "gaussians" else tol


def method_kernel(method, alpha, sigma_t, eta, tol, exact) -> ChannelKernel:
    return channel_kernel(alpha, sigma_t, eta, truncation_tol(method, tol), exact)


def gaussians_bound(alpha, sigma_t, eta, ck, exact) -> float:
    """truncation tol + the fit's L1 error + the round-off: |M - exact| / (max E * Rd) for any
    irradiance."""
    fit = fit_gaussians(alpha, sigma_t, eta, ck.tol, exact)
    return ck.tol + fit.l1_error + separable_roundoff(fit.radii)


def auto_choice(ck, alpha, sigma_t, eta, tol, exact, auto: AutoData) -> ChannelPlan:
    """``method="auto"``: the cheapest configuration measured by ``bdipole-cl report`` whose
    truncation tol and max error (relative to max(E) * Rd) are <= tol, on the workload of the
    nearest radius, in ``auto``'s data and methods, and whose bound (a gaussians fit's
    included) is <= tol; without data, ``direct`` up to AUTO_DIRECT_MAX_RADIUS (or always,
    where the host FFT is not allowed) and ``fft`` above, at truncation tol. A configuration
    whose tighter truncation makes the kernel wider than the largest radius is passed over
    (``ck``, at tol, fits: ``fft`` at tol would not have failed where ``auto`` did)."""
    exclude = ()
    while True:
        choice = auto_blur_config(ck.radius, tol, auto.data, auto.methods, exclude)
        if choice is None:
            host_fft = auto.methods is None or "fft" in auto.methods
            method = "direct" if ck.radius <= AUTO_DIRECT_MAX_RADIUS or not host_fft else "fft"
            return ChannelPlan(method, ck, AutoPick("radius", tol, data=auto.source), tol)
        try:
            used = method_kernel(choice.method, alpha, sigma_t, eta, choice.tol, exact)
        except ValueError:            # wider than max_radius at that truncation
            exclude += ((choice.method, choice.tol),)
            continue
        if choice.method != "gaussians" or gaussians_bound(alpha, sigma_t, eta, used,
                                                           exact) <= tol:
            return ChannelPlan(choice.method, used,
                               AutoPick("measured", used.tol, choice.max_error,
                                        choice.median_s * 1e3, choice.radius, auto.source),
                               tol)
        exclude += ("gaussians",)


def plan_channel(method, alpha, sigma_t, eta, tol, exact, auto: AutoData | None = None):
    """One channel's ChannelPlan; ``auto`` (for method "auto"; None: the default device's)."""
    if method == "auto":
        ck = channel_kernel(alpha, sigma_t, eta, tol, exact)
        return auto_choice(ck, alpha, sigma_t, eta, tol, exact, auto or auto_data())
    return ChannelPlan(method, method_kernel(method, alpha, sigma_t, eta, tol, exact), None,
                       tol)


def channel_plans(nchan, *, method, tol, exact, device=None, **physical):
    """Per-channel parameters and ChannelPlans: the one place that decides each channel's
    kernel, and so the halo of banded blurs. ``device``: the one ``auto`` decides for."""
    params = channel_parameters(nchan, exact=exact, **physical)
    auto = auto_data(device) if method == "auto" else None
    return params, [plan_channel(method, a, st, et, tol, exact, auto) for a, st, et in params]


def halo_of(plans) -> int:
    """The rows a band needs above and below: the largest kernel radius of its plans."""
    return max(p.kernel.radius for p in plans)


def planned_info(c, param, plan, exact, fft_precision=None) -> ChannelInfo:
    """Channel c's ChannelInfo from its plan alone (the irradiance's signs are added after):
    its method's error bound (the constant FFT's in ``fft_precision``), warned of where it
    exceeds the tol asked for."""
    a, st, et = param
    ck, tol = plan.kernel, plan.asked_tol
    if plan.method == "direct":
        bound = ck.truncated + DIRECT_ROUNDOFF
    elif plan.method == "gaussians":
        fit = fit_gaussians(a, st, et, ck.tol, exact)
        bound = gaussians_bound(a, st, et, ck, exact)
        if bound > tol:
            warn_caller(BlurAccuracyWarning(
                f"channel {c}: the gaussians fit of this kernel (radius {ck.radius}, "
                f"albedo {ck.rd:.3g}) has L1 error {fit.l1_error:.2e}: error bound "
                f"{bound:.2e} > tol {tol:g}; energy is kept, the shape is not: use "
                f"method='direct' or 'fft' for the exact kernel"))
    else:
        bound = fft_bound(ck, fft_precision)
    if plan.auto is not None and plan.auto.measured_error is not None:
        bound = max(bound, plan.auto.measured_error)
    if bound > tol and plan.method != "gaussians":
        warn_caller(BlurAccuracyWarning(
            f"channel {c}: method {plan.method!r}: error bound {bound:.2e} > tol {tol:g}"))
    return ChannelInfo(c, plan.method, ck.radius, bound, rd=ck.rd, auto=plan.auto)


def blur_whole(e, params, plans, border, exact, kernels):
    """One in-memory image (or band with its halo), its channel plans resolved, on the plan's
    device kernels (``dispatch.BlurKernels``), the constant FFT on the host: (M, BlurInfo)."""
    device = None
    fft_dtypes = {}                    # channel: the constant FFT's precision
    info = []
    for c, (param, plan) in enumerate(zip(params, plans)):
        check_stop()
        ck = plan.kernel
        if plan.method in ("direct", "gaussians") and device is None:
            device = DeviceBlur(e, kernels)
        if plan.method == "direct":
            device.run_direct(c, ck)
        elif plan.method == "gaussians":
            device.run_gaussians(c, fit_gaussians(*param, ck.tol, exact))
        else:
            fft_dtypes[c] = fft_dtype(ck.truncated, plan.asked_tol)
        info.append(planned_info(c, param, plan, exact, fft_dtypes.get(c)))
    out = device.result() if device is not None else np.empty_like(e)
    ranges = {}                        # channel: its irradiance's (min, max)
    others = [c for c in range(len(plans)) if c not in fft_dtypes]
    if others:
        lows, highs = channel_extremes(e)
        ranges.update({c: (float(lows[c]), float(highs[c])) for c in others})
    if fft_dtypes:                     # one batched transform, settled there
        got = []
        fft_blur_channels(e, list(fft_dtypes), [plans[c].kernel for c in fft_dtypes],
                          np.result_type(*fft_dtypes.values()), border, out,
                          tols=[plans[c].asked_tol for c in fft_dtypes], ranges=got)
        ranges.update(zip(fft_dtypes, got))
    for c, plan in enumerate(plans):
        if c not in fft_dtypes:
            settled(out[..., c], e[..., c], plan.kernel.rd, e_range=ranges[c])
        low, high = ranges[c]
        if low < 0 < high:
            info[c] = signed_irradiance_bound(info[c], plan.kernel.truncated, plan.asked_tol)
    return out, BlurInfo(tuple(info))


#: a channel whose peak |E| is below 2^-PEAK_RANGE is blurred scaled to a peak in [0.5, 1):
#: float32 products of E and the weights underflow into subnormals there (a 1e-44 peak's
#: exitance lost every bit: 370x its bound with gaussians). Scaling by a power of two is exact
#: both ways. (Large peaks need none: measured to 3e38, every method within 5e-7 of Rd E.)
PEAK_RANGE = 60
#: float32's absolute floor: half the spacing of its subnormals (2^-149), the error of any
#: exitance rounded to float32 below its normal range (docs/model.md "Blur error bound")
FLOAT32_FLOOR = 2.0 ** -150


def peak_exponents(e, peak=None) -> np.ndarray:
    """Per channel of an HxWxC band, the power of two k its peak |E| (``peak``, where known)
    is 2^k x [0.5, 1) where that is below 2^-PEAK_RANGE, else 0 (a zero channel: 0)."""
    if peak is None:
        peak = channel_peaks(e) if e.size else np.zeros(e.shape[-1])
    _, k = np.frexp(peak)
    far = (peak > 0) & (peak < 2.0 ** -PEAK_RANGE)
    return np.where(far, k, 0).astype(np.int32)


#: the float32 floor's share of a bound warned of even where the bound was above tol without
#: it (a texture-varying bound is tol plus its kernel error: the floor added to it was silent)
FLOOR_WARN_SHARE = 0.1


def lit_floor(rd) -> float:
    """The smallest Rd > 0 of an albedo map (0 where none is lit): the Rd a floor is relative
    to (an unlit texel's exitance is 0 exactly)."""
    rd = np.asarray(rd)
    lit = rd[rd > 0]
    return float(lit.min()) if lit.size else 0.0


def with_output_floor(info: BlurInfo, peaks, rd_floor, tol) -> BlurInfo:
    """``info`` with each channel's bound taking float32's absolute floor relative to its
    peak |E| (``peaks``, per channel) x Rd (``FLOAT32_FLOOR / (max|E| Rd)``: negligible but
    for an exitance below float32's normal range, where no float32 is closer); a bound so
    taken above ``tol``, or whose floor is past FLOOR_WARN_SHARE of tol, is warned of."""
    chans = list(info.channels)
    for c, ch in enumerate(chans):
        scale = peaks[c] * rd_floor[c]
        if scale <= 0:
            continue
        floor = FLOAT32_FLOOR / scale
        bound = ch.error_bound + floor
        if bound > tol and (ch.error_bound <= tol or floor > FLOOR_WARN_SHARE * tol):
            # the words are the same in every band of an image (its peak and bound are the
            # band's): said once, not once a band; BlurInfo has the bound
            warn_caller(BlurAccuracyWarning(
                f"channel {c}: the exitance is below float32's normal range (faint "
                f"irradiance), stored to {2 * FLOAT32_FLOOR:.2g} absolute: the error bound "
                f"relative to max(E) Rd passes tol {tol:g} (BlurInfo.error_bound)"))
        chans[c] = replace(ch, error_bound=bound)
    return replace(info, channels=tuple(chans))
