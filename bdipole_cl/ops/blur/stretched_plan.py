"""The stretched blur's plan: anisotropic kernels per texel over a shared eigen-kernel basis and
a near field (docs/stretch.md "The blur in surface distance", "The lattice", "The near field").

A texel whose steps along u and v are s_u and s_v long on the surface scatters with R of the
surface distance ``r = |(s_u du, s_v dv)|`` (an axis-aligned metric: the shear is bounded, not
modelled, docs/stretch.md "Shear"). In texels its kernel is R with the diffusion length
``l_u = ld / s_u`` along u and ``l_v = ld / s_v`` along v, integrated over each texel as the
plain blur's (``stretched_quadrant``), truncated at a square of side 2K + 1 holding the
ellipse where the profile's tail is tol Rd, and normalized to sum to 1. Its shape depends on
(Rd, l_u, l_v); the lattice's variables are logit(Rd), ln l = ln sqrt(l_u l_v) (the scale)
and s = ln(l_u / l_v) (the anisotropy), so that a map's range of anisotropy is an axis of its
own (a chart of one aspect collapses it to one node) and the box of the ranges holds only
kernels of the aspects the map has. The cells within ``near`` of the texel are the near field
(``near_field``, classes of four cells: the kernels are even in u and v), whose values each
node keeps exactly; the eigen-kernels fit the rest, each node's far part projected on them, and
the texels' weights (far and near) are the lattice's cubic interpolation, tabulated REFINE
times finer per axis and read at the corners of the texel's tetrahedron
(kernels/blur_stretched.cl). The fit and interpolation errors are measured
against exact kernels at the range's corners and lattice cells' middles, and reported with the
truncation's tol as the bound, as for the texture-varying blur.
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass, field

import numpy as np

from ...caches import ByteCache
from ...physics import reference as ref
from .near_field import DEFAULT_GATHER_COSTS, GatherCosts, near_field_basis, with_near_classes
from .plan_files import (STRETCHED_FOLDER, PlanFormat, axes_arrays, axes_of, kept_plan,
                         kernels_array, scalars_array, scalars_of)
from .textured_plan import (LATTICE_STEPS, RD_MAX, RD_MIN, REFINE, Axis, lagrange4, logit,
                            sigmoid, training_kernels)
from .weights import quadrant_sum, quadrant_weights, truncation_radius, unfold_quadrant

STRETCHED_KERNELS = ByteCache("stretched node kernels", 256 << 20)
STRETCHED_PLANS = ByteCache("stretched plans", 256 << 20)

#: check points per axis: the range's ends and the middles of the lattice cells' fine cells
#: (where the cubic and then the tetrahedra err most), at most this many evenly chosen
CHECKS_PER_AXIS = 4
#: planning refuses a lattice of more nodes than this
MAX_NODES = 4096
#: planning holds the nodes' exact kernels and the SVD's weighted copies of them: refused
#: beyond these bytes before any is built (as ``textured_plan.PLAN_PEAK_BYTES``)
PLAN_PEAK_BYTES = 4 << 30
PLAN_PEAK_PER_NODE_BYTE = 8
#: lattice step of s = ln(l_u / l_v) at tol = 1e-3 (halved per factor 16 of tighter tol, as
#: the others): the kernel changes with s about as fast as with ln l (a change of s by ds
#: stretches u by e^(ds/2) and v by e^(-ds/2)); the error is measured either way
ANISOTROPY_STEP = 0.2
#: near field radii the stretched plan tries (``near_field.NEAR_RADII``: its classes are
#: (n + 1)^2, not the radially symmetric (n + 1)(n + 2) / 2)
NEAR_RADII = (-1, 0, 1, 2, 3, 4, 5, 6)


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
    return quadrant_weights(alpha, st, eta, k, exact, su=1.0 / lu, sv=1.0 / lv)


@STRETCHED_KERNELS.memoize
def node_kernel(rd, lu, lv, eta, radius, exact=False):
    """The normalized (sums to 1) quadrant of (Rd, l_u, l_v texels) at radius K, read-only."""
    quad = stretched_quadrant(rd, lu, lv, eta, radius, exact)
    quad /= quadrant_sum(quad)
    quad.setflags(write=False)
    return quad


def lattice_variables(rd, lu, lv):
    """The lattice variables (logit Rd, Rd clipped to [RD_MIN, RD_MAX]; ln l; s) of Rd and the
    diffusion lengths l_u, l_v (texels), float64: l = sqrt(l_u l_v), s = ln(l_u / l_v)."""
    a = np.log(np.asarray(lu, np.float64))
    b = np.log(np.asarray(lv, np.float64))
    return logit(np.clip(np.asarray(rd, np.float64), RD_MIN, RD_MAX)), 0.5 * (a + b), a - b


def kernel_at(t, eta, radius, exact=False):
    """``node_kernel`` at lattice variables t = (logit Rd, ln l, s)."""
    rd = float(np.clip(sigmoid(t[0]), RD_MIN, RD_MAX))
    return node_kernel(rd, float(np.exp(t[1] + 0.5 * t[2])), float(np.exp(t[1] - 0.5 * t[2])),
                       eta, radius, exact)


def kernel_radius(rd, l_max, eta, tol, exact=False) -> int:
    """K: the square of side 2K + 1 holds the ellipse beyond which the tail is tol Rd, for the
    longest diffusion length ``l_max`` (texels) on either axis."""
    alpha, st = coefficients(rd, eta, exact)
    r_t = truncation_radius(alpha, st, eta, tol, exact) * l_max
    return int(np.ceil(r_t - 0.5)) if r_t > 0.5 else 0


def lattice_axis(lo, hi, step) -> Axis:
    """Nodes (their lattice variable) covering [lo, hi] for a 4-point cubic; one if lo == hi."""
    if hi - lo <= 1e-12 * max(1.0, abs(lo)):
        return Axis((float(lo),), 0.0, 0.0)
    i0 = int(np.floor(lo / step)) - 1
    i1 = max(int(np.floor(hi / step)) + 2, i0 + 3)
    return Axis(tuple(float(i * step) for i in range(i0, i1 + 1)), float(i0), step)


def lattice_axes(ranges, tol) -> tuple:
    """The lattice's Axis of each of transformed ranges at tol (``lattice_axis``)."""
    return tuple(lattice_axis(lo, hi, step) for (lo, hi), step in zip(ranges,
                                                                      lattice_steps(tol)))


def lattice_nodes(ranges, tol) -> int:
    """The nodes of the lattice over transformed ranges at tol."""
    return int(np.prod([len(a.values) for a in lattice_axes(ranges, tol)]))


def ranges_union(a, b):
    """The box of two boxes of transformed ranges."""
    return tuple((min(p[0], q[0]), max(p[1], q[1])) for p, q in zip(a, b))


#: a window joins a group's plan where their union is at most this many lattice steps wider,
#: on every axis, than the group's first window (``shared_ranges``)
MERGE_STEPS = 1.0
#: widths in steps are compared within this (0.6 / 0.2 is 2.9999999999999996)
STEPS_SLACK = 1e-9


def range_steps(ranges, tol) -> np.ndarray:
    """The widths of transformed ranges on each axis, in lattice steps at tol."""
    return np.array([(hi - lo) / step for (lo, hi), step in zip(ranges, lattice_steps(tol))])


def shared_ranges(ranges, sizes, tol) -> list:
    """Per window (its transformed ``ranges``, its texels ``sizes``), the ranges of the plan
    it shares: windows are taken largest first, each joining the group whose union with it is
    narrowest (the rank grows with the ranges' widths), where that union is at most
    MERGE_STEPS wider on every axis than the group's first window (its largest) and has at
    most MAX_NODES nodes, else starting a group. So a UV layout's charts of overlapping ranges
    share one plan (planned once, cached: one table and its spectra), while a window wider than
    a group (a sliver chart of many aspects) starts its own rather than widen the plan of all
    its windows; no group grows past its first window by more than MERGE_STEPS, by chains of
    near neighbours or of ever wider slivers; and charts of distinct narrow ranges (a
    cylinder's, one aspect each) keep their own plans."""
    groups, member = [], [0] * len(ranges)     # per group: [box, its first window's widths]
    for i in sorted(range(len(ranges)), key=lambda i: (-sizes[i], i)):
        best = None
        for g, (box, first) in enumerate(groups):
            union = ranges_union(box, ranges[i])
            width = range_steps(union, tol)
            if (np.all(width <= first + MERGE_STEPS + STEPS_SLACK)
                    and lattice_nodes(union, tol) <= MAX_NODES
                    and (best is None or width.sum() < best[1])):
                best = (g, float(width.sum()), union)
        if best is None:
            groups.append((tuple(ranges[i]), range_steps(ranges[i], tol)))
            member[i] = len(groups) - 1
        else:
            g, _, union = best
            groups[g] = (union, groups[g][1])
            member[i] = g
    return [groups[g][0] for g in member]


def lattice_steps(tol):
    """The steps of logit Rd, ln l and s at tol: LATTICE_STEPS' and ANISOTROPY_STEP, halved
    per factor 16 of tol below 1e-3 (the cubic's error goes as h^4)."""
    level = max(0, int(np.ceil(np.log2(max(1e-3 / tol, 1.0)) / 4.0)))
    return tuple(s / 2 ** level for s in (*LATTICE_STEPS, ANISOTROPY_STEP))


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
    """The gather's table: the node weights (n0, n1, n2, G) (float32) interpolated by the
    cubic along each axis at REFINE points per lattice step, float32."""
    m0, m1, m2 = (cubic_matrix(n) for n in table.shape[:3])
    return np.einsum("ai,bj,ck,ijkg->abcg", m0, m1, m2, table.astype(np.float64),
                     optimize=True).astype(np.float32)


def fine_entries(table, index):
    """The fine table's entries (float32, as ``fine_table3``) at fine indices ``index`` (n, 3)
    only: each the cubic's 4 x 4 x 4 (or fewer, on one-node axes) node weights."""
    rows = [cubic_matrix(n)[np.asarray(index)[:, a]] for a, n in enumerate(table.shape[:3])]
    return np.einsum("na,nb,nc,abcg->ng", *rows, table.astype(np.float64),
                     optimize=True).astype(np.float32)


def tetrahedral_taps(shape, coords):
    """The gather's four table taps at fine coordinates ``coords`` (3,) of a fine table of
    ``shape`` (3,): (fine indices (4, 3), weights (4,)). From the cell's first corner one step
    along each axis by decreasing fraction (Kuhn's tetrahedra; a one-node axis has fraction 0
    and no step), as kernels/blur_stretched.cl ``texel_weights``."""
    base = np.zeros(3, int)
    frac = np.zeros(3)
    for a, (n, c) in enumerate(zip(shape, coords)):
        if n > 1:
            base[a] = int(np.clip(np.floor(c), 0, n - 2))
            frac[a] = c - base[a]
    order = np.argsort(-frac, kind="stable")
    idx = [base.copy()]
    for a in order:
        step = idx[-1].copy()
        step[a] += shape[a] > 1
        idx.append(step)
    f = np.concatenate([[1.0], frac[order], [0.0]])
    return np.array(idx), f[:-1] - f[1:]


@dataclass(frozen=True)
class StretchedPlan:
    """One channel's (or chart's) stretched basis: eigen-kernels, near field, lattice and the
    gather's table (duck-typed as a ``TexturedPlan`` where ``fft.basis_blurs`` reads it)."""

    radius: int
    kernels: tuple               # (K+1)^2 quadrants of the blurred eigen-kernels
    axes: tuple                  # Axis of logit Rd, ln l, s
    fine: np.ndarray             # (f0, f1, f2, G + M) float32
    eta: float
    fit_error: float
    interp_error: float
    truncation_tol: float
    nodes: int
    near: int = -1               # the near field's radius (-1: none)
    near_values: np.ndarray = field(default_factory=lambda: np.zeros((0, 0), np.float32))
    #                              (M, (near + 1)^2) float32: the near kernels per class
    near_direct: bool = False    # near kernels = the classes (identity): weights of class sums

    @property
    def error_bound(self) -> float:
        return self.truncation_tol + max(self.fit_error, self.interp_error)

    def blurred_quadrants(self):
        return np.asarray(self.kernels).reshape((-1, self.radius + 1, self.radius + 1))

    @property
    def near_basis(self):
        return np.ascontiguousarray(self.near_values, np.float32)

    def quadrants(self):
        """(G + M, K+1, K+1): the table's kernels in its order (blurred, then near)."""
        return with_near_classes(self.blurred_quadrants(), self.near_values, self.near,
                                 self.radius, mirrored=False)

    def axis_maps(self):
        """Per axis (scale, offset) of its fine coordinate, t * scale - offset (0, 0 on a
        constant axis), float32 as the gather computes it."""
        return [(np.float32(0), np.float32(0)) if a.step == 0 else
                (np.float32(REFINE / a.step), np.float32(REFINE * a.origin)) for a in self.axes]


def check_points(lo, hi, step):
    """Where to check one axis: its ends and, inside, the middles of the fine cells at the
    lattice cells' middles, at most CHECKS_PER_AXIS evenly chosen (one point on a constant
    axis)."""
    if step == 0:
        return [lo]
    mids = (np.arange(np.floor(lo / step), np.ceil(hi / step)) + 0.5 + 0.5 / REFINE) * step
    pts = np.unique(np.concatenate([[lo, hi], mids[(mids > lo) & (mids < hi)]]))
    return list(pts[np.linspace(0, len(pts) - 1, min(len(pts), CHECKS_PER_AXIS)).astype(int)])


def fine_coords(axes, t):
    """Fine-table coordinates of lattice variables t (3,)."""
    return [0.0 if a.step == 0 else (v / a.step - a.origin) * REFINE for a, v in zip(axes, t)]


def interp_error(table, quads, axes, checks):
    """The largest L1 error of the gather's kernel (the fine table of node weights ``table``
    (n0, n1, n2, G + M) float32, at each check's tetrahedron, of the kernels ``quads``) against
    the exact ``checks`` ((t, quadrant))."""
    shape = [REFINE * (n - 1) + 1 for n in table.shape[:3]]
    taps = [tetrahedral_taps(shape, fine_coords(axes, t)) for t, _ in checks]
    entries = fine_entries(table, np.concatenate([idx for idx, _ in taps]))
    worst = 0.0
    for k, ((_, weights), (_, exact_q)) in enumerate(zip(taps, checks)):
        w = weights @ entries[4 * k:4 * k + 4].astype(np.float64)
        worst = max(worst, float(np.abs(unfold_quadrant(np.tensordot(w, quads, 1)
                                                         - exact_q)).sum()))
    return worst


def inside_box(axes, ranges):
    """Per node (in the lattice's order): whether it lies within every range (the nodes
    beyond serve the cubic's stencil only)."""
    per_axis = [np.abs(np.asarray(a.values) - np.clip(a.values, lo - 1e-9, hi + 1e-9)) == 0
                for a, (lo, hi) in zip(axes, ranges)]
    return [bool(all(f)) for f in itertools.product(*per_axis)]


def plan_radius(ranges, eta, tol, exact=False) -> int:
    """K over transformed ranges: the longest diffusion length of the box, l e^(|s| / 2) at
    its largest l and |s|, at five albedos across the range."""
    s_max = max(abs(ranges[2][0]), abs(ranges[2][1]))
    l_max = float(np.exp(ranges[1][1] + 0.5 * s_max))
    rds = sigmoid(np.linspace(ranges[0][0], ranges[0][1], 5))
    return max(kernel_radius(float(np.clip(r, RD_MIN, RD_MAX)), l_max, eta, tol, exact)
               for r in rds)


def plan_peak_bytes(nodes, radius) -> int:
    """The bytes planning holds at its peak: the nodes' kernels of radius K and the SVD's
    weighted copies of them."""
    return PLAN_PEAK_PER_NODE_BYTE * nodes * (radius + 1) ** 2 * 8


def check_plan_size(nodes, radius, ranges):
    """ValueError naming the ranges where planning them would take more than MAX_NODES
    kernels or PLAN_PEAK_BYTES."""
    peak = plan_peak_bytes(nodes, radius)
    if nodes > MAX_NODES or peak > PLAN_PEAK_BYTES:
        (t0, t1), (l0, l1), (s0, s1) = ranges
        raise ValueError(
            f"stretched blur: albedo {sigmoid(t0):.4g}..{sigmoid(t1):.4g}, diffusion length "
            f"{np.exp(l0):.3g}..{np.exp(l1):.3g} texels, aspect l_u/l_v {np.exp(s0):.3g}.."
            f"{np.exp(s1):.3g} need {nodes} lattice kernels of radius {radius} (~"
            f"{peak / 2 ** 30:.1f} GiB to plan; at most {MAX_NODES} and "
            f"{PLAN_PEAK_BYTES / 2 ** 30:.0f} GiB): blur the texture's materials separately, "
            f"or raise tol")


#: the scalar fields of a StretchedPlan, in its file's ``scalars`` order
FILE_SCALARS = ("radius", "eta", "fit_error", "interp_error", "truncation_tol", "nodes", "near",
                "near_direct")


def plan_file_arrays(plan: StretchedPlan) -> dict:
    """A StretchedPlan as the arrays of its file (``plan_files``)."""
    return {"fine": plan.fine, "near_values": plan.near_values,
            "kernels": kernels_array(plan.kernels, plan.radius),
            "scalars": scalars_array(plan, FILE_SCALARS), **axes_arrays(plan.axes)}


def plan_of_file_arrays(arrays) -> StretchedPlan:
    """The StretchedPlan ``plan_file_arrays`` wrote."""
    sc = scalars_of(arrays, FILE_SCALARS)
    return StretchedPlan(axes=axes_of(arrays, Axis), fine=arrays["fine"],
                         near_values=arrays["near_values"], kernels=tuple(arrays["kernels"]),
                         radius=int(sc["radius"]), nodes=int(sc["nodes"]), near=int(sc["near"]),
                         near_direct=bool(sc["near_direct"]),
                         **{f: sc[f] for f in ("eta", "fit_error", "interp_error",
                                               "truncation_tol")})


PLAN_FORMAT = PlanFormat(STRETCHED_FOLDER, plan_file_arrays, plan_of_file_arrays)


@STRETCHED_PLANS.memoize
def stretched_plan(ranges, eta, tol, exact=False, max_radius=2048,
                   costs: GatherCosts = DEFAULT_GATHER_COSTS) -> StretchedPlan:
    """``make_stretched_plan``'s plan, made once per version of the code that makes it: kept
    in memory and, across processes, in the user cache folder (``plan_files``)."""
    key = repr(("stretched", tuple((float(lo), float(hi)) for lo, hi in ranges), float(eta),
                float(tol), bool(exact), int(max_radius), costs, NEAR_RADII))

    return kept_plan(PLAN_FORMAT, key,
                     lambda plan: plan_is_whole(plan, ranges, eta, tol, exact),
                     lambda: make_stretched_plan(ranges, eta, tol, exact, max_radius, costs))


def plan_is_whole(plan: StretchedPlan, ranges, eta, tol, exact=False) -> bool:
    """Whether a plan (read from a file) is one of these arguments could be: their lattice,
    radius, eta and tol; a near field the plan tries, its classes exact ((n + 1)^2 of them);
    (K+1)^2 float64 eigen-kernels; the float32 table REFINE times finer than the lattice with
    a weight per eigen-kernel and class, float32 near values; every value finite, the errors
    >= 0. Not its values: those only the making checks."""
    axes = lattice_axes(ranges, tol)
    classes = (plan.near + 1) ** 2 if plan.near >= 0 else 0
    k = plan.radius + 1
    fine = tuple(REFINE * (len(a.values) - 1) + 1 for a in axes)
    arrays = (plan.fine, plan.near_values, *plan.kernels)
    return (plan.axes == axes and plan.eta == float(eta) and plan.truncation_tol == float(tol)
            and plan.nodes == int(np.prod([len(a.values) for a in axes]))
            and plan.near in NEAR_RADII and (plan.near < 0 or plan.near_direct)
            and plan.radius == plan_radius(ranges, eta, tol, exact)
            and plan.fine.dtype == np.float32 and plan.near_values.dtype == np.float32
            and all(q.shape == (k, k) and q.dtype == np.float64 for q in plan.kernels)
            and plan.near_values.shape[0] == classes
            and (classes == 0 or plan.near_values.shape == (classes, classes))
            and plan.fine.shape == (*fine, len(plan.kernels) + classes)
            and all(np.all(np.isfinite(a)) for a in arrays)
            and 0 <= plan.fit_error < np.inf and 0 <= plan.interp_error < np.inf)


def make_stretched_plan(ranges, eta, tol, exact=False, max_radius=2048,
                        costs: GatherCosts = DEFAULT_GATHER_COSTS) -> StretchedPlan:
    """The StretchedPlan of transformed ranges ((lo, hi) of logit Rd, ln l, s) at tol: the
    cheapest near field for the gather's ``costs`` (``near_field.near_field_basis``, classes
    of four cells), its ranks grown until the measured interpolation error is within tol."""
    axes = lattice_axes(ranges, tol)
    radius = plan_radius(ranges, eta, tol, exact)
    if radius > max_radius:
        raise ValueError(f"stretched blur: truncation radius {radius} texels exceeds "
                         f"max_radius={max_radius}: raise tol, or the stretch is too small for "
                         f"the mfp (texels far shorter than a diffusion length)")
    shape = tuple(len(a.values) for a in axes)
    check_plan_size(int(np.prod(shape)), radius, ranges)
    targets = [kernel_at(t, eta, radius, exact) for t in itertools.product(*(a.values
                                                                              for a in axes))]
    checks = [(t, kernel_at(t, eta, radius, exact)) for t in itertools.product(
        *(check_points(lo, hi, a.step) for (lo, hi), a in zip(ranges, axes)))]
    inside = inside_box(axes, ranges)
    train = training_kernels(targets, checks, inside)

    def measure(quads, values, near, coef):
        return interp_error(coef.reshape(*shape, -1).astype(np.float32),
                            with_near_classes(quads, values, near, radius, mirrored=False),
                            axes, checks)
    best = near_field_basis(targets, train, tol, radius, measure, costs, mirrored=False,
                            radii=NEAR_RADII, direct=True)
    every = with_near_classes(best.quads, best.near_values, best.near, radius, mirrored=False)
    fit = max((float(np.abs(unfold_quadrant(np.tensordot(c, every, 1) - t)).sum())
               for c, t, i in zip(best.coef, targets, inside) if i), default=0.0)
    table = best.coef.reshape(*shape, -1).astype(np.float32)
    return StretchedPlan(radius, tuple(best.quads), axes, fine_table3(table), float(eta), fit,
                         best.interp_error, float(tol), int(np.prod(shape)), best.near,
                         best.near_values, best.direct)
