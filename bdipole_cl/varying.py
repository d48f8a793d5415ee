"""Texture-varying blur parameters: per-texel weights over a shared Gaussian basis.

With albedo/mfp (or alpha'/sigma_t') given as textures, texel x scatters with *its own*
profile (the exit texel's parameters, a gather): ``M(x) = sum_cells E(cell) W_x(cell - x)``,
``W_x`` the texel-integrated weights of x's parameters. Every ``W_x`` is written over one
shared basis of separable texel-integrated Gaussians ``g_j`` (sigmas geometric from 0.15
texel to half the common radius):

    W_x ~ Rd(x) * sum_j w_j(x) g_j      so      M(x) = Rd(x) * sum_j w_j(x) (g_j * E)(x).

Each basis blur ``g_j * E`` is done once for the whole image (FFT on the host, or the separable
OpenCL kernels); only the weights vary per texel. They come from a lattice over the two
parameters that shape the kernel, logit(Rd) and ln(ld in texels) (an axis on which the texture
is constant collapses to its one value): the exact normalized kernel of each lattice node is
fitted in the basis, and ``w(x)`` interpolates the node weights: the 4x4-node Lagrange cubic,
tabulated REFINE times finer per axis (``fine_table``), then bilinear in that table per texel
(kernels/blur_varying.cl). Interpolating weights over a fixed basis is interpolating the
kernels themselves, so the error is the nodes' fit error plus the kernel's interpolation error;
both are measured (``VaryingPlan.fit_error`` over all nodes and ``interp_error`` against exact
kernels at the range's corners and lattice-cell midpoints) and reported as the error bound.
Plans depend on the parameter ranges only and are cached, and so (up to SPECTRA_CACHE_BYTES)
are their kernels' spectra per FFT shape.

Every texel's kernel is truncated at the common radius K (the largest truncation radius at
``tol`` over the texture's nodes) and normalized there: node weights sum to 1, so a constant
irradiance E returns E * Rd(x) at every interior texel, exactly (energy-conserving).

Albedo is used in [RD_MIN, RD_MAX] for the kernel's *shape* (texels outside take the shape of
the bound; the energy is always Rd(x), and Rd = 0 gives 0); Rd >= 1, Rd < 0, NaN, mfp <= 0 or
non-finite are errors naming the texel. eta is constant per channel.
"""
from __future__ import annotations

import itertools
import os
import threading
from collections import OrderedDict
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
import pyopencl as cl

from . import reference as ref
from .blur import (fft_padded, fft_shape, gaussian_1d, quadrant_weights, truncation_radius,
                   unfold_quadrant)
from .device import build_options, get_program

#: the kernel's shape is taken at albedo within these bounds (its energy is always Rd(x))
RD_MIN, RD_MAX = 1e-3, 0.999
#: lattice steps in logit(Rd) and ln(ld) at tol = 1e-3; halved per factor 16 of tighter tol
#: (the cubic interpolation error goes as h^4). Measured kernel interpolation error (L1 of the
#: normalized kernel) at these steps: <= 3e-4 over albedo 0.02..0.98, ld 0.5..16 texels.
LATTICE_STEPS = (0.4, 0.2)
#: the texels' weights are bilinear in a table REFINE times finer than the lattice per axis,
#: whose entries are the lattice's Lagrange-cubic interpolation: 4 taps a texel, not 16 (the
#: gather's cost). Bilinear interpolation of the cubic adds ~ (h / REFINE)^2 / 8 times the
#: weights' curvature; it is measured with the rest (``VaryingPlan.interp_error``).
REFINE = 8
BASIS_MIN_SIGMA = 0.15      # texels: narrower texel-integrated Gaussians are ~ a delta
BASIS_RATIO = 1.5           # geometric ratio of the basis sigmas (densified if the fit needs)
MAX_BASIS = 24
CHECKS_PER_AXIS = 4         # interpolation checked at up to 4 x 4 points of the range


class VaryingParameterError(ValueError):
    """A texel's parameters are invalid (the message names the texel and channel);
    ``parameter`` is the parameter's name (albedo, mfp, alpha, sigma_t)."""

    def __init__(self, message, parameter=None):
        super().__init__(message)
        self.parameter = parameter


def _texture_channel(value, shape, c, name):
    """Channel c of a scalar, per-channel tuple, HxW or HxWxC parameter, as an HxW array (a
    texture keeps its float type: it is checked before it is rounded to float32)."""
    h, w, nch = shape
    v = np.asarray(value)
    if not np.issubdtype(v.dtype, np.floating):
        v = v.astype(np.float64)
    if v.ndim <= 1:
        v = np.atleast_1d(v)
        if v.size not in (1, nch):
            raise ValueError(f"{name} has {v.size} values for {nch} channels")
        return np.full((h, w), v[c if v.size > 1 else 0])
    if v.ndim == 2:
        v = v[..., None]
    if v.shape[:2] != (h, w) or v.shape[2] not in (1, nch):
        raise ValueError(f"{name} texture has shape {v.shape}; expected ({h}, {w}) or "
                         f"({h}, {w}, {nch}) to match the irradiance")
    return v[..., c if v.shape[2] > 1 else 0]


#: the texel rules of the parameters: unit interval (albedo, alpha') or positive and finite
_RULES = {"[0, 1)": lambda v: (v >= 0) & (v < 1),
          "(0, inf)": lambda v: (v > 0) & np.isfinite(v)}


def _checked(value, shape, c, name, rule):
    """Channel c of a parameter as HxW, every texel within ``rule``, else a
    VaryingParameterError naming the count and the first bad texel."""
    v = _texture_channel(value, shape, c, name)
    bad = ~_RULES[rule](v)
    if bad.any():
        y, x = (int(i) for i in np.argwhere(bad)[0])
        raise VaryingParameterError(f"{int(bad.sum())} texel(s) of {name} outside {rule}; "
                                    f"first at x={x}, y={y}, channel {c}: {float(v[y, x]):g}",
                                    parameter=name)
    return v


def _float32_map(v):
    return np.ascontiguousarray(v, np.float32)


def texel_parameters(shape, c, *, albedo=None, mfp=None, eta=1.4, texel_size=1.0, alpha=None,
                     sigma_t=None, exact=False):
    """(Rd, ld in texels) HxW float32 maps of channel c, from albedo + mfp or alpha' + sigma_t'
    (the node coordinates, ``texel_coords``, are computed from these same float32 values)."""
    if alpha is not None or sigma_t is not None:
        if alpha is None or sigma_t is None or albedo is not None or mfp is not None:
            raise ValueError("give either albedo and mfp, or alpha and sigma_t")
        a = _checked(alpha, shape, c, "alpha", "[0, 1)").astype(np.float64)
        st = _checked(sigma_t, shape, c, "sigma_t", "(0, inf)").astype(np.float64)
        ld = 1.0 / (st * texel_size * ref.mu_tr_over_sigma_t(1.0 - a))
        return _float32_map(ref.rd(a, eta, exact)), _float32_map(ld)
    if albedo is None or mfp is None:
        raise ValueError("give albedo and mfp (or alpha and sigma_t)")
    rd = _float32_map(_checked(albedo, shape, c, "albedo", "[0, 1)"))
    mfp = _checked(mfp, shape, c, "mfp", "(0, inf)")
    return rd, _float32_map(mfp if texel_size == 1.0 else mfp / texel_size)


# {{{ lattice of nodes

def _logit(p):
    return np.log(p) - np.log1p(-p)


def _sigmoid(t):
    return 1.0 / (1.0 + np.exp(-t))


@dataclass(frozen=True)
class Axis:
    """One parameter axis: node values, and the map from texel values to node coordinates."""

    values: tuple            # the parameter (Rd or ld) at the nodes
    origin: float            # lattice index of node 0 (0 for a constant axis)
    step: float              # lattice step in the transformed variable (0: constant axis)

    def coords(self, t):
        """Node coordinates (float, node 0 at 0) of transformed values t."""
        if self.step == 0:
            return np.zeros(np.shape(t))
        return np.asarray(t) / self.step - self.origin


def _axis(lo, hi, step, back):
    """Nodes covering transformed values [lo, hi] for a 4-point cubic; one node if lo == hi."""
    if hi - lo <= 1e-12 * max(1.0, abs(lo)):
        return Axis((float(back(lo)),), 0.0, 0.0)
    i0 = int(np.floor(lo / step)) - 1
    i1 = max(int(np.floor(hi / step)) + 2, i0 + 3)
    return Axis(tuple(float(back(i * step)) for i in range(i0, i1 + 1)), float(i0), step)


def lattice_steps(tol):
    """LATTICE_STEPS, halved per factor 16 of tol below 1e-3."""
    level = max(0, int(np.ceil(np.log2(max(1e-3 / tol, 1.0)) / 4.0)))
    return tuple(s / 2**level for s in LATTICE_STEPS)


@lru_cache(maxsize=4096)
def node_kernel(rd, ld, eta, radius, exact=False):
    """Exact normalized (sums to 1) quadrant of the kernel of (Rd, ld texels) at radius K."""
    sa, ss = ref.albedo_to_coefficients(rd, ld, eta, exact)
    st = float(sa + ss)
    q = quadrant_weights(float(ss / st), st, eta, radius, exact)
    q /= _quadrant_sum(q)
    q.setflags(write=False)
    return q


def _quadrant_sum(q):
    """Sum of the unfolded kernel of quadrant q (axis cells twice, the centre once)."""
    return float((q * _multiplicity(q.shape[0] - 1)).sum())


@lru_cache(maxsize=4096)
def node_radius(rd, ld, eta, tol, exact=False):
    sa, ss = ref.albedo_to_coefficients(rd, ld, eta, exact)
    st = float(sa + ss)
    r_t = truncation_radius(float(ss / st), st, eta, tol, exact)
    return int(np.ceil(r_t - 0.5)) if r_t > 0.5 else 0

# }}}


# {{{ shared Gaussian basis and the node fits

def basis_sigmas(radius, ratio):
    hi = max(1.0, radius / 2.0)
    count = max(2, int(np.ceil(np.log(hi / BASIS_MIN_SIGMA) / np.log(ratio))) + 1)
    return np.geomspace(BASIS_MIN_SIGMA, hi, count)


def basis_kernels(sigmas, radius):
    """The 1D texel-integrated Gaussians of the basis, each on [-r_j, r_j], r_j <= radius."""
    return tuple(gaussian_1d(s, int(min(radius, np.ceil(4.0 * s)))) for s in sigmas)


def _basis_columns(kernels, radius):
    """The quadrant (offsets 0..K) of each separable basis kernel, flattened as columns."""
    cols = []
    for g in kernels:
        r = (len(g) - 1) // 2
        half = np.zeros(radius + 1)
        half[:r + 1] = g[r:]
        cols.append(np.outer(half, half).ravel())
    return np.stack(cols, axis=1)


def _row_weights(target):
    """NNLS row weights: relative (absolute below 1e-4 of the peak), times the number of
    kernel cells each quadrant cell stands for (as in blur.fit_gaussians)."""
    k = target.shape[0] - 1
    mult = np.full(k + 1, 2.0)
    mult[0] = 1.0
    count_w = np.sqrt(mult[:, None] * mult[None, :])
    return (count_w / np.maximum(target, 1e-4 * target.max())).ravel()


def fit_node(target, columns):
    """Non-negative weights (summing to 1) of the basis columns for one node's kernel quadrant,
    and the L1 error of the fitted kernel (unfolded)."""
    from scipy.optimize import nnls
    rw = _row_weights(target)
    coef, _ = nnls(columns * rw[:, None], target.ravel() * rw, maxiter=100 * columns.shape[1])
    coef /= coef.sum()
    fitted = (columns @ coef).reshape(target.shape)
    return coef, float(np.abs(unfold_quadrant(fitted - target)).sum())

# }}}


def _multiplicity(radius):
    """How many kernel cells each quadrant cell stands for (centre 1, axis 2, others 4)."""
    m = np.full(radius + 1, 2.0)
    m[0] = 1.0
    return m[:, None] * m[None, :]


def svd_basis(targets, tol):
    """Eigen-kernels of the node kernels (SVD of the quadrants, weighted by cell multiplicity
    so that it is the SVD of the whole kernels): the fewest whose reconstruction of every node
    is within L1 error tol (or all of them). Returns (quadrants (G, K+1, K+1), node
    coefficients (nodes, G), each row scaled so that its kernel sums to 1)."""
    shape = targets[0].shape
    mult = _multiplicity(shape[0] - 1).ravel()
    sw = np.sqrt(mult)
    a_mat = np.stack([t.ravel() * sw for t in targets], axis=1)        # cells x nodes
    u, _, _ = np.linalg.svd(a_mat, full_matrices=False)
    for rank in range(1, u.shape[1] + 1):
        phi = u[:, :rank] / sw[:, None]                                 # quadrant values
        coef = (u[:, :rank].T @ a_mat).T                                # nodes x rank
        coef /= (coef @ (phi.T @ mult))[:, None]                        # kernels sum to 1
        err = np.abs(phi @ coef.T - a_mat / sw[:, None]).T @ mult
        if err.max() <= tol:
            break
    return phi.T.reshape((rank,) + shape), coef


@dataclass(frozen=True)
class VaryingPlan:
    """One channel's shared basis, lattice and node weights."""

    radius: int              # K, the common kernel radius (texels)
    basis: str               # "gaussians" (separable, NNLS weights) or "svd" (eigen-kernels)
    kernels: tuple           # gaussians: 1D texel-integrated weights; svd: (K+1)^2 quadrants
    axes: tuple              # (Axis of Rd via logit, Axis of ld via ln)
    table: np.ndarray        # (n_rd, n_ld, G) float32 node weights; node kernels sum to 1
    fine: np.ndarray         # (REFINE (n_rd - 1) + 1, ..., G) float32: the gather's table
    eta: float
    fit_error: float         # max L1 error of the node kernels in the basis
    interp_error: float      # max L1 error at the check points (basis + interpolation)
    truncation_tol: float

    @property
    def error_bound(self):
        """Bound on |M - exact| / (max E * Rd(x)): truncation + the measured kernel error."""
        return self.truncation_tol + max(self.fit_error, self.interp_error)

    def quadrants(self):
        """(G, K+1, K+1) quadrant of each basis kernel."""
        if self.basis == "svd":
            return np.asarray(self.kernels)
        return _basis_columns(self.kernels, self.radius).T.reshape(
            (-1, self.radius + 1, self.radius + 1))


def _transformed(rd, ld):
    """The lattice variables (logit Rd, with Rd clipped to [RD_MIN, RD_MAX]; ln ld), float64."""
    return (_logit(np.clip(np.asarray(rd, np.float64), RD_MIN, RD_MAX)),
            np.log(np.asarray(ld, np.float64)))


def parameter_ranges(rd, ld):
    """((lo, hi) of logit Rd, (lo, hi) of ln ld) over maps rd, ld: the transforms are monotone,
    so these are the transformed extremes."""
    t_rd = _transformed([rd.min(), rd.max()], [ld.min(), ld.max()])
    return tuple((float(t[0]), float(t[1])) for t in t_rd)


def lagrange4(t):
    """Cubic Lagrange weights of nodes -1, 0, 1, 2 at t in [0, 1]."""
    return np.stack([-t * (t - 1) * (t - 2) / 6, (t + 1) * (t - 1) * (t - 2) / 2,
                     -(t + 1) * t * (t - 2) / 2, (t + 1) * t * (t - 1) / 6], axis=-1)


def _cubic_taps(nodes, coord):
    """(node indices, weights) of the 4-node cubic at lattice coordinate(s) coord on an axis of
    ``nodes`` nodes (one node: a constant axis)."""
    coord = np.asarray(coord, np.float64)
    if nodes == 1:
        return np.zeros(coord.shape + (1,), int), np.ones(coord.shape + (1,))
    base = np.clip(np.floor(coord).astype(int), 1, nodes - 3)
    return base[..., None] + np.arange(-1, 3), lagrange4(coord - base)


def _linear_taps(nodes, coord):
    """(node indices, weights) of linear interpolation at fine-table coordinate(s) coord (as
    in blur_varying.cl)."""
    coord = np.asarray(coord, np.float64)
    if nodes == 1:
        return np.zeros(coord.shape + (1,), int), np.ones(coord.shape + (1,))
    base = np.clip(np.floor(coord).astype(int), 0, nodes - 2)
    t = (coord - base)[..., None]
    return base[..., None] + np.arange(2), np.concatenate([1.0 - t, t], axis=-1)


def _interpolate(table, taps_u, taps_v):
    (iu, lu), (iv, lv) = taps_u, taps_v
    return np.einsum("...a,...b,...abj->...j", lu, lv, table[iu[..., :, None], iv[..., None, :]])


def fine_table(table):
    """The gather's table: the lattice's cubic interpolation of the node weights (n_u, n_v, G)
    at REFINE points per lattice step (fine node i at lattice coordinate i / REFINE)."""
    nu, nv, _ = table.shape
    fu = np.arange(REFINE * (nu - 1) + 1) / REFINE
    fv = np.arange(REFINE * (nv - 1) + 1) / REFINE
    taps_u = _cubic_taps(nu, fu[:, None])
    taps_v = _cubic_taps(nv, fv[None, :])
    return _interpolate(table.astype(np.float64), taps_u, taps_v).astype(np.float32)


def interpolated_weights(plan, cu, cv):
    """Host (float64) version of blur_varying.cl's per-texel weights at fine-table coordinates
    (cu, cv), for checks."""
    nu, nv, _ = plan.fine.shape
    return _interpolate(plan.fine.astype(np.float64), _linear_taps(nu, cu), _linear_taps(nv, cv))


def common_radius(rd_range, ld_range, eta, tol, exact=False):
    """K: the largest truncation radius at tol over the texels' parameter range (the profile
    widens with ld; its dependence on Rd is sampled at 9 albedos across the range)."""
    ld_max = float(np.exp(ld_range[1]))
    rds = _sigmoid(np.linspace(rd_range[0], rd_range[1], 9))
    return max(node_radius(float(np.clip(r, RD_MIN, RD_MAX)), ld_max, eta, tol, exact)
               for r in rds)


@lru_cache(maxsize=32)
def plan_for_ranges(rd_range, ld_range, eta, tol, exact=False, basis="svd", max_radius=2048):
    """The VaryingPlan for logit(Rd) in rd_range and ln(ld texels) in ld_range."""
    steps = lattice_steps(tol)
    axes = (_axis(*rd_range, steps[0], lambda t: min(max(_sigmoid(t), RD_MIN), RD_MAX)),
            _axis(*ld_range, steps[1], np.exp))
    radius = common_radius(rd_range, ld_range, eta, tol, exact)
    if radius > max_radius:
        raise ValueError(f"truncation radius {radius} texels exceeds max_radius={max_radius}: "
                         f"raise tol or the texel size")
    targets = [node_kernel(a, b, eta, radius, exact) for a in axes[0].values
               for b in axes[1].values]
    if basis == "svd":
        quads, coef = svd_basis(targets, tol)
        kernels = tuple(quads)
        fit_error = float(max(np.abs(unfold_quadrant(np.tensordot(c, quads, 1) - t)).sum()
                              for c, t in zip(coef, targets)))
    else:
        kernels, coef, fit_error = _gaussian_fits(targets, radius, tol)
    table = coef.reshape(len(axes[0].values), len(axes[1].values), -1).astype(np.float32)
    plan = VaryingPlan(radius, basis, kernels, axes, table, fine_table(table), eta, fit_error,
                       0.0, tol)
    return _with_interp_error(plan, rd_range, ld_range, exact)


def _gaussian_fits(targets, radius, tol):
    """Shared separable Gaussian basis and NNLS node weights, densified until every node fits
    within L1 error tol (or MAX_BASIS is reached)."""
    ratio = BASIS_RATIO
    while True:
        kernels = basis_kernels(basis_sigmas(radius, ratio), radius)
        columns = _basis_columns(kernels, radius)
        fits = [fit_node(t, columns) for t in targets]
        fit_error = max(err for _, err in fits)
        if fit_error <= tol or len(kernels) >= MAX_BASIS:
            return kernels, np.stack([c for c, _ in fits]), fit_error
        ratio = ratio ** (2.0 / 3.0)


def _check_points(lo, hi, step):
    """Where to check one axis: the range's ends and, inside it, the middles of the fine cells
    at the lattice cells' midpoints (where the cubic and then the bilinear err most), at most
    CHECKS_PER_AXIS evenly chosen."""
    if step == 0:
        return [lo]
    mids = (np.arange(np.floor(lo / step), np.ceil(hi / step)) + 0.5 + 0.5 / REFINE) * step
    pts = np.unique(np.concatenate([[lo, hi], mids[(mids > lo) & (mids < hi)]]))
    return pts[np.linspace(0, len(pts) - 1, min(len(pts), CHECKS_PER_AXIS)).astype(int)]


def _fine_coords(axis, t):
    """Fine-table coordinates of transformed values t on one axis."""
    return axis.coords(t) * REFINE


def _with_interp_error(plan, rd_range, ld_range, exact):
    """Measure the gather's kernel (bilinear in the fine table) against the exact kernel at
    check points of the parameter range (its corners and the lattice cells' midpoints)."""
    quads = plan.quadrants()
    worst = 0.0
    for t_rd, t_ld in itertools.product(_check_points(*rd_range, plan.axes[0].step),
                                        _check_points(*ld_range, plan.axes[1].step)):
        w = interpolated_weights(plan, _fine_coords(plan.axes[0], t_rd),
                                 _fine_coords(plan.axes[1], t_ld))
        rd_shape = float(np.clip(_sigmoid(t_rd), RD_MIN, RD_MAX))
        exact_q = node_kernel(rd_shape, float(np.exp(t_ld)), plan.eta, plan.radius, exact)
        worst = max(worst, float(np.abs(unfold_quadrant(np.tensordot(w, quads, 1)
                                                        - exact_q)).sum()))
    return VaryingPlan(**{**plan.__dict__, "interp_error": worst})


def texel_coords(plan, rd, ld):
    """Fine-table coordinates (float32 maps) of the texels' Rd, ld float32 maps: logit(Rd
    clipped to [RD_MIN, RD_MAX]) and ln(ld) in fine steps (lattice step / REFINE) from node 0
    (zeros on a constant axis). In float32 they are good to ~1e-6 of a lattice step."""
    def on_axis(axis, t):
        if axis.step == 0:
            return np.zeros(t.shape, np.float32)
        t *= np.float32(REFINE / axis.step)
        t -= np.float32(REFINE * axis.origin)
        return t

    p = np.clip(rd, np.float32(RD_MIN), np.float32(RD_MAX))
    u = np.log(np.divide(p, np.float32(1.0) - p, out=p), out=p)
    return on_axis(plan.axes[0], u), on_axis(plan.axes[1], np.log(ld))


def _lattice_args(plan):
    """Program options and the lattice arguments of kernels/blur_varying.cl for a plan."""
    nu, nv, g = plan.fine.shape
    opts = build_options({"NBASIS": g, "NU_TAPS": 1 if nu == 1 else 2,
                          "NV_TAPS": 1 if nv == 1 else 2})
    return opts, (np.int32(nu), np.int32(nv))


def _host_buffer(rt, array, flags):
    """A device buffer over a host array (zero-copy on CPU devices)."""
    return cl.Buffer(rt.context, flags | cl.mem_flags.USE_HOST_PTR,
                     hostbuf=np.ascontiguousarray(array))


def _read_back(rt, buf, array):
    """Make the device's writes to a USE_HOST_PTR buffer visible in ``array``."""
    mapped, _ = cl.enqueue_map_buffer(rt.queue, buf, cl.map_flags.READ, 0, array.shape,
                                      array.dtype)
    mapped.base.release(rt.queue)
    rt.queue.finish()


def weight_planes(plan, rd, ld, rt):
    """w_j(x) * Rd(x), (G, H, W) float32, computed on ``rt``'s device (kernels/blur_varying.cl)."""
    h, w = rd.shape
    mf = cl.mem_flags
    opts, axis_args = _lattice_args(plan)
    out = np.empty((plan.fine.shape[2], h, w), np.float32)
    bufs = [_host_buffer(rt, a, mf.READ_ONLY) for a in (rd, *texel_coords(plan, rd, ld),
                                                         plan.fine)]
    dst = _host_buffer(rt, out, mf.WRITE_ONLY)
    cl.Kernel(get_program(rt, "blur_varying", opts), "lattice_weights")(
        rt.queue, (h * w,), None, *bufs, dst, np.int32(h * w), *axis_args)
    _read_back(rt, dst, out)
    return out


def kernel_spectra(quads, shape):
    """Real DFTs (G, N0 // 2 + 1, N1 // 2 + 1) float32, rows 0..N0/2, of the even kernels of
    quadrants quads (G, K+1, K+1) centred on 0, at the even FFT shape (N0, N1). An even
    kernel's DFT is the cosine sum sum_{a,b} m_a m_b Q(a, b) cos(2 pi f a / N0) cos(2 pi g b /
    N1) (m: 1 at 0, else 2): the DCT-I of the quadrant zero-padded to (N0/2 + 1, N1/2 + 1).
    Rows N0/2 + 1..N0 - 1 are rows N0/2 - 1..1 (``_times_spectrum``)."""
    import scipy.fft as sfft
    n0, n1 = shape
    g, kk = quads.shape[:2]
    rows = np.zeros((g, kk, n1 // 2 + 1), np.float32)      # the other rows are zero: so are
    rows[:, :, :kk] = quads                                 # their transforms along axis 2
    half = np.zeros((g, n0 // 2 + 1, n1 // 2 + 1), np.float32)
    half[:, :kk] = sfft.dct(rows, type=1, axis=2, workers=-1, overwrite_x=True)
    return sfft.dct(half, type=1, axis=1, workers=-1, overwrite_x=True)


#: kernel spectra are kept across calls up to this many bytes (least recently used first out):
#: blurring again with the same parameter maps (a material under new light) skips them
SPECTRA_CACHE_BYTES = 1 << 30
_spectra_cache = OrderedDict()
_spectra_lock = threading.Lock()      # blur may run in several threads (a batch)


def cached_spectra(plan, shape):
    """kernel_spectra of the plan's basis at FFT shape, from the cache when it has them."""
    key = (id(plan), tuple(shape))
    with _spectra_lock:
        hit = _spectra_cache.get(key)
        if hit is not None and hit[0] is plan:    # the entry holds the plan: its id is its own
            _spectra_cache.move_to_end(key)
            return hit[1]
    spec = kernel_spectra(plan.quadrants(), shape)
    if spec.nbytes <= SPECTRA_CACHE_BYTES:
        with _spectra_lock:
            _spectra_cache[key] = (plan, spec)
            while sum(v[1].nbytes for v in _spectra_cache.values()) > SPECTRA_CACHE_BYTES:
                _spectra_cache.popitem(last=False)
    return spec


def _times_spectrum(ks, spec, out):
    """out = K * spec, K the full (N0, N1 // 2 + 1) spectrum of half spectrum ks (rows
    0..N0/2): an even kernel's rows N0 - f and f are equal."""
    m = ks.shape[0]
    np.multiply(ks, spec[:m], out=out[:m])
    np.multiply(ks[m - 2:0:-1], spec[m:], out=out[m:])


#: threads for the row-wise inverse FFTs (numpy's FFT releases the GIL): the cores this
#: process may run on
FFT_THREADS = (len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity")
               else os.cpu_count() or 1)


@lru_cache(maxsize=1)
def _fft_threads():
    from concurrent.futures import ThreadPoolExecutor
    return ThreadPoolExecutor(FFT_THREADS, thread_name_prefix="bdipole-irfft")


def basis_blurs(e2d, plan, kspec, border, planes):
    """planes[j] = (B_j * E) for every basis kernel of the plan, as (H, W + 2K) float32 rows
    whose columns [K, K + W) are the image's: float32 FFTs, one forward transform, and per basis
    kernel an inverse transform pruned to the image's rows. One basis kernel at a time, in
    place: scipy.fft (all cores) in place over the columns, then numpy's ``irfft`` straight into
    the plane, in row blocks on all cores (fresh large arrays and copies cost more here than
    the FFTs' own threads save)."""
    import scipy.fft as sfft
    k = plan.radius
    h = e2d.shape[0]
    pad, shape = fft_padded(e2d, k, border)
    spec = sfft.rfft2(pad, shape, workers=-1)
    prod = np.empty_like(spec)
    pool = _fft_threads()
    edges = np.linspace(0, h, FFT_THREADS + 1).astype(int)
    for plane, ks in zip(planes, kspec):
        _times_spectrum(ks, spec, prod)
        cols = sfft.ifft(prod, axis=0, workers=-1, overwrite_x=True)

        def rows_of_plane(r0, r1, cols=cols, plane=plane):
            np.fft.irfft(cols[k + r0:k + r1], shape[1], axis=-1, out=plane[r0:r1])
        list(pool.map(rows_of_plane, edges[:-1], edges[1:]))
    return planes


def gather_exitance(out, c, plan, rd, ld, planes, x0, rt):
    """out[..., c] = Rd(x) sum_j w_j(x) planes[j, y, x0 + x], on ``rt``'s device."""
    h, w, nch = out.shape
    mf = cl.mem_flags
    opts, axis_args = _lattice_args(plan)
    bufs = [_host_buffer(rt, a, mf.READ_ONLY) for a in (rd, *texel_coords(plan, rd, ld),
                                                         plan.fine, planes)]
    dst = _host_buffer(rt, out, mf.READ_WRITE)
    cl.Kernel(get_program(rt, "blur_varying", opts), "gather_exitance")(
        rt.queue, (w, h), None, *bufs, dst, np.int32(w), np.int32(h),
        np.int32(planes.shape[2]), np.int32(planes.shape[1] * planes.shape[2]), np.int32(x0),
        np.int32(nch), np.int32(c), *axis_args)
    _read_back(rt, dst, out)


VARYING_METHODS = ("auto", "fft", "gaussians")


def channel_plans(shape, *, tol, exact=False, eta=1.4, basis="svd", **physical):
    """Per channel: (VaryingPlan, Rd map, ld map) for an HxWxC image. Each channel has the plan
    of its own ranges (a union over channels would need more basis kernels per channel; the
    kernels' spectra are cheap, so sharing them saves little)."""
    etas = np.broadcast_to(np.atleast_1d(np.asarray(eta, np.float64)), (shape[2],)) \
        if np.ndim(eta) <= 1 and np.size(eta) in (1, shape[2]) else None
    if etas is None:
        raise ValueError(f"eta must be one value or one per channel (constant over the texture); "
                         f"got shape {np.shape(eta)}")
    out = []
    for c in range(shape[2]):
        rd, ld = texel_parameters(shape, c, eta=float(etas[c]), exact=exact, **physical)
        out.append((plan_for_ranges(*parameter_ranges(rd, ld), float(etas[c]), float(tol),
                                    exact, basis), rd, ld))
    return out


def _blur_band(e, plans, rows, method, border, rt):
    """Blur one image or band (rows: the rows of the parameter maps it covers)."""
    h, w, _ = e.shape
    if method == "gaussians":
        from .blur import _Blur
        ctx = _Blur(e, border, rt)
        for c, (plan, rd, ld) in enumerate(plans):
            ctx.run_varying(c, plan, weight_planes(plan, rd[rows], ld[rows], rt))
        return ctx.result()
    out = np.empty_like(e)
    planes = None          # the basis blurs, (G, H, FFT width), reused across channels
    for c, (plan, rd, ld) in enumerate(plans):
        shape = fft_shape((h, w), plan.radius)
        kspec = cached_spectra(plan, shape)
        if planes is None or planes.shape != (len(kspec), h, shape[1]):
            planes = np.empty((len(kspec), h, shape[1]), np.float32)
        basis_blurs(e[..., c], plan, kspec, border, planes)
        gather_exitance(out, c, plan, rd[rows], ld[rows], planes, plan.radius, rt)
    return out


def blur_textured(e, *, method, tol, border, exact, return_info, max_memory, rt, **physical):
    """``blur`` with texture-varying parameters (see the module docstring)."""
    from .blur import BlurInfo, _halo_rows
    if method not in VARYING_METHODS:
        raise ValueError(f"method={method!r} needs constant parameters; with texture-varying "
                         f"parameters use one of {VARYING_METHODS}")
    used = "fft" if method == "auto" else method
    plans = channel_plans(e.shape, tol=tol, exact=exact,
                          basis="gaussians" if used == "gaussians" else "svd", **physical)
    h, w, nch = e.shape
    k = max(p[0].radius for p in plans)
    g = max(len(p[0].kernels) for p in plans)
    # per band row (of width ~ w + 2k): input, output, parameter maps, and per basis kernel its
    # spectrum, product spectrum (complex) and blurred plane (or its weight plane)
    per_row = (w + 2 * k) * 4 * (4 * nch + 4 * g + 6)
    rows = h if max_memory is None else max(1, int(max_memory // per_row) - 2 * k)
    if rows >= h:
        out = _blur_band(e, plans, slice(0, h), used, border, rt)
    else:
        out = np.empty_like(e)
        for y0 in range(0, h, rows):
            y1 = min(y0 + rows, h)
            idx = _halo_rows(y0, y1, k, h, border)
            band = np.where((idx >= 0)[:, None, None], e[np.maximum(idx, 0)], np.float32(0))
            # the halo rows' own parameters are never used (a gather: exit texel's profile)
            res = _blur_band(band, plans, np.maximum(idx, 0), used, border, rt)
            out[y0:y1] = res[k:k + (y1 - y0)]
    if not return_info:
        return out
    info = [{"channel": c, "method": f"{used} (texture-varying, {len(p.kernels)} {p.basis} "
                                      f"basis kernels)",
             "radius": p.radius, "error_bound": p.error_bound, "fit_error": p.fit_error,
             "interp_error": p.interp_error, "nodes": int(np.prod(p.table.shape[:2]))}
            for c, (p, *_) in enumerate(plans)]
    return out, BlurInfo(info)

