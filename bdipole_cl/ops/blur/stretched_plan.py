"""The stretched blur's plan: anisotropic kernels per texel over a shared eigen-kernel basis
(docs/stretch.md "The blur in surface distance").

A texel whose steps along u and v are s_u and s_v long on the surface scatters with R of the
surface distance ``r = |(s_u du, s_v dv)|`` (an axis-aligned metric: the shear is bounded, not
modelled, docs/stretch.md "Shear"). In texels its kernel is R with the diffusion length
``l_u = ld / s_u`` along u and ``l_v = ld / s_v`` along v, integrated over each texel as the
plain blur's (``stretched_quadrant``: the corner integrals on a non-square grid, then the
product rule), truncated at a square of side 2K + 1 holding the ellipse where the profile's
tail is tol Rd, and normalized to sum to 1. So its shape depends on (Rd, l_u, l_v): the
lattice is three-dimensional over logit(Rd), ln(l_u), ln(l_v) (an axis on which the maps are
constant collapses to one node), each node's exact kernel is projected on the eigen-kernels of
the range's kernels (SVD, ``near_field.EigenKernels``), and the texels' weights are the
lattice's cubic interpolation, tabulated REFINE times finer per axis and read trilinearly
(kernels/blur_stretched.cl). The fit and interpolation errors are measured at the range's
corners and midpoints against exact kernels and reported, with the truncation's tol, as the
bound, as for the texture-varying blur.
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from ...caches import ByteCache
from ...physics import reference as ref
from ...signals import check_stop
from .near_field import EigenKernels
from .textured_plan import (LATTICE_STEPS, RD_MAX, RD_MIN, REFINE, Axis, lagrange4, logit,
                            sigmoid)
from .weights import (EXACT_CELLS, GL_NODES, quadrant_integral, quadrant_sum,
                      truncation_radius, unfold_quadrant)

STRETCHED_KERNELS = ByteCache("stretched node kernels", 256 << 20)
STRETCHED_PLANS = ByteCache("stretched plans", 256 << 20)

#: check points per axis (the range's ends and middle): 3^3 exact kernels per plan
CHECKS_PER_AXIS = 3
#: planning refuses a lattice of more nodes than this (each a (K+1)^2 float64 kernel)
MAX_NODES = 4096


def coefficients(rd, eta, exact=False):
    """(alpha', sigma_t') of albedo ``rd`` with the diffusion length as the unit of length."""
    sa, ss = ref.albedo_to_coefficients(rd, 1.0, eta, exact)
    st = float(sa + ss)
    return float(ss / st), st


def stretched_quadrant(rd, lu, lv, eta, k, exact=False):
    """The texel-integrated weights quad[a, b] (a rows, along v; b columns, along u; 0..k) of
    R at surface distance ``|(du / lu, dv / lv)|`` in diffusion lengths: each cell's integral
    over the surface rectangle it maps to (exact corner integrals within EXACT_CELLS, the
    GL_NODES^2 product rule beyond, as ``weights.quadrant_weights``)."""
    alpha, st = coefficients(rd, eta, exact)
    su, sv = 1.0 / lu, 1.0 / lv
    n = min(k, EXACT_CELLS)
    c = np.concatenate([[0.0], np.arange(n + 1) + 0.5])
    f = quadrant_integral(sv * c[:, None], su * c[None, :], alpha, st, eta, exact)
    near = f[1:, 1:] - f[:-1, 1:] - f[1:, :-1] + f[:-1, :-1]
    m = np.ones(n + 1)
    m[0] = 2.0
    quad = np.zeros((k + 1, k + 1))
    if k > n:
        x, w = np.polynomial.legendre.leggauss(GL_NODES)
        x, w = 0.5 * x, 0.5 * w
        pos = np.arange(k + 1)[:, None] + x[None, :]
        ww = w[:, None] * w[None, :] * (su * sv)
        for i0 in range(0, k + 1, 64):
            check_stop()
            r = np.hypot(sv * pos[i0:i0 + 64, None, :, None], su * pos[None, :, None, :])
            quad[i0:i0 + 64] = np.einsum("ijab,ab->ij", ref.profile(r, alpha, st, eta, exact),
                                         ww)
    quad[:n + 1, :n + 1] = near * m[:, None] * m[None, :]
    return quad


@STRETCHED_KERNELS.memoize
def node_kernel(rd, lu, lv, eta, radius, exact=False):
    """The normalized (sums to 1) quadrant of (Rd, l_u, l_v texels) at radius K, read-only."""
    quad = stretched_quadrant(rd, lu, lv, eta, radius, exact)
    quad /= quadrant_sum(quad)
    quad.setflags(write=False)
    return quad


def kernel_radius(rd, l_max, eta, tol, exact=False) -> int:
    """K: the square of side 2K + 1 holds the ellipse beyond which the tail is tol Rd, for the
    longest diffusion length ``l_max`` (texels) on either axis."""
    alpha, st = coefficients(rd, eta, exact)
    r_t = truncation_radius(alpha, st, eta, tol, exact) * l_max
    return int(np.ceil(r_t - 0.5)) if r_t > 0.5 else 0


def lattice_axis(lo, hi, step, back) -> Axis:
    """Nodes covering transformed values [lo, hi] for a 4-point cubic; one if lo == hi."""
    if hi - lo <= 1e-12 * max(1.0, abs(lo)):
        return Axis((float(back(lo)),), 0.0, 0.0)
    i0 = int(np.floor(lo / step)) - 1
    i1 = max(int(np.floor(hi / step)) + 2, i0 + 3)
    return Axis(tuple(float(back(i * step)) for i in range(i0, i1 + 1)), float(i0), step)


def cubic_matrix(nodes):
    """(REFINE (nodes - 1) + 1, nodes) weights of the 4-node Lagrange cubic at every fine
    point of an axis of ``nodes`` nodes (one node: the identity)."""
    if nodes == 1:
        return np.ones((1, 1))
    fine = np.arange(REFINE * (nodes - 1) + 1) / REFINE
    base = np.clip(np.floor(fine).astype(int), 1, nodes - 3)
    mat = np.zeros((len(fine), nodes))
    np.put_along_axis(mat, base[:, None] + np.arange(-1, 3), lagrange4(fine - base), axis=1)
    return mat


def fine_table3(table):
    """The gather's table: the node weights (n0, n1, n2, G) interpolated by the cubic along
    each axis at REFINE points per lattice step."""
    m0, m1, m2 = (cubic_matrix(n) for n in table.shape[:3])
    return np.einsum("ai,bj,ck,ijkg->abcg", m0, m1, m2, table.astype(np.float64),
                     optimize=True).astype(np.float32)


def linear_taps(nodes, coord):
    """(indices, weights) of linear interpolation at fine coordinate ``coord`` (as the
    gather: the last cell extended, one node: weight 1)."""
    if nodes == 1:
        return np.array([0]), np.array([1.0])
    base = int(np.clip(np.floor(coord), 0, nodes - 2))
    t = coord - base
    return np.array([base, base + 1]), np.array([1.0 - t, t])


def interpolated(fine, coords):
    """The gather's weights (float64) at fine coordinates ``coords`` (3,)."""
    (i0, w0), (i1, w1), (i2, w2) = (linear_taps(n, c) for n, c in zip(fine.shape[:3], coords))
    block = fine[np.ix_(i0, i1, i2)].astype(np.float64)
    return np.einsum("a,b,c,abcg->g", w0, w1, w2, block)


@dataclass(frozen=True)
class StretchedPlan:
    """One channel's stretched basis: eigen-kernels, lattice and node weights (duck-typed as
    a ``TexturedPlan`` where ``fft.basis_blurs`` reads it)."""

    radius: int
    kernels: tuple               # (K+1)^2 quadrants of the eigen-kernels
    axes: tuple                  # Axis of logit Rd, ln l_u, ln l_v
    fine: np.ndarray             # (f0, f1, f2, G) float32
    eta: float
    fit_error: float
    interp_error: float
    truncation_tol: float
    nodes: int

    @property
    def error_bound(self) -> float:
        return self.truncation_tol + max(self.fit_error, self.interp_error)

    def blurred_quadrants(self):
        return np.asarray(self.kernels).reshape((-1, self.radius + 1, self.radius + 1))

    def axis_maps(self):
        """Per axis (scale, offset) of its fine coordinate, t * scale - offset (0, 0 on a
        constant axis), float32 as the gather computes it."""
        return [(np.float32(0), np.float32(0)) if a.step == 0 else
                (np.float32(REFINE / a.step), np.float32(REFINE * a.origin)) for a in self.axes]


def transformed(rd, lu, lv):
    """The lattice variables of (Rd, l_u, l_v): logit of Rd clipped to [RD_MIN, RD_MAX], ln."""
    return (logit(np.clip(np.asarray(rd, np.float64), RD_MIN, RD_MAX)),
            np.log(np.asarray(lu, np.float64)), np.log(np.asarray(lv, np.float64)))


def check_points(lo, hi, step):
    if step == 0:
        return [lo]
    return list(np.linspace(lo, hi, CHECKS_PER_AXIS))


def interp_error(plan_fine, quads, axes, checks):
    """The largest L1 error of the gather's kernel against the exact ``checks``."""
    worst = 0.0
    for t, exact_q in checks:
        coords = [0.0 if a.step == 0 else (v / a.step - a.origin) * REFINE
                  for a, v in zip(axes, t)]
        w = interpolated(plan_fine, coords)
        worst = max(worst, float(np.abs(unfold_quadrant(np.tensordot(w, quads, 1)
                                                         - exact_q)).sum()))
    return worst


@STRETCHED_PLANS.memoize
def stretched_plan(ranges, eta, tol, exact=False, max_radius=2048) -> StretchedPlan:
    """The StretchedPlan of transformed ranges ((lo, hi) of logit Rd, ln l_u, ln l_v) at tol:
    the rank grows from where every kernel of the range fits within tol until the measured
    interpolation error is within tol too (or every eigen-kernel is used)."""
    steps = (LATTICE_STEPS[0], LATTICE_STEPS[1], LATTICE_STEPS[1])
    level = max(0, int(np.ceil(np.log2(max(1e-3 / tol, 1.0)) / 4.0)))
    steps = tuple(s / 2 ** level for s in steps)
    backs = (lambda t: min(max(sigmoid(t), RD_MIN), RD_MAX), np.exp, np.exp)
    axes = tuple(lattice_axis(lo, hi, s, b) for (lo, hi), s, b in zip(ranges, steps, backs))
    l_max = float(np.exp(max(ranges[1][1], ranges[2][1])))
    rds = sigmoid(np.linspace(ranges[0][0], ranges[0][1], 5))
    radius = max(kernel_radius(float(np.clip(r, RD_MIN, RD_MAX)), l_max, eta, tol, exact)
                 for r in rds)
    if radius > max_radius:
        raise ValueError(f"stretched blur: truncation radius {radius} texels exceeds "
                         f"max_radius={max_radius}: raise tol, or the stretch is too small for "
                         f"the mfp (texels far shorter than a diffusion length)")
    nodes = int(np.prod([len(a.values) for a in axes]))
    if nodes > MAX_NODES:
        raise ValueError(f"stretched blur: {nodes} lattice kernels (ranges {ranges}): "
                         f"over {MAX_NODES}: blur the texture's materials separately")
    shape = tuple(len(a.values) for a in axes)
    targets = [node_kernel(a, b, c, eta, radius, exact)
               for a, b, c in itertools.product(*(ax.values for ax in axes))]
    checks = [(t, node_kernel(float(np.clip(sigmoid(t[0]), RD_MIN, RD_MAX)),
                              float(np.exp(t[1])), float(np.exp(t[2])), eta, radius, exact))
              for t in itertools.product(*(check_points(lo, hi, a.step)
                                           for (lo, hi), a in zip(ranges, axes)))]
    inside = [all(lo - 1e-9 <= v <= hi + 1e-9 for v, (lo, hi) in zip(t, ranges)) for t in
              itertools.product(*[[(i + a.origin) * a.step if a.step else ranges[k][0]
                                   for i in range(len(a.values))]
                                  for k, a in enumerate(axes)])]
    train = [t for t, i in zip(targets, inside) if i] + [q for _, q in checks]
    eigen = EigenKernels.of(train)
    proj = eigen.project(targets)
    rank = eigen.project(train).rank_within(tol)
    while True:
        check_stop()
        coef = proj.coefficients(rank)
        quads = eigen.kernels(rank)
        fine = fine_table3(coef.reshape(*shape, -1))
        err = interp_error(fine, quads, axes, checks)
        if err <= tol or rank >= eigen.most:
            break
        rank += 1
    fit = max((float(np.abs(unfold_quadrant(np.tensordot(c, quads, 1) - t)).sum())
               for c, t, i in zip(coef, targets, inside) if i), default=0.0)
    return StretchedPlan(radius, tuple(quads), axes, fine, float(eta), fit, err, float(tol),
                         nodes)
