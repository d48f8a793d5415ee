"""The texture-varying blur's bases (docs/model.md "Texture-varying parameters"): eigen-kernels
of the kernels of a parameter range and the projections of the lattice's node kernels on them,
and the near field, whose kernels the gather convolves with the irradiance itself
(kernels/blur_textured.cl), chosen by the gather's cost on the device in use.

The near field's cells fall into classes of equal weight by the kernels' symmetry: eight cells
(+-a, +-b), (+-b, +-a) for the radially symmetric kernels of the texture-varying blur
(``mirrored``), four cells (+-a, +-b) for the stretched blur's, which are even in u and in v
but not mirrored across the diagonal (docs/stretch.md "The near field")."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...signals import check_stop
from .weights import multiplicity


@dataclass(frozen=True)
class EigenKernels:
    """The eigen-kernels of a set of kernels (the SVD of their values weighted by ``mult``, the
    cells each value stands for: the cell multiplicity of a quadrant, so that it is the SVD of
    the whole kernels), and the projections of kernels on the first ``rank`` of them."""

    u: np.ndarray            # (values, kernels): the left singular vectors, weighted
    mult: np.ndarray         # (values,) cells per value
    shape: tuple             # a kernel's shape

    @classmethod
    def of(cls, kernels, mult=None):
        shape = kernels[0].shape
        mult = multiplicity(shape[0] - 1).ravel() if mult is None else np.ravel(mult)
        u, _, _ = np.linalg.svd(cls._weighted(kernels, mult), full_matrices=False)
        return cls(u, mult, shape)

    @staticmethod
    def _weighted(kernels, mult):                                   # values x kernels
        return np.stack([np.ravel(t) for t in kernels], axis=1) * np.sqrt(mult)[:, None]

    @property
    def most(self) -> int:
        return self.u.shape[1]

    def kernels(self, rank):
        """(rank, *shape): the first ``rank`` eigen-kernels' values."""
        return (self.u[:, :rank] / np.sqrt(self.mult)[:, None]).T.reshape((rank,) + self.shape)

    def project(self, kernels) -> "Projection":
        """The projections of ``kernels`` on the eigen-kernels, at any rank."""
        a_mat = self._weighted(kernels, self.mult)
        sw = np.sqrt(self.mult)
        return Projection(self, a_mat, (self.u.T @ a_mat).T, a_mat.T @ sw, self.u.T @ sw)


@dataclass(frozen=True)
class Projection:
    """Kernels projected on EigenKernels: their weighted values ``a_mat`` (values, kernels),
    their full projections (kernels, most), their sums, and each eigen-kernel's sum."""

    eigen: EigenKernels
    a_mat: np.ndarray
    full: np.ndarray
    sums: np.ndarray
    eigen_sums: np.ndarray

    def coefficients(self, rank):
        """(kernels, rank): each kernel's orthogonal projection on the first ``rank``
        eigen-kernels, scaled so that it sums to what the kernel does (a far part that is all
        zero, a kernel within the near field, keeps coefficients 0, not 0 / 0)."""
        coef = self.full[:, :rank].copy()
        recon = coef @ self.eigen_sums[:rank]
        coef *= np.divide(self.sums, recon, out=np.zeros_like(self.sums),
                          where=recon != 0)[:, None]
        return coef

    def fit_error(self, rank):
        """The largest L1 error of the kernels' reconstructions (``coefficients``)."""
        recon = self.eigen.u[:, :rank] @ self.coefficients(rank).T
        return float((np.abs(recon - self.a_mat).T @ np.sqrt(self.eigen.mult)).max())

    def rank_within(self, tol):
        """The fewest eigen-kernels that reconstruct every kernel within L1 error tol (or all
        of them): at least one unless every kernel is 0 (a far part within tol of 0 is still
        kept, so that every node sums to 1: energy is conserved)."""
        for rank in range(0 if not self.sums.any() else 1, self.eigen.most + 1):
            check_stop()
            if self.fit_error(rank) <= tol:
                return rank
        return self.eigen.most


def near_classes(near, mirrored=True):
    """The near field's cell classes (a, b): mirrored, near >= a >= b >= 0, class (a, b) the
    cells (+-a, +-b) and (+-b, +-a) of the radially symmetric kernel, whose weights are equal
    (the order of kernels/blur_textured.cl ``gather_exitance``, ``class_sum``); else every
    0 <= a, b <= near, class (a, b) the cells (+-a rows, +-b columns) of a kernel even in u
    and v (the order of kernels/blur_stretched.cl). near < 0: none."""
    return tuple((a, b) for a in range(near + 1) for b in range(a + 1 if mirrored
                                                                  else near + 1))


def class_quadrants(classes, radius, mirrored=True):
    """(n, K+1, K+1) quadrant of each near class's kernel: 1 on its cells."""
    quads = np.zeros((len(classes), radius + 1, radius + 1))
    for q, (a, b) in zip(quads, classes):
        q[a, b] = 1.0
        if mirrored:
            q[b, a] = 1.0
    return quads


def class_sizes(classes, mirrored=True):
    """The cells of the kernel in each near class (a, b): mirrored, 1 for the centre, 4 on the
    axes and diagonals, else 8; else 1 for the centre, 2 on the axes, else 4."""
    if not mirrored:
        return np.array([(1 if a == 0 else 2) * (1 if b == 0 else 2) for a, b in classes],
                        float)
    return np.array([1 if a == 0 else 4 if b in (0, a) else 8 for a, b in classes], float)


def class_values(quad, classes):
    """A kernel's value on each near class, from its quadrant."""
    return np.array([quad[a, b] for a, b in classes], np.float64).reshape(len(classes))


def near_quadrants(values, near, radius, mirrored=True):
    """(M, K+1, K+1) quadrants of the near kernels of values (M, classes) per near class."""
    return np.tensordot(np.asarray(values, np.float64),
                        class_quadrants(near_classes(near, mirrored), radius, mirrored),
                        1).reshape((-1, radius + 1, radius + 1))


def with_near_classes(quads, near_values, near, radius, mirrored=True):
    """The table's kernels, in its order: the blurred basis quadrants ``quads``, then the near
    kernels' (``near_quadrants`` of their values per class)."""
    return np.concatenate([quads, near_quadrants(near_values, near, radius, mirrored)])


#: near field radii tried per plan: the cells within ``near`` (Chebyshev) of the texel are the
#: near field, whose kernels (``near_field_basis``) the gather convolves with the irradiance
#: itself, so the FFT basis fits only the kernels beyond, which the parameters change less
#: (fewer basis kernels: at mfp 4 texels, 7 with no near field, 4 with near 3). -1: none.
NEAR_RADII = (-1, 0, 1, 2, 3, 4, 5, 6)
#: the near kernels' share of the fit's L1 error budget tol: their reconstruction of the nodes'
#: near fields is within NEAR_TOL_SHARE * tol (the FFT basis's of the rest within tol)
NEAR_TOL_SHARE = 0.125


@dataclass(frozen=True)
class GatherCosts:
    """The gather's cost per texel on a device (kernels/blur_textured.cl ``gather_exitance``),
    in units of one basis blur (an inverse FFT of the image on the host and its weight: ~15 ms
    at 2048^2 on the 2-core AVX-512 CPU): of a near cell (its load and add into its class's
    sum), of one near kernel's value on one class (a multiply-add), and of one weight of the
    table (its four taps). Measured per runtime (``dispatch.GATHER_COSTS``); they choose the
    near field (``near_cost``), never the result's accuracy."""

    cell: float
    term: float
    weight: float


#: Intel's CPU runtime's, measured there (``dispatch.GATHER_COSTS``), for devices not measured
DEFAULT_GATHER_COSTS = GatherCosts(cell=0.005, term=0.0, weight=0.04)


def near_cells(near) -> int:
    """The cells of near field ``near`` (-1: none)."""
    return (2 * near + 1) ** 2 if near >= 0 else 0


def near_cost(near, nbasis, nnear, costs: GatherCosts, mirrored=True, direct=False):
    """The blur's cost model in basis blurs per texel: nbasis inverse FFTs, the near field's
    cells and class terms (none where its weights are the classes' own: ``direct``), and the
    table's weights."""
    terms = 0 if direct else len(near_classes(near, mirrored)) * nnear
    return (nbasis + costs.cell * near_cells(near) + costs.term * terms
            + costs.weight * (nbasis + nnear))


def far_parts(kernels, near, radius):
    """The quadrants ``kernels`` with the cells of near field ``near`` (every cell within
    Chebyshev distance ``near``, whatever the classes) zeroed: what the FFT basis fits."""
    mask = np.zeros((radius + 1, radius + 1), bool)
    mask[:near + 1, :near + 1] = near >= 0
    return [np.where(mask, 0.0, t) for t in kernels]


def far_rank(train, near, radius, tol) -> int:
    """The fewest far eigen-kernels that fit every ``train`` kernel beyond near field ``near``
    within L1 error tol: where ``_near_field_fit``'s ranks start (a lower bound on the FFT
    blurs a channel of that range needs)."""
    parts = far_parts(train, near, radius)
    return EigenKernels.of(parts).project(parts).rank_within(tol)


@dataclass(frozen=True)
class NearFieldFit:
    """One near field's basis: the far (FFT) eigen-kernels' quadrants, the near kernels'
    values per class, the node coefficients (nodes, G + M), and their measured errors."""

    near: int
    quads: np.ndarray        # (G, K+1, K+1)
    near_values: np.ndarray  # (M, classes) float32
    coef: np.ndarray         # (nodes, G + M)
    interp_error: float      # ``interp_error`` of the node coefficients' table
    mirrored: bool = True    # the classes' symmetry (``near_classes``)
    direct: bool = False     # near kernels one per class (values the identity): no projection

    def cost(self, costs: GatherCosts):
        return near_cost(self.near, len(self.quads), len(self.near_values), costs,
                         self.mirrored, self.direct)


def near_field_basis(targets, train, tol, radius, measure, costs: GatherCosts,
                     mirrored=True, radii=None, direct=False):
    """The cheapest NearFieldFit over NEAR_RADII (``near_cost``) for the node kernels
    ``targets`` and the kernels of the texture's parameter range, ``train``. The near kernels
    are eigen-kernels of the ``train`` kernels' values on the near classes, the far basis of
    the ``train`` kernels with the near cells removed; each node's parts are projected on them
    (each fitted to its mass, so every node still sums to 1). The ranks start where every
    ``train`` kernel is within tol (far) and NEAR_TOL_SHARE * tol (near), and grow, the near
    first where that does as well (it is the cheaper), until ``measure`` (the interpolation
    error of a (quads, values, coef) fit over the range) is within tol too: the nodes beyond
    the range serve the cubic's stencil, and their projections enter the texels' kernels. The
    cost is the device's (``costs``). ``mirrored``: the classes' symmetry (``near_classes``);
    ``radii``: the near field radii tried (NEAR_RADII); ``direct``: one near kernel per class
    (each node's near field exact, only the far rank grows: ``_near_field_fit``)."""
    best = None
    for near in (r for r in (NEAR_RADII if radii is None else radii) if r <= radius):
        if best is not None and near_cost(near, 0, 0, costs, mirrored) >= best.cost(costs):
            break                                    # its cells alone cost more
        fit = _near_field_fit(targets, train, tol, radius, near, measure, mirrored, direct)
        if best is None or fit.cost(costs) < best.cost(costs):
            best = fit
    return best


def _near_field_fit(targets, train, tol, radius, near, measure, mirrored=True, direct=False):
    """The NearFieldFit of near field ``near`` (``near_field_basis``). ``direct``: the near
    kernels are the classes themselves (values the identity, each node's coefficients its own
    class values: exact), which the gather reads as weights of the class sums, with no
    multiply-adds of near kernels on classes (kernels/blur_stretched.cl, the stretched blur's
    near field)."""
    classes = near_classes(near, mirrored)
    if direct and classes:
        return _direct_near_fit(targets, train, tol, radius, near, measure, mirrored)

    def far(kernels):
        return far_parts(kernels, near, radius)

    def near_part(kernels):
        return [class_values(t, classes) for t in kernels]
    far_eigen = EigenKernels.of(far(train))
    far_t = far_eigen.project(far(targets))
    if classes:
        near_eigen = EigenKernels.of(near_part(train), class_sizes(classes, mirrored))
        near_t = near_eigen.project(near_part(targets))

    def fit(g, m):
        values = (near_eigen.kernels(m) if classes else np.zeros((0, 0))).astype(np.float32)
        parts = [far_t.coefficients(g)] + ([near_t.coefficients(m)] if classes else [])
        coef = np.concatenate(parts, axis=1)
        quads = far_eigen.kernels(g)
        return NearFieldFit(near, quads, values, coef, measure(quads, values, near, coef),
                            mirrored)
    g = far_eigen.project(far(train)).rank_within(tol)
    m = near_eigen.project(near_part(train)).rank_within(NEAR_TOL_SHARE * tol) if classes else 0
    current = fit(g, m)
    while current.interp_error > tol:
        check_stop()
        more_near = fit(g, m + 1) if classes and m < near_eigen.most else None
        more_far = fit(g + 1, m) if g < far_eigen.most else None
        if more_near is None and more_far is None:
            break
        if more_far is None or (more_near is not None
                                and more_near.interp_error <= more_far.interp_error):
            current, m = more_near, m + 1
        else:
            current, g = more_far, g + 1
    return current


def _direct_near_fit(targets, train, tol, radius, near, measure, mirrored):
    """``_near_field_fit`` with the classes as the near kernels: the far rank starts where
    every ``train`` kernel's far part is within tol and grows until ``measure`` is too."""
    classes = near_classes(near, mirrored)
    values = np.eye(len(classes), dtype=np.float32)
    near_coef = np.array([class_values(t, classes) for t in targets])
    far_eigen = EigenKernels.of(far_parts(train, near, radius))
    far_t = far_eigen.project(far_parts(targets, near, radius))

    def fit(g):
        coef = np.concatenate([far_t.coefficients(g), near_coef], axis=1)
        quads = far_eigen.kernels(g)
        return NearFieldFit(near, quads, values, coef, measure(quads, values, near, coef),
                            mirrored, direct=True)
    g = far_eigen.project(far_parts(train, near, radius)).rank_within(tol)
    current = fit(g)
    while current.interp_error > tol and g < far_eigen.most:
        check_stop()
        g += 1
        current = fit(g)
    return current
