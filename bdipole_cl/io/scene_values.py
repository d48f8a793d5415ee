"""Scene values checked (I/O layer): numbers and constants as a scene file, stage or document
may give them, a material's etas in its model's range and its constant mfp times its scale
in the range the kernels take (``CONSTANT_RULES``); ``fail(section, index, key, message)``
reports where (``scene_file``)."""
from __future__ import annotations

import math

from ..ops.blur.params import CONSTANT_RULES, scaled_mfp_problem
from ..physics.fresnel import check_eta
from ..physics.models import MODEL


def number(v):
    """A finite int or float (not a bool)."""
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def numbers_or_number(v):
    """A number, or a non-empty list of them (one per channel)."""
    return number(v) or (isinstance(v, list) and v and all(number(x) for x in v))


def positive(v):
    """A number > 0."""
    return number(v) and v > 0


def mfp_constants(v):
    """An mfp given as constants: each one the kernels can take (``CONSTANT_RULES``)."""
    return numbers_or_number(v) and all(bool(CONSTANT_RULES["mfp"][1](x)) for x in as_list(v))


def check_material_eta(fail, index, entry, m, from_stage=False):
    """The material's etas within its model's range (``fresnel.check_eta``), else a failure
    at its eta key (or [defaults]' where neither it nor the stage gives one)."""
    try:
        check_eta(floats(m["eta"]), m["exact"], MODEL.canonical(m["model"]))
    except ValueError as exc:
        where = ("material", index) if "eta" in entry or from_stage else ("defaults", 0)
        fail(*where, "eta", f"eta = {m['eta']!r}: {exc}")


def check_scaled_mfp(fail, index, entry, m):
    """A constant mfp times its mfp_scale (a stage's radius times the unit conversion, too)
    within the range the kernels take (``CONSTANT_RULES``, as float32), else a failure naming
    both at the key that set the scale (or the mfp)."""
    why = None if isinstance(m["mfp"], str) else scaled_mfp_problem(floats(m["mfp"]),
                                                                      floats(m["mfp_scale"]))
    if why:
        fail("material", index, "mfp_scale" if "mfp_scale" in entry else "mfp", why)


def floats(v) -> tuple:
    return tuple(map(float, as_list(v)))


def as_list(v):
    return v if isinstance(v, list) else [v]
