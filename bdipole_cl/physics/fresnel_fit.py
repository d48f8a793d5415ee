"""d'Eon & Irving 2011's fits of the first two Fresnel moments, evaluated exactly (docs/model.md
"Fresnel moments").

The fits are polynomials (and, for C2 above eta = 1, a Laurent polynomial) with decimal
coefficients. In float64 their Horner sums cancel: C2 at eta 2.8 sums terms of ~1500 to ~0.4,
so a few ulp of 1500 (~3e-13) land on 3 C2, and 1 - 2 C1 (0.027 at eta 2.8) carries the same
absolute error; rho inverted with such constants is 3.6e-12 off. Here each fit is evaluated
once per eta in 40-digit decimal arithmetic from its decimal coefficients (the values the paper
gives, not their float64 roundings), then rounded once: C1 and C2 correctly rounded to float64.
1 - 2 C1 and 1 - 3 C2 then round exactly or within an ulp of 3 C2 (2 C1 in [1/2, 2]: Sterbenz).
"""
from __future__ import annotations

from decimal import Decimal, localcontext
from functools import lru_cache

import numpy as np

#: coefficients of eta^0, eta^1, ... (decimal strings: the fit as published)
C1_BELOW_1 = ("0.45966", "-1.73965", "3.37668", "-3.904945", "2.49277", "-0.68441")
C1_ABOVE_1 = ("-4.61686", "11.1136", "-10.4646", "5.11455", "-1.27198", "0.12746")
C2_BELOW_1 = ("0.27614", "-0.87350", "1.12077", "-0.65095", "0.07883", "0.04860")
#: C2 above 1: coefficients of eta^-3 .. eta^5
C2_ABOVE_1 = ("45.3087", "-218.725", "458.843", "-547.033", "404.557", "-189.519", "54.9327",
              "-9.00603", "0.63942")
DIGITS = 40


def _horner(x: Decimal, coefs) -> Decimal:
    acc = Decimal(0)
    for c in reversed(coefs):
        acc = acc * x + Decimal(c)
    return acc


@lru_cache(maxsize=4096)
def moments_of(eta: float) -> tuple:
    """(C1, C2) of one eta, each correctly rounded to float64."""
    with localcontext() as ctx:
        ctx.prec = DIGITS
        e = Decimal(eta)                       # the float64 eta, exactly
        if eta < 1.0:
            return float(_horner(e, C1_BELOW_1)), float(_horner(e, C2_BELOW_1))
        c2 = _horner(e, C2_ABOVE_1) / e**3
        return float(_horner(e, C1_ABOVE_1)), float(c2)


def fresnel_moments_fit(eta):
    """The fits' (C1, C2) for eta (any shape; each distinct value evaluated once, cached)."""
    e = np.asarray(eta, dtype=np.float64)
    values, inverse = np.unique(e, return_inverse=True)
    with np.errstate(all="ignore"):
        pairs = np.array([moments_of(float(v)) if np.isfinite(v) and v > 0 else (np.nan, np.nan)
                          for v in values]).reshape(-1, 2)
    c1 = pairs[:, 0][inverse].reshape(e.shape)
    c2 = pairs[:, 1][inverse].reshape(e.shape)
    return (c1[()], c2[()]) if e.ndim == 0 else (c1, c2)
