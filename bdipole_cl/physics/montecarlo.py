"""An independent Monte Carlo of the random walk (docs/transport.md "Monte Carlo").

Photon random walks in a homogeneous half-space z > 0 (units: the mean free path 1/sigma_t)
under a smooth dielectric boundary of relative index eta (medium over outside), vectorised in
NumPy, float64, seeded. Written apart from ``transport`` (it shares no code with it, not even
the Fresnel formula), to check it:

* entry: the outside direction is cosine-distributed (diffuse) or along the normal; the
  photon enters with weight 1 - F (the specular part is set apart, not sampled);
* flights of length -log(u), Henyey-Greenstein scattering (the inverse CDF), implicit capture
  (the weight times alpha at each collision) and Russian roulette below ROULETTE_WEIGHT;
* at the boundary the weight splits: w (1 - F) escapes (tallied, with the exit radius), w F is
  mirrored back (total internal reflection: F = 1).

Each photon's escaped weight is one sample; the reflectance is their mean and its standard
error their standard deviation over sqrt(paths). The exit radii (for normal incidence, a pencil
beam at the origin) are tallied in log-spaced bins, per batch: the radius holding a fraction of
the reflected energy and its standard error come from the batches.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

#: weight below which Russian roulette plays (survivors get weight / ROULETTE_SURVIVAL)
ROULETTE_WEIGHT = 1e-2
ROULETTE_SURVIVAL = 0.1
#: photons walked at once (memory: ~20 float64 arrays of this size)
CHUNK = 1 << 17
#: exit radius bins: log-spaced edges [mean free paths]; r < RADIUS_MIN goes to the first
RADIUS_MIN, RADIUS_MAX, RADIUS_BINS = 1e-4, 1e5, 3600
RADIUS_EDGES = np.geomspace(RADIUS_MIN, RADIUS_MAX, RADIUS_BINS + 1)


class WalkResult(NamedTuple):
    """A Monte Carlo estimate: reflectance (specular excluded) with its standard error, the
    paths walked, and the exit-radius histogram per batch (normal incidence: a pencil)."""

    reflectance: float
    stderr: float
    paths: int
    radius_hist: np.ndarray      # (batches, RADIUS_BINS + 1): bin 0 holds r < RADIUS_MIN


def dielectric_reflectance(cos_i, n_ratio):
    """Unpolarised Fresnel reflectance for light meeting a plane boundary at cosine cos_i from
    the side of relative index n_ratio = n_incident / n_transmitted; 1 past the critical angle."""
    cos_i = np.asarray(cos_i, np.float64)
    sin2_t = n_ratio * n_ratio * (1.0 - cos_i * cos_i)
    tir = sin2_t >= 1.0
    cos_t = np.sqrt(np.where(tir, 0.0, 1.0 - sin2_t))
    rs = (n_ratio * cos_i - cos_t) / (n_ratio * cos_i + cos_t)
    rp = (cos_i - n_ratio * cos_t) / (cos_i + n_ratio * cos_t)
    return np.where(tir, 1.0, 0.5 * (rs * rs + rp * rp))


def sample_hg_cosine(u, g: float):
    """cos theta of Henyey-Greenstein by its inverse CDF (g = 0: uniform on [-1, 1])."""
    if abs(g) < 1e-6:
        return 2.0 * u - 1.0
    frac = (1.0 - g * g) / (1.0 - g + 2.0 * g * u)
    return np.clip((1.0 + g * g - frac * frac) / (2.0 * g), -1.0, 1.0)


def scatter(ux, uy, uz, cos_t, phi):
    """New unit direction at angle acos(cos_t), azimuth phi, around (ux, uy, uz)."""
    sin_t = np.sqrt(np.maximum(1.0 - cos_t * cos_t, 0.0))
    cp, sp = np.cos(phi), np.sin(phi)
    polar = np.abs(uz) > 0.99999
    den = np.sqrt(np.maximum(1.0 - uz * uz, 1e-300))
    nx = np.where(polar, sin_t * cp,
                  sin_t * (ux * uz * cp - uy * sp) / den + ux * cos_t)
    ny = np.where(polar, sin_t * sp,
                  sin_t * (uy * uz * cp + ux * sp) / den + uy * cos_t)
    nz = np.where(polar, np.sign(uz) * cos_t, -sin_t * cp * den + uz * cos_t)
    norm = np.sqrt(nx * nx + ny * ny + nz * nz)          # keep unit length over long walks
    return nx / norm, ny / norm, nz / norm


def enter(rng, n: int, eta: float, incidence: str):
    """Initial directions inside (uz > 0 is into the medium) and weights 1 - F."""
    if incidence == "normal":
        mu_o = np.ones(n)
    else:
        mu_o = np.sqrt(rng.random(n))                     # cosine-weighted: irradiance
    weight = 1.0 - dielectric_reflectance(mu_o, 1.0 / eta)
    sin_o = np.sqrt(np.maximum(1.0 - mu_o * mu_o, 0.0))
    sin_i = np.minimum(sin_o / eta, 1.0)
    phi = 2.0 * np.pi * rng.random(n)
    return (sin_i * np.cos(phi), sin_i * np.sin(phi), np.sqrt(1.0 - sin_i * sin_i), weight)


def _similar(alpha, g):
    """(sigma_t, alpha) of the isotropic medium similar to (1, alpha, g): sigma_s (1 - g)
    scattering, the absorption kept (Cycles' walks after their 10th flight)."""
    sigma_t = 1.0 - alpha * g
    return sigma_t, alpha * (1.0 - g) / sigma_t


def walk_chunk(rng, n, alpha, g, eta, incidence, hist, exit_="dielectric",
               similarity_after=None, max_flights=None):
    """Walk n photons to the end; return each photon's escaped weight (adds to hist).
    ``exit_`` "first_crossing": no Fresnel on the way out (Cycles' walks).
    ``similarity_after`` k: flights after the k-th (0-based) walk the similar isotropic
    medium (``_similar``), as Cycles' random walk does (its SIMILARITY_LEVEL 9).
    ``max_flights``: a walk still inside after that many flights is lost (Cycles'
    BSSRDF_MAX_BOUNCES = 256)."""
    ux, uy, uz, w = enter(rng, n, eta, incidence)
    x, y, z = np.zeros(n), np.zeros(n), np.zeros(n)
    ident = np.arange(n)
    escaped = np.zeros(n)
    flights = np.zeros(n, np.int64)
    late_sigma_t, late_alpha = _similar(alpha, g)
    while ident.size:
        late = (flights > similarity_after if similarity_after is not None
                else np.zeros(ident.size, bool))
        step = -np.log1p(-rng.random(ident.size)) / np.where(late, late_sigma_t, 1.0)
        xn, yn, zn = x + ux * step, y + uy * step, z + uz * step
        out = zn < 0.0
        if np.any(out):
            # the crossing point, then the Fresnel split: w (1 - F) leaves, w F is mirrored
            t_hit = z[out] / -uz[out]
            r_exit = np.hypot(x[out] + ux[out] * t_hit, y[out] + uy[out] * t_hit)
            f = (dielectric_reflectance(-uz[out], eta) if exit_ == "dielectric"
                 else np.zeros(int(out.sum())))
            leave = w[out] * (1.0 - f)
            escaped[ident[out]] += leave
            k = np.searchsorted(RADIUS_EDGES, r_exit)
            hist += np.bincount(k, weights=leave, minlength=RADIUS_BINS + 2)[:RADIUS_BINS + 1]
            w[out] *= f
            zn[out] = -zn[out]
            uz[out] = -uz[out]
        x, y, z = xn, yn, zn
        # collision: implicit capture, then a new direction
        w *= np.where(late, late_alpha, alpha)
        flights += 1
        u = rng.random(ident.size)
        if similarity_after is None:
            cos_t = sample_hg_cosine(u, g)
        else:           # the direction leaving flight k is drawn with the phase of flight k + 1
            cos_t = np.where(flights > similarity_after, sample_hg_cosine(u, 0.0),
                             sample_hg_cosine(u, g))
        ux, uy, uz = scatter(ux, uy, uz, cos_t, 2.0 * np.pi * rng.random(ident.size))
        low = w < ROULETTE_WEIGHT
        if np.any(low):
            live = rng.random(int(low.sum())) < ROULETTE_SURVIVAL
            w[low] = np.where(live, w[low] / ROULETTE_SURVIVAL, 0.0)
        keep = w > 0.0
        if max_flights is not None:
            keep &= flights < max_flights
        if not np.all(keep):
            ident, x, y, z, ux, uy, uz, w, flights = (
                a[keep] for a in (ident, x, y, z, ux, uy, uz, w, flights))
    return escaped


def walk(alpha: float, g: float = 0.0, eta: float = 1.0, incidence: str = "diffuse",
         paths: int = 100_000, seed: int = 1, batches: int = 10,
         exit_: str = "dielectric", similarity_after: int | None = None,
         max_flights: int | None = None) -> WalkResult:
    """Monte Carlo diffuse reflectance (specular excluded) of the semi-infinite medium; the
    walk leaves through the dielectric, or (``exit_="first_crossing"``) at its first crossing."""
    if incidence not in ("diffuse", "normal"):
        raise ValueError(f"incidence={incidence!r}: expected 'diffuse' or 'normal'")
    if exit_ not in ("dielectric", "first_crossing"):
        raise ValueError(f"exit_={exit_!r}: expected 'dielectric' or 'first_crossing'")
    rng = np.random.default_rng(seed)
    per_batch = -(-paths // batches)
    hist = np.zeros((batches, RADIUS_BINS + 1))
    samples = []
    for b in range(batches):
        left = per_batch
        while left > 0:
            n = min(left, CHUNK)
            samples.append(walk_chunk(rng, n, alpha, g, eta, incidence, hist[b], exit_,
                                      similarity_after, max_flights))
            left -= n
    sample = np.concatenate(samples)
    return WalkResult(float(sample.mean()), float(sample.std(ddof=1) / np.sqrt(sample.size)),
                      int(sample.size), hist)


def radius_quantile(hist, fraction: float):
    """Radius holding ``fraction`` of the tallied energy of each histogram row (linear in
    log r within a bin)."""
    hist = np.atleast_2d(hist)
    cdf = np.cumsum(hist, axis=-1)
    cdf = cdf / cdf[:, -1:]
    logr = np.log(np.concatenate([[RADIUS_MIN * 1e-3], RADIUS_EDGES]))  # bin 0: (0, RADIUS_MIN]
    out = np.empty(len(hist))
    for i, c in enumerate(cdf):
        k = int(np.searchsorted(c, fraction))
        c0 = c[k - 1] if k else 0.0
        t = (fraction - c0) / (c[k] - c0) if c[k] > c0 else 0.5
        out[i] = np.exp(logr[k] + t * (logr[k + 1] - logr[k]))
    return out


def spread(result: WalkResult, fraction: float = 0.5):
    """``(radius, stderr)``: the radius holding ``fraction`` of the reflected energy, pooled,
    and its standard error from the spread of the batches' radii."""
    pooled = radius_quantile(result.radius_hist.sum(axis=0), fraction)[0]
    per_batch = radius_quantile(result.radius_hist, fraction)
    return pooled, float(per_batch.std(ddof=1) / np.sqrt(len(per_batch)))
