"""Elementwise evaluation of the kernels' physics functions on a device
(kernels/physics_eval.cl), for cross-checks against ``bdipole_cl.physics.reference``."""
from __future__ import annotations

import numpy as np
import pyopencl as cl
import pyopencl.array as cla

from ..device import build_options, get_program, get_runtime, real_dtype
from ..device.layout import channel_params
from ..physics import reference as ref


#: function name -> (build define, reference evaluator taking (x, y, z, eta, exact))
FUNCTIONS = {
    "rd": ("BD_FUNC_RD", lambda x, y, z, eta, exact: ref.rd(x, eta, exact)),
    "one_minus_rd": ("BD_FUNC_ONE_MINUS_RD",
                     lambda x, y, z, eta, exact: ref.one_minus_rd_of_rho(x * x, eta, exact)),
    "profile": ("BD_FUNC_PROFILE", lambda x, y, z, eta, exact: ref.profile(x, y, z, eta, exact)),
    "profile_cdf": ("BD_FUNC_PROFILE_CDF",
                    lambda x, y, z, eta, exact: ref.profile_cdf(x, y, z, eta, exact)),
    "profile_tail": ("BD_FUNC_PROFILE_TAIL",
                     lambda x, y, z, eta, exact: ref.profile_tail(x, y, z, eta, exact)),
    # the device's sqrt, and the correctly rounded one of kernels/bdipole.h (BD_SQRT_RN); their
    # reference is float32's correctly rounded sqrt of the float32 input
    "sqrt": ("BD_FUNC_SQRT", lambda x, y, z, eta, exact: np.sqrt(np.float32(x))),
    "sqrt_rn": ("BD_FUNC_SQRT_RN",
                lambda x, y, z, eta, exact: np.sqrt(np.maximum(np.float32(x), 0))),
}


def evaluate(func, x, y=0.0, z=1.0, *, eta=1.4, exact=False, double=False, rho=None,
             device=None):
    """Evaluate kernel function ``func`` (a key of FUNCTIONS) on the device, elementwise.

    ``x``: alpha' (rd), q (one_minus_rd) or r (profile*); ``y``: alpha'; ``z``: sigma_t'.
    ``rho`` defaults to 1 - y computed in float64 (pass it where 1 - alpha' would cancel).
    """
    define, _ = FUNCTIONS[func]
    rt = get_runtime(device)
    dtype = real_dtype(double)
    ref.check_eta(eta, exact)
    x, y, z = np.broadcast_arrays(*(np.asarray(v, dtype=np.float64) for v in (x, y, z)))
    w = 1.0 - y if rho is None else np.broadcast_to(np.asarray(rho, dtype=np.float64), x.shape)
    prg = get_program(rt, "physics_eval", build_options({define: None}, double=double))
    args = [cla.to_device(rt.queue, np.ascontiguousarray(v, dtype=dtype).reshape(-1))
            for v in (x, y, z, w)]
    out = cla.empty(rt.queue, x.size, dtype)
    params = channel_params((eta,), exact=exact, dtype=dtype)
    params_buf = cl.Buffer(rt.context, cl.mem_flags.READ_ONLY | cl.mem_flags.COPY_HOST_PTR,
                           hostbuf=params)
    if x.size:
        cl.Kernel(prg, "physics_eval")(rt.queue, (x.size,), None, *(a.data for a in args),
                                       out.data, params_buf, np.uint64(x.size))
    return out.get().reshape(x.shape)


def reference_value(func, x, y=0.0, z=1.0, *, eta=1.4, exact=False):
    """The float64 reference of ``func`` (same arguments as ``evaluate``)."""
    return FUNCTIONS[func][1](np.asarray(x, np.float64), np.asarray(y, np.float64),
                              np.asarray(z, np.float64), eta, exact)
