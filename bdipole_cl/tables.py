"""Per-channel kernel constants and the inversion tables, built on the host in float64.

The table method interpolates the inverse of Rd on each half of the split (reference.py):

* lower half: ``alpha'`` as a function of ``x = Rd^(1/n)`` on ``[0, Rd_split^(1/n)]``;
* upper half: ``q = sqrt(1 - alpha')`` as a function of ``x = -log Rd`` on ``[0, -log Rd_split]``.

Both inverses are analytic up to and including their ends (SPEC.md's square-root behaviour is
absorbed by the variables), so a uniform cubic Hermite table with exact node slopes converges
as h^4 everywhere, the stiff ends included. Node values come from the float64 solver and slopes
from the analytic derivative, ``dv/dx = 1/F'(v)``.
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np

from . import reference as ref

PARAM_STRIDE = 8  # kernels/bdipole.h: BD_PARAM_STRIDE
P_CPHI, P_CE, P_A, P_RD_SPLIT, P_LO_SCALE, P_HI_SCALE = range(6)


def _hermite_coefficients(x_end, values, slopes):
    """Per-interval cubic coefficients in the local coordinate u in [0, 1)."""
    n = len(values) - 1
    h = x_end / n
    v0, v1 = values[:-1], values[1:]
    m0, m1 = h * slopes[:-1], h * slopes[1:]
    return np.stack([v0, m0, 3.0 * (v1 - v0) - 2.0 * m0 - m1, 2.0 * (v0 - v1) + m0 + m1], axis=-1)


@lru_cache(maxsize=64)
def inversion_table(eta: float, n: int, exact: bool = False, model: str = "better"):
    """``(coefficients float32 (2n, 4), lo_scale, hi_scale)`` of one eta: n intervals a half."""
    c = ref.dipole_constants(eta, exact, model)
    split = float(ref.rd_split(c, model))
    power = 2 if model == "better" else 1
    # lower half: alpha' of x = Rd^(1/n)
    x_lo_end = split ** (1.0 / power)
    x_lo = np.linspace(0.0, x_lo_end, n + 1)
    a = ref._solve_increasing(lambda v: ref.lower_residual(v, c, model), x_lo, 0.0,
                              ref.ALPHA_SPLIT)
    da = 1.0 / ref.lower_residual(a, c, model)[1]
    # upper half: q of x = -log Rd
    x_hi_end = -np.log(split)
    x_hi = np.linspace(0.0, x_hi_end, n + 1)
    q = ref._solve_increasing(lambda v: ref.upper_residual(v, c, model), x_hi, 0.0,
                              np.sqrt(1.0 - ref.ALPHA_SPLIT))
    dq = 1.0 / ref.upper_residual(q, c, model)[1]
    coefs = np.concatenate([_hermite_coefficients(x_lo_end, a, da),
                            _hermite_coefficients(x_hi_end, q, dq)])
    coefs = coefs.astype(np.float32)
    coefs.setflags(write=False)
    return coefs, n / x_lo_end, n / x_hi_end


def channel_params(etas, *, exact=False, model="better", table_n=0, dtype=np.float32):
    """The kernels' per-channel constant records (bdipole.h: BD_P_*) for a tuple of etas."""
    out = np.zeros((len(etas), PARAM_STRIDE), dtype=np.float64)
    for i, eta in enumerate(etas):
        c = ref.dipole_constants(eta, exact, model)
        out[i, P_CPHI], out[i, P_CE], out[i, P_A] = c.cphi, c.ce, c.a_coef
        out[i, P_RD_SPLIT] = ref.rd_split(c, model)
        if table_n:
            _, out[i, P_LO_SCALE], out[i, P_HI_SCALE] = inversion_table(float(eta), table_n,
                                                                        exact, model)
    return out.astype(dtype).reshape(-1)


def channel_tables(etas, n, *, exact=False, model="better"):
    """All channels' tables stacked, float32 ``(len(etas) * 2n, 4)``."""
    return np.concatenate([inversion_table(float(e), n, exact, model)[0] for e in etas])
