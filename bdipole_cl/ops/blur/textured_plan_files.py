"""The texture-varying blur's plans kept in memory and on disk (``plan_files``; docs/model.md
"Texture-varying parameters"): a plan of one (ranges, eta, tol, exact, basis, max_radius,
gather costs, near field radii) is made once per version of the code that makes it; a CLI
blur of a texture at mfp 16 texels spent 8 s of its 9 s making its plans in every process.
Plans of the Gaussians basis (``method="gaussians"``) are kept in memory only."""
from __future__ import annotations

import numpy as np

from . import near_field
from .near_field import DEFAULT_GATHER_COSTS, GatherCosts, near_classes
from .plan_files import (TEXTURED_FOLDER, PlanFormat, axes_arrays, axes_of, kept_plan,
                         kernels_array, scalars_array, scalars_of)
from .textured_plan import (PLAN_CACHE, Axis, TexturedPlan, common_radius, fine_table,
                            lattice_axes, make_plan_for_ranges)

#: the scalar fields of a TexturedPlan, in its file's ``scalars`` order
FILE_SCALARS = ("radius", "eta", "fit_error", "interp_error", "truncation_tol", "near")


def plan_file_arrays(plan: TexturedPlan) -> dict:
    """An eigen-kernel ("svd") TexturedPlan as the arrays of its file."""
    return {"table": plan.table, "fine": plan.fine, "near_values": plan.near_values,
            "kernels": kernels_array(plan.kernels, plan.radius),
            "scalars": scalars_array(plan, FILE_SCALARS), **axes_arrays(plan.axes)}


def plan_of_file_arrays(arrays) -> TexturedPlan:
    """The TexturedPlan ``plan_file_arrays`` wrote."""
    sc = scalars_of(arrays, FILE_SCALARS)
    return TexturedPlan(int(sc["radius"]), "svd", tuple(arrays["kernels"]),
                        axes_of(arrays, Axis), arrays["table"], arrays["fine"], sc["eta"],
                        sc["fit_error"], sc["interp_error"], sc["truncation_tol"],
                        int(sc["near"]), arrays["near_values"])


PLAN_FORMAT = PlanFormat(TEXTURED_FOLDER, plan_file_arrays, plan_of_file_arrays)


def plan_is_whole(plan: TexturedPlan, rd_range, ld_range, eta, tol, exact=False) -> bool:
    """Whether a plan (read from a file) is one of these arguments could be: their lattice,
    radius, eta and tol; a near field of NEAR_RADII within the radius with its classes'
    values (float32); (K+1)^2 float64 eigen-kernels; the float32 table of a weight per
    eigen-kernel and near kernel at each node, and its fine table as ``fine_table`` makes it;
    every value finite, the errors >= 0. Not its values: those only the making checks."""
    axes = lattice_axes(rd_range, ld_range, tol)
    k, g = plan.radius + 1, len(plan.kernels)
    classes = len(near_classes(plan.near)) if plan.near >= 0 else 0
    m = plan.table.shape[-1] - g
    arrays = (plan.table, plan.near_values, *plan.kernels)
    return (plan.axes == axes and plan.eta == float(eta) and plan.truncation_tol == float(tol)
            and plan.radius == common_radius(rd_range, ld_range, eta, tol, exact)
            and plan.near in near_field.NEAR_RADII and plan.near <= plan.radius
            and all(q.shape == (k, k) and q.dtype == np.float64 for q in plan.kernels)
            and plan.table.dtype == np.float32 and plan.near_values.dtype == np.float32
            and plan.table.shape == (*(len(a.values) for a in axes), g + m) and m >= 0
            and (m == 0 if classes == 0 else plan.near_values.shape == (m, classes))
            and all(np.all(np.isfinite(a)) for a in arrays)
            and plan.fine.dtype == np.float32
            and np.array_equal(plan.fine, fine_table(plan.table))
            and 0 <= plan.fit_error < np.inf and 0 <= plan.interp_error < np.inf)


@PLAN_CACHE.memoize
def plan_for_ranges(rd_range, ld_range, eta, tol, exact=False, basis="svd", max_radius=2048,
                    costs: GatherCosts = DEFAULT_GATHER_COSTS) -> TexturedPlan:
    """``textured_plan.make_plan_for_ranges``'s plan, made once per version of the code that
    makes it: kept in memory and (eigen-kernel plans) across processes in the user cache
    folder. The near field radii tried are in the key: a plan made under other radii (a
    calibration's, one at a time) is not read as the default's."""
    if basis != "svd":
        return make_plan_for_ranges(rd_range, ld_range, eta, tol, exact, basis, max_radius,
                                    costs)
    key = repr(("textured", tuple(float(t) for t in rd_range),
                tuple(float(t) for t in ld_range), float(eta), float(tol), bool(exact),
                int(max_radius), costs, tuple(near_field.NEAR_RADII)))

    return kept_plan(PLAN_FORMAT, key,
                     lambda plan: plan_is_whole(plan, rd_range, ld_range, eta, tol, exact),
                     lambda: make_plan_for_ranges(rd_range, ld_range, eta, tol, exact, basis,
                                                  max_radius, costs))
