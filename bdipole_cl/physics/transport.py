"""What a random walk renders: the diffuse reflectance of a semi-infinite medium under a smooth
dielectric boundary, by a deterministic transport solver (docs/transport.md).

A float64 reference, vectorised over alpha, written for accuracy first:

* the azimuthally averaged Henyey-Greenstein phase function on a composite Gauss quadrature
  (split at the critical cosine, where the Fresnel reflectance has its kink; the last interval
  is Gauss-Radau, so mu = 1 is a node and normal incidence is a column of the matrices);
* a thin layer from the diamond (trapezoidal) scheme, doubled to an optical depth where its
  transmission is below 1e-18 (the semi-infinite medium, to rounding);
* the Fresnel interface added in the quadrature: refraction into the medium (n^2 law), total
  internal reflection, the light escaping through the Fresnel transmission.

The reflectance excludes the surface's own (specular) reflection, set apart as
``specular_reflectance``. ``walk_reflectance`` evaluates a Chebyshev series in van de Hulst's
similarity parameter ``s = sqrt((1 - alpha)/(1 - alpha g))`` (``Rd`` is analytic in s on
[0, 1]) built once per (g, eta) from the direct solver (``solve_reflectance``) and cached in
memory and on disk; ``walk_alpha`` inverts it, ``walk_spread`` reads Monte Carlo radii.

Notation: ``alpha`` single-scattering albedo sigma_s/sigma_t [1]; ``rho = 1 - alpha``;
``s`` similarity parameter [1]; ``g`` Henyey-Greenstein mean cosine [1]; ``eta`` relative index of
refraction, medium over outside [1]; ``mu`` cosine to the normal [1]; ``tau`` optical depth
(mean free paths, 1/sigma_t) [1].
"""
from __future__ import annotations

import hashlib
import itertools
import os
import tempfile
from pathlib import Path

import numpy as np
from numpy.polynomial import chebyshev, legendre
from scipy.special import ellipe

from ..caches import ByteCache, user_cache_dir
from ..durable import durable_replace
from . import transport_tables as tables
from .fresnel import fresnel_moments_exact, fresnel_reflectance
from .transport_tables import alpha_of_s, rho_of_s, similarity_s  # noqa: F401 (re-exported)

#: the two incidences the reflectance is defined for (docs/transport.md "Incidence")
INCIDENCES = ("diffuse", "normal")
#: how a walk leaves: through the dielectric, or at its first crossing (docs/transport.md)
EXITS = ("dielectric", "first_crossing")
#: the interpolant's curves: one per (exit, incidence)
CURVE_KEYS = tuple(i if e == "dielectric" else f"{e}_{i}" for e in EXITS for i in INCIDENCES)
#: g interval: the quadrature orders below are measured to keep Rd within ~1e-9 there
G_RANGE = (-0.9, 0.9)
#: eta interval (medium over outside)
ETA_RANGE = (0.5, 2.5)
#: below this cosine the quadrature splits once more when no critical cosine is above it
#: (a node-dense interval near mu = 1, where a forward-peaked phase function is sharpest)
MU_SPLIT = 0.5
#: the thin layer's optical depth (diamond scheme: error O(tau0^2) per unit depth)
TAU0 = 2.0 ** -20
#: doubling stops once every transmission entry is below this (semi-infinite to rounding)
T_STOP = 1e-18
#: doubling steps at most (2^-20 doubled 100 times: 1e24 mean free paths)
MAX_DOUBLINGS = 100
#: Chebyshev degree of the interpolant Rd(s) at least (docs/transport.md "Interpolant")
CHEB_DEGREE = 32

CURVES = ByteCache("transport reflectance curves", 4 << 20)


def check_arguments(g, eta, incidence, exit_="dielectric"):
    """Raise ValueError naming the first bad argument."""
    if exit_ not in EXITS:
        raise ValueError(f"exit={exit_!r}: expected one of {', '.join(EXITS)}")
    if incidence not in INCIDENCES:
        raise ValueError(f"incidence={incidence!r}: expected one of {', '.join(INCIDENCES)}")
    if not G_RANGE[0] <= g <= G_RANGE[1]:
        raise ValueError(f"g={g!r} is outside [{G_RANGE[0]}, {G_RANGE[1]}], the range the "
                         f"transport solver's quadrature is measured on")
    if not ETA_RANGE[0] <= eta <= ETA_RANGE[1]:
        raise ValueError(f"eta={eta!r} is outside [{ETA_RANGE[0]}, {ETA_RANGE[1]}]")


def quadrature_order(g: float) -> int:
    """Gauss nodes per interval for a mean cosine g (measured: docs/transport.md)."""
    a = abs(g)
    return 16 if a <= 0.5 else 24 if a <= 0.7 else 32 if a <= 0.8 else 48


# {{{ quadrature

def critical_cosine(eta: float) -> float:
    """Cosine (inside) of total internal reflection, 0 when eta <= 1."""
    return float(np.sqrt(max(1.0 - 1.0 / eta**2, 0.0)))


def gauss_radau_right(n: int):
    """Gauss-Radau nodes and weights on [0, 1] with the node 1 fixed (exact to degree 2n-2).

    Nodes of the rule fixed at -1 on [-1, 1] are the roots of (P_{n-1} + P_n)/(1 + x), weights
    (1 - x)/(n P_{n-1}(x))^2 and 2/n^2 at -1 (Abramowitz & Stegun 25.4.31); mirrored here."""
    c = np.zeros(n + 1)
    c[n - 1:] = 1.0
    x = np.sort(np.real(legendre.legroots(c)))
    x[0] = -1.0
    p = legendre.legval(x, np.eye(n)[n - 1])
    w = (1.0 - x) / (n * p) ** 2
    w[0] = 2.0 / n**2
    t = 0.5 * (1.0 - x[::-1])
    t[-1] = 1.0
    return t, 0.5 * w[::-1]


def quadrature(eta: float, n: int):
    """Nodes mu in (0, 1] and weights of the hemisphere: n nodes on each of the intervals cut
    at 0, the critical cosine mu_c (eta > 1), MU_SPLIT (when mu_c is below it) and 1.

    The first interval and the one starting at mu_c are graded at their start (mu = a + (b-a)
    u^2): it smooths the Fresnel kink sqrt(mu - mu_c) and the mu log mu of the reflection
    function at grazing. The last interval is Gauss-Radau (mu = 1 a node, for normal
    incidence)."""
    mu_c = critical_cosine(eta)
    cuts = [0.0] + ([mu_c] if mu_c > 0.0 else []) + ([MU_SPLIT] if mu_c < MU_SPLIT else [])
    cuts.append(1.0)
    x, wx = legendre.leggauss(n)
    gauss = (0.5 * (x + 1.0), 0.5 * wx)
    mus, weights = [], []
    for k, (a, b) in enumerate(itertools.pairwise(cuts)):
        u, wu = gauss_radau_right(n) if k == len(cuts) - 2 else gauss
        if a == 0.0 or a == mu_c:
            mus.append(a + (b - a) * u**2)
            weights.append(wu * 2.0 * (b - a) * u)
        else:
            mus.append(a + (b - a) * u)
            weights.append(wu * (b - a))
    return np.concatenate(mus), np.concatenate(weights)

# }}}


# {{{ phase function and layer operators

def hg_azimuthal(mu_i, mu_j, g: float):
    """Azimuthal mean of the Henyey-Greenstein phase function (normalised to 1 over the
    sphere's 4 pi), between directions of cosines mu_i and mu_j:

    p0 = (1 - g^2)/pi Int_0^pi (a - b cos phi)^(-3/2) dphi = 2 (1 - g^2) E(m) / (pi (a - b)
    sqrt(a + b)), a = 1 + g^2 - 2 g mu_i mu_j, b = 2 |g| sin_i sin_j, m = 2b/(a + b)
    (Gradshteyn & Ryzhik 2.571; E the complete elliptic integral of the second kind)."""
    mu_i, mu_j = np.asarray(mu_i, np.float64), np.asarray(mu_j, np.float64)
    if g == 0.0:
        return np.ones(np.broadcast(mu_i, mu_j).shape)
    sin_i = np.sqrt(np.clip((1.0 - mu_i) * (1.0 + mu_i), 0.0, None))
    sin_j = np.sqrt(np.clip((1.0 - mu_j) * (1.0 + mu_j), 0.0, None))
    a = 1.0 + g * g - 2.0 * g * mu_i * mu_j
    b = 2.0 * abs(g) * sin_i * sin_j
    return 2.0 * (1.0 - g * g) * ellipe(2.0 * b / (a + b)) / (np.pi * (a - b) * np.sqrt(a + b))


def phase_matrices(mu, w, g: float):
    """``(P++, P+-)``: p0(mu_i, mu_j) and p0(mu_i, -mu_j) on the nodes, scaled symmetrically
    (d_i P_ij d_j) so that each row conserves energy in the quadrature,
    (1/2) sum_j w_j (P++ + P+-)_ij = 1, and stays symmetric (reciprocity)."""
    pp = hg_azimuthal(mu[:, None], mu[None, :], g)
    pm = hg_azimuthal(mu[:, None], -mu[None, :], g)
    total = pp + pm
    d = np.ones_like(mu)
    for _ in range(200):
        s = 0.5 * d * (total @ (w * d))
        d = d / np.sqrt(s)
        if np.max(np.abs(s - 1.0)) <= 2e-16:
            break
    scale = np.outer(d, d)
    return pp * scale, pm * scale


def layer_operators(mu, w, g: float, rho):
    """``(Gamma, Sigma)`` of d/dtau I+ = -Gamma I+ + Sigma I-, batched over rho:
    Gamma = M^-1 (I - alpha/2 P++ W), Sigma = M^-1 alpha/2 P+- W, with 1 - alpha/2 P++ written
    as (1 - P++/2) + rho P++/2 so that a small rho keeps its digits."""
    rho = np.asarray(rho, np.float64)[..., None, None]
    pp, pm = phase_matrices(mu, w, g)
    half_pp, half_pm = 0.5 * pp * w, 0.5 * pm * w
    gamma = ((np.eye(len(mu)) - half_pp) + rho * half_pp) / mu[:, None]
    sigma = (1.0 - rho) * half_pm / mu[:, None]
    return gamma, sigma

# }}}


# {{{ doubling

def thin_layer(gamma, sigma, tau0: float):
    """``(R, E = 1 - T)`` of a layer of depth tau0 by the diamond scheme (Wiscombe 1976):
    A = 1 + h Gamma, B = h Sigma, h = tau0/2, S = A - B A^-1 B,
    R = 2 A^-1 B S^-1, E = 2 S^-1 (h Gamma - B A^-1 B) (no cancellation in 1 - T)."""
    h = 0.5 * tau0
    a = np.eye(gamma.shape[-1]) + h * gamma
    b = h * sigma
    a_inv_b = np.linalg.solve(a, b)
    bab = b @ a_inv_b
    s = a - bab
    r = 2.0 * np.swapaxes(np.linalg.solve(np.swapaxes(s, -1, -2),
                                          np.swapaxes(a_inv_b, -1, -2)), -1, -2)
    e = 2.0 * np.linalg.solve(s, h * gamma - bab)
    return r, e


def double(r, e, t_stop=T_STOP, max_doublings=MAX_DOUBLINGS, keep_e=False):
    """Double a homogeneous layer until its transmission is below ``t_stop``:
    G = (1 - R R)^-1, R' = R + T R G T, T' = T G T, written for E = 1 - T as
    E' = 2E - E E - T R R G T (the thin layers' T = 1 - E keeps its digits).
    Returns ``(R, doublings)``, or ``(R, E)`` with ``keep_e``."""
    eye = np.eye(r.shape[-1])
    k = 0
    while k < max_doublings:
        t = eye - e
        if np.max(np.abs(t)) < t_stop:
            break
        rr = r @ r
        x = np.linalg.solve(eye - rr, t)
        r, e = r + t @ r @ x, 2.0 * e - e @ e - t @ rr @ x
        k += 1
    return (r, e) if keep_e else (r, k)


def semi_infinite_reflection(rho, g: float, eta: float, n: int | None = None,
                             tau0: float = TAU0):
    """``(mu, w, R)``: the quadrature and the reflection matrix (radiance to radiance) of the
    semi-infinite medium without boundary, batched over rho."""
    mu, w = quadrature(eta, n or quadrature_order(g))
    gamma, sigma = layer_operators(mu, w, g, rho)
    r, e = thin_layer(gamma, sigma, tau0)
    r, _ = double(r, e)
    return mu, w, r

def slab(rho, g: float, eta: float, doublings: int, n: int | None = None,
         tau0: float = TAU0):
    """``(mu, w, R, T)`` of a slab of depth tau0 2^doublings (no boundary), for the checks of
    energy conservation and convergence in depth."""
    mu, w = quadrature(eta, n or quadrature_order(g))
    gamma, sigma = layer_operators(mu, w, g, rho)
    r, e = thin_layer(gamma, sigma, tau0)
    r, e = double(r, e, t_stop=0.0, max_doublings=doublings, keep_e=True)
    return mu, w, r, np.eye(len(mu)) - e

# }}}


# {{{ the Fresnel interface

def incident_radiance(mu, w, eta: float, incidence: str):
    """Radiance just inside the surface for unit outside irradiance over pi (radiance 1 for
    diffuse; a beam of flux pi along the normal, on the Radau node mu = 1, for normal)."""
    transmit = 1.0 - fresnel_reflectance(mu, eta)
    if incidence == "diffuse":
        return eta**2 * transmit                     # n^2 law of radiance
    beam = np.zeros_like(mu)
    k = int(np.argmax(mu))
    beam[k] = transmit[k] / (2.0 * w[k] * mu[k])     # 2 pi sum w mu D = pi (1 - F(1))
    return beam


def boundary_reflectance(mu, w, r, eta: float, incidence: str):
    """Diffuse reflectance with the interface added: U = (1 - R F)^-1 R D0 below the surface,
    Rd = 2 sum_i w_i mu_i (1 - F_i) U_i (etendue: eta^2 mu dmu inside = mu_o dmu_o outside)."""
    f = fresnel_reflectance(mu, eta)
    d0 = incident_radiance(mu, w, eta, incidence)
    eye = np.eye(len(mu))
    u = np.linalg.solve(eye - r * f, (r @ d0)[..., None])[..., 0]
    return 2.0 * np.sum(w * mu * (1.0 - f) * u, axis=-1)


def first_crossing_reflectance(mu, w, r, eta: float, incidence: str):
    """Rd of a walk refracted in that leaves at its first crossing (no Fresnel on the way
    out): 2 sum_i w_i mu_i (R D0)_i; 1 - specular at alpha = 1, as under the dielectric."""
    d0 = incident_radiance(mu, w, eta, incidence)
    return 2.0 * np.sum(w * mu * (r @ d0), axis=-1)


def specular_reflectance(eta: float, incidence: str = "diffuse") -> float:
    """The surface's own Fresnel reflectance for light from outside: 2 Int F(mu_o) mu_o dmu_o
    (diffuse) or ((eta - 1)/(eta + 1))^2 (normal). What walk_reflectance sets apart."""
    if incidence not in INCIDENCES:
        raise ValueError(f"incidence={incidence!r}: expected one of {', '.join(INCIDENCES)}")
    if incidence == "normal":
        return float(((eta - 1.0) / (eta + 1.0)) ** 2)
    return float(2.0 * fresnel_moments_exact(1.0 / eta)[0])


def solve_reflectance(alpha=None, g: float = 0.0, eta: float = 1.0, incidence="diffuse",
                      n: int | None = None, tau0: float = TAU0, rho=None):
    """The direct solver: Rd of each alpha (or of rho = 1 - alpha when given, the precise
    argument near alpha = 1). Slow (one doubling per value); walk_reflectance interpolates it."""
    check_arguments(g, eta, incidence)
    rho = np.asarray(1.0 - np.asarray(alpha, np.float64) if rho is None else rho, np.float64)
    mu, w, r = semi_infinite_reflection(rho.reshape(-1), g, eta, n, tau0)
    rd = boundary_reflectance(mu, w, r, eta, incidence).reshape(rho.shape)
    # alpha = 1: a conservative medium returns all the light that entered (1 - specular).
    # Doubling cannot reach it (its T falls as 1/tau, and 1 - Rd ~ sqrt(rho) turns rounding
    # of order eps into 1e-8..1e-6); the finite slab's R + T = 1 is checked instead
    # (docs/transport.md "Energy").
    return np.where(rho == 0.0, 1.0 - specular_reflectance(eta, incidence), rd)

# }}}


# {{{ the interpolant and the public functions

def chebyshev_degree(g: float) -> int:
    """Degree of the Chebyshev series of Rd(s): alpha(s) has a pole at s = 1/sqrt(g) (g > 0),
    which bounds the series' convergence to rho^-N, rho = x + sqrt(x^2 - 1), x = 2/sqrt(g) - 1
    (the Bernstein ellipse); the degree brings rho^-N to 1e-16, within [32, 128]."""
    if g <= 0.25:
        return CHEB_DEGREE
    x = 2.0 / np.sqrt(g) - 1.0
    return int(np.clip(np.ceil(37.0 / np.log(x + np.sqrt(x * x - 1.0))), CHEB_DEGREE, 128))


def chebyshev_nodes(degree: int = CHEB_DEGREE):
    """Chebyshev-Lobatto points on [0, 1] (0 first)."""
    return 0.5 * (1.0 - np.cos(np.pi * np.arange(degree + 1) / degree))


def node_reflectances(s, g: float, eta: float):
    """Rd at the similarity parameters s for each incidence and exit (CURVE_KEYS), one batched
    doubling; s = 0 (alpha = 1) exact by energy conservation, Rd = 1 - specular."""
    mu, w, r = semi_infinite_reflection(rho_of_s(s, g), g, eta)
    out = {}
    for incidence in INCIDENCES:
        conservative = 1.0 - specular_reflectance(eta, incidence)
        for key, rd in ((incidence, boundary_reflectance), (f"{EXITS[1]}_{incidence}",
                                                            first_crossing_reflectance)):
            out[key] = np.where(s == 0.0, conservative, rd(mu, w, r, eta, incidence))
    return out


#: the series is refined (degree doubled, the old nodes kept) while its last three
#: coefficients exceed this: a strongly reflecting boundary (eta 2.5: 84% of the inner
#: hemisphere totally reflected) bends Rd(s) near s = 0 more than g alone predicts
CHEB_TAIL = 1e-12
CHEB_MAX_DEGREE = 256


def computed_curves(g: float, eta: float):
    """Chebyshev coefficients (in x = 2s - 1) of Rd(s) for each incidence, from doublings of
    the medium at Chebyshev-Lobatto points: chebyshev_degree(g) first, doubled while the tail
    is above CHEB_TAIL (the degree-N nodes are the even ones of degree 2N)."""
    degree = chebyshev_degree(g)
    s = chebyshev_nodes(degree)
    rd = node_reflectances(s, g, eta)
    while True:
        curves = {k: chebyshev.chebfit(2.0 * s - 1.0, v, degree) for k, v in rd.items()}
        tail = max(np.max(np.abs(c[-3:])) for c in curves.values())
        if tail <= CHEB_TAIL or degree >= CHEB_MAX_DEGREE:
            break
        degree *= 2
        s = chebyshev_nodes(degree)
        new = node_reflectances(s[1::2], g, eta)
        for k in rd:
            both = np.empty(degree + 1)
            both[0::2], both[1::2] = rd[k], new[k]
            rd[k] = both
    return curves


def curve_cache_path(g: float, eta: float) -> Path:
    """The curves' file in the user cache dir, named by (g, eta) exactly and by a digest of
    the solver's source (any change to it, or to the Fresnel formula, is a new file)."""
    here = Path(__file__).resolve().parent
    digest = hashlib.sha256()
    for name in ("transport.py", "transport_tables.py", "fresnel.py"):
        digest.update((here / name).read_bytes())
    return (user_cache_dir() / tables.CURVES_FOLDER
            / f"curves-{digest.hexdigest()[:16]}-g{float(g).hex()}-eta{float(eta).hex()}.npz")


def read_cached_curves(path: Path):
    """The curves from a cache file, or None when absent or not as written (then rebuilt)."""
    try:
        with np.load(path) as data:
            curves = {k: np.array(data[k], np.float64) for k in CURVE_KEYS}
    except (OSError, KeyError, ValueError):
        return None
    ok = all(c.ndim == 1 and CHEB_DEGREE < len(c) <= CHEB_MAX_DEGREE + 1
             and np.all(np.isfinite(c)) for c in curves.values())
    return curves if ok else None


def write_cached_curves(path: Path, curves) -> None:
    """Temp file, verified by reading back, then a durable rename; a cache that cannot be
    written is only a cache (nothing raised)."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(suffix=".npz", dir=path.parent)
        try:
            with os.fdopen(fd, "wb") as f:
                np.savez(f, **curves)
            back = read_cached_curves(Path(tmp))
            if back is None or any(not np.array_equal(back[k], curves[k]) for k in curves):
                return
            durable_replace(tmp, path)
        finally:
            if os.path.exists(tmp):
                os.unlink(tmp)
    except OSError:
        return


@CURVES.memoize
def reflectance_curves(g: float, eta: float):
    """The curves of (g, eta), read-only: from memory, else from the user cache dir
    (curve_cache_path), else computed_curves (and written there)."""
    check_arguments(g, eta, "diffuse")
    path = curve_cache_path(g, eta)
    curves = read_cached_curves(path)
    if curves is None:
        curves = computed_curves(g, eta)
        write_cached_curves(path, curves)
    for c in curves.values():
        c.setflags(write=False)
    return curves


def reflectance_curve(g: float, eta: float, incidence: str, exit_: str = "dielectric"):
    """The Chebyshev coefficients of Rd(s) of one incidence and exit (reflectance_curves)."""
    key = incidence if exit_ == "dielectric" else f"{exit_}_{incidence}"
    return reflectance_curves(float(g), float(eta))[key]


def reflectance_of_s(s, g: float, eta: float, incidence: str, exit_: str = "dielectric"):
    """Rd of the similarity parameter s from the cached interpolant."""
    check_arguments(g, eta, incidence, exit_)
    coefs = reflectance_curve(float(g), float(eta), incidence, exit_)
    return chebyshev.chebval(2.0 * np.asarray(s, np.float64) - 1.0, coefs)


def walk_reflectance(alpha, g: float = 0.0, eta: float = 1.0, incidence: str = "diffuse"):
    """Total diffuse reflectance [1] of a semi-infinite medium of single-scattering albedo
    alpha, HG mean cosine g, under a smooth dielectric boundary of relative index eta,
    specular reflection excluded; incidence "diffuse" (uniform environment) or "normal".
    alpha outside [0, 1] is an error; NaN gives NaN."""
    return reflectance_of_s(similarity_s(checked_alpha(alpha), g), g, eta, incidence)


def first_crossing_walk_reflectance(alpha, g: float = 0.0, eta: float = 1.0,
                                    incidence: str = "diffuse"):
    """walk_reflectance of a walk refracted in that leaves at its first surface crossing,
    without Fresnel (Cycles' walks: docs/transport.md "First crossing")."""
    return reflectance_of_s(similarity_s(checked_alpha(alpha), g), g, eta, incidence,
                            "first_crossing")


def checked_alpha(alpha):
    """alpha as float64, ValueError naming the first value outside [0, 1] (NaN passes)."""
    a = np.asarray(alpha, np.float64)
    bad = (a < 0.0) | (a > 1.0)
    if np.any(bad):
        raise ValueError(f"alpha={float(a[bad].flat[0])!r} is outside [0, 1]")
    return a


def walk_alpha(rd, g: float = 0.0, eta: float = 1.0, incidence: str = "diffuse"):
    """The single-scattering albedo alpha whose walk_reflectance is rd (docs/transport.md
    "Inversion": rd <= 0 gives 0, rd >= the reflectance of alpha = 1 gives 1, NaN stays NaN)."""
    return tables.evaluate_inverse(inverse_table(float(g), float(eta), incidence), rd)[0]


def walk_rho(rd, g: float = 0.0, eta: float = 1.0, incidence: str = "diffuse"):
    """1 - walk_alpha(rd) [1] with its digits near alpha = 1 (from s: rho = s^2 (1 - g)/
    (1 - g s^2), relative error ~1e-12 where 1 - alpha itself would keep only eps/rho);
    the same clipping (rd <= 0: 1, rd >= the maximum: 0; NaN stays NaN)."""
    table = inverse_table(float(g), float(eta), incidence)
    alpha, s = tables.evaluate_inverse(table, rd)
    upper = np.asarray(rd, np.float64) >= table.rd_split
    return np.where(upper, rho_of_s(s, g), 1.0 - alpha)


@tables.INVERSE_TABLES.memoize
def inverse_table(g: float, eta: float, incidence: str) -> tables.InverseTable:
    """The monotone table of s over Rd of one (g, eta, incidence), checked when built."""
    check_arguments(g, eta, incidence)
    return tables.build_inverse_table(reflectance_curve(g, eta, incidence), g)


def walk_spread(alpha, g: float = 0.0, eta: float = 1.0, fraction: float = 0.5):
    """Radius [mean free paths, 1/sigma_t] of the disk around a normally incident pencil beam
    that holds ``fraction`` of the diffusely reflected energy (Monte Carlo table:
    docs/transport.md "Spread")."""
    check_arguments(g, eta, "normal")
    s = similarity_s(checked_alpha(alpha), g)
    return tables.spread_lookup(s, float(g), float(eta), float(fraction))


def walk_spread_stderr(alpha, g: float = 0.0, eta: float = 1.0, fraction: float = 0.5):
    """The Monte Carlo standard error of walk_spread [mean free paths], interpolated alike."""
    check_arguments(g, eta, "normal")
    table = tables.spread_table()
    s = similarity_s(checked_alpha(alpha), g)
    return tables.spread_lookup(s, float(g), float(eta), float(fraction), table.stderr)

# }}}
