"""Radial-profile blur of irradiance maps with the Better Dipole profile R(r), per channel.

The subpackage, one concern a module: ``weights`` (the exact texel-integrated kernel),
``fit`` (sums of separable Gaussians), ``params`` (parameters and their checks), ``fft`` (host
FFT paths), ``dispatch`` (OpenCL kernels), ``planning`` (constant parameters: method, kernel,
``auto``; BlurInfo), ``textured_plan`` and ``textured`` (texture-varying parameters). ``blur``
below is the entry point. The definition (exitance as a discrete convolution with exact
texel-integrated weights, truncated and renormalized to sum to Rd) is in ``weights`` and
docs/model.md "Texel-integrated weights".

Methods (``method=``)
---------------------
``direct``     2D gather of the exact weights (kernels/blur_direct.cl), local-memory tiles.
``gaussians``  the weights fitted (non-negative least squares) by a sum of separable
               texel-integrated Gaussians (d'Eon et al. 2007's texture-space diffusion);
               truncated at tol/2, the fit's L1 error kept <= tol/2 where the basis allows,
               so that their sum, the reported bound, is <= tol (kernels/blur_separable.cl).
``fft``        the exact weights by FFT convolution on the host (scipy.fft, all cores).
``auto``       the cheapest configuration (method, truncation tol) that ``bdipole-cl report``
               measured to meet ``tol`` on the workload of the nearest kernel radius, among
               those whose truncation tol is <= tol (``bdipole_cl.methods.choice``);
               BlurInfo says which and why.

With constant parameters ``tol`` bounds the error relative to max|E| * Rd for any
non-negative irradiance (docs/model.md "Blur error bound"; of both signs the truncation counts
twice; an exitance below float32's normal range adds float32's absolute floor, 2^-150): ``error_bound`` reports the bound, and a bound above tol raises BlurAccuracyWarning.
With textures the bound is tol (the truncation) plus the basis fit and the interpolation, each
measured and <= tol by design, so up to 2 tol: ``error_bound`` reports it (with no warning;
one that would always fire says nothing), and what widens it beyond (a basis that cannot fit
the kernels within tol, the albedo shape clamp, an irradiance of both signs) is warned of.

Parameters are scalars, per-channel tuples or HxW / HxWxC textures. With textures each texel
uses its own (the exit texel's) profile, through per-texel weights over a shared basis
(``textured``; methods fft, gaussians, auto).

Invalid input follows ``on_invalid``: ``"raise"`` (default) reports the count and first texel;
``"clamp"`` treats NaN/Inf irradiance as unlit (0) and clamps parameter texels into range.
HDR values are fine: weights sum to Rd <= 1.
"""
from __future__ import annotations

from pyopencl.array import to_device

from ...device.runtime import get_runtime, runtime_of_array
from ...device.transfer import is_device_array, ready_array
from ...methods.registry import BLUR_METHODS, BORDERS
from .fit import fit_gaussians
from .params import PARAM_KEYS, channel_parameters, irradiance_shape
from .plan import BlurPlan, Scattering, plan_blur
from .planning import BlurInfo, ChannelInfo
from .weights import channel_kernel

__all__ = ["BLUR_METHODS", "BORDERS", "PARAM_KEYS", "BlurInfo", "BlurPlan", "ChannelInfo",
           "Scattering", "blur", "channel_kernel", "channel_parameters", "fit_gaussians",
           "is_textured", "plan_blur"]


def is_textured(**physical) -> bool:
    """Whether any physical parameter (``blur``'s keywords) is a texture (2D or more)
    rather than per channel: ``Scattering.textured``."""
    return Scattering.split(physical)[0].textured


def blur(irradiance, *, albedo=None, mfp=None, eta=1.4, texel_size=1.0, alpha=None,
         sigma_t=None, tol=1e-3, method="auto", border="clamp", exact=False,
         on_invalid="raise", return_info=False, max_memory=None, device=None, stretch=None,
         charts="clamp"):
    """Texture-space subsurface scattering: ``irradiance`` (HxW or HxWxC) blurred by R(r).

    ``albedo`` (Rd) and ``mfp`` (ld = 1/mu_tr, same unit as ``texel_size``), or ``alpha``
    (alpha', the reduced albedo; ``Scattering.alpha_prime``) and ``sigma_t`` (sigma_t',
    1/unit): scalars, per channel, or HxW(xC) textures (texture-varying: the exit texel's
    profile); ``eta`` per channel. Returns the exitance, float32 of the irradiance's shape
    (HxW for HxW, as ``bdipole_cl.dask.blur``), and a BlurInfo with ``return_info``. See the package docstring. It is ``plan_blur(...).apply(...)``: make
    the plan yourself to blur many images (or bands) of one shape with the same parameters.

    ``max_memory`` (bytes): blur in bands of rows, each with a halo of the truncation radius
    taken by the border rule, so the working set stays bounded; the result is the same as in
    one piece (the halo holds every texel an interior kernel reaches).

    ``device``: where to run (None, a string such as ``"intel"``, a pyopencl Device or a
    Runtime; see ``bdipole_cl.device``).

    ``stretch``: the surface length of a texel step along u and v per texel (an (su, sv)
    pair of HxW maps, an HxWx2 array, a ``stretched.Stretch`` or an ``ops.stretch.StretchTile``
    from ``bdipole_cl.stretch_maps``), in the mfp's unit, instead of ``texel_size``: the profile
    in surface distance, per texel anisotropic (docs/stretch.md). ``charts`` (with a stretch
    that has charts): "clamp", "zero" or "none" (``methods.registry.CHART_BORDER``).
    """
    given = {"irradiance": irradiance, "albedo": albedo, "mfp": mfp, "alpha": alpha,
             "sigma_t": sigma_t}
    on_device = {k: v for k, v in given.items() if is_device_array(v)}
    if on_device:                        # checked, and after their own queues' work
        if device is None:
            device = runtime_of_array(next(iter(on_device.values())))
        rt = get_runtime(device)
        given.update({k: ready_array(v, rt, k) for k, v in on_device.items()})
        irradiance, albedo, mfp, alpha, sigma_t = given.values()
    if is_device_array(irradiance):
        shape = irradiance.shape
    else:
        shape = irradiance_shape(irradiance)
    plan = plan_blur(shape, Scattering(albedo, mfp, eta, texel_size, alpha, sigma_t, stretch),
                     tol=tol, method=method, border=border, exact=exact,
                     on_invalid=on_invalid, device=device, charts=charts)
    if is_device_array(irradiance) and not isinstance(plan, BlurPlan):
        # the stretched blur runs on the host: the exitance goes back where the light was
        out, info = plan.apply(irradiance.get(), max_memory)
        out = to_device(irradiance.queue, out)
    else:
        out, info = plan.apply(irradiance, max_memory)
    return (out, info) if return_info else out
