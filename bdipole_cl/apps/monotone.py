"""Exhaustive float32 monotonicity sweeps of an inversion (applications layer).

A painted ramp of albedo must map to a monotone ramp of coefficients: alpha' non-decreasing in
Rd (rho non-increasing). ``sweep`` runs an inversion on every float32 Rd of an interval, in
chunks, and counts the *reversals*: consecutive float32 albedos whose alpha' decreases (each
with its size in ulps of alpha')."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..methods.registry import MethodConfig
from ..ops.invert import InversionKernel

#: float32 albedos per kernel call (64 MiB of input)
SWEEP_CHUNK = 1 << 24


@dataclass
class Reversal:
    rd: float            # the larger of the two albedos
    drop_ulps: int       # how far alpha' fell, in float32 ulps of alpha' (or of alpha' float64)


@dataclass
class MonotoneResult:
    method: str
    eta: float
    lo: float
    hi: float
    count: int = 0       # float32 albedos swept
    reversals: int = 0
    worst_ulps: int = 0
    nan: int = 0
    first: list = field(default_factory=list)   # the first few Reversals


def float32_bits(lo: float, hi: float):
    """The bit patterns [a, b) of the float32 values in [lo, hi) (positive lo, hi)."""
    return int(np.float32(lo).view(np.uint32)), int(np.float32(hi).view(np.uint32))


def ulps(a, b, double=False):
    """Signed distance from a to b in units in the last place (same-sign floats)."""
    itype = np.int64 if double else np.int32
    return b.view(itype).astype(np.int64) - a.view(itype).astype(np.int64)


def sweep(config: MethodConfig, eta: float, lo=1e-4, hi=1.0, *, model="better", double=False,
          device=None, chunk=SWEEP_CHUNK, keep=5) -> MonotoneResult:
    """Every float32 Rd in [lo, hi), inverted by ``config``: its reversals."""
    kernel = InversionKernel((float(eta),), config, model=model, double=double, runtime=device)
    a, b = float32_bits(lo, hi)
    res = MonotoneResult(config.describe(), float(eta), float(lo), float(hi))
    prev_rd = prev_alpha = None
    for start in range(a, b, chunk):
        rd = np.arange(start, min(start + chunk, b), dtype=np.uint32).view(np.float32)
        alpha = kernel.run(rd, None, ("alpha",))["alpha"]
        res.count += rd.size
        res.nan += int(np.count_nonzero(~np.isfinite(alpha)))
        if prev_alpha is not None:                  # across the chunk boundary
            rd = np.concatenate([[prev_rd], rd])
            alpha = np.concatenate([[prev_alpha], alpha]).astype(alpha.dtype)
        drop = np.flatnonzero(alpha[1:] < alpha[:-1])
        if drop.size:
            sizes = -ulps(alpha[drop], alpha[drop + 1], double)
            res.reversals += int(drop.size)
            res.worst_ulps = max(res.worst_ulps, int(sizes.max()))
            for i, s in zip(drop[:max(0, keep - len(res.first))], sizes):
                res.first.append(Reversal(float(rd[i + 1]), int(s)))
        prev_rd, prev_alpha = rd[-1], alpha[-1]
    return res
