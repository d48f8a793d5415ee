"""Blur parameters: constants per channel or textures per texel, checked by one rule table.

Physical parameters are ``albedo`` (Rd) and ``mfp`` (ld = 1/mu_tr, in the unit of
``texel_size``), or ``alpha`` (alpha') and ``sigma_t`` (sigma_t', 1/unit), with ``eta`` per
channel (docs/model.md "Mean free path"). Constants give each channel's (alpha', sigma_t' per
texel, eta) in float64 (``channel_parameters``); textures give each texel's Rd and ld in texels
as float32 maps (``texel_parameters``). Both check their values with ``RULES``; textures follow
``on_invalid`` (raise, or clamp into the rule's range).
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np

from ...device.transfer import ALIGNMENT, aligned_empty
from ...methods.registry import not_a_number
from ...errors import (InvalidInputError, check_numbers, check_policy, find_invalid,
                       plain_array)
from ...physics import reference as ref
from ...physics.conversion import RADIUS_RANGE
from ..inversion_kernel import MFP_MIN
from .fft import copy_rows, value_range

#: the physical parameters of ``blur``
PARAM_KEYS = ("albedo", "mfp", "eta", "texel_size", "alpha", "sigma_t")
#: the largest float32 below 1: the top of [0, 1) for the float32 maps the kernels read (the
#: float64 nextafter(1, 0) rounds to 1.0 in float32)
BELOW_ONE_32 = float(np.nextafter(np.float32(1), np.float32(0)))
FLOAT32_MAX = float(np.finfo(np.float32).max)
#: each parameter's valid range: (rule text, test, clamp range). albedo and mfp are checked on
#: their float32 rounding, the values the kernels see; alpha and sigma_t in float64, which is
#: what Rd and ld are computed from
RULES = {
    "albedo": ("[0, 1)", lambda v: (v >= 0) & (v < 1), (0.0, BELOW_ONE_32)),
    "alpha": ("[0, 1)", lambda v: (v >= 0) & (v < 1), (0.0, float(np.nextafter(1.0, 0.0)))),
    "mfp": ("(0, inf)", lambda v: (v > 0) & np.isfinite(v), (1e-20, 1e20)),
    "sigma_t": ("(0, inf)", lambda v: (v > 0) & np.isfinite(v), (1e-20, 1e20)),
}
#: constants must also give a kernel: albedo and alpha' of 0 have no profile to blur with
#: and an mfp the inversion's kernels can take (docs/model.md "Mean free path": below MFP_MIN
#: its coefficients overflow float32, above float32's largest it is inf there)
CONSTANT_RULES = {"albedo": ("(0, 1)", lambda v: (v > 0) & (v < 1)),
                  "alpha": ("[0, 1)", RULES["alpha"][1]),
                  "mfp": (f"[{MFP_MIN:g}, {FLOAT32_MAX:.3g}]",
                          lambda v: (v >= MFP_MIN) & (v <= FLOAT32_MAX)),
                  "sigma_t": RULES["sigma_t"][:2],
                  # convert's radius: every convention's range, as its texels are checked
                  "radius": (f"[{RADIUS_RANGE[0]:g}, {RADIUS_RANGE[1]:g}]",
                             lambda v: (v >= RADIUS_RANGE[0]) & (v <= RADIUS_RANGE[1]))}


def scaled_mfp_problem(mfp, scale) -> str | None:
    """Why a constant mfp times its mfp_scale (each one value or one per channel) leaves the
    range the kernels take (CONSTANT_RULES, as float32), naming the first such pair; else
    None (the CLI's and the scene files' one rule)."""
    rule, valid = CONSTANT_RULES["mfp"]
    mfp, scale = [float(v) for v in np.atleast_1d(mfp)], [float(k) for k in np.atleast_1d(scale)]
    if len(mfp) == 1:                  # one value for every channel of the other
        mfp = mfp * len(scale)
    if len(scale) == 1:
        scale = scale * len(mfp)
    for v, k in zip(mfp, scale):
        with np.errstate(over="ignore", under="ignore"):
            product = float(np.float32(v * k))
        if not valid(product):
            return f"mfp {v:g} x mfp_scale {k:g} = {v * k:g}: expected mfp in {rule} (as float32)"
    return None


#: a sigma_t' per texel below this is an mfp of > ~1e6 texels: a kernel far wider than any
#: max_radius, whose truncation radius no longer computes in float64 (1/sigma_t' overflows)
MIN_SIGMA_T_PER_TEXEL = 1e-6


def parameter_pair(albedo, mfp, alpha, sigma_t) -> str:
    """Which pair is given: "albedo" (albedo and mfp) or "alpha" (alpha and sigma_t)."""
    if alpha is not None or sigma_t is not None:
        if alpha is None or sigma_t is None or albedo is not None or mfp is not None:
            raise ValueError("give either albedo and mfp, or alpha and sigma_t")
        return "alpha"
    if albedo is None or mfp is None:
        raise ValueError("give albedo and mfp (or alpha and sigma_t)")
    return "albedo"


def channel_values(value, nchan, name):
    """One value or one per channel (real numbers: ``errors.check_numbers``), as a (nchan,)
    float64 array checked by CONSTANT_RULES."""
    v = np.atleast_1d(np.asarray(check_numbers(value, name), np.float64))
    if v.ndim > 1:
        raise ValueError(f"{name}: one value or one per channel here; texture-varying "
                         f"parameters go to blur() (bdipole_cl.ops.blur.textured)")
    if v.size not in (1, nchan):
        raise ValueError(f"{name} has {v.size} values for {nchan} channels")
    if name in CONSTANT_RULES:
        rule, ok = CONSTANT_RULES[name]
        if not np.all(ok(v)):
            raise ValueError(f"{name}={v.tolist()}: expected values in {rule}")
    return np.broadcast_to(v, (nchan,))


@lru_cache(maxsize=4096)
def channel_coefficients(rd: float, ld: float, eta: float, exact: bool):
    """(sigma_a, sigma_s') of one channel's constant albedo and mfp (the float64 reference's
    inversion, ~4 ms), kept: the same material is planned again for every image and band."""
    return tuple(float(v) for v in ref.albedo_to_coefficients(rd, ld, eta, exact))


def checked_texel_size(texel_size) -> float:
    """``texel_size`` as a float: one finite number > 0 (a bool, string, sequence, NaN, 0 or
    negative a ValueError naming it), for constant and texture-varying parameters alike."""
    try:
        size = float(texel_size) if not not_a_number(texel_size) else np.nan
    except (TypeError, ValueError):
        size = np.nan
    if not (np.isfinite(size) and size > 0):
        raise ValueError(f"texel_size={texel_size!r} must be one finite number > 0 (the texel's "
                         f"width in the mfp's unit)")
    return size


def channel_parameters(nchan, *, albedo=None, mfp=None, eta=1.4, texel_size=1.0, alpha=None,
                       sigma_t=None, exact=False):
    """Per-channel (alpha', sigma_t' per texel, eta) from albedo + mfp (memo's mapping, float64)
    or directly from alpha' + sigma_t' (per world unit)."""
    etas = channel_values(eta, nchan, "eta")
    if parameter_pair(albedo, mfp, alpha, sigma_t) == "alpha":
        a = channel_values(alpha, nchan, "alpha")
        st = channel_values(sigma_t, nchan, "sigma_t")
    else:
        rd = channel_values(albedo, nchan, "albedo")
        ld = channel_values(mfp, nchan, "mfp")
        sa = np.empty(nchan)
        ss = np.empty(nchan)
        for c in range(nchan):
            sa[c], ss[c] = channel_coefficients(float(rd[c]), float(ld[c]), float(etas[c]),
                                                bool(exact))
        st = sa + ss
        a = ss / st
    texel_size = checked_texel_size(texel_size)
    with np.errstate(over="ignore", under="ignore"):
        per_texel = st * texel_size
    if np.any(per_texel < MIN_SIGMA_T_PER_TEXEL):
        c = int(np.flatnonzero(per_texel < MIN_SIGMA_T_PER_TEXEL)[0])
        raise ValueError(f"channel {c}: sigma_t' of {per_texel[c]:.3g} per texel (texel_size="
                         f"{texel_size!r}): an mfp of over a million texels, whose kernel is "
                         f"far wider than any max_radius; give the mfp and the texel size in "
                         f"one unit")
    if not np.all(np.isfinite(per_texel)):
        c = int(np.flatnonzero(~np.isfinite(per_texel))[0])
        raise ValueError(f"texel_size={texel_size!r}: channel {c}'s sigma_t' {st[c]:g} per unit "
                         f"times the texel size overflows (the texel is more than 1e308 mean "
                         f"free paths wide); use a texel size in the mfp's unit")
    return [(float(a[c]), float(per_texel[c]), float(etas[c])) for c in range(nchan)]


def texture_channel(value, shape, c, name):
    """Channel c of a scalar, per-channel tuple, HxW or HxWxC parameter, as an HxW array (a
    texture keeps its float type: it is checked before it is rounded to float32)."""
    h, w, nch = shape
    v = plain_array(value, name)
    if not np.issubdtype(v.dtype, np.floating):
        v = v.astype(np.float64)
    if v.ndim <= 1:
        v = np.atleast_1d(v)
        if v.size not in (1, nch):
            raise ValueError(f"{name} has {v.size} values for {nch} channels")
        return np.full((h, w), v[c if v.size > 1 else 0])
    if v.ndim == 2:
        v = v[..., None]
    if v.shape[:2] != (h, w) or v.shape[2] not in (1, nch):
        raise ValueError(f"{name} texture has shape {v.shape}; expected ({h}, {w}) or "
                         f"({h}, {w}, {nch}) to match the irradiance")
    return v[..., c if v.shape[2] > 1 else 0]


def add_count(counts, name, n):
    """counts[name] += n (a dict of invalid values clamped, by kind; None: not kept)."""
    if counts is not None and n:
        counts[name] = counts.get(name, 0) + int(n)


def texture_invalid_count(value, shape, name, ok, dtype=None) -> int:
    """The values of a parameter (every channel of a texture) that break the rule ``ok``, as
    the kernels see them (rounded to ``dtype``): what an error counts."""
    v = np.asarray(value)
    n = 0
    for c in range(v.shape[2] if v.ndim == 3 else 1):
        m = texture_channel(value, shape, c, name)
        if dtype is not None:
            with np.errstate(over="ignore"):
                m = m.astype(dtype)
        n += int(np.count_nonzero(~ok(m)))
    return n


def checked_parameter(value, shape, c, name, on_invalid="raise", dtype=None, ranges=None,
                      counts=None):
    """Channel c of a parameter as HxW (rounded to ``dtype`` first, if given: the check sees
    what the kernel will), every texel within ``RULES[name]``: else an InvalidInputError
    naming the count and the first bad texel, or, with ``on_invalid="clamp"``, the bad texels
    (only they) clamped into the range of the channel's valid texels (NaN to its bottom; the
    rule's range if no texel is valid). So a bad texel never widens the range the
    texture-varying plan is built for, and the valid texels' exitance is what it would be
    without it. ``ranges``: a ``MapRanges`` that keeps the (min, max) the check found.
    ``counts``: a dict that gets the clamped values' count under ``name`` (``add_count``)."""
    rule, ok, (lo, hi) = RULES[name]
    v = texture_channel(value, shape, c, name)
    if dtype is not None:
        with np.errstate(over="ignore"):          # an overflow to inf is caught by the rule
            # float32: the aligned map the kernels read (``float32_map``), in one copy
            v = aligned_float32(v) if np.dtype(dtype) == np.float32 else v.astype(dtype)
    extremes = value_range(v)
    if np.all(ok(np.array(extremes))):             # a NaN makes both NaN: fails every rule
        if ranges is not None:
            ranges.keep(v, extremes)
        return v
    bad = ~ok(v)
    try:
        n = find_invalid(name, v, bad, f"outside {rule}", check_policy(on_invalid),
                         texels=True, channel=c)
    except InvalidInputError as exc:            # named in this channel, counted in every one
        raise exc.with_(count=texture_invalid_count(value, shape, name, ok, dtype)) from None
    if n:
        add_count(counts, name, n)
        good = v[~bad]
        lo, hi = (good.min(), good.max()) if good.size else (lo, hi)
        v = np.where(bad, np.clip(np.nan_to_num(v, nan=lo, posinf=hi, neginf=lo), lo, hi),
                     v).astype(v.dtype)
    return v


class MapRanges:
    """The (min, max) of the maps a check has read whole, by map (the same object), so that
    the plan does not read them again (``textured_plan.map_extremes``)."""

    def __init__(self):
        self._kept = {}

    def keep(self, v, extremes):
        self._kept[id(v)] = (v, extremes)

    def of(self, v):
        """(min, max) of map ``v`` (its own reduction where the check did not keep it)."""
        hit = self._kept.get(id(v))
        return hit[1] if hit is not None and hit[0] is v else value_range(v)


def float32_map(v):
    """``v`` as a C-contiguous float32 map on the device-alignment boundary (a CPU runtime
    reads it in place: ``device.transfer``), copied only where it is not one already."""
    v = np.asarray(v)
    if (v.dtype == np.float32 and v.flags.c_contiguous
            and v.ctypes.data % ALIGNMENT == 0):
        return v
    return aligned_float32(v)


def aligned_float32(v):
    """A new float32 copy of ``v`` on the device-alignment boundary."""
    out = aligned_empty(np.size(v), np.float32).reshape(np.shape(v))
    return copy_rows(out, v)                      # float64 -> float32: rounds as astype


def rd_map(rd):
    """A float32 Rd map of Rd < 1 in float64: an Rd within 2^-25 of 1 rounds to 1.0 in float32,
    so it is kept at the largest float32 below 1 (the nearest value the kernels can take)."""
    out = aligned_float32(rd)
    return np.minimum(out, np.float32(BELOW_ONE_32), out=out)


def source_channel(value, c) -> int:
    """The channel of parameter ``value`` (as ``texture_channel`` takes it) that channel c
    reads: 0 where it has one."""
    v = np.asarray(value)
    ones = v.size == 1 if v.ndim <= 1 else v.ndim == 2 or v.shape[2] == 1
    return 0 if ones else c


def texel_parameters(shape, c, *, albedo=None, mfp=None, eta=1.4, texel_size=1.0, alpha=None,
                     sigma_t=None, exact=False, on_invalid="raise", ld_maps=None, ranges=None,
                     counts=None):
    """(Rd, ld in texels) HxW float32 maps of channel c, from albedo + mfp or alpha' + sigma_t'
    (the node coordinates, ``texel_coords``, are computed from these same float32 values).
    ``ld_maps``: a dict of the ld maps made so far by mfp channel, so that channels that read
    one mfp channel share its map (made and checked once). ``ranges``: a ``MapRanges`` that
    keeps the extremes the checks found; ``counts``, a dict, the values clamped by kind (a map
    that several channels share counted once)."""
    texel_size = checked_texel_size(texel_size)

    def own(value):                     # counted where the channel reads its own values
        return counts if source_channel(value, c) == c else None
    if parameter_pair(albedo, mfp, alpha, sigma_t) == "alpha":
        a = checked_parameter(alpha, shape, c, "alpha", on_invalid,
                              counts=own(alpha)).astype(np.float64)
        st = checked_parameter(sigma_t, shape, c, "sigma_t", on_invalid,
                               counts=own(sigma_t)).astype(np.float64)
        with np.errstate(over="ignore", divide="ignore"):
            ld = 1.0 / (st * texel_size * ref.mu_tr_over_sigma_t(1.0 - a))
        return rd_map(ref.rd(a, eta, exact)), float32_map(ld_in_float32(ld, c))
    rd = float32_map(checked_parameter(albedo, shape, c, "albedo", on_invalid, np.float32,
                                       ranges, own(albedo)))
    source = source_channel(mfp, c)
    if ld_maps is not None and source in ld_maps:
        return rd, ld_maps[source]
    if texel_size != 1.0:               # ld in texels, checked as the kernel sees it
        mfp = texture_channel(mfp, shape, c, "mfp") / texel_size
    ld = float32_map(checked_parameter(mfp, shape, c, "mfp", on_invalid, np.float32, ranges,
                                       counts))
    if ld_maps is not None:
        ld_maps[source] = ld
    return rd, ld


def ld_in_float32(ld, c):
    """An ld map (texels, float64) from alpha' and sigma_t' maps as the float32 the kernels
    read: below float32's smallest normal it is that (the kernel is one texel all the same: a
    sigma_t' of 1e300 would round ld to 0), above float32's largest a ValueError naming the
    channel's first such texel (sigma_t' too small for any kernel)."""
    tiny = float(np.finfo(np.float32).tiny)
    ld = np.maximum(ld, tiny)
    wide = ~(ld <= FLOAT32_MAX)
    if wide.any():
        y, x = np.unravel_index(int(np.flatnonzero(wide)[0]), ld.shape)
        raise ValueError(f"sigma_t at x={x}, y={y}, channel {c}: a diffusion length of "
                         f"{ld[y, x]:.3g} texels, beyond float32 (sigma_t' times the texel size "
                         f"is too small for any kernel): give sigma_t and texel_size in one unit")
    return ld


def irradiance_array(irradiance) -> np.ndarray:
    """The irradiance as an HxWxC NumPy array (its values unchecked), else a ValueError naming
    what is wrong with its shape or kind."""
    e = plain_array(irradiance, "irradiance")
    if e.ndim == 2:
        e = e[..., None]
    if e.ndim != 3:
        raise ValueError(f"irradiance must be HxW or HxWxC, got shape {e.shape}")
    if 0 in e.shape:
        raise ValueError(f"irradiance is empty (shape {e.shape}: no texels or no channels): "
                         f"nothing to blur")
    return e


def irradiance_shape(irradiance) -> tuple:
    """The (H, W, C) of an irradiance (``irradiance_array``'s checks, no pass over its
    values)."""
    return irradiance_array(irradiance).shape


def checked_irradiance(irradiance, on_invalid="raise", counts=None):
    """Irradiance as HxWxC float32. NaN and infinite texels are invalid: an InvalidInputError
    naming the first, or with ``on_invalid="clamp"`` unlit (0): irradiance has no upper bound
    to clamp to, and an unlit texel neither adds nor removes light that is really there.
    ``counts``: a dict that gets the clamped values' count under "irradiance"."""
    e = float32_irradiance(irradiance_array(irradiance), on_invalid, counts)
    check_policy(on_invalid)
    if all_finite(e):
        return e
    bad = ~np.isfinite(e)
    n = find_invalid("irradiance", e, bad, "NaN or infinite", on_invalid, texels=True)
    if n:
        add_count(counts, "irradiance", n)
        e = np.where(bad, np.float32(0), e)
    return e


def float32_irradiance(e, on_invalid, counts=None):
    """``e`` as contiguous float32. A wider float's finite value beyond float32's range (a
    1e39 highlight) is invalid as such (it would read as infinite): named, or with
    ``on_invalid="clamp"`` clamped to float32's largest, keeping its light."""
    e = np.asarray(e)
    if e.dtype.kind == "f" and e.dtype.itemsize > 4:
        with np.errstate(invalid="ignore"):
            beyond = np.isfinite(e) & (np.abs(e) > FLOAT32_MAX)
        n = find_invalid("irradiance", e, beyond, f"finite but beyond float32's range "
                         f"({FLOAT32_MAX:.3g})", on_invalid, texels=True) if beyond.any() else 0
        if n:
            add_count(counts, "irradiance", n)
            e = np.where(beyond, np.clip(e, -FLOAT32_MAX, FLOAT32_MAX), e)
    with np.errstate(over="ignore"):
        return np.ascontiguousarray(e, dtype=np.float32)


def all_finite(a) -> bool:
    """True only if every value of float array ``a`` is finite, by one reduction: a NaN or
    infinity makes the sum NaN or infinite. A sum that overflows (HDR values near the float32
    limit) answers False too: then the caller tests texel by texel, so False is only "not
    known"."""
    with np.errstate(over="ignore", invalid="ignore"):
        return bool(np.isfinite(np.add.reduce(a, axis=None)))
