"""Exhaustive float32 monotonicity sweeps of an inversion (applications layer).

A painted ramp of albedo must map to a monotone ramp of coefficients: alpha' non-decreasing in
Rd (rho non-increasing). ``sweep`` runs an inversion on every float32 Rd of an interval, in
chunks, and counts the *reversals*: consecutive float32 albedos whose alpha' decreases, or
whose rho increases (each with its size in ulps of the output). ``device`` may be a Runtime
with other numerics (``Runtime.with_numerics("gpu")``: what a GPU's arithmetic does)."""
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
    drop_ulps: int       # how far the output went the wrong way, in its ulps (float32 or 64)
    output: str = "alpha"


#: each output's monotone direction as Rd grows: +1 non-decreasing, -1 non-increasing
DIRECTION = {"alpha": 1, "rho": -1}


@dataclass
class MonotoneResult:
    method: str
    eta: float
    lo: float
    hi: float
    count: int = 0       # float32 albedos swept
    reversals: int = 0   # of alpha'
    worst_ulps: int = 0
    nan: int = 0
    first: list = field(default_factory=list)   # the first few Reversals (of either output)
    rho_reversals: int = 0
    numerics: str = "device"                    # the arithmetic of the device's build

    @property
    def monotone(self) -> bool:
        """No reversal of alpha' or rho and no NaN."""
        return self.reversals == 0 and self.rho_reversals == 0 and self.nan == 0


def float32_bits(lo: float, hi: float):
    """The bit patterns [a, b) of the float32 values in [lo, hi) (positive lo, hi)."""
    return int(np.float32(lo).view(np.uint32)), int(np.float32(hi).view(np.uint32))


def ulps(a, b, double=False):
    """Signed distance from a to b in units in the last place (same-sign floats)."""
    itype = np.int64 if double else np.int32
    return b.view(itype).astype(np.int64) - a.view(itype).astype(np.int64)


def sweep(config: MethodConfig, eta: float, lo=1e-4, hi=1.0, *, model="better", double=False,
          device=None, chunk=SWEEP_CHUNK, keep=5) -> MonotoneResult:
    """Every float32 Rd in [lo, hi), inverted by ``config``: its reversals of alpha' and rho."""
    kernel = InversionKernel((float(eta),), config, model=model, double=double, runtime=device)
    a, b = float32_bits(lo, hi)
    res = MonotoneResult(config.describe(), float(eta), float(lo), float(hi),
                         numerics=kernel.rt.numerics.name)
    prev = None                                      # the last Rd and outputs of a chunk
    for start in range(a, b, chunk):
        rd = np.arange(start, min(start + chunk, b), dtype=np.uint32).view(np.float32)
        out = kernel.run(rd, None, tuple(DIRECTION))
        res.count += rd.size
        res.nan += sum(int(np.count_nonzero(~np.isfinite(v))) for v in out.values())
        if prev is not None:                         # across the chunk boundary
            rd = np.concatenate([[prev[0]], rd])
            out = {k: np.concatenate([[prev[1][k]], v]).astype(v.dtype) for k, v in out.items()}
        for name, sign in DIRECTION.items():
            _count_reversals(res, name, rd, sign * out[name], double, keep)
        prev = (rd[-1], {k: v[-1] for k, v in out.items()})
    return res


def _count_reversals(res: MonotoneResult, name: str, rd, values, double: bool, keep: int):
    """Add the places where ``values`` (oriented to be non-decreasing) decrease to ``res``."""
    drop = np.flatnonzero(values[1:] < values[:-1])
    if not drop.size:
        return
    sizes = np.abs(ulps(np.abs(values[drop]), np.abs(values[drop + 1]), double))
    if name == "alpha":
        res.reversals += int(drop.size)
    else:
        res.rho_reversals += int(drop.size)
    res.worst_ulps = max(res.worst_ulps, int(sizes.max()))
    for i, s in zip(drop[:max(0, keep - len(res.first))], sizes):
        res.first.append(Reversal(float(rd[i + 1]), int(s), name))
