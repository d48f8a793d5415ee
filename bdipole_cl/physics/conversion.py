"""``convert``: a painted colour and radius from one renderer's convention to another's, so
that both renderers produce the same diffuse reflectance and the same spread
(docs/conventions.md "Conversion").

Per texel: the source's renderer produces (rd, median) (``conventions.rendered``); the
target's colour is the one its renderer produces rd with (``conventions.colour_for``), and
its radius the one that puts half the reflected energy within the same median (every
convention's median is proportional to its radius). Float64, vectorised.
"""
from __future__ import annotations

from dataclasses import dataclass
import numpy as np

from ..errors import check_numbers, check_policy, find_invalid, plain_array
from .conventions import (CONVENTION, Medium, colour_for, medium, rd_range, rendered_rd,
                          unit_median)

#: the colours outside which the spread is taken at the nearest of them (a texel of colour 0
#: reflects nothing and one of colour 1 has an infinite extinction in the dipoles: their
#: spread is undefined, so their radius is converted as at these colours')
COLOUR_FLOOR, COLOUR_CEILING = 1e-4, 1.0 - 1e-7
#: the radius range every convention takes (errors' mfp rule)
RADIUS_RANGE = (1e-20, 1e20)


@dataclass(frozen=True)
class Conversion:
    """The target's ``colour`` and ``radius`` (in its own units, the source's length unit),
    what both render (``rd``, ``median``), and the counts of invalid inputs clamped
    (``invalid``: colour, radius, reflectance out of the target's reach)."""

    colour: np.ndarray
    radius: np.ndarray
    rd: np.ndarray
    median: np.ndarray
    source: str
    target: str
    eta: float
    g: float
    invalid: dict

    def medium(self) -> Medium:
        """The medium the target's renderer walks (target a walk convention; for
        ``random-walk``: sigma_a, sigma_s and g of a dielectric-bounded path tracer)."""
        return medium(self.target, self.colour, self.radius, self.eta, self.g)


def _scalar(value, name):
    check_numbers(value, name)
    v = np.asarray(value, np.float64)
    if v.ndim or not np.isfinite(v):
        raise ValueError(f"{name}={value!r}: expected one finite number")
    return float(v)


def check_colour(colour, on_invalid, name="colour", texels=False):
    """(colour in [0, 1], invalid mask): NaN, infinite or outside [0, 1] (below 0: outside
    the working space's gamut, or not a colour) is invalid, clamped into [0, 1] (NaN to 0)."""
    bad = ~((colour >= 0.0) & (colour <= 1.0))
    n = find_invalid(name, colour, bad, "NaN, infinite or outside [0, 1]", on_invalid,
                     texels=texels)
    return (np.clip(np.nan_to_num(colour, nan=0.0), 0.0, 1.0) if n else colour), bad


def check_radius(radius, on_invalid, name="radius", texels=False):
    """(radius in RADIUS_RANGE, count): NaN, infinite or not > 0 is invalid."""
    lo, hi = RADIUS_RANGE
    bad = ~((radius >= lo) & (radius <= hi))
    n = find_invalid(name, radius, bad, f"NaN, infinite or outside [{lo:g}, {hi:g}]",
                     on_invalid, texels=texels)
    return (np.clip(np.nan_to_num(radius, nan=1.0), lo, hi) if n else radius), n


def convert(colour, radius, source="better-dipole", target="van-de-hulst", eta=1.4, g=0.0,
            on_invalid="raise", texels=False) -> Conversion:
    """Colour and radius of ``target``'s convention that render as ``source``'s do.

    Parameters
    ----------
    colour, radius : array_like
        The painted colour [0, 1] and radius (> 0, any length unit), broadcast together.
    source, target : str
        ``conventions.CONVENTION`` names (``bdipole-cl conventions`` lists them).
    eta, g : float
        The surface's relative index and the walk's HG mean cosine (one each).
    on_invalid : {"raise", "clamp"}
        Out-of-range colour or radius, or a reflectance the target cannot render (Cycles'
        walk loses the entry's Fresnel part: at eta 1.4 it renders at most ~0.91):
        InvalidInputError naming the first, or clamped into range and counted.
    texels : bool
        Name the first invalid element as a texel (x, y, channel) of HxWxC data.
    """
    src, tgt = CONVENTION[source], CONVENTION[target]
    check_policy(on_invalid)
    eta, g = _scalar(eta, "eta"), _scalar(g, "g")
    if not (1.0 <= eta <= 3.0):
        raise ValueError(f"eta={eta!r}: expected a relative index in [1, 3]")
    if not (-0.9 <= g <= 0.9):
        raise ValueError(f"g={g!r}: expected an HG mean cosine in [-0.9, 0.9]")
    check_walk_g(src, tgt, g)
    colour = plain_array(colour, "colour").astype(np.float64)
    radius = plain_array(radius, "radius").astype(np.float64)
    colour, radius = np.broadcast_arrays(colour, radius)
    colour, outside = check_colour(colour, on_invalid, texels=texels)
    radius, n_radius = check_radius(radius, on_invalid, texels=texels)
    flat_c, inverse = np.unique(colour, return_inverse=True)
    inv = inverse.reshape(colour.shape)
    lo, hi = rd_range(tgt.name, eta, g)
    rd = rendered_rd(src, flat_c, eta, g)
    above = (rd > hi)[inv]
    find_invalid("colour", colour, above, f"renders a reflectance above {hi:.6g}, the most "
                 f"{tgt.name} renders at eta {eta:g}", on_invalid, texels=texels)
    # below the floor by more than the maps' rounding (a round trip's 1e-9 relative)
    below = (rd < lo * (1.0 - 1e-8))[inv]
    find_invalid("colour", colour, below, f"renders a reflectance below {lo:.6g}, the least "
                 f"{tgt.name} renders (its colour floor) at eta {eta:g}", on_invalid,
                 texels=texels)
    # a value is one invalid value, however many rules it breaks (1.5 is outside [0, 1] and,
    # clamped to 1, beyond a Cycles walk's reach: counted once)
    n_colour = int(np.count_nonzero(outside | above | below))
    # every distinct colour exactly, whatever their number: a texel's result is the same bits
    # in any array (no interpolated path whose error depends on how many colours there are)
    out_c, ratio, src_median = colour_maps(src, tgt, flat_c, eta, g)
    return Conversion(out_c[inv], radius * ratio[inv], np.clip(rd, lo, hi)[inv],
                      radius * src_median[inv], src.name, tgt.name, eta, g,
                      {"colour": n_colour, "radius": n_radius})


def check_walk_g(src, tgt, g) -> None:
    """ValueError before any texel is read when a walk of the pair would walk a g (after its
    renderer's clamp) outside the spread table's (the radius is matched by it)."""
    from .transport_tables import spread_table
    lo, hi = float(spread_table().g[0]), float(spread_table().g[-1])
    for conv in (src, tgt):
        if conv.walk and not lo <= conv.renderer_g(g) <= hi:
            raise ValueError(f"g={g!r}: {conv.name}'s spread is tabulated for g in [{lo:g}, "
                             f"{hi:g}] (the Monte Carlo table: docs/transport.md \"Spread\")")


def colour_maps(src, tgt, colour, eta, g):
    """Per colour in [0, 1] (exact, float64): the target's colour, the radius ratio (the
    source's median per unit radius over the target's at its colour) and the source's median
    per unit radius. Reflectances beyond the target's reach are taken at its edge."""
    lo, hi = rd_range(tgt.name, eta, g)
    rd = np.clip(rendered_rd(src, colour, eta, g), lo, hi)
    floor = np.clip(colour, COLOUR_FLOOR, COLOUR_CEILING)
    rd_floor = np.where(floor != colour, np.clip(rendered_rd(src, floor, eta, g), lo, hi), rd)
    out_c = colour_for(tgt.name, rd, eta, g)
    src_median = unit_median(src, floor, eta, g)
    ratio = src_median / unit_median(tgt, colour_for(tgt.name, rd_floor, eta, g), eta, g)
    return out_c, ratio, src_median
