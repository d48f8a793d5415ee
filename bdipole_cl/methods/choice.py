"""The measured choice data and ``method="auto"`` (pure data: no device, no operation).

Choice data are measured on one device and keyed by it (``DeviceKey``: vendor, name, driver).
``bdipole-cl report --calibrate`` measures the current device and stores its data in the
user's cache (``calibration_path``: ``$BDIPOLE_CL_CACHE_DIR``, else
``$XDG_CACHE_HOME/bdipole_cl``, else ``~/.cache/bdipole_cl``); ``bdipole-cl report
--write-choice PATH`` writes them to any file. Which data decide (``choice_for``):
``BDIPOLE_CL_CHOICE_DATA`` (a file named by the user) if set; else the calibration of the device
in use if there is one; else the data shipped with the package (``bdipole_cl/data/choice.json``),
``ChoiceSource`` says which, for ``BlurInfo``, ``plan`` and the INFO log; a warning is not
printed on every command. ``auto`` picks the cheapest
measured configuration whose measured error meets ``tol``.
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import os
import re
import threading
from dataclasses import dataclass
from pathlib import Path

from ..durable import durable_replace
from ..caches import CACHE_DIR_VARIABLE, ByteCache, user_cache_dir  # noqa: F401
from .registry import METHOD_OR_AUTO, BlurChoice, InversionChoice, MethodConfig

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
class DeviceKey:
    """The device choice data were measured on: OpenCL's vendor, device name and driver
    version (a new driver is a new device here: its compiler decides the timings)."""

    vendor: str
    name: str
    driver: str

    @classmethod
    def of(cls, device) -> "DeviceKey":
        """The key of a pyopencl Device (or anything with vendor, name, driver_version)."""
        return cls(device.vendor.strip(), device.name.strip(), device.driver_version.strip())

    def describe(self) -> str:
        return f"{self.name} ({self.vendor}, driver {self.driver})"

    def slug(self) -> str:
        """A file-name part: readable, and unique by a hash of the whole key."""
        text = re.sub(r"[^a-z0-9]+", "-", f"{self.vendor} {self.name}".lower()).strip("-")
        digest = hashlib.sha256("\0".join((self.vendor, self.name, self.driver)).encode())
        return f"{text[:48]}-{digest.hexdigest()[:12]}"


#: the widths the kernels are built for (kernels/lanes.h; the gather's 2 is not measured)
TABLE_WIDTHS_ALLOWED = (1, 2, 4, 8, 16)
GATHER_WIDTHS_ALLOWED = (1, 4, 8, 16)


@dataclass(frozen=True)
class KernelTuning:
    """How the kernels run fastest on the device the data were measured on (``report
    --calibrate``): elements per work-item of kernels/invert_table.cl and texels per work-item
    of kernels/blur_textured.cl's gather, and the gather's costs (cell, term, weight: what
    ``near_field.GatherCosts`` holds). None: not measured (the per-platform defaults).
    ``kernels_digest``: the kernel sources they were measured with
    (``device.programs.kernels_digest``; None: not recorded, as in a file written by hand)."""

    table_width: int | None = None
    gather_width: int | None = None
    gather_costs: tuple | None = None
    kernels_digest: str | None = None

    def fields(self) -> dict:
        return {"table_width": self.table_width, "gather_width": self.gather_width,
                "gather_costs": None if self.gather_costs is None else list(self.gather_costs),
                "kernels_digest": self.kernels_digest}

    @classmethod
    def from_fields(cls, raw) -> "KernelTuning | None":
        """From a file's "kernels" entry, each field checked (ValueError naming it)."""
        if raw is None:
            return None
        if not isinstance(raw, dict):
            raise ValueError(f"kernels: expected an object, got {raw!r}")
        table, gather, costs = (raw.get(k) for k in ("table_width", "gather_width",
                                                     "gather_costs"))
        for name, value, allowed in (("table_width", table, TABLE_WIDTHS_ALLOWED),
                                     ("gather_width", gather, GATHER_WIDTHS_ALLOWED)):
            if value is not None and (type(value) is not int or value not in allowed):
                raise ValueError(f"kernels.{name}: {value!r}, expected one of {allowed}")
        if costs is not None and not (
                isinstance(costs, list) and len(costs) == 3
                and all(type(c) in (int, float) and 0 <= c < float("inf") for c in costs)):
            raise ValueError(f"kernels.gather_costs: {costs!r}, expected 3 finite numbers >= 0 "
                             f"(cell, term, weight)")
        digest = raw.get("kernels_digest")
        if digest is not None and not isinstance(digest, str):
            raise ValueError(f"kernels.kernels_digest: {digest!r}, expected a string")
        return cls(table, gather, None if costs is None else tuple(float(c) for c in costs),
                   digest)


@dataclass(frozen=True)
class ChoiceData:
    device: str
    inversion: tuple          # InversionChoice, in the file's order
    blur: tuple               # BlurChoice
    device_key: DeviceKey | None = None     # None: not recorded (older files)
    kernels: KernelTuning | None = None     # None: not measured


@dataclass(frozen=True)
class ChoiceSource:
    """Which choice data decided, and why those."""

    path: Path
    kind: str                 # "calibrated" (this device), "named" (BDIPOLE_CL_CHOICE_DATA),
    #                           "shipped" (the package's)
    measured_on: str          # the data's device, as described when measured
    this_device: bool         # measured on the device in use

    def describe(self) -> str:
        if self.kind == "calibrated":
            return f"choice data calibrated on this device ({self.path})"
        if self.kind == "named":
            return f"choice data from {CHOICE_DATA_VARIABLE}={self.path} ({self.measured_on})"
        where = "this device" if self.this_device else "another device"
        return f"shipped choice data, measured on {where}: {self.measured_on}"


def device_auto_note(device_key: DeviceKey | None) -> str:
    """One line for plans: which choice data ``auto`` decides from on the device."""
    return choice_for(device_key)[1].describe()


def choice_data_path() -> Path:
    return Path(os.environ.get(CHOICE_DATA_VARIABLE) or PACKAGED_CHOICE_DATA)


def calibration_dir() -> Path:
    """This user's calibration folder (``caches.user_cache_dir``)."""
    return user_cache_dir()


#: the calibration files' names in ``calibration_dir()`` (``calibration_path``)
CALIBRATION_GLOB = "choice-*.json"
#: a calibration's exact file name (``DeviceKey.slug``: readable, a dash, 12 hex digits), so
#: that ``cache --clear`` never takes a user's file for one
CALIBRATION_NAME = re.compile(r"^choice-(?:[a-z0-9-]{1,48}-)?[0-9a-f]{12}\.json$")


def calibration_path(key: DeviceKey) -> Path:
    """Where ``bdipole-cl report --calibrate`` stores the data of the device ``key``."""
    return calibration_dir() / CALIBRATION_GLOB.replace("*", key.slug())


_noted: set = set()
_noted_lock = threading.Lock()


def choice_for(key: DeviceKey | None = None) -> tuple:
    """(ChoiceData, ChoiceSource) for the device ``key`` (None: unknown): the named file, else
    this device's calibration (only if it is keyed by this very device), else the shipped
    data; the ChoiceSource says which (``describe``: "measured on another device ...")."""
    named = os.environ.get(CHOICE_DATA_VARIABLE)
    if named:
        if not Path(named).is_file():
            raise ValueError(f"{CHOICE_DATA_VARIABLE}={named}: no such file")
        data = load_choice_data(named)
        return data, ChoiceSource(Path(named), "named", data.device,
                                  key is not None and data.device_key == key)
    if key is not None:
        path = calibration_path(key)
        data = readable_data(path)            # a broken calibration: the shipped data
        if data is not None and data.device_key == key:
            return data, ChoiceSource(path, "calibrated", data.device, True)
    data = load_choice_data(PACKAGED_CHOICE_DATA)
    source = ChoiceSource(PACKAGED_CHOICE_DATA, "shipped", data.device,
                          key is not None and data.device_key == key)
    # said where a user looks for it (a plan's lines, BlurInfo.data, the INFO log of
    # resolve_method), not as a warning on every command's stderr
    return data, source


#: set while ``report --calibrate`` measures: the kernels take their per-platform defaults (or
#: the widths it forces), whatever an earlier calibration says (a broken one included)
_measuring = threading.local()


class calibration_ignored:
    """Within it, ``device_tuning`` is None: the calibration's own measurements."""

    def __enter__(self):
        _measuring.active = True
        return self

    def __exit__(self, *exc):
        _measuring.active = False
        return False


def device_tuning(key: DeviceKey, kernels_digest: str | None = None) -> KernelTuning | None:
    """The KernelTuning measured on the device ``key`` itself: from the file named by
    BDIPOLE_CL_CHOICE_DATA, else this device's calibration, where either is keyed by this
    very device (never data measured on another: widths and costs are the CPU's own). A file
    that cannot be read as choice data, or whose kernels are not valid, is passed over with a
    one-line warning naming it (once per process): the per-platform defaults then. So is a
    tuning measured with other kernel sources than ``kernels_digest`` (the current ones: a
    width that was fastest for one version of a kernel may be the slowest for the next), with
    a one-line note."""
    if getattr(_measuring, "active", False):
        return None
    named = os.environ.get(CHOICE_DATA_VARIABLE)
    for path in ([Path(named)] if named else []) + [calibration_path(key)]:
        data = readable_data(path)
        if data is not None and data.device_key == key:
            tuned = data.kernels
            if (tuned is not None and tuned.kernels_digest is not None
                    and kernels_digest is not None and tuned.kernels_digest != kernels_digest):
                note_once(("stale kernels", str(path)),
                          "%s: kernel shapes measured with other kernels than these; passed "
                          "over (`bdipole-cl report --calibrate` measures them again)", path)
                return None
            return tuned
    return None


def note_once(key, message, *args):
    """``message`` to the "bdipole_cl" logger as a warning, the first time ``key`` is noted in
    this process."""
    with _noted_lock:
        first = key not in _noted
        _noted.add(key)
    if first:
        logging.getLogger("bdipole_cl").warning(message, *args)


def readable_data(path) -> ChoiceData | None:
    """The choice data at ``path``, None where there is no file, or one that cannot be read
    as choice data: passed over, with one warning naming it (once per process)."""
    if not Path(path).is_file():
        return None
    try:
        return load_choice_data(path)
    except (OSError, ValueError) as exc:
        note_once(("unreadable", str(path)),
                  "%s; passed over (`bdipole-cl report --calibrate` rewrites it)", exc)
        return None


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
    key = raw.get("device_key")
    return ChoiceData(raw.get("device", ""), inversion, blur,
                      DeviceKey(**key) if key else None,
                      KernelTuning.from_fields(raw.get("kernels")))


def choice_file_error(path, exc) -> ValueError:
    """A one-line ValueError naming the choice data file that could not be read."""
    return ValueError(f"{path}: not choice data bdipole-cl can read ({exc})")


def load_choice_data(path=None) -> ChoiceData:
    """The measured choices (read once per process and path); a file that is not choice data
    is a ValueError naming it."""
    path = str(path or choice_data_path())
    try:
        return _load(path)
    except (ValueError, TypeError, KeyError, AttributeError) as exc:   # (UnicodeDecodeError too)
        raise choice_file_error(path, exc) from None


def write_choice_data(data: ChoiceData, path) -> Path:
    """Write ``data`` as JSON with structured fields (what ``load_choice_data`` reads)."""
    key = data.device_key
    raw = {"device": data.device,
           "device_key": None if key is None else {"vendor": key.vendor, "name": key.name,
                                                   "driver": key.driver},
           "inversion": [{"config": c.config.fields(), "precision": c.precision,
                          "max_rho_error": c.max_rho_error, "median_s": c.median_s,
                          "monotone": c.monotone, "etas": list(c.etas)}
                         for c in data.inversion],
           "blur": [{"method": b.method, "tol": b.tol, "radius": b.radius, "mfp": b.mfp,
                     "max_error": b.max_error, "median_s": b.median_s} for b in data.blur]}
    if data.kernels is not None:
        raw["kernels"] = data.kernels.fields()
    raw["digest"] = choice_digest(raw)
    path = Path(path)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp.write_text(json.dumps(raw, indent=1))
        durable_replace(tmp, path)
    except OSError as exc:             # a full disk: named, and nothing half-written left
        raise OSError(exc.errno, f"writing {path}: {exc.strerror}") from None
    finally:
        if tmp.exists():
            tmp.unlink()
    _DATA_CACHE.clear()
    return path


#: the keys of a choice data file (``write_choice_data``): a JSON file without them is not one
CHOICE_KEYS = ("device", "inversion", "blur")


def choice_digest(raw: dict) -> str:
    """The sha256 of choice data's fields but its digest (canonical JSON)."""
    fields = {k: v for k, v in raw.items() if k != "digest"}
    return hashlib.sha256(json.dumps(fields, sort_keys=True).encode()).hexdigest()


def is_choice_data(path) -> bool:
    """Whether the file at ``path`` is choice data this tool wrote, unchanged since: a JSON
    object with CHOICE_KEYS whose ``digest`` matches its fields (a file without one, written
    by hand or by an earlier version, is not): what ``--write-choice`` may replace without
    --force."""
    try:
        raw = json.loads(Path(path).read_text())
    except (OSError, ValueError):
        return False
    return (isinstance(raw, dict) and all(k in raw for k in CHOICE_KEYS)
            and raw.get("digest") == choice_digest(raw))


#: ``auto`` takes a configuration whose measured max rho error is within tol / AUTO_MARGIN: a
#: maximum over the report's sampled albedos and etas is below the true one (an adversarial
#: sweep, every table node +-3 ulp, the split +-3000 ulp and 15.8M consecutive floats at 9
#: etas, found table(256)'s 8.38e-7 to be 9.48e-7, at eta 2.8 and Rd 0.4952512: 1.13x, the
#: largest gap of any configuration), so a measured error just under tol is no bound
AUTO_MARGIN = 1.15


def auto_inversion_config(tol: float, double: bool = False, data: ChoiceData | None = None,
                          device_key: DeviceKey | None = None) -> InversionChoice:
    """The cheapest measured monotone configuration of the precision whose max relative rho
    error, over every eta the report measured (the valid range, end to end), is <= tol /
    AUTO_MARGIN; from
    ``data``, else the data ``choice_for(device_key)`` gives."""
    data = data or choice_for(device_key)[0]
    precision = "f64" if double else "f32"
    pool = sorted((c for c in data.inversion if c.precision == precision and c.monotone),
                  key=lambda c: c.median_s)
    for choice in pool:
        if choice.max_rho_error * AUTO_MARGIN <= tol:
            return choice
    if not pool:
        raise ValueError(f"no measured {precision} configuration in {choice_data_path()}")
    best = min(pool, key=lambda c: c.max_rho_error)
    hint = ("" if double else "; float64 reaches 1e-12 (double=True, --double on the "
                              "command line)")
    raise ValueError(f"tol={tol:g}: no monotone {precision} configuration reaches it over eta "
                     f"(the best, {best.config.describe(double)}, measured "
                     f"{best.max_rho_error:.2e}: taken for tol >= "
                     f"{auto_inversion_floor(double, data):.3g}, its measurement x "
                     f"{AUTO_MARGIN:g} for what sampling misses){hint}")


def auto_inversion_floor(double: bool = False, data: ChoiceData | None = None) -> float:
    """The smallest tol ``auto_inversion_config`` takes in the precision: the least measured
    max rho error of its monotone configurations, times AUTO_MARGIN (with the shipped
    float32 data 9.64e-7: docs/numerics.md)."""
    data = data or choice_for(None)[0]
    precision = "f64" if double else "f32"
    return min(c.max_rho_error for c in data.inversion
               if c.precision == precision and c.monotone) * AUTO_MARGIN


def resolve_method(method="table", double=False, device_key=None, **knobs) -> MethodConfig:
    """A MethodConfig from a method name and knobs (None knobs keep the defaults).

    ``method="auto"``: the cheapest monotone configuration of the precision (``double``) whose
    measured max relative error of rho over eta is <= ``tol`` (default AUTO_DEFAULT_TOL), in
    the choice data of the device ``device_key`` (``choice_for``); the choice and the data
    that decided are logged (logger "bdipole_cl")."""
    if isinstance(method, MethodConfig):
        return method
    METHOD_OR_AUTO[method]              # an unknown name: the error lists auto too
    if method == "auto":
        tol = knobs.get("tol")
        tol = AUTO_DEFAULT_TOL if tol is None else tol
        if not 0 < tol < 1:             # also NaN
            raise ValueError(f"tol={tol!r}: method='auto' takes 0 < tol < 1 (the largest "
                             f"relative error of rho it may give)")
        data, source = choice_for(device_key)
        choice = auto_inversion_config(tol, double, data)
        logging.getLogger("bdipole_cl").info(
            "method='auto', tol=%g: picked %s (measured max rho error %.2e, %.2f ms; %s)",
            tol, choice.config.describe(double), choice.max_rho_error, choice.median_s * 1e3,
            source.describe())
        return choice.config
    return MethodConfig(method, **{k: v for k, v in knobs.items() if v is not None})


#: the tol whose timing stands for a (method, radius) when timings are rescaled
#: (``timing_references``, ``rescaled_blur``): the middle one measured
TIMING_TOL = 1e-3


def timing_references(data: ChoiceData) -> list:
    """One BlurChoice per (method, radius) of ``data``: the one at TIMING_TOL, else its
    tightest tol measured."""
    refs = {}
    for b in data.blur:
        key = (b.method, b.radius)
        held = refs.get(key)
        if held is None or b.tol == TIMING_TOL or (held.tol != TIMING_TOL and b.tol < held.tol):
            refs[key] = b
    return list(refs.values())


def rescaled_blur(data: ChoiceData, seconds: dict) -> ChoiceData | None:
    """``data`` with each blur timing scaled by what its (method, radius) reference took on
    another device (``seconds``: {(method, radius): seconds}): the choices' relative costs
    at each radius become that device's, their errors stay (they do not depend on the
    device). None unless every (method, radius) was timed."""
    refs = {(b.method, b.radius): b for b in timing_references(data)}
    if not refs or any(k not in seconds or not seconds[k] > 0 for k in refs):
        return None
    blur = tuple(dataclasses.replace(b, median_s=b.median_s * seconds[(b.method, b.radius)]
                                     / refs[(b.method, b.radius)].median_s)
                 for b in data.blur)
    return dataclasses.replace(data, blur=blur)


def auto_blur_config(radius: int, tol: float, data: ChoiceData | None = None,
                     methods=None, exclude: tuple = ()):
    """The BlurChoice for ``blur(method="auto", tol=tol)`` on a kernel of ``radius`` texels:
    the cheapest measured configuration (of ``methods``, default all), on the measured
    workload of the nearest radius (in log(radius + 1)), whose truncation tol is <= tol and
    whose measured max error is <= tol; None if none qualifies. The truncation tol bounds the
    error for ANY irradiance (relative to max(E) * Rd, docs/model.md "Blur error bound"); the
    measured error, on one random workload, does not: a hole or a single bright texel can meet
    the whole bound, so a looser truncation is never picked, however well it did on the
    workload. ``exclude``: methods not to pick (a gaussians fit that misses its share of
    tol), or (method, truncation tol) configurations (one whose kernel is wider than the
    largest radius: a looser truncation, still <= tol, may not be)."""
    import math
    data = data or load_choice_data()
    blurs = [b for b in data.blur if methods is None or b.method in methods]
    if not blurs:
        return None
    radii = sorted({b.radius for b in blurs})
    near = min(radii, key=lambda r: abs(math.log((r + 1.0) / (radius + 1.0))))
    ok = [b for b in blurs if b.radius == near and b.tol <= tol and b.max_error <= tol
          and b.method not in exclude and (b.method, b.tol) not in exclude]
    return min(ok, key=lambda b: b.median_s) if ok else None
