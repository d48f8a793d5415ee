"""The measured choice data and ``method="auto"`` (pure data: no device, no operation).

``bdipole-cl report --write-choice PATH`` measures every configuration on the current device
and writes them, with structured fields, to a JSON file; the package ships one
(``bdipole_cl/data/choice.json``), and ``BDIPOLE_CL_CHOICE_DATA`` names another to use instead.
``auto`` picks the cheapest measured configuration whose measured error meets ``tol``.
"""
from __future__ import annotations

import json
import logging
import os
from dataclasses import dataclass
from pathlib import Path

from ..caches import ByteCache
from .registry import BlurChoice, InversionChoice, MethodConfig

#: the data shipped with the package
PACKAGED_CHOICE_DATA = Path(__file__).resolve().parent.parent / "data" / "choice.json"
CHOICE_DATA_VARIABLE = "BDIPOLE_CL_CHOICE_DATA"
#: rho accuracy that ``method="auto"`` aims for when no ``tol`` is given (the inversion's
#: accuracy contract, docs/model.md "Accuracy")
AUTO_DEFAULT_TOL = 1e-4
#: without blur data: kernels up to this radius (texels) use ``direct``, larger ones ``fft``
AUTO_DIRECT_MAX_RADIUS = 4

_DATA_CACHE = ByteCache("choice data", 1 << 20)


@dataclass(frozen=True)
class ChoiceData:
    device: str
    inversion: tuple          # InversionChoice, in the file's order
    blur: tuple               # BlurChoice


def choice_data_path() -> Path:
    return Path(os.environ.get(CHOICE_DATA_VARIABLE) or PACKAGED_CHOICE_DATA)


@_DATA_CACHE.memoize
def _load(path: str) -> ChoiceData:
    raw = json.loads(Path(path).read_text())
    inversion = tuple(InversionChoice(MethodConfig.from_fields(e["config"]), e["precision"],
                                      float(e["max_rho_error"]), float(e["median_s"]),
                                      bool(e.get("monotone", False)),
                                      tuple(e.get("etas", ())))
                      for e in raw["inversion"])
    blur = tuple(BlurChoice(e["method"], float(e["tol"]), int(e["radius"]), float(e["mfp"]),
                            float(e["max_error"]), float(e["median_s"])) for e in raw["blur"])
    return ChoiceData(raw.get("device", ""), inversion, blur)


def load_choice_data(path=None) -> ChoiceData:
    """The measured choices (read once per process and path)."""
    return _load(str(path or choice_data_path()))


def write_choice_data(data: ChoiceData, path) -> Path:
    """Write ``data`` as JSON with structured fields (what ``load_choice_data`` reads)."""
    raw = {"device": data.device,
           "inversion": [{"config": c.config.fields(), "precision": c.precision,
                          "max_rho_error": c.max_rho_error, "median_s": c.median_s,
                          "monotone": c.monotone, "etas": list(c.etas)}
                         for c in data.inversion],
           "blur": [{"method": b.method, "tol": b.tol, "radius": b.radius, "mfp": b.mfp,
                     "max_error": b.max_error, "median_s": b.median_s} for b in data.blur]}
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text(json.dumps(raw, indent=1))
    os.replace(tmp, path)
    _DATA_CACHE.clear()
    return path


def auto_inversion_config(tol: float, double: bool = False,
                          data: ChoiceData | None = None) -> InversionChoice:
    """The cheapest measured monotone configuration of the precision whose max relative rho
    error, over every eta the report measured (the valid range, end to end), is <= tol."""
    data = data or load_choice_data()
    precision = "f64" if double else "f32"
    pool = sorted((c for c in data.inversion if c.precision == precision and c.monotone),
                  key=lambda c: c.median_s)
    for choice in pool:
        if choice.max_rho_error <= tol:
            return choice
    if not pool:
        raise ValueError(f"no measured {precision} configuration in {choice_data_path()}")
    best = min(pool, key=lambda c: c.max_rho_error)
    hint = ("" if double else "; float64 reaches 1e-12 (double=True, --double on the "
                              "command line)")
    raise ValueError(f"tol={tol:g}: no monotone {precision} configuration reaches it over eta "
                     f"(best measured: {best.config.describe(double)} at "
                     f"{best.max_rho_error:.2e}){hint}")


def resolve_method(method="table", double=False, **knobs) -> MethodConfig:
    """A MethodConfig from a method name and knobs (None knobs keep the defaults).

    ``method="auto"``: the cheapest monotone configuration of the precision (``double``) whose
    measured max relative error of rho over eta is <= ``tol`` (default AUTO_DEFAULT_TOL); the
    choice is logged (logger "bdipole_cl")."""
    if isinstance(method, MethodConfig):
        return method
    if method == "auto":
        tol = knobs.get("tol") or AUTO_DEFAULT_TOL
        choice = auto_inversion_config(tol, double)
        logging.getLogger("bdipole_cl").info(
            "method='auto', tol=%g: picked %s (measured max rho error %.2e, %.2f ms in the "
            "report run)", tol, choice.config.describe(double), choice.max_rho_error,
            choice.median_s * 1e3)
        return choice.config
    return MethodConfig(method, **{k: v for k, v in knobs.items() if v is not None})


def auto_blur_config(radius: int, tol: float, data: ChoiceData | None = None):
    """The BlurChoice for ``blur(method="auto", tol=tol)`` on a kernel of ``radius`` texels:
    the cheapest measured configuration, on the measured workload of the nearest radius (in
    log(radius + 1)), whose measured max error is <= tol; None if none qualifies."""
    import math
    data = data or load_choice_data()
    if not data.blur:
        return None
    radii = sorted({b.radius for b in data.blur})
    near = min(radii, key=lambda r: abs(math.log((r + 1.0) / (radius + 1.0))))
    ok = [b for b in data.blur if b.radius == near and b.max_error <= tol]
    return min(ok, key=lambda b: b.median_s) if ok else None
