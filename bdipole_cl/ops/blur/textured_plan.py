"""Texture-varying blur: the plan (lattice, node kernels, shared basis, node weights).

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
(kernels/blur_textured.cl; applied by ``textured``). Interpolating weights over a fixed basis is
interpolating the kernels themselves, so the error is the nodes' fit error plus the kernel's
interpolation error; both are measured (``TexturedPlan.fit_error`` over all nodes and
``interp_error`` against exact kernels at the range's corners and lattice-cell midpoints) and
reported as the error bound. Plans depend on the parameter ranges only and are cached (up to
PLAN_CACHE's bytes, and on disk: ``textured_plan_files``), and so are their kernels' spectra
per FFT shape (``fft.SPECTRA_CACHE``).

Every texel's kernel is truncated at the common radius K (the largest truncation radius at
``tol`` over the texture's nodes) and normalized there: node weights sum to 1, so a constant
irradiance E returns E * Rd(x) at every interior texel, exactly (energy-conserving).

Albedo is used in [RD_MIN, RD_MAX] for the kernel's *shape* (texels outside take the shape of
the bound; the energy is always Rd(x), and Rd = 0 gives 0); Rd >= 1, Rd < 0, NaN, mfp <= 0 or
non-finite are invalid (``params.checked_parameter``). eta is constant per channel.
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass, field, replace
from typing import NamedTuple

import numpy as np

from ...caches import ByteCache
from ...physics import reference as ref
from ...signals import check_stop
from .fft import value_range
from .near_field import DEFAULT_GATHER_COSTS, GatherCosts, near_field_basis, with_near_classes
from .fit import (BASIS_RATIO, MAX_BASIS, basis_columns, basis_count, basis_kernels,
                  basis_sigmas, fit_node)
from .weights import (quadrant_sum, quadrant_weights, truncation_radius,
                      unfold_quadrant)

#: node kernels (each up to (K+1)^2 float64), plans (their tables and basis), per process
NODE_CACHE = ByteCache("node kernels", 256 << 20)
PLAN_CACHE = ByteCache("texture-varying plans", 256 << 20)


#: the kernel's shape is taken at albedo within these bounds (its energy is always Rd(x)).
#: At a fixed mfp the shape still changes between Rd = 1e-3 and 1e-5 (and 0.999 and 1 - 1e-5):
#: 2.7e-3 of L1 for an impulse at mfp 1 texel, more than tol. Beyond these bounds the change is
#: measured (``shape_clamp_error``), added to the bound and warned of
RD_MIN, RD_MAX = 1e-5, 1.0 - 1e-5


#: lattice steps in logit(Rd) and ln(ld) at tol = 1e-3; halved per factor 16 of tighter tol
#: (the cubic interpolation error goes as h^4). Measured kernel interpolation error (L1 of the
#: normalized kernel) at these steps: <= 3e-4 over albedo 0.02..0.98, ld 0.5..16 texels.
LATTICE_STEPS = (0.4, 0.2)


#: the texels' weights are bilinear in a table REFINE times finer than the lattice per axis,
#: whose entries are the lattice's Lagrange-cubic interpolation: 4 taps a texel, not 16 (the
#: gather's cost). Bilinear interpolation of the cubic adds ~ (h / REFINE)^2 / 8 times the
#: weights' curvature; it is measured with the rest (``TexturedPlan.interp_error``).
REFINE = 8


CHECKS_PER_AXIS = 4         # interpolation checked at up to 4 x 4 points of the range


def logit(p):
    return np.log(p) - np.log1p(-p)


def sigmoid(t):
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


@NODE_CACHE.memoize
def node_kernel(rd, ld, eta, radius, exact=False):
    """Exact normalized (sums to 1) quadrant of the kernel of (Rd, ld texels) at radius K."""
    sa, ss = ref.albedo_to_coefficients(rd, ld, eta, exact)
    st = float(sa + ss)
    quad = quadrant_weights(float(ss / st), st, eta, radius, exact)
    quad /= quadrant_sum(quad)
    quad.setflags(write=False)
    return quad


@NODE_CACHE.memoize
def node_radius(rd, ld, eta, tol, exact=False):
    sa, ss = ref.albedo_to_coefficients(rd, ld, eta, exact)
    st = float(sa + ss)
    r_t = truncation_radius(float(ss / st), st, eta, tol, exact)
    return int(np.ceil(r_t - 0.5)) if r_t > 0.5 else 0


@dataclass(frozen=True)
class TexturedPlan:
    """One channel's shared basis, lattice and node weights."""

    radius: int              # K, the common kernel radius (texels)
    basis: str               # "gaussians" (separable, NNLS weights) or "svd" (eigen-kernels)
    kernels: tuple           # gaussians: 1D texel-integrated weights; svd: (K+1)^2 quadrants
    axes: tuple              # (Axis of Rd via logit, Axis of ld via ln)
    table: np.ndarray        # (n_rd, n_ld, G) float32 node weights; node kernels sum to 1
    fine: np.ndarray         # (REFINE (n_rd - 1) + 1, ..., G) float32: the gather's table
    eta: float
    fit_error: float         # max L1 error of the node kernels in the basis (svd: of the nodes
    #                          within the texture's range; the others serve the cubic only)
    interp_error: float      # max L1 error at the check points (basis + interpolation)
    truncation_tol: float
    near: int = -1           # the near field's radius (``near_classes``; -1: none)
    near_values: np.ndarray = field(default_factory=lambda: np.zeros((0, 0), np.float32))
    #                          (M, classes) float32: the near kernels' values per near class
    #                          (``near_field_basis``)

    @property
    def error_bound(self):
        """Bound on |M - exact| / (max E * Rd(x)): truncation + the measured kernel error."""
        return self.truncation_tol + max(self.fit_error, self.interp_error)

    def blurred_quadrants(self):
        """(G, K+1, K+1) quadrant of each basis kernel the image is blurred with (by FFT or
        the separable kernels)."""
        if self.basis == "svd":         # none where the near field holds the whole kernel
            return np.asarray(self.kernels).reshape((-1, self.radius + 1, self.radius + 1))
        return basis_columns(self.kernels, self.radius).T.reshape(
            (-1, self.radius + 1, self.radius + 1))

    @property
    def near_basis(self):
        """(M, classes) float32: the near kernels' values per near class (``near_classes``),
        in the table's order after the blurred basis kernels (kernels/blur_textured.cl
        ``gather_exitance``)."""
        return np.ascontiguousarray(self.near_values, np.float32)

    def quadrants(self):
        """(G + M, K+1, K+1): the blurred basis kernels' quadrants, then the near kernels'
        (``near_quadrants``): the table's weights, in its order."""
        return with_near_classes(self.blurred_quadrants(), self.near_values, self.near,
                                 self.radius)


def transformed(rd, ld):
    """The lattice variables (logit Rd, with Rd clipped to [RD_MIN, RD_MAX]; ln ld), float64."""
    return (logit(np.clip(np.asarray(rd, np.float64), RD_MIN, RD_MAX)),
            np.log(np.asarray(ld, np.float64)))


@dataclass(frozen=True)
class MapExtremes:
    """The extremes of one channel's Rd and ld maps that its plan and bound depend on."""

    rd_lit_min: float        # the smallest Rd > 0 (the smallest Rd if no texel is lit)
    rd_max: float
    ld_min: float
    ld_max: float


def map_extremes(rd, ld, ranges=None) -> MapExtremes:
    """MapExtremes of float maps rd, ld, by whole-map reductions (a masked one only where some
    texel is unlit), or the (min, max) that ``ranges`` (``params.MapRanges``) kept of them."""
    extremes = value_range if ranges is None else ranges.of
    lo, hi = extremes(rd)
    if lo <= 0 < hi:
        lo = np.min(rd, where=rd > 0, initial=np.inf)
    ld_lo, ld_hi = extremes(ld)
    return MapExtremes(float(lo), float(hi), float(ld_lo), float(ld_hi))


def parameter_ranges(ext: MapExtremes):
    """((lo, hi) of logit Rd, (lo, hi) of ln ld) over maps of extremes ``ext``: the transforms
    are monotone, so these are the transformed extremes. Texels of Rd = 0 give 0 whatever
    their shape, so they do not widen the albedo range (a masked map would pay for nodes down
    to RD_MIN)."""
    t_rd = transformed([ext.rd_lit_min, ext.rd_max], [ext.ld_min, ext.ld_max])
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
    in blur_textured.cl)."""
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
    """Host (float64) version of blur_textured.cl's per-texel weights at fine-table coordinates
    (cu, cv), for checks."""
    nu, nv, _ = plan.fine.shape
    return _interpolate(plan.fine.astype(np.float64), _linear_taps(nu, cu), _linear_taps(nv, cv))


def common_radius(rd_range, ld_range, eta, tol, exact=False):
    """K: the largest truncation radius at tol over the texels' parameter range (the profile
    widens with ld; its dependence on Rd is sampled at 9 albedos across the range)."""
    ld_max = float(np.exp(ld_range[1]))
    rds = sigmoid(np.linspace(rd_range[0], rd_range[1], 9))
    return max(node_radius(float(np.clip(r, RD_MIN, RD_MAX)), ld_max, eta, tol, exact)
               for r in rds)


#: planning holds every lattice node's exact kernel, (K+1)^2 float64 each, and the SVD's
#: weighted copies and factors of them: measured peaks 7-8x the node kernels' bytes (1.35 GiB
#: for 1632 nodes at K = 115, 5.4 GiB for 1836 at K = 230). A plan whose estimate exceeds
#: this is refused before any of it is built (``check_plan_size``)
PLAN_PEAK_BYTES = 4 << 30
PLAN_PEAK_PER_NODE_BYTE = 8


def check_plan_size(axes, radius, rd_range, ld_range):
    """ValueError naming the ranges, if planning them would need more than PLAN_PEAK_BYTES:
    the lattice's node count grows with the width of both ranges and the kernels' size with
    the largest mfp, whatever the image's size (albedo 1e-4..0.9999 with mfp 0.05..64 texels:
    ~2000 nodes of radius 460, tens of GiB)."""
    nodes = len(axes[0].values) * len(axes[1].values)
    peak = PLAN_PEAK_PER_NODE_BYTE * nodes * (radius + 1) ** 2 * 8
    if peak <= PLAN_PEAK_BYTES:
        return
    (t0, t1), (l0, l1) = rd_range, ld_range
    raise ValueError(
        f"texture-varying blur: albedo {sigmoid(t0):.6g}..{sigmoid(t1):.6g} with mfp "
        f"{np.exp(l0):.3g}..{np.exp(l1):.3g} texels needs {nodes} lattice kernels of radius "
        f"{radius} (~{peak / 2**30:.0f} GiB to plan, over {PLAN_PEAK_BYTES / 2**30:.0f} GiB): "
        f"blur the texture's materials separately (narrower ranges), or raise tol or the "
        f"texel size")


class LatticeKernels(NamedTuple):
    """A range's lattice and its exact kernels: the axes, the common radius K, every node's
    normalized quadrant (``targets``, Rd-major), the check points' ((t_rd, t_ld), quadrant)
    (``range_kernels``), and per node whether it lies inside the range."""

    axes: tuple
    radius: int
    targets: list
    checks: list
    inside: list


def lattice_axes(rd_range, ld_range, tol) -> tuple:
    """The (Rd, ld) Axes of logit(Rd) in rd_range and ln(ld texels) in ld_range at tol."""
    steps = lattice_steps(tol)
    return (_axis(*rd_range, steps[0], lambda t: min(max(sigmoid(t), RD_MIN), RD_MAX)),
            _axis(*ld_range, steps[1], np.exp))


def lattice_kernels(rd_range, ld_range, eta, tol, exact=False, max_radius=2048):
    """The LatticeKernels of logit(Rd) in rd_range and ln(ld texels) in ld_range at tol
    (ValueError where the radius exceeds max_radius or the plan would be too large)."""
    axes = lattice_axes(rd_range, ld_range, tol)
    radius = common_radius(rd_range, ld_range, eta, tol, exact)
    if radius > max_radius:
        raise ValueError(f"truncation radius {radius} texels exceeds max_radius={max_radius}: "
                         f"raise tol or the texel size")
    check_plan_size(axes, radius, rd_range, ld_range)
    targets = [node_kernel(a, b, eta, radius, exact) for a in axes[0].values
               for b in axes[1].values]
    inside = [a and b for a in inside_range(axes[0], rd_range)
              for b in inside_range(axes[1], ld_range)]
    return LatticeKernels(axes, radius, targets,
                          range_kernels(axes, rd_range, ld_range, eta, radius, exact), inside)


def training_kernels(targets, checks, inside):
    """The kernels of the range, which the eigen-kernels are fitted to: the nodes inside it and
    the exact kernels at its check points (docs/model.md "What the eigen-kernels are fitted
    to")."""
    return [t for t, i in zip(targets, inside) if i] + [q for _, q in checks]


def make_plan_for_ranges(rd_range, ld_range, eta, tol, exact=False, basis="svd",
                         max_radius=2048, costs: GatherCosts = DEFAULT_GATHER_COSTS):
    """The TexturedPlan for logit(Rd) in rd_range and ln(ld texels) in ld_range, its near
    field chosen for a device of gather costs ``costs`` (made; ``textured_plan_files.
    plan_for_ranges`` keeps them in memory and on disk)."""
    axes, radius, targets, checks, inside = lattice_kernels(rd_range, ld_range, eta, tol, exact,
                                                            max_radius)
    shape_axes = tuple(len(a.values) for a in axes)
    if basis == "svd":
        train = training_kernels(targets, checks, inside)

        def measure(quads, values, near, coef):
            table = coef.reshape(*shape_axes, -1).astype(np.float32)
            return interp_error(fine_table(table), with_near_classes(quads, values, near, radius),
                                axes, checks)
        best = near_field_basis(targets, train, tol, radius, measure, costs)
        every = with_near_classes(best.quads, best.near_values, best.near, radius)
        fit_error = max((float(np.abs(unfold_quadrant(np.tensordot(c, every, 1) - t)).sum())
                         for c, t, i in zip(best.coef, targets, inside) if i), default=0.0)
        table = best.coef.reshape(*shape_axes, -1).astype(np.float32)
        # the fit's interpolation error is measured on this very table (``measure``)
        return TexturedPlan(radius, basis, tuple(best.quads), axes, table, fine_table(table),
                            eta, fit_error, best.interp_error, tol, best.near, best.near_values)
    kernels, coef, fit_error = _gaussian_fits(targets, radius, tol)
    table = coef.reshape(*shape_axes, -1).astype(np.float32)
    plan = TexturedPlan(radius, basis, kernels, axes, table, fine_table(table), eta, fit_error,
                       0.0, tol)
    return replace(plan, interp_error=interp_error(plan.fine, plan.quadrants(), axes, checks))


def _gaussian_fits(targets, radius, tol):
    """Shared separable Gaussian basis and NNLS node weights, densified until every node fits
    within L1 error tol (or MAX_BASIS is reached)."""
    ratio = BASIS_RATIO
    while True:
        kernels = basis_kernels(basis_sigmas(radius, basis_count(radius, ratio)), radius)
        columns = basis_columns(kernels, radius)
        fits = [fit_node(t, columns) for t in targets]
        fit_error = max(err for _, err in fits)
        if fit_error <= tol or len(kernels) >= MAX_BASIS:
            return kernels, np.stack([c for c, _ in fits]), fit_error
        ratio = ratio ** (2.0 / 3.0)


def inside_range(axis, t_range):
    """Per node of ``axis``: True if it lies within the transformed range t_range = (lo, hi)
    (texels have its kernel's parameters; the nodes beyond serve the cubic's stencil only)."""
    lo, hi = t_range
    if axis.step == 0:
        return [True] * len(axis.values)
    t = (np.arange(len(axis.values)) + axis.origin) * axis.step
    slack = 1e-9 * max(1.0, abs(lo), abs(hi))
    return list((t >= lo - slack) & (t <= hi + slack))


def range_kernels(axes, rd_range, ld_range, eta, radius, exact=False):
    """((t_rd, t_ld), exact kernel quadrant) at the check points of the range
    (``_check_points``: its corners and the lattice cells' midpoints), where the
    interpolation is measured; with the nodes inside the range, the kernels the SVD bases are
    fitted to."""
    return [((t_rd, t_ld), node_kernel(float(np.clip(sigmoid(t_rd), RD_MIN, RD_MAX)),
                                       float(np.exp(t_ld)), eta, radius, exact))
            for t_rd, t_ld in itertools.product(_check_points(*rd_range, axes[0].step),
                                                _check_points(*ld_range, axes[1].step))]


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


def interp_error(fine, quads, axes, checks):
    """The largest L1 error of the gather's kernel (the fine table's ``fine`` weights, bilinear,
    of the kernels ``quads``) against the exact kernels ``checks`` (``range_kernels``)."""
    worst = 0.0
    for (t_rd, t_ld), exact_q in checks:
        check_stop()
        w = _interpolate(fine.astype(np.float64),
                         _linear_taps(fine.shape[0], _fine_coords(axes[0], t_rd)),
                         _linear_taps(fine.shape[1], _fine_coords(axes[1], t_ld)))
        worst = max(worst, float(np.abs(unfold_quadrant(np.tensordot(w, quads, 1)
                                                        - exact_q)).sum()))
    return worst


def fine_axis_map(axis):
    """(scale, offset) of an axis's fine-table coordinate, t * scale - offset for transformed
    value t (float32; both 0 on a constant axis): as ``texel_coords`` and the device's
    ``fine_coords`` (kernels/blur_textured.cl) compute it."""
    if axis.step == 0:
        return np.float32(0), np.float32(0)
    return np.float32(REFINE / axis.step), np.float32(REFINE * axis.origin)


def texel_coords(plan, rd, ld):
    """Fine-table coordinates (float32 maps) of the texels' Rd, ld float32 maps: logit(Rd
    clipped to [RD_MIN, RD_MAX]) and ln(ld) in fine steps (lattice step / REFINE) from node 0
    (zeros on a constant axis). In float32 they are good to ~1e-6 of a lattice step. The host
    version of what the device computes per texel (kernels/blur_textured.cl ``fine_coords``)."""
    def on_axis(axis, t):
        if axis.step == 0:
            return np.zeros(t.shape, np.float32)
        scale, offset = fine_axis_map(axis)
        t *= scale
        t -= offset
        return t

    p = np.clip(rd, np.float32(RD_MIN), np.float32(RD_MAX))
    u = np.log(np.divide(p, np.float32(1.0) - p, out=p), out=p)
    return on_axis(plan.axes[0], u), on_axis(plan.axes[1], np.log(ld))


def shape_clamp_error(plan, ext: MapExtremes, exact=False) -> float:
    """L1 error (of the normalized kernel) of taking the shape of RD_MIN or RD_MAX for the
    texels of maps with extremes ``ext`` beyond them (Rd = 0 aside: it gives 0), at the
    extremes of ld: what the clamp adds to the bound (0 if no texel is beyond). The shape
    moves away from the bound's monotonically with Rd, so the most extreme texel is the
    worst."""
    if not ext.rd_max > 0:
        return 0.0
    worst = 0.0
    for far, bound in ((ext.rd_lit_min, RD_MIN), (ext.rd_max, RD_MAX)):
        if RD_MIN <= far <= RD_MAX:
            continue
        for length in {ext.ld_min, ext.ld_max}:
            check_stop()
            diff = (node_kernel(far, length, plan.eta, plan.radius, exact)
                    - node_kernel(bound, length, plan.eta, plan.radius, exact))
            worst = max(worst, float(np.abs(unfold_quadrant(diff)).sum()))
    return worst
