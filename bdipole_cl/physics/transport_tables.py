"""Monotone inverse tables of the transport reflectance (docs/transport.md "Inversion").

The forward curve Rd(s) (``transport.reflectance_curve``: a Chebyshev series in van de Hulst's
similarity parameter s in [0, 1]) is strictly decreasing and analytic, and so is its inverse
s(Rd) on [0, Rd(0)], both ends included (Rd ~ k alpha near alpha = 0, Rd(0) - Rd ~ c s near
alpha = 1). A uniform cubic Hermite table of s over Rd with exact node slopes 1/Rd'(s)
therefore converges as h^4 everywhere; it is checked monotone (Fritsch & Carlson's sufficient
condition on every interval) when built. Pure functions of the Chebyshev coefficients: this
module imports nothing of transport.py (transport.py imports it).
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numpy.polynomial import chebyshev

from ..caches import ByteCache

#: intervals of an inverse table (measured bound on s: docs/transport.md "Inversion")
INVERSE_INTERVALS = 4096
#: Newton steps on the Chebyshev series from the bisected start (quadratic: 2 suffice)
NEWTON_STEPS = 4
#: bisection steps before Newton (the series is monotone: a bracket is always kept)
BISECTIONS = 30

INVERSE_TABLES = ByteCache("transport inverse tables", 16 << 20)


class InverseTable(NamedTuple):
    """s(Rd) on [0, rd_max]: per interval the cubic's coefficients in the local u in [0, 1)."""

    rd_max: float
    coefs: np.ndarray            # (n, 4): c0 + c1 u + c2 u^2 + c3 u^3


def curve_values(coefs, s):
    """Rd and dRd/ds of the Chebyshev series (in x = 2s - 1) at s."""
    x = 2.0 * np.asarray(s, np.float64) - 1.0
    return chebyshev.chebval(x, coefs), 2.0 * chebyshev.chebval(x, chebyshev.chebder(coefs))


def solve_s(coefs, rd):
    """s in [0, 1] with Rd(s) = rd for a decreasing series (rd within [Rd(1), Rd(0)]):
    bisection to 1e-9, then Newton (quadratic; the slope is bounded away from 0)."""
    rd = np.asarray(rd, np.float64)
    lo, hi = np.zeros_like(rd), np.ones_like(rd)
    for _ in range(BISECTIONS):
        mid = 0.5 * (lo + hi)
        above = curve_values(coefs, mid)[0] > rd       # decreasing: the root is right of mid
        lo, hi = np.where(above, mid, lo), np.where(above, hi, mid)
    s = 0.5 * (lo + hi)
    for _ in range(NEWTON_STEPS):
        value, slope = curve_values(coefs, s)
        s = np.clip(s - (value - rd) / slope, lo, hi)
    return s


def hermite_rows(values, slopes, h):
    """Cubic Hermite coefficients per interval in u in [0, 1) (slopes per unit Rd)."""
    v0, v1 = values[:-1], values[1:]
    m0, m1 = h * slopes[:-1], h * slopes[1:]
    return np.stack([v0, m0, 3.0 * (v1 - v0) - 2.0 * m0 - m1, 2.0 * (v0 - v1) + m0 + m1],
                    axis=-1)


def is_monotone(values, slopes, h) -> bool:
    """Fritsch & Carlson (1980): a Hermite cubic with node slopes of the secant's sign and
    (m0/d)^2 + (m1/d)^2 <= 9, d the secant, is monotone on its interval."""
    secant = np.diff(values) / h
    a, b = slopes[:-1] / secant, slopes[1:] / secant
    return bool(np.all(secant < 0.0) and np.all(a > 0.0) and np.all(b > 0.0)
                and np.all(a * a + b * b <= 9.0))


def build_inverse_table(coefs, n: int = INVERSE_INTERVALS) -> InverseTable:
    """The table of s over Rd from the series; raises if a check fails (not monotone)."""
    rd_max = float(curve_values(coefs, 0.0)[0])
    rd_zero = float(curve_values(coefs, 1.0)[0])
    if abs(rd_zero) > 1e-12:                 # alpha = 0: no scattering, nothing comes back
        raise ValueError(f"Rd(alpha = 0) = {rd_zero!r}, expected 0")
    rd = np.linspace(0.0, rd_max, n + 1)
    s = solve_s(coefs, rd)
    s[0], s[-1] = 1.0, 0.0
    slopes = 1.0 / curve_values(coefs, s)[1]           # ds/dRd
    h = rd_max / n
    if not is_monotone(s, slopes, h):
        raise ValueError("the inverse table of Rd is not monotone (docs/transport.md)")
    rows = hermite_rows(s, slopes, h)
    rows.setflags(write=False)
    return InverseTable(rd_max, rows)


def evaluate_inverse(table: InverseTable, rd):
    """s of rd from the table; rd <= 0 gives s = 1 (alpha = 0), rd >= rd_max gives s = 0
    (alpha = 1), NaN stays NaN."""
    rd = np.asarray(rd, np.float64)
    n = len(table.coefs)
    x = np.clip(rd, 0.0, table.rd_max) * (n / table.rd_max)
    i = np.clip(np.floor(np.nan_to_num(x)), 0, n - 1).astype(np.intp)
    u = x - i
    c = table.coefs[i]
    s = c[..., 0] + u * (c[..., 1] + u * (c[..., 2] + u * c[..., 3]))
    return np.where(np.isnan(rd), np.nan, np.clip(s, 0.0, 1.0))
