"""The inversion tables, built on the host in float64 (the physics layer).

The table method interpolates the inverse of Rd on three segments (kernels/invert.cl):

* segment 0: ``alpha'`` of ``x = Rd^(1/n)`` on ``[0, Rd_split^(1/n)]``;
* segment 1: ``q = sqrt(1 - alpha')`` of ``x = Rd^(1/n)`` on ``[Rd_split^(1/n), 2^(-1/n)]``;
* segment 2: ``q`` of ``x = 1 - Rd`` on ``[0, 1/2]`` (exact in float32 for Rd >= 1/2).

Each inverse is analytic up to and including its ends (the square-root behaviour of Rd at
both ends, docs/model.md "Stiffness", is absorbed by the variables), so a uniform cubic
Hermite table with exact node slopes converges as h^4 everywhere, the stiff ends included,
and no texel needs a log. Node values come from the float64 solver and slopes from the
analytic derivatives.
"""
from __future__ import annotations

import numpy as np

from ..caches import ByteCache
from . import reference as ref
from .models import MODEL

SEGMENTS = 3


def entries_per_channel(n: int) -> int:
    """Table rows per channel: each segment's n cubics and its end node (kernels/invert.cl)."""
    return SEGMENTS * (n + 1)
#: tables kept across calls (a 1024-interval table is 48 KiB)
TABLE_CACHE = ByteCache("inversion tables", 16 << 20)


def _hermite_coefficients(x0, x1, values, slopes):
    """Per-interval cubic coefficients in the local coordinate u in [0, 1)."""
    n = len(values) - 1
    h = (x1 - x0) / n
    v0, v1 = values[:-1], values[1:]
    m0, m1 = h * slopes[:-1], h * slopes[1:]
    return np.stack([v0, m0, 3.0 * (v1 - v0) - 2.0 * m0 - m1, 2.0 * (v0 - v1) + m0 + m1], axis=-1)


def _segment(x0, x1, values, slopes):
    """One segment's rows: n cubics and the end node (its .x)."""
    end = np.array([[values[-1], 0.0, 0.0, 0.0]])
    return np.concatenate([_hermite_coefficients(x0, x1, values, slopes), end])


def _solve_q(c, model, neg_log_rd):
    return ref.solve_increasing(lambda v, i: ref.upper_residual(v, c, model), neg_log_rd,
                                 0.0, np.sqrt(1.0 - ref.ALPHA_SPLIT))


def derived_c3(rows):
    """One segment's float32 rows with each cubic's c3 replaced by the float32
    ``((end - c0) - c1) - c2`` (end: the next row's c0), the value kernels/invert_table.cl
    derives from the 16 bytes it gathers per lane (c0, c1, c2, end) rather than reading c3.
    In exact arithmetic the Hermite cubic meets its end node, c0 + c1 + c2 + c3 = end, so this
    moves c3 by a few ulps of the interval's values; every kernel reads the same floats (the
    same bits everywhere), and the monotone margin is checked on them as stored. (At the
    largest tables the true c3 is below the rounding, so the stored one is rounding noise of
    a few ulps of the values: at 65536 intervals the margin's headroom is ~12x instead of
    ~1e4x, still met at every eta; it shrinks as 1/n, so a larger size cap would need it
    checked again: ``table_is_monotone`` does.)"""
    c0, c1, c2 = rows[:-1, 0], rows[:-1, 1], rows[:-1, 2]
    out = rows.copy()
    out[:-1, 3] = ((rows[1:, 0] - c0) - c1) - c2      # float32 operations, in this order
    return out


@TABLE_CACHE.memoize
def inversion_table(eta: float, n: int, exact: bool = False, model: str = "better"):
    """``(rows float32 (3 (n + 1), 4), scales (3,))`` of one eta: per segment n cubics and its
    end node. Neighbouring segments share their nodes exactly: segment 0 ends at alpha' =
    ALPHA_SPLIT and segment 1 starts at q = sqrt(1 - ALPHA_SPLIT) (the split, where the result
    is clamped to its half), and segments 1 and 2 end at the same float64 q of Rd = 1/2."""
    c = ref.dipole_constants(eta, exact, model)
    split = float(ref.rd_split(c, model))
    if not split < 0.5:
        raise ValueError(f"eta={eta}: Rd(alpha'=1/2) = {split} >= 1/2; the table needs it below")
    power = MODEL[model].power
    x_split, x_mid = split ** (1.0 / power), 0.5 ** (1.0 / power)
    # segment 0: alpha' of x = Rd^(1/n); dalpha/dx = 1/F'(alpha)
    x0 = np.linspace(0.0, x_split, n + 1)
    a = ref.solve_increasing(lambda v, i: ref.lower_residual(v, c, model), x0, 0.0,
                              ref.ALPHA_SPLIT)
    a[-1] = ref.ALPHA_SPLIT
    seg0 = _segment(0.0, x_split, a, 1.0 / ref.lower_residual(a, c, model)[1])
    # segment 1: q of x = Rd^(1/n), G = -n log x; dq/dx = (dG/dx)/G'(q) = -n/(x G'(q))
    x1 = np.linspace(x_split, x_mid, n + 1)
    q1 = _solve_q(c, model, -power * np.log(x1))
    q1[0] = np.sqrt(1.0 - ref.ALPHA_SPLIT)
    seg1 = _segment(x_split, x_mid, q1, -power / (x1 * ref.upper_residual(q1, c, model)[1]))
    # segment 2: q of x = 1 - Rd, G = -log(1 - x); dq/dx = 1/((1 - x) G'(q))
    x2 = np.linspace(0.0, 0.5, n + 1)
    q2 = _solve_q(c, model, -np.log1p(-x2))
    q2[-1] = q1[-1]                       # Rd = 1/2 ends both segments: one value
    seg2 = _segment(0.0, 0.5, q2, 1.0 / ((1.0 - x2) * ref.upper_residual(q2, c, model)[1]))
    coefs = np.concatenate([derived_c3(s.astype(np.float32)) for s in (seg0, seg1, seg2)])
    coefs.setflags(write=False)
    return coefs, (n / x_split, n / (x_mid - x_split), n / 0.5)


#: a table interval's float evaluation ``c0 + fma(u, c1, u^2 (c2 + c3 u))`` is monotone in u
#: when |c1| >= MONOTONE_MARGIN_Z |c2| + MONOTONE_MARGIN_W |c3| (docs/model.md "Monotone
#: inverse"): the first-order term's growth beats the rest's rounding. The margin also makes the
#: exact cubic monotone (its derivative c1 + 2 c2 u + 3 c3 u^2 keeps the sign of c1).
MONOTONE_MARGIN_Z, MONOTONE_MARGIN_W = 10.0, 11.0


def table_is_monotone(eta: float, n: int, exact: bool = False, model: str = "better") -> bool:
    """Whether every interval of the table (float32 coefficients as stored) meets the margin,
    so that the kernel's lookup is monotone in Rd (with the shared nodes and the clamps)."""
    rows = inversion_table(float(eta), n, exact, model)[0].astype(np.float64)
    cubic = rows.reshape(SEGMENTS, n + 1, 4)[:, :n]
    need = MONOTONE_MARGIN_Z * np.abs(cubic[..., 2]) + MONOTONE_MARGIN_W * np.abs(cubic[..., 3])
    return bool(np.all(np.abs(cubic[..., 1]) >= need))


def channel_tables(etas, n, *, exact=False, model="better"):
    """All channels' tables stacked, float32 ``(len(etas) * entries_per_channel(n), 4)``."""
    return np.concatenate([inversion_table(float(e), n, exact, model)[0] for e in etas])
