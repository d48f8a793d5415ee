"""Albedo inversion on an OpenCL device: Rd -> alpha', rho and (with a mean free path)
sigma_a, sigma_s' (the kernels: ``bdipole_cl.ops.inversion_kernel``). The methods and their
knobs are in ``bdipole_cl.methods.registry``; ``method="auto"`` is resolved by
``bdipole_cl.methods.choice``.
"""
from __future__ import annotations

import numpy as np

from ..device import get_runtime
from ..errors import check_policy, find_invalid
from ..methods.choice import DeviceKey, resolve_method
from ..methods.registry import MFP_KIND, OUTPUTS, MethodConfig
from .inversion_kernel import (CHECK_ALBEDO, CHECK_COEFFICIENTS, InversionKernel,
                               inversion_kernel, output_array)


#: largest float32 below 1: where ``on_invalid="clamp"`` puts Rd >= 1 for coefficients.
RD_CLAMP_MAX = float(np.nextafter(np.float32(1.0), np.float32(0.0)))


#: where ``on_invalid="clamp"`` puts mfp values that are NaN, <= 0 or infinite.
MFP_CLAMP_RANGE = (1e-20, 1e20)


def channel_etas(eta, shape):
    """Etas per channel: one eta (also when all are equal), or one per channel along the last
    axis of ``shape``."""
    etas = np.atleast_1d(np.asarray(eta, dtype=np.float64))
    if etas.ndim != 1:
        raise ValueError(f"eta must be a scalar or one value per channel, got shape {etas.shape}")
    if etas.size == 1 or np.all(etas == etas[0]):
        return (float(etas[0]),)
    if len(shape) == 0 or shape[-1] != etas.size:
        raise ValueError(f"eta has {etas.size} values but the input's last axis has "
                         f"{shape[-1] if shape else 'no'} channels")
    return tuple(float(e) for e in etas)


def _checked_albedo(rd, on_invalid):
    """``rd`` with invert_albedo's rule applied: NaN, infinite or > 1 raise (count, first
    index) or, with "clamp", NaN and -inf become 0 and > 1 becomes 1."""
    bad = ~(rd <= 1.0) | np.isinf(rd)
    if find_invalid("albedo", rd, bad, "NaN, infinite or > 1", on_invalid):
        rd = np.where(np.isnan(rd) | np.isneginf(rd), 0.0, np.minimum(rd, 1.0))
    return rd


def invert_albedo(rd, eta, method="table", *, return_rho=False, model="better", exact=False,
                  double=False, on_invalid="raise", iterations=None, tol=None, table_size=None,
                  polish=None, seed_size=None, device=None, out=None):
    """Invert memo eq. 3 on the device: reduced albedo alpha' (and rho = 1 - alpha') of ``rd``.

    Parameters
    ----------
    rd : array_like, any shape, float32 or float64
        Diffuse reflectance ("albedo"), linear. Rd <= 0 gives alpha' = 0, Rd = 1 gives 1.
    eta : float or sequence of float
        Relative index of refraction; one per channel (the last axis of ``rd``) allowed.
    method : {"table", "secant", "bisection", "memo", "auto"} or MethodConfig
        See the module docstring; knobs ``iterations``, ``tol``, ``table_size``, ``polish``,
        ``seed_size`` (None keeps each method's default). ``"auto"`` picks the cheapest
        measured configuration whose max relative rho error is <= ``tol`` (see
        ``resolve_method``).
    return_rho : bool
        Also return rho = 1 - alpha', computed without cancellation (use it, not 1 - alpha').
    model : {"better", "dipole"}
        Better Dipole (memo) or Jensen's classical dipole.
    exact : bool
        Exact Fresnel moments by quadrature instead of d'Eon's fits (wider eta range).
    double : bool
        Compute in float64 on the device (needs cl_khr_fp64).
    on_invalid : {"raise", "clamp"}
        Rd that is NaN, infinite or > 1: raise InvalidInputError (count, first index), or clamp
        (NaN and -inf -> 0, > 1 -> 1).
    device : None, str, pyopencl.Device or Runtime
        Where to run (``bdipole_cl.device``): None is the automatic choice.
    out : ndarray or (ndarray, ndarray), optional
        Where to write alpha' (with ``return_rho``: alpha' and rho): C-contiguous, writeable,
        ``rd``'s size, float32 (float64 with ``double``); returned, reshaped to ``rd``'s shape.
        On a CPU device the kernel writes into them directly (no copies, no allocations).

    Returns
    -------
    alpha or (alpha, rho) : ndarray, shape of ``rd``, float32 (float64 with ``double``)

    Notes
    -----
    Host arrays are handed to the device without copies where it shares host memory
    (``bdipole_cl.device.transfer``). float32 input is tested for invalid values by the kernel
    itself as it reads them; the host looks for the first invalid value only when one was seen.
    """
    rt = get_runtime(device)
    config = resolve_method(method, double=double, device_key=DeviceKey.of(rt.device),
                            iterations=iterations, tol=tol, table_size=table_size,
                            polish=polish, seed_size=seed_size)
    rd = np.asarray(rd)
    if rd.dtype.kind != "f":
        rd = rd.astype(np.float64)
    etas = channel_etas(eta, rd.shape)
    check_policy(on_invalid)
    kernel = inversion_kernel(etas, config, exact=exact, model=model, double=double,
                              runtime=rt)
    in_kernel = kernel.checks_inputs(rd)
    if not in_kernel:
        rd = _checked_albedo(rd, on_invalid)
    want = ("alpha", "rho") if return_rho else ("alpha",)
    if out is not None:
        out = dict(zip(want, (out,) if isinstance(out, np.ndarray) else tuple(out)))
    outs, flagged = kernel.run_checked(rd, None, want, out=out,
                                       check=CHECK_ALBEDO if in_kernel else 0)
    if flagged:
        # the first invalid value named (raise); with "clamp" the kernel's results already are
        # those of the clamped input: NaN, -inf -> (0, 1) as Rd = 0, > 1 -> (1, 0) as Rd = 1
        _checked_albedo(rd, on_invalid)
    alpha = outs["alpha"].reshape(rd.shape)
    return (alpha, outs["rho"].reshape(rd.shape)) if return_rho else alpha


def check_outputs(outputs):
    """``outputs`` as a tuple: some of OUTPUTS, each at most once (a channel is written once),
    else ValueError."""
    outputs = tuple(outputs)
    unknown = [o for o in outputs if o not in OUTPUTS]
    if not outputs or unknown:
        raise ValueError(f"unknown outputs {unknown or 'none'}: expected some of {OUTPUTS}")
    twice = sorted({o for o in outputs if outputs.count(o) > 1})
    if twice:
        raise ValueError(f"outputs {', '.join(twice)} given more than once: each output is one "
                         f"set of channels")
    return outputs


def check_mfp_kind(mfp_kind):
    return MFP_KIND.canonical(mfp_kind)


def kernel_outputs(outputs, mfp_kind):
    """What the kernel computes for ``outputs``: with an extinction mfp the coefficients are
    alpha' and rho over the mfp (the host divides), so the kernel gives alpha' and rho."""
    wanted = set(outputs)
    if "sigma_t" in wanted:
        wanted |= {"sigma_a", "sigma_s"}
    if mfp_kind == "extinction":
        wanted |= {"rho"} if "sigma_a" in wanted else set()
        wanted |= {"alpha"} if "sigma_s" in wanted else set()
        wanted -= {"sigma_a", "sigma_s"}
    return tuple(k for k in ("alpha", "rho", "sigma_a", "sigma_s") if k in wanted)


def extinction_coefficients(outs, mfp, outputs, out=None):
    """sigma_a = rho / mfp and sigma_s' = alpha' / mfp (sigma_t' = 1/mfp, docs/model.md
    "Mean free path"), added to ``outs`` in its precision (into ``out``'s arrays if given)."""
    wanted = set(outputs) | ({"sigma_a", "sigma_s"} if "sigma_t" in outputs else set())
    for sigma, base in (("sigma_a", "rho"), ("sigma_s", "alpha")):
        if sigma in wanted:
            dtype = outs[base].dtype
            outs[sigma] = np.divide(outs[base], mfp.astype(dtype, copy=False),
                                    out=output_array(out, sigma, mfp.size, dtype))


def as_kernel_dtype(values, dtype):
    """``values`` rounded to the kernel's precision: what it will see, and so what is checked
    (a float64 Rd = 1 - 1e-8 < 1 is 1.0 in float32; an mfp of 1e-50 is 0)."""
    with np.errstate(over="ignore", under="ignore"):
        return np.asarray(values).astype(dtype, copy=False)


def _sanitize_albedo_for_coefficients(rd, on_invalid, dtype=np.float32):
    given, rd = rd, as_kernel_dtype(rd, dtype)
    n = find_invalid("albedo", given, ~(rd < 1.0) | np.isneginf(rd),
                     f"NaN, infinite or >= 1 as {np.dtype(dtype).name}", on_invalid)
    if n:
        rd = np.where(np.isnan(rd) | np.isneginf(rd), 0.0,
                      np.minimum(rd, RD_CLAMP_MAX)).astype(dtype)
    return rd, n


def _sanitize_mfp(mfp, on_invalid, dtype=np.float32):
    given, mfp = mfp, as_kernel_dtype(mfp, dtype)
    n = find_invalid("mfp", given, ~((mfp > 0.0) & np.isfinite(mfp)),
                     f"NaN, <= 0 or infinite as {np.dtype(dtype).name}", on_invalid)
    if n:
        lo, hi = MFP_CLAMP_RANGE
        mfp = np.clip(np.nan_to_num(mfp, nan=hi, posinf=hi, neginf=lo), lo, hi).astype(dtype)
    return mfp, n


class CoefficientMapper:
    """(albedo, mfp) arrays -> the requested outputs, with one prepared kernel; the engine of
    ``albedo_to_coefficients`` and of the texture pipeline (called once per band).

    ``bake``: a kernel specialised for this job (``InversionKernel``), with ``mfp_const`` (a
    constant mfp per channel, valid) compiled in when given. ``mfp_kind``: what the mfp is
    (``MFP_KINDS``)."""

    def __init__(self, etas, config: MethodConfig, *, outputs=("sigma_a", "sigma_s"),
                 model="better", exact=False, double=False, on_invalid="raise", device=None,
                 bake=False, mfp_const=None, mfp_kind="diffuse"):
        self.outputs = check_outputs(outputs)
        self.on_invalid = check_policy(on_invalid)
        self.extinction = check_mfp_kind(mfp_kind) == "extinction"
        self.kernel_wants = kernel_outputs(outputs, mfp_kind)
        if mfp_const is not None:
            _sanitize_mfp(np.asarray(mfp_const, np.float64), "raise",   # baked: must be valid
                          np.float64 if double else np.float32)
        mfp_const = None if self.extinction else mfp_const
        self.kernel = (InversionKernel(etas, config, exact=exact, model=model, double=double,
                                       runtime=device, bake=True, mfp_const=mfp_const,
                                       outputs=self.kernel_wants) if bake else
                       inversion_kernel(etas, config, exact=exact, model=model, double=double,
                                        runtime=device))

    def __call__(self, rd, mfp, mask=None, out=None):
        """Returns ({output: array of rd's broadcast shape}, {"albedo": n, "mfp": n} invalid).

        ``mask`` (broadcast against ``rd``): texels where it is 0 are left out, neither
        validated nor inverted, and come out as 0. ``out``: {output: array} to write into (as
        ``InversionKernel.run``)."""
        rd, mfp = np.broadcast_arrays(np.asarray(rd), np.asarray(mfp))
        keep = None if mask is None else np.broadcast_to(np.asarray(mask) > 0, rd.shape)
        if keep is not None:
            if not keep.any():                 # nothing to invert: no device call at all
                zeros = np.zeros(rd.shape, self.kernel.dtype)
                return {k: zeros for k in self.outputs}, {"albedo": 0, "mfp": 0}
            rd = np.where(keep, rd, 0.0).astype(rd.dtype, copy=False)
            mfp = np.where(keep, mfp, 1.0).astype(mfp.dtype, copy=False)
        out = {} if out is None else dict(out)
        outs, n_rd, n_mfp, mfp = self._coefficients(rd, mfp, out)
        if self.extinction:
            extinction_coefficients(outs, mfp.reshape(-1), self.outputs, out)
        if keep is not None:
            flat = keep.reshape(-1)
            for k in outs:
                outs[k][~flat] = 0
        if "sigma_t" in self.outputs:
            outs["sigma_t"] = np.add(outs["sigma_a"], outs["sigma_s"],
                                     out=output_array(out, "sigma_t", rd.size, self.kernel.dtype))
        return ({k: outs[k].reshape(rd.shape) for k in self.outputs},
                {"albedo": n_rd, "mfp": n_mfp})


    def _coefficients(self, rd, mfp, out):
        """The kernel's outputs (1-D), the invalid albedo and mfp counts, and the mfp (checked,
        for the host's share of the work: an extinction mfp's division). An mfp constant
        per channel goes to the kernel as one value per channel (no per-texel mfp array), and
        float32 inputs are tested by the kernel as it reads them: the host looks at them again
        only when it saw an invalid one."""
        k = self.kernel
        reads_mfp = not (k.mfp_baked or self.extinction)
        per_channel = channel_values(mfp, k.nchan) if reads_mfp and k.width else None
        as_kernel = None if per_channel is None else as_kernel_dtype(per_channel, k.dtype)
        if as_kernel is not None and not np.all((as_kernel > 0) & np.isfinite(as_kernel)):
            per_channel = None            # the texels named (or clamped) one by one, below
        n_mfp, host_mfp = 0, mfp
        if not reads_mfp:                 # compiled in, or divided by on the host: checked here
            host_mfp, n_mfp = _sanitize_mfp(mfp, self.on_invalid, k.dtype)
        if per_channel is not None or not reads_mfp:
            mfp = None
        in_kernel = k.checks_inputs(rd, *([] if mfp is None else [mfp]))
        n_rd = 0
        if not in_kernel:
            rd, n_rd = _sanitize_albedo_for_coefficients(rd, self.on_invalid, k.dtype)
            if mfp is not None:
                mfp, n_mfp = _sanitize_mfp(mfp, self.on_invalid, k.dtype)
        outs, flagged = k.run_checked(rd, mfp, self.kernel_wants, mfp_channels=per_channel,
                                      check=CHECK_COEFFICIENTS if in_kernel else 0, out=out)
        if flagged:     # name the first (raise), or clamp and map again (rare)
            rd, n_rd = _sanitize_albedo_for_coefficients(rd, self.on_invalid, k.dtype)
            if mfp is not None:
                mfp, n_mfp = _sanitize_mfp(mfp, self.on_invalid, k.dtype)
            outs = k.run(rd, mfp, self.kernel_wants, mfp_channels=per_channel, out=out)
        return outs, n_rd, n_mfp, host_mfp if mfp is None else mfp


def channel_values(values, nchan):
    """``values`` (broadcast to the input's shape) as one float per channel when it holds no
    more than that (a scalar or a per-channel tuple broadcast: zero strides), else None."""
    v = np.asarray(values)
    if v.ndim == 0 or all(st == 0 for st in v.strides):
        return np.full(nchan, v.reshape(-1)[0] if v.size else 0.0, np.float64)
    if any(st != 0 for st in v.strides[:-1]) or v.shape[-1] != nchan:
        return None
    return np.array(v[(0,) * (v.ndim - 1)], np.float64)


def albedo_to_coefficients(rd, mfp, eta, method="table", *, model="better", exact=False,
                           double=False, on_invalid="raise", outputs=("sigma_a", "sigma_s"),
                           mfp_kind="diffuse", device=None, out=None, **knobs):
    """The memo's drop-in mapping: (albedo Rd, mean free path ld, eta) -> (sigma_a, sigma_s').

    ``mfp_kind="diffuse"`` (default): ``mfp = ld = 1/mu_tr`` (Jensen/Hery skin convention,
    docs/model.md "Mean free path"):
    ``sigma_t' = 1/(ld * mu_tr/sigma_t')`` with ``mu_tr/sigma_t' = sqrt(3 rho/(1 + rho))``
    (``sqrt(3 rho)`` for ``model="dipole"``),
    ``sigma_a = sigma_t' rho``, ``sigma_s' = sigma_t' alpha'``, in 1/(unit of mfp).
    ``mfp_kind="extinction"``: mfp is the medium's mean free path, ``sigma_t' = 1/mfp`` (OpenPBR,
    Standard Surface; exact for isotropic scattering, docs/model.md says what anisotropy means).

    ``rd`` and ``mfp`` are scalars, per-channel tuples or arrays, broadcast against each other;
    ``eta`` a scalar or one per channel. Rd -> 1 drives sigma_t' -> infinity for a fixed ld, so
    here Rd >= 1 is invalid (as are NaN/inf albedo and mfp that is NaN, <= 0 or infinite);
    ``on_invalid="clamp"`` maps Rd >= 1 to the largest float32 below 1 (finite, very large
    sigma_t'), NaN albedo to 0, and mfp into ``MFP_CLAMP_RANGE`` (NaN -> its top).

    ``outputs`` picks what is returned, in order, from alpha, rho, sigma_a, sigma_s, sigma_t.
    ``device``: where to run, as for ``invert_albedo``. ``out``: arrays to write the outputs
    into, one per output in order (as ``invert_albedo``'s ``out``); returned.
    """
    rt = get_runtime(device)
    config = resolve_method(method, double=double, device_key=DeviceKey.of(rt.device), **knobs)
    rd, mfp = np.broadcast_arrays(np.asarray(rd), np.asarray(mfp))
    rd = rd.astype(np.float64) if rd.dtype.kind != "f" else rd
    mfp = mfp.astype(np.float64) if mfp.dtype.kind != "f" else mfp
    etas = channel_etas(eta, rd.shape)
    mapper = CoefficientMapper(etas, config, outputs=outputs, model=model, exact=exact,
                               double=double, on_invalid=on_invalid, device=rt,
                               mfp_kind=mfp_kind)
    if out is not None:
        out = dict(zip(outputs, (out,) if isinstance(out, np.ndarray) else tuple(out)))
    outs, _ = mapper(rd, mfp, out=out)
    result = tuple(outs[k] for k in outputs)
    return result if len(result) > 1 else result[0]
