"""Albedo inversion on an OpenCL device: Rd -> alpha', rho and (with a mean free path)
sigma_a, sigma_s'. Each call is an inversion plan and one apply
(``bdipole_cl.ops.inversion_plan``: make the plan once to invert many bands or files); the
kernels are in ``bdipole_cl.ops.inversion_kernel``. The methods and their knobs are in
``bdipole_cl.methods.registry``; ``method="auto"`` is resolved by ``bdipole_cl.methods.choice``.
"""
from __future__ import annotations

import numpy as np

from ..errors import check_numbers
from ..methods.registry import MethodConfig
from ..device.runtime import runtime_of_array
from ..device.transfer import is_device_array
from .inversion_kernel import InversionKernel
from .host_arrays import texel_broadcast
from .inversion_plan import (MFP_CLAMP_RANGE, OUTPUTS, RD_CLAMP_MAX, InversionPlan, Inverted,
                             as_float, check_mfp_kind, check_outputs, plan_inversion)

__all__ = ["CoefficientMapper", "InversionKernel", "InversionPlan", "Inverted",
           "MFP_CLAMP_RANGE", "OUTPUTS", "RD_CLAMP_MAX", "albedo_to_coefficients",
           "channel_etas", "check_mfp_kind", "check_outputs", "invert_albedo",
           "plan_inversion"]


def device_of(device, *values):
    """``device``, else the runtime of the first device array among ``values`` (an inversion
    of device arrays runs where they are), else None (the default device)."""
    if device is not None:
        return device
    return next((runtime_of_array(v) for v in values if is_device_array(v)), None)


def device_channel_etas(etas, rd, mfp):
    """``etas``, one per channel where device albedos take a per-channel mfp beside one eta
    (the kernel reads one mfp a channel: a map of them would cross the bus)."""
    if (is_device_array(rd) and not is_device_array(mfp) and len(etas) == 1 and rd.ndim
            and np.ndim(mfp) == 1 and np.size(mfp) == rd.shape[-1] > 1):
        return etas * rd.shape[-1]
    return etas


def channel_etas(eta, shape):
    """Etas per channel: one eta (also when all are equal), or one per channel along the last
    axis of ``shape``; real numbers (``errors.check_numbers``)."""
    etas = np.atleast_1d(np.asarray(check_numbers(eta, "eta"), dtype=np.float64))
    if etas.ndim != 1 or etas.size == 0:
        raise ValueError(f"eta must be a scalar or one value per channel, got shape {etas.shape}")
    if etas.size == 1 or np.all(etas == etas[0]):
        return (float(etas[0]),)
    if len(shape) == 0 or shape[-1] != etas.size:
        raise ValueError(f"eta has {etas.size} values but the input's last axis has "
                         f"{shape[-1] if shape else 'no'} channels")
    return tuple(float(e) for e in etas)


def invert_albedo(rd, eta, method="table", *, return_rho=False, model="better", exact=False,
                  double=False, on_invalid="raise", iterations=None, tol=None, table_size=None,
                  polish=None, seed_size=None, device=None, out=None):
    """Invert memo eq. 3 on the device: reduced albedo alpha' (and rho = 1 - alpha') of ``rd``.

    Parameters
    ----------
    rd : array_like, any shape, float32 or float64; or a pyopencl.array.Array
        Diffuse reflectance ("albedo"), linear. Rd <= 0 gives alpha' = 0, Rd = 1 gives 1.
        A device array (C-contiguous, of the computation's precision) is inverted where it
        is, into device arrays (``out`` too): nothing crosses the bus but one int
        (docs/python.md "Arrays on the device").
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
    rd = rd if is_device_array(rd) else as_float(rd)
    plan = plan_inversion(channel_etas(eta, rd.shape), method,
                          outputs=("alpha", "rho") if return_rho else ("alpha",), model=model,
                          exact=exact, double=double, on_invalid=on_invalid,
                          device=device_of(device, rd),
                          iterations=iterations, tol=tol, table_size=table_size, polish=polish,
                          seed_size=seed_size)
    arrays = plan.apply(rd, out=out).arrays
    return (arrays["alpha"], arrays["rho"]) if return_rho else arrays["alpha"]


class CoefficientMapper:
    """A coefficient ``InversionPlan`` under its older name and call, for the texture
    pipeline: ``CoefficientMapper(etas, config, outputs=..., ...)`` is ``InversionPlan(etas,
    config, outputs=..., mfp_kind=..., ...)`` (``device`` its runtime, ``bake`` the old name
    of ``specialise``); calling it, ``(albedo, mfp, mask, out) -> ({output: array}, {"albedo":
    n, "mfp": n} invalid)``, is ``plan.apply``. Other attributes are the plan's."""

    def __init__(self, etas, config: MethodConfig, *, outputs=("sigma_a", "sigma_s"),
                 model="better", exact=False, double=False, on_invalid="raise", device=None,
                 bake=False, specialise=False, mfp_const=None, mfp_kind="diffuse"):
        self.plan = InversionPlan(tuple(etas), config, outputs=outputs,
                                  mfp_kind=check_mfp_kind(mfp_kind), model=model, exact=exact,
                                  double=double, on_invalid=on_invalid,
                                  specialise=bool(specialise or bake), mfp_const=mfp_const,
                                  runtime=device)

    def __getattr__(self, name):
        if name == "plan":                    # not made yet (a failed __init__, a copy)
            raise AttributeError(name)
        return getattr(self.plan, name)

    def __call__(self, rd, mfp, mask=None, out=None):
        done = self.plan.apply(rd, mfp, mask, out)
        return done.arrays, {"albedo": done.invalid_albedo, "mfp": done.invalid_mfp}


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

    ``rd`` and ``mfp`` are scalars, per-channel tuples or arrays, broadcast against each other
    (an HxW mfp map beside HxWxC albedos serves every channel);
    ``eta`` a scalar or one per channel. Rd -> 1 drives sigma_t' -> infinity for a fixed ld, so
    here Rd >= 1 is invalid (as are NaN/inf albedo and mfp that is NaN, <= 0 or infinite);
    ``on_invalid="clamp"`` maps Rd >= 1 to the largest float32 below 1 (finite, very large
    sigma_t'), NaN albedo to 0, and mfp into ``MFP_CLAMP_RANGE`` (NaN -> its top).

    ``rd`` and ``mfp`` may be device arrays (``pyopencl.array.Array``, the mfp of the albedos'
    shape, or one value or one per channel on the host): the outputs are device arrays then
    (as ``invert_albedo``'s).

    ``outputs`` picks what is returned, in order, from alpha, rho, sigma_a, sigma_s, sigma_t.
    ``device``: where to run, as for ``invert_albedo``. ``out``: arrays to write the outputs
    into, one per output in order (as ``invert_albedo``'s ``out``); returned.
    """
    if not (is_device_array(rd) or is_device_array(mfp)):
        rd, mfp = texel_broadcast(as_float(rd), as_float(mfp))
        rd = np.broadcast_to(rd, np.broadcast_shapes(rd.shape, mfp.shape))  # one albedo
    etas = device_channel_etas(channel_etas(eta, np.shape(rd)), rd, mfp)
    plan = plan_inversion(etas, method,
                          outputs=check_outputs(outputs),
                          mfp_kind=check_mfp_kind(mfp_kind), model=model, exact=exact,
                          double=double, on_invalid=on_invalid,
                          device=device_of(device, rd, mfp), **knobs)
    result = tuple(plan.apply(rd, mfp, out=out).arrays.values())
    return result if len(result) > 1 else result[0]
