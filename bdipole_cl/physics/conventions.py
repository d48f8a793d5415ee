"""Renderers' subsurface conventions (``convention=``, ``--source``/``--target``): one registry
of what a painted colour and radius mean to each renderer, and what each renders from them
(docs/conventions.md).

A convention is either a *diffusion profile* (the renderer integrates an analytic profile
whose total is the colour: better-dipole, dipole, burley) or a *random walk* (the renderer
turns colour and radius into a medium, alpha = sigma_s/sigma_t with HG g, and walks it; what
it renders is then the walk's reflectance, ``physics.transport``, under its boundary rule).
``rendered`` gives both kinds' diffuse reflectance and spread (the median radius of the
reflected energy); ``colour_for`` inverts the reflectance; ``physics.convert`` matches them.

Names: ``colour`` the painted colour [1], ``radius`` the painted radius [length], ``eta`` the
relative index of the surface [1], ``g`` the HG mean cosine [1], ``rd`` the diffuse
reflectance a renderer produces (specular excluded) [1], ``median`` the radius holding half of
it [length].
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, NamedTuple

import numpy as np

from ..vocabulary import Option, Registry
from . import half_space, reference
from . import renderer_fits as fits

#: how a walk meets the surface (docs/conventions.md "Boundaries"): a property of each
#: convention, not an option (so a table, not a registry)
BOUNDARIES = dict(
    dielectric="a smooth dielectric at eta bounds the walk: refraction in, Fresnel and total "
               "internal reflection at every exit (Mitsuba, pbrt, Hyperion 2018)",
    entry="refracted in (the surface's specular lobe keeps the Fresnel part), then the walk "
          "leaves at its first surface crossing: no internal reflection (Cycles)",
    cosine_entry="let in through 1 - F as a diffuse (cosine) bounce, then the index-matched "
                 "walk leaves at its first crossing (Cycles Skin, as measured: half its "
                 "entries are cosine bounces, half a roughness-1 refraction)",
    matched="index-matched: no Fresnel on the way in or out (what the OpenPBR, Chiang 2016 "
            "and Wrenninge 2017 fits assume)",
    diffusion="an analytic profile whose integral is the colour (a dipole's boundary is in "
              "its formula)")

#: fraction of the reflected energy the spread criterion holds (the median radius)
SPREAD_FRACTION = 0.5


class Rendered(NamedTuple):
    """What a renderer makes of a colour and radius: diffuse reflectance ``rd`` [1] and the
    radius ``median`` holding half of it [the radius' length unit]."""

    rd: np.ndarray
    median: np.ndarray


class Medium(NamedTuple):
    """A homogeneous medium: ``sigma_a``, ``sigma_s`` [1/length] and HG ``g``."""

    sigma_a: np.ndarray
    sigma_s: np.ndarray
    g: float


@dataclass(frozen=True)
class Convention(Option):
    """One renderer convention. ``colour``, ``radius``: what the two inputs mean (``unit``:
    the radius' kind); ``boundary``: a ``BOUNDARIES`` name; ``renderers``, ``source``: who uses
    it and where the formula is read from.

    Walks: ``alpha_fit(colour, g)`` the single-scattering albedo, ``extinction(colour,
    radius, eta, g)`` sigma_t; ``alpha_max`` the renderer's clamp; ``min_alpha`` Cycles'
    floor (alpha raised to it, the throughput scaled by alpha/min_alpha). Profiles:
    ``profile`` ("better-dipole", "dipole" or "burley") and, for burley, ``burley_s`` (d =
    radius/s). ``g_range``: the anisotropy the
    renderer takes (``renderer_g``); ``colour_floor``: the least colour it takes (MoonRay's
    0.001: darker colours render as it)."""

    renderers: str = ""
    colour: str = ""
    radius: str = ""
    unit: str = ""
    boundary: str = "diffusion"
    source: str = ""
    alpha_fit: Callable | None = None
    extinction: Callable | None = None
    alpha_max: float = 1.0
    min_alpha: float = 0.0
    profile: str | None = None
    burley_s: Callable | None = None
    g_range: tuple = (-1.0, 1.0)
    colour_floor: float = 0.0

    def renderer_g(self, g) -> float:
        """The HG g the renderer walks with: ``g`` clamped to ``g_range`` (Cycles clamps
        Subsurface Anisotropy to [0, 0.9])."""
        return float(np.clip(g, *self.g_range))

    @property
    def walk(self) -> bool:
        return self.profile is None


#: the anisotropy Cycles takes: Subsurface Anisotropy clamped to [0, 0.9] (svm_closure.h,
#: "clamps protecting against bad/extreme and non physical values")
CYCLES_G = (0.0, 0.9)


def _sigma_t_plain(colour, radius, eta, g):
    return 1.0 / np.asarray(radius, np.float64)


def _sigma_t_cycles(colour, radius, eta, g):
    # bssrdf_setup_radius: radius x 1/(4 pi) (every method but Skin)
    return 1.0 / (np.asarray(radius, np.float64) * 0.25 / np.pi)


def _sigma_t_cycles_legacy(colour, radius, eta, g):
    return _sigma_t_cycles(colour, radius, eta, g) / (1.0 - g)


def _sigma_t_cycles_skin(colour, radius, eta, g):
    # radius x sqrt(3 (1 - alpha')), alpha' Jensen's Rd inverted in float32; no 1/(4 pi)
    a = fits.cycles_skin_alpha_prime(colour, eta)
    return 1.0 / (np.asarray(radius, np.float64) * np.sqrt(3.0 * (1.0 - a)) * (1.0 - g))


def _sigma_t_s(s_fit, scale=1.0, floor=0.0):
    def extinction(colour, radius, eta, g):
        d = np.maximum(np.asarray(radius, np.float64) * scale, floor)
        return 1.0 / (d * s_fit(colour))
    return extinction


#: MoonRay's colour floor (VolumeSubsurface.cc)
MOONRAY_COLOUR_FLOOR = 0.001


def _moonray_alpha(colour, g):
    return fits.moonray_alpha(np.maximum(colour, MOONRAY_COLOUR_FLOOR))


def _moonray_s(colour):
    return fits.burley_s_transmission(np.maximum(colour, 0.001))


_DMFP = "diffuse mean free path ld = 1/mu_tr"
_MFP = "volume mean free path 1/sigma_t"

CONVENTION = Registry("convention", (
    Convention("better-dipole", "the Better Dipole profile (d'Eon 2012), Hery's inversion: "
               "this library", aliases=("pxrsurface", "better"),
               renderers="RenderMan PxrSurface (subsurfaceColor, subsurfaceDmfp), this library",
               colour="the profile's total diffuse reflectance", radius=_DMFP, unit="dmfp",
               source="Hery TM 12-11; docs/model.md", profile="better-dipole"),
    Convention("dipole", "Jensen et al. 2001's dipole", renderers="classic dipole BSSRDFs",
               colour="the profile's total diffuse reflectance (Jensen's Rd)", radius=_DMFP,
               unit="dmfp", source="Jensen et al. 2001 eqs. 4-5; Jensen & Buhler 2002",
               profile="dipole"),
    Convention("burley", "normalized diffusion, searchlight s for the dmfp",
               renderers="MoonRay NormalizedDiffusion, PxrSurface (Burley)",
               colour="the profile's total (normalised)", radius=_DMFP, unit="dmfp",
               source="Christensen & Burley 2015 eq. 8; MoonRay NormalizedDiffusion.cc",
               profile="burley", burley_s=fits.burley_s_searchlight),
    Convention("burley-perpendicular", "normalized diffusion, perpendicular s for the mfp",
               renderers="Christensen & Burley 2015 (mfp parameterisation)",
               colour="the profile's total", radius=_MFP, unit="mfp",
               source="Christensen & Burley 2015 eq. 5", profile="burley",
               burley_s=fits.burley_s_perpendicular),
    Convention("burley-transmission", "normalized diffusion, diffuse-transmission s for the "
               "mfp", renderers="Christensen & Burley 2015; Cycles Christensen-Burley (with "
               "radius x 1/(4 pi))", colour="the profile's total", radius=_MFP, unit="mfp",
               source="Christensen & Burley 2015 eq. 6; Cycles bssrdf.h", profile="burley",
               burley_s=fits.burley_s_transmission),
    Convention("van-de-hulst", "van de Hulst albedo map, walked inside the dielectric",
               aliases=("openpbr", "standard-surface"),
               renderers="OpenPBR, Autodesk Standard Surface in a path tracer that bounds the "
                         "medium by its specular_ior (Mitsuba, pbrt)",
               colour="multiple-scattering albedo of an index-matched half-space",
               radius=_MFP, unit="mfp", boundary="dielectric",
               source="OpenPBR 1.1 spec; d'Eon, A Hitchhiker's Guide eq. 53.7",
               alpha_fit=fits.van_de_hulst_alpha, extinction=_sigma_t_plain),
    Convention("van-de-hulst-matched", "van de Hulst albedo map, index-matched walk",
               aliases=("openpbr-matched",),
               renderers="OpenPBR as its spec defines the albedo (boundary ignored)",
               colour="multiple-scattering albedo of an index-matched half-space",
               radius=_MFP, unit="mfp", boundary="matched",
               source="OpenPBR 1.1 spec", alpha_fit=fits.van_de_hulst_alpha,
               extinction=_sigma_t_plain),
    Convention("cycles-random-walk", "Cycles Random Walk: van de Hulst, radius x 1/(4 pi), "
               "no internal reflection", renderers="Blender Cycles (Principled, Random Walk)",
               colour="Subsurface colour (base colour)", radius="Subsurface radius x scale, "
               "an mfp x 4 pi", unit="mfp", boundary="entry",
               source="Cycles subsurface_random_walk.h, bssrdf.h",
               alpha_fit=fits.van_de_hulst_alpha, extinction=_sigma_t_cycles,
               alpha_max=0.999999, min_alpha=0.2, g_range=CYCLES_G),
    Convention("cycles-legacy", "Cycles Random Walk (Legacy): Wrenninge 2017 fit",
               renderers="Blender Cycles (Random Walk (Legacy))",
               colour="Subsurface colour", radius="radius x 1/(4 pi) = sigma_t' mfp",
               unit="mfp", boundary="entry", source="Cycles subsurface_random_walk.h; "
               "Wrenninge, Villemin & Hery 2017", alpha_fit=fits.wvh_alpha,
               extinction=_sigma_t_cycles_legacy, alpha_max=0.999999, min_alpha=0.2,
               g_range=CYCLES_G),
    Convention("cycles-skin", "Cycles Random Walk (Skin): radius x sqrt(3 (1 - Jensen "
               "alpha')), Wrenninge fit", renderers="Blender Cycles (Random Walk (Skin))",
               colour="Subsurface colour", radius=_DMFP + " (Jensen's)", unit="dmfp",
               boundary="cosine_entry", source="Cycles bssrdf.h bssrdf_setup_radius",
               alpha_fit=fits.wvh_alpha, extinction=_sigma_t_cycles_skin,
               alpha_max=0.999999, min_alpha=0.2, g_range=CYCLES_G),
    Convention("moonray-walk", "MoonRay random walk: its refit albedo, Chiang's s, radius x "
               "0.3333", renderers="MoonRay VolumeSubsurface", colour="scattering colour",
               radius="scattering radius (a dmfp-like radius, in 'shrekles' = 3 cm)",
               unit="dmfp", boundary="entry", source="MoonRay VolumeSubsurface.cc",
               alpha_fit=_moonray_alpha, colour_floor=MOONRAY_COLOUR_FLOOR,
               extinction=_sigma_t_s(_moonray_s, scale=0.3333, floor=0.001)),
    Convention("chiang-burley-2016", "Chiang, Kutz & Burley 2016 fits", aliases=("chiang",),
               renderers="Hyperion 2016; Arnold-style randomwalk", colour="surface albedo A",
               radius="dmfp-like distance d (sigma_t = 1/(d s))", unit="dmfp",
               boundary="matched", source="Chiang, Kutz & Burley 2016 eqs. 1-3",
               alpha_fit=lambda c, g: fits.chiang_alpha(c),
               extinction=_sigma_t_s(fits.burley_s_transmission)),
    Convention("hyperion-2018", "Burley et al. 2018 fits for an IOR 1.4 boundary",
               aliases=("hyperion",), renderers="Disney Hyperion 2018",
               colour="surface albedo A", radius="distance d (sigma_t = 1/(d s))",
               unit="dmfp", boundary="dielectric",
               source="Burley et al. 2018, The Design and Evolution of Disney's Hyperion "
                      "Renderer, 4.4.2", alpha_fit=lambda c, g: fits.hyperion_alpha(c),
               extinction=_sigma_t_s(fits.hyperion_s)),
    Convention("random-walk", "the medium itself: single-scattering albedo and mean free "
               "path, walked inside the dielectric",
               renderers="any path tracer with a dielectric-bounded homogeneous medium",
               colour="single-scattering albedo sigma_s/sigma_t", radius=_MFP, unit="mfp",
               boundary="dielectric", source="physics.transport",
               alpha_fit=lambda c, g: np.asarray(c, np.float64), extinction=_sigma_t_plain),
))
CONVENTIONS = CONVENTION.names


# {{{ media and what is rendered

def lookup(convention) -> Convention:
    """A convention by name or alias (ValueError listing them), or as given."""
    return convention if isinstance(convention, Convention) else CONVENTION[convention]


def medium(convention, colour, radius, eta=1.4, g=0.0) -> Medium:
    """The medium a walk convention's renderer walks (alpha clamped as it clamps; Cycles'
    alpha floor not applied: it is a throughput factor, ``rendered`` applies it)."""
    conv = lookup(convention)
    g = conv.renderer_g(g)
    if not conv.walk:
        if conv.profile == "burley":
            raise ValueError(f"convention={conv.name!r} is a profile, not a medium")
        model = "better" if conv.profile == "better-dipole" else "dipole"
        sa, ss = reference.albedo_to_coefficients(colour, radius, eta, model=model)
        return Medium(sa, ss, 0.0)          # reduced coefficients, isotropic
    alpha = np.clip(conv.alpha_fit(np.asarray(colour, np.float64), g), 0.0, conv.alpha_max)
    sigma_t = conv.extinction(colour, radius, eta, g)
    return Medium(sigma_t * (1.0 - alpha), sigma_t * alpha, float(g))


def _transport():
    from . import transport
    return transport


def _walk_eta(conv, eta):
    return eta if conv.boundary == "dielectric" else 1.0


def _walked(conv, alpha, eta, g):
    """The walk's own reflectance under the convention's boundary (no Cycles floor)."""
    if conv.boundary == "cosine_entry":
        if g == 0.0:                    # Chandrasekhar's H: exact, and cross-checks the solver
            return half_space.cosine_entry_reflectance_fast(alpha, eta)
        return (1.0 - half_space.diffuse_fresnel(eta)) * _transport().walk_reflectance(
            alpha, g=g, eta=1.0)
    if conv.boundary == "entry":
        if g == 0.0:
            return half_space.entry_reflectance_fast(alpha, eta)
        return _transport().first_crossing_walk_reflectance(alpha, g=g, eta=eta)
    return _transport().walk_reflectance(alpha, g=g, eta=_walk_eta(conv, eta))


def walk_rd(conv, alpha, eta, g):
    """The diffuse reflectance a walk convention renders for single-scattering ``alpha``:
    the walk under its boundary; Cycles' floor raises alpha to ``min_alpha`` and scales the
    throughput by alpha/min_alpha."""
    a = np.asarray(alpha, np.float64)
    rd = _walked(conv, np.maximum(a, conv.min_alpha), eta, g)
    if conv.min_alpha:
        rd = rd * np.where(a < conv.min_alpha, a / conv.min_alpha, 1.0)
    return rd


def rendered(convention, colour, radius, eta=1.4, g=0.0) -> Rendered:
    """Diffuse reflectance and median radius a convention's renderer produces."""
    conv = lookup(convention)
    g = conv.renderer_g(g)
    colour = np.asarray(colour, np.float64)
    radius = np.asarray(radius, np.float64)
    if not conv.walk:
        return Rendered(colour + 0.0 * radius, radius * unit_median(conv, colour, eta))
    m = medium(conv, colour, radius, eta, g)
    sigma_t = m.sigma_a + m.sigma_s
    alpha = m.sigma_s / sigma_t
    spread = _transport().walk_spread(np.maximum(alpha, conv.min_alpha), g=g,
                                      eta=_walk_eta(conv, eta), fraction=SPREAD_FRACTION)
    return Rendered(walk_rd(conv, alpha, eta, g), spread / sigma_t)


def rendered_rd(convention, colour, eta=1.4, g=0.0):
    """The diffuse reflectance alone (``rendered(...).rd``, no spread computed)."""
    conv = lookup(convention)
    g = conv.renderer_g(g)
    colour = np.asarray(colour, np.float64)
    if not conv.walk:
        return colour
    alpha = np.clip(conv.alpha_fit(colour, g), 0.0, conv.alpha_max)
    return walk_rd(conv, alpha, eta, g)


def unit_median(conv, colour, eta, g=0.0):
    """Median radius per unit of the convention's radius, as a function of colour."""
    if conv.walk:
        return rendered(conv.name, colour, 1.0, eta, g).median
    colour = np.asarray(colour, np.float64)
    if conv.profile == "burley":
        return fits.BURLEY_MEDIAN_X / conv.burley_s(colour)
    return profile_median(conv.profile, colour, eta)

# }}}


# {{{ diffusion profiles' medians

def _dipole_sources(alpha_prime, sigma_t, eta):
    """Jensen's dipole: (mu_tr, z_r, z_v) of its real and virtual sources."""
    fdr = fits.jensen_fdr(eta)
    big_a = (1.0 + fdr) / (1.0 - fdr)
    mu = np.sqrt(3.0 * (1.0 - alpha_prime)) * sigma_t
    z_r = 1.0 / sigma_t
    return mu, z_r, z_r * (1.0 + 4.0 / 3.0 * big_a)


def dipole_tail(r, alpha_prime, sigma_t, eta):
    """Jensen's dipole: energy beyond radius r, alpha'/2 sum_z z e^(-mu d)/d over the real
    (z_r = 1/sigma_t') and virtual (z_v = z_r (1 + 4A/3)) sources, mu = sqrt(3 rho) sigma_t'
    (the closed form of docs/model.md "Radial energy" with Cphi = 0, Ce = 1)."""
    mu, z_r, z_v = _dipole_sources(alpha_prime, sigma_t, eta)
    d_r, d_v = np.hypot(r, z_r), np.hypot(r, z_v)
    return 0.5 * alpha_prime * (z_r * np.exp(-mu * d_r) / d_r + z_v * np.exp(-mu * d_v) / d_v)


def dipole_tail_slope(r, alpha_prime, sigma_t, eta):
    """-d tail / d(log r) of Jensen's dipole: alpha'/2 r^2 sum_z z (mu d + 1) e^(-mu d)/d^3."""
    mu, z_r, z_v = _dipole_sources(alpha_prime, sigma_t, eta)
    d_r, d_v = np.hypot(r, z_r), np.hypot(r, z_v)
    return 0.5 * alpha_prime * r * r * (z_r * (mu * d_r + 1.0) * np.exp(-mu * d_r) / d_r**3
                                        + z_v * (mu * d_v + 1.0) * np.exp(-mu * d_v) / d_v**3)


#: the median's search interval [1e-8, 1e3] per unit dmfp, in log r shifted to be positive
#: (the solver's relative stopping rule then means ~1e-14 of the median, not of log r near 0)
MEDIAN_LOG_RANGE, MEDIAN_SHIFT = (np.log(1e-8), np.log(1e3)), 20.0


def profile_median(profile, colour, eta):
    """Median radius of a dipole profile per unit dmfp: tail(r) = rd/2 solved in log r by
    ``reference.solve_increasing`` (safeguarded Newton, the slope -dtail/dlog r = 2 pi r^2
    R(r); the tail is decreasing in r): ~5 steps, where a bisection took 80."""
    colour = np.asarray(colour, np.float64)
    model = "better" if profile == "better-dipole" else "dipole"
    sa, ss = reference.albedo_to_coefficients(colour, 1.0, eta, model=model)
    st = np.reshape(sa + ss, -1)
    a = np.reshape(ss, -1) / st

    def minus_tail(x, idx):
        r = np.exp(x - MEDIAN_SHIFT)
        if model == "better":
            return (-reference.profile_tail(r, a[idx], st[idx], eta),
                    2.0 * np.pi * r * r * reference.profile(r, a[idx], st[idx], eta))
        return (-dipole_tail(r, a[idx], st[idx], eta),
                dipole_tail_slope(r, a[idx], st[idx], eta))

    half = 0.5 * minus_tail(np.full(st.shape, -np.inf), np.arange(st.size))[0]
    lo, hi = (v + MEDIAN_SHIFT for v in MEDIAN_LOG_RANGE)
    x = reference.solve_increasing(minus_tail, half, lo, hi)
    return np.exp(x - MEDIAN_SHIFT).reshape(colour.shape)

# }}}


# {{{ inverse: the colour that renders a reflectance

def increasing_inverse(f, target, lo=0.0, hi=1.0, iterations=64):
    """Vectorised bisection: x in [lo, hi] with f(x) = target, f increasing (2^-64 of the
    interval: float64's resolution)."""
    target = np.asarray(target, np.float64)
    a = np.full(target.shape, lo)
    b = np.full(target.shape, hi)
    for _ in range(iterations):
        mid = 0.5 * (a + b)
        below = f(mid) < target
        a, b = np.where(below, mid, a), np.where(below, b, mid)
    return 0.5 * (a + b)


def colour_for(convention, rd, eta=1.4, g=0.0):
    """The colour with which a convention's renderer produces diffuse reflectance ``rd``
    (``rd`` within ``rd_range``; NaN outside)."""
    conv = lookup(convention)
    g = conv.renderer_g(g)
    rd = np.asarray(rd, np.float64)
    lo, hi = rd_range(conv.name, eta, g)
    inside = (rd >= lo) & (rd <= hi)
    if not conv.walk:
        return np.where(inside, rd, np.nan)
    r = np.where(inside, rd, 0.5 * (lo + hi))
    alpha = single_scattering_albedo(conv, r, eta, g)
    colour = increasing_inverse(lambda c: np.clip(conv.alpha_fit(c, g), 0.0, conv.alpha_max),
                                alpha)
    # below a colour floor every colour renders alike: the floor is the one that says so
    return np.where(inside, np.maximum(colour, conv.colour_floor), np.nan)


def single_scattering_albedo(conv, rd, eta, g):
    """The alpha whose walk renders ``rd`` under the convention's boundary (and floor)."""
    if conv.boundary in ("entry", "cosine_entry"):
        return increasing_inverse(lambda a: walk_rd(conv, a, eta, g), rd)
    t = _transport()
    alpha = t.walk_alpha(rd, g=g, eta=_walk_eta(conv, eta))
    if conv.min_alpha:        # below the floor's reflectance, rd = alpha/min_alpha R(min_alpha)
        r_min = t.walk_reflectance(conv.min_alpha, g=g, eta=_walk_eta(conv, eta))
        alpha = np.where(rd < r_min, conv.min_alpha * rd / r_min, alpha)
    return alpha


def rd_range(convention, eta=1.4, g=0.0):
    """(lowest, highest) diffuse reflectance the convention can render: its colour's [0, 1]
    (a colour floor raises the lowest above 0)."""
    conv = lookup(convention)
    if not conv.walk:
        return 0.0, 1.0
    g = conv.renderer_g(g)
    top = np.clip(conv.alpha_fit(np.float64(1.0), g), 0.0, min(conv.alpha_max, 1.0 - 1e-9))
    low = (float(walk_rd(conv, conv.alpha_fit(np.float64(conv.colour_floor), g), eta, g))
           if conv.colour_floor else 0.0)          # MoonRay's colour floor renders more than 0
    return low, float(walk_rd(conv, top, eta, g))

# }}}
