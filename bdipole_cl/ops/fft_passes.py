"""The device FFTs' sizes, radices, passes and twiddles (pure NumPy: what
``device_fft.DeviceFFT`` launches; docs/device_fft.md).

A complex FFT of length n is split into *passes* (``axis_passes``): each reads the data from
global memory once, does a radix-R step of a Stockham FFT (R a product of the small radices
the kernels have, ``RADICES``) with its R points of each sequence in local memory, and writes
it back. R is bounded by the tile a work-group's local memory holds, so short axes take one
pass and long ones two or three. A real row of even length 2m is transformed as m complex
points and twisted (kernels/fft.cl ``r2c_twist``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

#: the butterflies kernels/fft.cl has, largest first: a pass's stages use them in this order
RADICES = (8, 4, 2, 5, 3, 7)
#: the primes an axis length may have (every product of them is a product of RADICES)
PRIMES = (2, 3, 5, 7)
#: bits a radix takes in a pass's packed stage list (kernels/fft.cl ``local_fft``)
STAGE_BITS = 4
#: at most this many stages in a pass: their radices are packed into 64 bits
MAX_STAGES = 64 // STAGE_BITS


def prime_factors(n: int) -> list:
    """n's prime factors among PRIMES, with multiplicity, and what is left (1 when n has no
    other factor)."""
    factors = []
    for p in PRIMES:
        while n % p == 0:
            factors.append(p)
            n //= p
    return factors, n


def is_fft_len(n: int) -> bool:
    """Whether the device FFTs take an axis of length n: even, >= 2, no prime factor above 7."""
    return n >= 2 and n % 2 == 0 and prime_factors(n)[1] == 1


def device_fft_len(n: int) -> int:
    """The smallest axis length >= n that the device FFTs take (even, factors 2, 3, 5, 7)."""
    m = max(2, int(n) + int(n) % 2)
    while not is_fft_len(m):
        m += 2
    return m


def check_fft_shape(shape) -> tuple:
    """(N0, N1) as ints, or a ValueError naming the axis that the device FFTs do not take and
    the nearest lengths they do."""
    if len(shape) != 2:
        raise ValueError(f"device FFT shape {tuple(shape)}: two axes (N0, N1) expected")
    out = tuple(int(n) for n in shape)
    for axis, n in enumerate(out):
        if not is_fft_len(n):
            below = [m for m in range(max(2, n - n % 2), 1, -2) if is_fft_len(m)][:1]
            raise ValueError(
                f"device FFT axis {axis} of length {n}: lengths are even with no prime factor "
                f"above 7 (nearest: {', '.join(str(m) for m in below + [device_fft_len(n)])}"
                f"; device_fft_len(n) gives the next)")
    return out


def stage_radices(r: int) -> tuple:
    """The butterflies of a length-r DFT in local memory, largest first: the twos grouped in
    eights (then one four or two), then fives, threes and sevens."""
    factors, rest = prime_factors(r)
    if rest != 1:
        raise ValueError(f"length {r} has a prime factor above 7")
    twos = factors.count(2)
    out = [8] * (twos // 3) + ([4] if twos % 3 == 2 else [2] if twos % 3 == 1 else [])
    out += [p for p in (5, 3, 7) for _ in range(factors.count(p))]
    return tuple(out)


def pack_stages(radices) -> int:
    """The stage list as kernels/fft.cl reads it: radix s in bits [4 s, 4 s + 4)."""
    if len(radices) > MAX_STAGES:
        raise ValueError(f"{len(radices)} stages: at most {MAX_STAGES} in one pass")
    return sum(r << (STAGE_BITS * s) for s, r in enumerate(radices))


def split_radices(n: int, max_radix: int) -> tuple:
    """The fewest pass radices R_1..R_p (each <= max_radix, product n), balanced: the prime
    factors, largest first, each into the pass with the smallest product it still fits."""
    factors, rest = prime_factors(n)
    if rest != 1:
        raise ValueError(f"length {n} has a prime factor above 7")
    if max_radix < max(PRIMES):
        raise ValueError(f"a pass of at most {max_radix} points cannot take radix 7")
    for p in range(1, len(factors) + 2):
        groups = [1] * p
        for f in sorted(factors, reverse=True):
            fits = [g for g in range(p) if groups[g] * f <= max_radix]
            if not fits:
                break
            g = min(fits, key=lambda g: groups[g])
            groups[g] *= f
        else:
            return tuple(sorted(groups, reverse=True))
    raise AssertionError("unreachable: p = len(factors) puts each factor in its own pass")


def unit_roots(n: int, dtype) -> np.ndarray:
    """W_n^m = exp(-2 pi i m / n), m in [0, n), as (n, 2) (re, im) in ``dtype``: computed in
    float64 on the first octant (m reduced exactly in integers; the octant's edge, where cos =
    sin, is sqrt(1/2) for both), so each is within 2 ulps of float64 and the symmetries are
    exact (W^(n/4) = -i, W^(n/2) = -1, W^(n-m) = conj W^m), then rounded once."""
    m = np.arange(n, dtype=np.int64)
    quadrant, rest = np.divmod(4 * m, n)               # angle = (pi / 2)(quadrant + rest / n)
    flip = 2 * rest > n                                # past the octant: use the complement
    a = (np.pi / 2) * np.where(flip, n - rest, rest) / n
    c, s = np.cos(a), np.sin(a)
    c, s = np.where(flip, s, c), np.where(flip, c, s)  # cos, sin of (pi / 2) rest / n
    edge = 2 * rest == n                               # pi / 4: cos = sin, one value
    c, s = np.where(edge, np.sqrt(0.5), c), np.where(edge, np.sqrt(0.5), s)
    for _ in range(3):                                 # each quadrant: (c, s) -> (-s, c)
        turn = quadrant > 0
        c, s = np.where(turn, -s, c), np.where(turn, c, s)
        quadrant = quadrant - turn
    return np.stack([c, -s], axis=-1).astype(dtype)


@dataclass(frozen=True)
class AxisPass:
    """One pass of a complex FFT of length n along an axis (kernels/fft.cl ``fft_pass``):
    radix R (its butterflies ``stages``) at span ``span`` (the product of the earlier passes'
    radices); a work-group takes ``j_tile`` consecutive butterflies of ``lane_tile``
    consecutive lanes."""

    n: int
    radix: int
    stages: tuple
    span: int
    lane_tile: int
    j_tile: int

    @property
    def tile(self) -> int:
        """Complex points a work-group holds (each in two local buffers)."""
        return self.radix * self.lane_tile * self.j_tile

    def groups(self, batch: int, lanes: int) -> int:
        return batch * (self.n // self.radix // self.j_tile) * -(-lanes // self.lane_tile)


#: consecutive butterflies a work-group of a lane-less axis (long rows) takes: 16 complex
#: points are 128 bytes of float32, a GPU's memory transaction
J_TILE = 16
#: bytes of consecutive lanes a work-group of a laned axis (columns) moves per point: two
#: 32-byte sectors of a GPU's memory; more lanes would shrink the radix a pass holds
LANE_BYTES = 64


def axis_passes(n: int, lanes: int, tile_points: int, complex_bytes: int) -> tuple:
    """The passes of a complex FFT of length n with ``lanes`` contiguous lanes (1 for a row),
    a work-group holding at most ``tile_points`` complex points."""
    lane_tile = min(lanes, max(1, LANE_BYTES // complex_bytes))
    j_cap = J_TILE if lanes == 1 else 1
    radices = split_radices(n, max(7, tile_points // (lane_tile * j_cap)))
    passes, span = [], 1
    for r in radices:
        j_tile = max(d for d in range(1, j_cap + 1) if (n // r) % d == 0)
        passes.append(AxisPass(n, r, stage_radices(r), span, lane_tile, j_tile))
        span *= r
    return tuple(passes)


def work_group_size(tile: int, stages, cols: int, device_max: int, cap: int = 256) -> int:
    """Work-items for a tile of ``tile`` points in ``cols`` sequences: enough for the most
    butterflies a stage has (tile / its smallest radix), a multiple of cols (each work-item
    keeps one sequence: kernels/fft.cl) and of 16 where it can (a CPU's vector, a quarter of a
    GPU's wavefront), at most ``cap`` and the kernel's own limit."""
    limit = max(cols, min(cap, device_max))
    unit = cols * 16 // math.gcd(cols, 16)
    unit = unit if unit <= limit else cols
    want = tile // min(stages) if stages else tile
    want = -(-max(1, want) // unit) * unit
    return min(want, limit // unit * unit)
