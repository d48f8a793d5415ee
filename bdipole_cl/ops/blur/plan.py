"""The blur's typed plan: made once from the resolved scattering parameters, applied to an
image or to bands of rows (``blur`` is ``plan_blur(...).apply(...)``).

A ``BlurPlan`` holds, per channel, what was chosen and why (constant parameters: the method,
its exact truncated kernel and the ``auto`` record, ``planning.ChannelPlan``; texture-varying
parameters: the lattice, basis and node weights, ``textured_plan.TexturedPlan``, with the
channel's Rd and ld maps), the halo a band needs (the largest kernel radius), and the device
kernels and weight buffers it runs with, built on first use and kept (``dispatch.BlurKernels``).
The file blur, Dask and scenes make one plan per image and apply it to every band.
"""
from __future__ import annotations

import operator
from dataclasses import dataclass, field, replace

import numpy as np
import pyopencl.array as cla

from ...device import Runtime, get_runtime
from ...device.transfer import is_device_array
from ...errors import check_policy
from ...methods.registry import BLUR_METHOD, BORDER
from ..bands import band_rows, bands, gather_rows
from ..widths import fft_engine
from .dispatch import BlurKernels, gather_costs
from .fft import channel_peaks
from .params import checked_irradiance, irradiance_shape
from .planning import (BlurInfo, blur_whole, channel_plans, constant_row_bytes, halo_of,
                       lit_floor, peak_exponents, signed_irradiance_bound, with_output_floor,
                       worse)
from .textured import blur_band, textured_info, textured_method, textured_plans, textured_row_bytes
from .whole_device import apply_band_on_device, apply_on_device


#: ``blur``'s keyword of each Scattering field (``alpha`` is alpha', the API's older name)
KEYWORDS = {"albedo": "albedo", "mfp": "mfp", "eta": "eta", "texel_size": "texel_size",
            "alpha_prime": "alpha", "sigma_t": "sigma_t"}


@dataclass(frozen=True)
class Scattering:
    """The blur's physical parameters: albedo (Rd) and mfp (ld = 1/mu_tr, in the unit of
    ``texel_size``), or alpha_prime (alpha', the reduced albedo; never the image's alpha
    channel) and sigma_t (sigma_t', 1/unit); each a scalar, one value per channel, or an
    HxW(xC) texture; eta per channel (docs/model.md "Mean free path")."""

    albedo: object = None
    mfp: object = None
    eta: object = 1.4
    texel_size: float = 1.0
    alpha_prime: object = None
    sigma_t: object = None
    stretch: object = None     # per-texel texel lengths (``stretched.as_stretch``): replaces
    #                            texel_size; the blur in surface distance (docs/stretch.md)

    @property
    def textured(self) -> bool:
        """Whether a parameter is a texture (2D or more) rather than one value per channel."""
        return self.stretch is not None or any(np.ndim(v) >= 2 for v in self.keywords().values()
                                               if v is not None)

    def keywords(self) -> dict:
        """The parameters as ``params.channel_parameters`` and ``texel_parameters`` take them."""
        return {key: getattr(self, name) for name, key in KEYWORDS.items()}

    @classmethod
    def split(cls, keywords: dict):
        """(Scattering, the other keywords) of ``blur``-style keywords."""
        rest = dict(keywords)
        given = {name: rest.pop(key) for name, key in KEYWORDS.items() if key in rest}
        return cls(**given), rest

    def on_host(self) -> "Scattering":
        """These parameters with every device array brought to the host: a texture-varying
        plan is made from its maps' ranges and per-texel Rd and ld maps there, once per plan
        (the irradiance and the exitance stay on the device)."""
        return replace(self, **{f: getattr(self, f).get() for f in KEYWORDS
                                if is_device_array(getattr(self, f))})

    def header(self) -> dict:
        """The given parameters for an output's ``bdipole:*`` attributes ("texture" for maps)."""
        head = {key: (v if np.ndim(v) < 2 else "texture") for key, v in self.keywords().items()
                if v is not None}
        if self.stretch is not None:
            head["texel_size"] = "stretch map"
            if getattr(self.stretch, "unit", ""):
                head["stretch_unit"] = self.stretch.unit
        return head


@dataclass(eq=False)
class BlurPlan:
    """One image's blur, decided once (``plan_blur``): apply it to the image or to bands. Its
    device (runtime, kernels and uploaded weights) is bound on first use and not pickled: a
    plan sent to another process binds that process's device (``runtime=None``: the default,
    or ``on(device)``)."""

    scattering: Scattering
    shape: tuple                       # (H, W, C) of the irradiance it was planned for
    tol: float
    method: str
    border: str
    exact: bool
    on_invalid: str
    halo: int                          # rows a band needs above and below
    params: tuple = ()                 # constant: (alpha', sigma_t' per texel, eta) per channel
    channels: tuple = ()               # constant: planning.ChannelPlan per channel
    textured: tuple = ()               # texture-varying: (TexturedPlan, Rd map, ld map)
    textured_info: BlurInfo | None = None   # texture-varying: what each channel does
    invalid: dict = field(default_factory=dict)   # parameter values clamped, by kind
    runtime: Runtime | None = field(default=None, compare=False, repr=False)
    kernels: BlurKernels | None = field(default=None, compare=False, repr=False)

    @property
    def nchan(self) -> int:
        return self.shape[2]

    def row_bytes(self) -> int:
        """Working set per image row (``bands.band_rows`` takes it)."""
        h, w, nch = self.shape
        if self.textured:
            nbasis = max(len(ch.plan.kernels) for ch in self.textured)
            return textured_row_bytes(w, nch, self.halo, nbasis)
        return constant_row_bytes(w, nch)

    def __getstate__(self):
        return {**self.__dict__, "runtime": None, "kernels": None}

    def on(self, device=None) -> BlurPlan:
        """This plan on ``device``'s runtime: itself if it is there (or unbound, then bound
        there), else a copy (its kernels built there on first use)."""
        rt = get_runtime(device)
        if self.runtime is None and self.kernels is None:
            self.runtime = rt
        if self.runtime is rt:
            return self
        return replace(self, runtime=rt, kernels=None)

    def bound_kernels(self) -> BlurKernels:
        """The plan's device kernels, bound on first use (to ``runtime``, None: the default)."""
        if self.kernels is None:
            self.runtime = get_runtime(self.runtime)
            self.kernels = BlurKernels(self.runtime, self.border)
        return self.kernels

    def apply_band(self, e, rows=None, peaks=None):
        """One in-memory image or band of rows with its halo (HxWxC float32, checked): (M,
        BlurInfo) over the whole of it. ``rows``: texture-varying parameters: the rows of the
        parameter maps the band covers (``bands.halo_rows``; None: all). A channel whose peak
        is far from 1 is blurred at a peak in [0.5, 1) (``peak_exponents``) and scaled back,
        its bound taking float32's absolute floor (``with_output_floor``) relative to
        ``peaks`` (per channel max|E| of the image the band is of; None: the band's own, which
        is at most the image's: a larger bound, still one). On the device end to end where the
        plan runs there (``runs_on_device``)."""
        if self.runs_on_device():
            done = apply_band_on_device(self, e, rows)
            if done is not None:
                return done
        shifts = peak_exponents(e)
        if not shifts.any():
            return self._apply_band(e, rows)
        out, info = self._apply_band(np.ldexp(e, -shifts), rows)
        out = np.ldexp(out, shifts)          # one rounding, where the result is subnormal
        return out, with_output_floor(info, channel_peaks(e) if peaks is None else peaks,
                                      self.channel_rd_floor(), self.tol)

    def runs_on_device(self) -> bool:
        """Whether the blur runs on the device end to end (``whole_device``,
        ``textured_device``): every constant channel's method there, the FFT's where its engine
        is the device (``widths.fft_engine``, by measurement on the device); texture-varying
        parameters where that engine is the device."""
        if self.textured:                # the basis blurs: transforms, or the separable kernels
            return fft_engine(self.bound_kernels().rt) == "device"
        return (not any(p.method == "fft" for p in self.channels)
                or fft_engine(self.bound_kernels().rt) == "device")

    def channel_rd_floor(self) -> list:
        """Per channel the smallest Rd its exitance is relative to: the constant channel's,
        a texture-varying channel's smallest texel's."""
        if self.textured:                   # unlit texels' exitance is 0 exactly
            return [lit_floor(ch[1]) for ch in self.textured]
        return [p.kernel.rd for p in self.channels]

    def _apply_band(self, e, rows=None):
        kernels = self.bound_kernels()
        if self.textured:
            rows = slice(0, self.shape[0]) if rows is None else np.maximum(rows, 0)
            ranges = []
            out = blur_band(e, self.textured, rows, textured_method(self.method), self.border,
                            kernels, ranges)
            chans = list(self.textured_info.channels)
            for c, (low, high) in enumerate(ranges):
                if low < 0 < high:
                    chans[c] = signed_irradiance_bound(chans[c],
                                                       self.textured[c].plan.truncation_tol,
                                                       self.tol)
            return out, BlurInfo(tuple(chans))
        return blur_whole(e, self.params, self.channels, self.border, self.exact, kernels)

    def apply(self, irradiance, max_memory=None):
        """The whole image (HxW or HxWxC), in bands of rows within ``max_memory`` bytes if
        given (each band carries the halo, so the result is the one-piece result up to the
        float32 FFT's round-off, whose transform sizes differ by band): (M, BlurInfo), M of
        the irradiance's shape; the BlurInfo counts the irradiance values and (from planning)
        the parameter values clamped."""
        counts = dict(self.invalid)
        on_device_array = is_device_array(irradiance)
        if on_device_array or self.runs_on_device():
            self._check_shape(irradiance.shape if on_device_array
                              else irradiance_shape(irradiance))
            done = (apply_on_device(self, irradiance, max_memory, counts)
                    if self.runs_on_device() else None)
            if done is not None:
                return done[0], replace(done[1], invalid=counts)
            counts = dict(self.invalid)                  # the host's check counts again
        host = irradiance.get() if on_device_array else irradiance
        out, info = self.apply_checked(checked_irradiance(host, self.on_invalid, counts),
                                       max_memory)
        out = as_given(out, host)
        if on_device_array:                              # returned where it was given
            out = cla.to_device(irradiance.queue or self.bound_kernels().rt.queue, out)
        return out, replace(info, invalid=counts)

    def _check_shape(self, shape):
        if checked_shape(shape) != tuple(self.shape):
            raise ValueError(f"irradiance has shape {tuple(shape)}; the plan is for "
                             f"{self.shape}")

    def apply_checked(self, e, max_memory=None):
        """``apply`` of an irradiance ``params.checked_irradiance`` has already checked."""
        if e.shape != tuple(self.shape):
            raise ValueError(f"irradiance has shape {e.shape}; the plan is for {self.shape}")
        h = e.shape[0]
        rows = band_rows(h, self.row_bytes(), max_memory, halo=self.halo)
        if rows >= h:
            return self.apply_band(e)
        out = np.empty_like(e)
        info, peaks = None, channel_peaks(e)     # a band's floor is relative to the image's
        for y0, y1, idx in bands(h, rows, self.halo, self.border):
            res, band_info = self.apply_band(gather_rows(e, idx), idx, peaks)
            info = worse(info, band_info)
            out[y0:y1] = res[self.halo:self.halo + (y1 - y0)]
        return out, info


def as_given(out, irradiance):
    """The HxWxC exitance ``out`` in the shape of the irradiance given: HxW for HxW."""
    return out[..., 0] if np.ndim(irradiance) == 2 else out


def checked_shape(shape) -> tuple:
    """An irradiance shape as (H, W, C): HxW or HxWxC of positive integers, else a ValueError
    naming it."""
    try:
        dims = tuple(operator.index(n) for n in shape)
    except TypeError:
        dims = ()
    if len(dims) not in (2, 3) or min(dims) < 1:
        raise ValueError(f"shape {tuple(shape) if np.iterable(shape) else shape!r}: expected "
                         f"(height, width) or (height, width, channels), each >= 1")
    return dims if len(dims) == 3 else (*dims, 1)


def stretched_blur_plan(shape, scattering, tol, method, border, exact, on_invalid, device,
                        charts):
    """``plan_blur``'s stretched plan: method fft or auto only (its basis is eigen-kernels)."""
    from .stretched import plan_stretched
    if method not in ("auto", "fft"):
        raise ValueError(f"method={method!r}: the stretched blur runs fft (or auto)")
    if np.any(np.asarray(scattering.texel_size) != 1.0):
        raise ValueError(f"texel_size={scattering.texel_size!r} with stretch=: the stretch "
                         f"maps give each texel's lengths (in the mfp's unit); leave "
                         f"texel_size out")
    return plan_stretched(shape, scattering, scattering.stretch, tol=tol, border=border,
                          charts=charts, exact=exact, on_invalid=on_invalid, device=device)


def check_blur_options(method, tol, border, on_invalid):
    """ValueError naming the option and its choices unless each is one of its registry's."""
    BLUR_METHOD[method], BORDER[border]
    if not 0 < tol < 1:
        raise ValueError(f"tol={tol!r}: expected 0 < tol < 1")
    check_policy(on_invalid)


def plan_blur(shape, scattering: Scattering, *, tol=1e-3, method="auto", border="clamp",
              exact=False, on_invalid="raise", device=None, charts="clamp") -> BlurPlan:
    """The BlurPlan of an irradiance of ``shape`` (HxW or HxWxC) under ``scattering``: each
    channel's method and kernel decided here, once (``auto`` for ``device``'s runtime). With
    ``scattering.stretch``, the stretched blur's plan (``stretched.plan_stretched``; chart
    borders by ``charts``)."""
    check_blur_options(method, tol, border, on_invalid)
    shape = checked_shape(shape)
    scattering = scattering.on_host()
    if scattering.stretch is not None:
        return stretched_blur_plan(shape, scattering, tol, method, border, exact, on_invalid,
                                   device, charts)
    rt = get_runtime(device)
    base = BlurPlan(scattering, shape, tol, method, border, exact, on_invalid, 0, runtime=rt)
    if scattering.textured:
        counts = {}
        chans = textured_plans(shape, tol=tol, exact=exact, on_invalid=on_invalid,
                               method=method, costs=gather_costs(rt), counts=counts,
                               **scattering.keywords())
        plan = replace(base, textured=tuple(chans), halo=max(ch.plan.radius for ch in chans),
                       textured_info=textured_info(chans, textured_method(method), exact),
                       invalid=counts)
    else:
        params, plans = channel_plans(shape[2], method=method, tol=tol, exact=exact,
                                      device=rt, **scattering.keywords())
        plan = replace(base, params=tuple(params), channels=tuple(plans), halo=halo_of(plans))
    return plan                        # on the device ``auto`` decided for
