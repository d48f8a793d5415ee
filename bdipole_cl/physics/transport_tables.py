"""Monotone inverse tables of the transport reflectance (docs/transport.md "Inversion").

The forward curve Rd(s) (``transport.reflectance_curve``: a Chebyshev series in van de Hulst's
similarity parameter s in [0, 1]) is strictly decreasing and analytic. Its inverse is tabulated
in two uniform segments split at s = 1/2: alpha(Rd) below (Rd ~ k alpha near alpha = 0:
analytic and nearly linear, where s(Rd) bends sharply for large g), s(Rd) above (Rd(0) - Rd ~
c s near alpha = 1). Cubic Hermite tables with exact node slopes converge as h^4 on both; each
is checked monotone (Fritsch & Carlson's sufficient condition on every interval) when built.
Pure functions of the Chebyshev coefficients: this module imports nothing of transport.py
(transport.py imports it). Also the Monte Carlo table of the spread (``spread_lookup``).
"""
from __future__ import annotations

import re
from pathlib import Path
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


#: s where the inverse table switches from alpha(Rd) (s above) to s(Rd) (s below): alpha(Rd)
#: is analytic on all of [0, Rd(0)], but near alpha = 1 rho = 1 - alpha must come from s to
#: keep its digits; at s = 1/2, rho >= 0.05 and a 1e-13 error of alpha is 2e-12 of rho
S_SPLIT = 0.5


def similarity_s(alpha, g: float):
    """van de Hulst's similarity parameter s = sqrt((1 - alpha)/(1 - alpha g)) [1]: Rd is
    analytic in s on [0, 1], the square root at alpha = 1 included."""
    a = np.asarray(alpha, np.float64)
    return np.sqrt((1.0 - a) / (1.0 - a * g))


def rho_of_s(s, g: float):
    """1 - alpha of s, without cancellation: rho = s^2 (1 - g)/(1 - g s^2)."""
    s2 = np.asarray(s, np.float64) ** 2
    return s2 * (1.0 - g) / (1.0 - g * s2)


def alpha_of_s(s, g: float):
    """alpha = (1 - s^2)/(1 - g s^2) (the inverse of similarity_s)."""
    s2 = np.asarray(s, np.float64) ** 2
    return (1.0 - s2) / (1.0 - g * s2)


def dalpha_ds(s, g: float):
    """d alpha / ds = -2 s (1 - g)/(1 - g s^2)^2."""
    s = np.asarray(s, np.float64)
    return -2.0 * s * (1.0 - g) / (1.0 - g * s * s) ** 2


class InverseTable(NamedTuple):
    """The inverse of Rd in two uniform segments: alpha(Rd) on [0, rd_split] (nearly linear:
    Rd ~ k alpha), s(Rd) on [rd_split, rd_max] (Rd(0) - Rd ~ c s), rd_split = Rd(S_SPLIT).
    Rows: per interval the cubic's coefficients in the local u in [0, 1):
    c0 + c1 u + c2 u^2 + c3 u^3."""

    g: float
    rd_split: float
    rd_max: float
    lower: np.ndarray            # (n, 4): alpha
    upper: np.ndarray            # (n, 4): s


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
    """Fritsch & Carlson (1980): a Hermite cubic whose node slopes have the secant's sign and
    (m0/d)^2 + (m1/d)^2 <= 9, d the secant, is monotone on its interval."""
    secant = np.diff(values) / h
    a, b = slopes[:-1] / secant, slopes[1:] / secant
    return bool(np.all(secant != 0.0) and np.all(a > 0.0) and np.all(b > 0.0)
                and np.all(a * a + b * b <= 9.0))


def segment(rd0, rd1, n, coefs, g, lower: bool):
    """One segment's rows: alpha (lower) or s (upper) at n + 1 uniform Rd, exact slopes."""
    rd = np.linspace(rd0, rd1, n + 1)
    s = solve_s(coefs, rd)
    s_split = S_SPLIT
    if lower:
        s[0], s[-1] = 1.0, s_split
    else:
        s[0], s[-1] = s_split, 0.0
    ds_drd = 1.0 / curve_values(coefs, s)[1]
    values, slopes = (alpha_of_s(s, g), dalpha_ds(s, g) * ds_drd) if lower else (s, ds_drd)
    h = (rd1 - rd0) / n
    if not is_monotone(values, slopes, h):
        raise ValueError(f"g={g}: the inverse table of Rd is not monotone "
                         f"({'alpha' if lower else 's'} segment; docs/transport.md)")
    rows = hermite_rows(values, slopes, h)
    rows.setflags(write=False)
    return rows


def build_inverse_table(coefs, g: float, n: int = INVERSE_INTERVALS) -> InverseTable:
    """The table from the series of Rd(s); raises if a check fails (not monotone)."""
    rd_max = float(curve_values(coefs, 0.0)[0])
    rd_zero = float(curve_values(coefs, 1.0)[0])
    if abs(rd_zero) > 1e-12:                 # alpha = 0: no scattering, nothing comes back
        raise ValueError(f"Rd(alpha = 0) = {rd_zero!r}, expected 0")
    rd_split = float(curve_values(coefs, S_SPLIT)[0])
    return InverseTable(g, rd_split, rd_max, segment(0.0, rd_split, n, coefs, g, True),
                        segment(rd_split, rd_max, n, coefs, g, False))


def cubic_lookup(rows, x0, x1, x):
    """The segment's cubic at x in [x0, x1] (clamped)."""
    n = len(rows)
    t = (np.clip(x, x0, x1) - x0) * (n / (x1 - x0))
    i = np.clip(np.floor(t), 0, n - 1).astype(np.intp)
    u = t - i
    c = rows[i]
    return c[..., 0] + u * (c[..., 1] + u * (c[..., 2] + u * c[..., 3]))


def evaluate_inverse(table: InverseTable, rd):
    """``(alpha, s)`` of rd from the table: rd <= 0 gives alpha = 0, rd >= rd_max alpha = 1,
    NaN stays NaN. s is exact-ish on the upper segment (where rho = 1 - alpha is small and
    better taken from s: rho_of_s) and derived from alpha on the lower one."""
    rd = np.asarray(rd, np.float64)
    missing = np.isnan(rd)
    rd = np.where(missing, 0.0, rd)
    upper = rd >= table.rd_split
    s_up = np.clip(cubic_lookup(table.upper, table.rd_split, table.rd_max, rd), 0.0, 1.0)
    a_lo = np.clip(cubic_lookup(table.lower, 0.0, table.rd_split, rd), 0.0, 1.0)
    alpha = np.where(upper, alpha_of_s(s_up, table.g), a_lo)
    s = np.where(upper, s_up, similarity_s(a_lo, table.g))
    return np.where(missing, np.nan, alpha), np.where(missing, np.nan, s)


#: the reflectance curves' files in the user cache folder (``transport.curve_cache_path``,
#: listed and cleared by ``bdipole-cl cache``): curves-{source digest}-g{g.hex()}-eta{eta.hex()}
CURVES_FOLDER = "transport"
CURVES_NAME = re.compile(r"^curves-[0-9a-f]{16}-g[-+0-9a-fx.p]+-eta[-+0-9a-fx.p]+\.npz$")


# {{{ spread: the Monte Carlo table of radii (tools/walk_montecarlo.py spread)

#: the table written by ``tools/walk_montecarlo.py spread`` (docs/transport.md "Spread")
SPREAD_FILE = Path(__file__).resolve().parent.parent / "data" / "walk_spread.npz"


class SpreadTable(NamedTuple):
    """Radii [mean free paths] holding ``fraction`` of the reflected energy of a normally
    incident pencil, on the grid s x g x eta x fraction, with their standard errors."""

    s: np.ndarray
    g: np.ndarray
    eta: np.ndarray
    fraction: np.ndarray
    radius: np.ndarray
    stderr: np.ndarray
    paths: int


@INVERSE_TABLES.memoize
def spread_table() -> SpreadTable:
    """The packaged table, read-only."""
    with np.load(SPREAD_FILE) as data:
        table = SpreadTable(*(np.array(data[k], np.float64) for k in
                              ("s", "g", "eta", "fraction", "radius", "stderr")),
                            int(data["paths"]))
    for a in table[:-1]:
        a.setflags(write=False)
    return table


def spread_lookup(s, g: float, eta: float, fraction: float, values=None):
    """Interpolate the table at similarity parameters ``s`` (array) for one (g, eta,
    fraction): linear in (s, g, eta) of log(r (1 - g)) (the radius in transport mean free
    paths, nearly independent of g at a given s), then linear in the fraction. Below the grid's
    smallest s the line through its first two s is extended to s = 0 (the radii tend to finite
    limits as alpha -> 1); above its largest s the value is held (single scattering).
    ``values``: another array on the grid (the standard errors), interpolated alike."""
    t = spread_table()
    for name, v, axis in (("g", g, t.g), ("eta", eta, t.eta), ("fraction", fraction,
                                                                 t.fraction)):
        if not axis[0] <= v <= axis[-1]:
            raise ValueError(f"{name}={v!r} is outside [{axis[0]}, {axis[-1]}], the Monte "
                             f"Carlo spread table's range (docs/transport.md \"Spread\")")
    s = np.asarray(s, np.float64)
    grid = t.radius if values is None else values
    scaled = np.log(grid * (1.0 - t.g)[None, :, None, None])
    # g, eta and fraction: multilinear weights on the three scalar axes
    plane = scaled
    for axis, v in ((t.fraction, fraction), (t.eta, eta), (t.g, g)):
        j = min(int(np.searchsorted(axis, v, side="right")) - 1, len(axis) - 2)
        w = (v - axis[j]) / (axis[j + 1] - axis[j])
        plane = (1.0 - w) * plane[..., j] + w * plane[..., j + 1]
    # s: linear inside, the first segment's line extended below, held above
    s_in = np.clip(np.nan_to_num(s), 0.0, t.s[-1])
    slope = (plane[1] - plane[0]) / (t.s[1] - t.s[0])
    log_r = np.where(s_in < t.s[0], plane[0] + slope * (s_in - t.s[0]),
                     np.interp(s_in, t.s, plane))
    return np.where(np.isnan(s), np.nan, np.exp(log_r) / (1.0 - g))

# }}}
