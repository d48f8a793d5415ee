"""Methods and their knobs: the registry the API, the CLI and the report share.

Each kind of option is one ``vocabulary.Registry`` of objects (docs/python.md "Vocabulary"):

- ``METHOD``: the inversion methods, each a specialization of kernels/invert.cl by build
  options (``InversionMethod``: what it is, its knobs and their defaults per precision, its
  build options, its label; ``MethodConfig`` delegates to it); ``METHOD_OR_AUTO`` adds
  ``auto``, the measured choice (``methods.choice``);
- ``BLUR_METHOD`` (bdipole_cl/ops/blur; ``textured``: takes texture-varying parameters) and
  ``BORDER``;
- ``MFP_KIND``, ``OUTPUT`` and ``ALPHA_CHANNEL``.

The tuples of names (``METHODS``, ``BLUR_METHODS``, ...) are read from them, never retyped.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

from ..vocabulary import Option, Registry


@dataclass(frozen=True)
class InversionMethod(Option):
    """One inversion method: a specialisation of kernels/invert.cl (``BD_METHOD_<NAME>``).

    ``defaults``: (knob, float32 default, float64 default) of each knob a config may leave
    None; ``table``: the knob that is the intervals per segment of the table the kernel reads
    (None: no table); ``defines``: (build option, knob) set beside ``BD_METHOD_<NAME>``, in
    order; ``label``: ``MethodConfig.describe``'s format, filled with the precision's resolved
    knobs except those in ``label_as_given`` (shown as given; None as 'default'); ``fields``:
    the knobs ``MethodConfig.fields`` writes, in order, those in ``fields_resolved`` with their
    default filled in; ``refused_in_float64``: why it cannot keep double=True's promise
    (``DOUBLE_RHO_TOL``), None if it can; ``baseline``: kept for comparison, not held to the
    accuracy contract (docs/model.md "Accuracy")."""

    defaults: tuple = ()
    table: str | None = None
    defines: tuple = ()
    label: str = ""
    label_as_given: tuple = ()
    fields: tuple = ()
    fields_resolved: tuple = ()
    refused_in_float64: str | None = None
    baseline: bool = False

    @property
    def define(self) -> str:
        return f"BD_METHOD_{self.name.upper()}"

    def default(self, knob: str, double: bool):
        """The knob's default in the precision (None: the config's own value)."""
        return next((f64 if double else f32 for k, f32, f64 in self.defaults if k == knob),
                    None)


#: how a knob's value is written as a build option (others as given)
KNOB_FORMAT = {"tol": lambda v: repr(float(v))}

#: Bisection runs over the unknown's bit patterns and stops when they are adjacent: 31 steps
#: suffice in float32, 63 in float64 (64: one to spare). The secant's relative residual
#: tolerance by precision: a few ulp of the unknown in float32; in float64 small enough that
#: rho (2x the unknown's relative error) is within 1e-12. Newton steps after the table lookup
#: by precision: none in float32 (the table is as accurate as float32 allows); in float64, 2
#: take the float32-coefficient table's ~1e-7 to ~1e-15.
METHOD = Registry("method", (
    InversionMethod(
        "table", "cubic Hermite table of the inverse in split variables, optional Newton "
                 "polish (the default; docs/model.md \"Inversion table\")",
        defaults=(("polish", 0, 2),), table="table_size",
        defines=(("BD_TABLE_N", "table_size"), ("BD_POLISH", "polish")),
        label="table(size={table_size}, polish={polish})", fields=("table_size", "polish")),
    InversionMethod(
        "secant", "safeguarded secant in the split variables, seeded from a coarse table "
                  "(value and slope), bracketed",
        defaults=(("iterations", 40, 40), ("tol", 2e-7, 1e-14)), table="seed_size",
        defines=(("BD_ITERATIONS", "iterations"), ("BD_TOL", "tol"),
                 ("BD_TABLE_N", "seed_size")),
        label="secant(tol={tol}, seed={seed_size})", label_as_given=("tol",),
        fields=("tol", "seed_size", "iterations")),
    InversionMethod(
        "bisection", "bisection in the split variables (robust fallback)",
        defaults=(("iterations", 64, 64),), defines=(("BD_ITERATIONS", "iterations"),),
        label="bisection(iterations={iterations})", fields=("iterations",),
        fields_resolved=("iterations",)),
    InversionMethod(
        "memo", "Hery TM 12-11's float bisection in alpha', verbatim (baseline; loses rho "
                "near alpha' = 1, docs/model.md)",
        defaults=(("iterations", 50, 50),), defines=(("BD_ITERATIONS", "iterations"),),
        label="memo(iterations={iterations})", fields=("iterations",),
        fields_resolved=("iterations",), baseline=True,
        refused_in_float64="method='memo' is the memo's bisection in alpha', a float32 "
                           "baseline: it cannot give rho to 1e-12 near alpha' = 1 "
                           "(docs/model.md \"Stiffness\"); use table, secant or bisection "
                           "with double=True"),
))
METHODS = METHOD.names
#: ``method="auto"``: the measured choice (``methods.choice``), beside the methods themselves
AUTO = Option("auto", "the cheapest measured configuration meeting tol (bdipole-cl report's "
                      "data, methods/choice.py)")
METHOD_OR_AUTO = Registry("method", (*METHOD, AUTO))


@dataclass(frozen=True)
class BlurMethod(Option):
    """One blur method: ``textured``, it takes texture-varying parameters; ``chooses``, it
    picks one of the others (``auto``)."""

    textured: bool = False
    chooses: bool = False


BLUR_METHOD = Registry("method", (
    BlurMethod("auto", "the cheapest method meeting tol on this device (measured data)",
               textured=True, chooses=True),
    BlurMethod("direct", "the exact truncated kernel, summed on the device (constant "
                         "parameters only)"),
    BlurMethod("gaussians", "a sum of separable Gaussians fitted to the profile, on the "
                            "device", textured=True),
    BlurMethod("fft", "FFT convolution with the exact kernel (float32 FFTs, their round-off "
                      "in the bound; on the device or the host, whichever its probe timed "
                      "faster)", textured=True),
))
BLUR_METHODS = BLUR_METHOD.names
TEXTURED_BLUR_METHODS = tuple(m.name for m in BLUR_METHOD if m.textured)
#: the methods themselves, not the choice among them (the report and crosscheck sweep these)
BLUR_KERNELS = tuple(m.name for m in BLUR_METHOD if not m.chooses)

@dataclass(frozen=True)
class Border(Option):
    """A blur's border rule, and the wrap mode a texture of its result declares (OpenImageIO's
    ``wrapmodes``): a lookup beyond the edges sees what the blur saw beyond them."""

    texture_wrap: str = "black"


BORDER = Registry("border", (
    Border("clamp", "texels beyond the image edge are the nearest edge texel",
           texture_wrap="clamp"),
    Border("zero", "texels beyond the image edge are 0", texture_wrap="black"),
    Border("wrap", "the image repeats (tiling textures)", texture_wrap="periodic"),
))
BORDERS = BORDER.names

@dataclass(frozen=True)
class TextureWrap(Option):
    """How a lookup beyond a texture's edges reads it, and MaterialX's image address mode
    of it (``uaddressmode``, ``vaddressmode``: its default, periodic, would read across a
    tile's edge)."""

    mtlx_address: str = "clamp"


#: how a lookup beyond a texture output's edges reads it (OpenImageIO's ``wrapmodes``, maketx
#: ``--wrap``, txmake ``-mode``; docs/textures.md)
TEXTURE_WRAP = Registry("wrap", (
    TextureWrap("clamp", "the nearest edge texel (no seam at a UDIM tile's edge; the default)",
                mtlx_address="clamp"),
    TextureWrap("black", "0 beyond the edges (maketx's default: a tile's edge reads dark)",
                mtlx_address="constant"),            # the image's default value, 0
    TextureWrap("periodic", "the texture repeats", mtlx_address="periodic"),
    TextureWrap("mirror", "the texture repeats, mirrored", mtlx_address="mirror"),
))
#: level 0 of a texture output resized to powers of two per axis (txmake ``-resize``; maketx
#: ``--resize`` is up), by the area average that keeps its mean
TEXTURE_RESIZE = Registry.of(
    "resize", none="kept as it is (the plain output, bit for bit)",
    up="the next power of two up", down="the power of two below",
    round="the nearest power of two")

#: what a mean free path is (docs/model.md "Mean free path")
MFP_KIND = Registry.of(
    "mfp_kind", diffuse="ld = 1/mu_tr (Jensen/Hery, the default)",
    extinction="the medium's mean free path 1/sigma_t' (OpenPBR, Standard Surface)")
MFP_KINDS = MFP_KIND.names

#: the channel groups an inversion writes (``outputs=``, ``--outputs``, scene ``outputs``)
OUTPUT = Registry.of(
    "outputs", alpha="alpha', the reduced albedo sigma_s'/sigma_t'",
    rho="rho = 1 - alpha' = sigma_a/sigma_t'",
    sigma_a="sigma_a, the absorption coefficient (1/unit of mfp)",
    sigma_s="sigma_s', the reduced scattering coefficient (1/unit of mfp)",
    sigma_t="sigma_t' = sigma_a + sigma_s', the reduced extinction (1/unit of mfp)")
OUTPUTS = OUTPUT.names

#: what a texture batch does with the albedo's alpha channel (``process_textures(alpha=)``,
#: ``invert --alpha``)
ALPHA_CHANNEL = Registry.of(
    "alpha", keep="copied through to the output unchanged (never inverted)",
    drop="left out of the output")

#: what double=True promises: rho within this relative error of the exact inverse
DOUBLE_RHO_TOL = 1e-12
#: MethodConfig's knobs (None: the method's default in the precision)
KNOBS = ("iterations", "tol", "table_size", "polish", "seed_size")


#: the integer knobs' ranges: beyond them a kernel would not do better, only cost more (a
#: float64 bisection resolves its interval in 64 halvings; a table of 65536 intervals per
#: segment is ~2^16 times finer than float32's inverse needs), and a table of 1e8 intervals
#: took 18 GB to build
KNOB_RANGES = {"iterations": (1, 256), "table_size": (1, 1 << 16), "seed_size": (1, 1 << 16),
               "polish": (0, 16)}


def not_a_number(value) -> bool:
    """A bool (Python's or NumPy's) or a string: True would pass as 1, "8" as a parse."""
    return isinstance(value, (bool, str)) or getattr(getattr(value, "dtype", None), "kind",
                                                     "") == "b"


@dataclass(frozen=True)
class MethodConfig:
    """One inversion configuration: a method and its cost knobs (what each means for the
    method, and its defaults: ``METHOD[method]``)."""

    method: str = "table"
    iterations: int | None = None
    tol: float | None = None
    table_size: int = 256
    polish: int | None = None
    seed_size: int = 16

    def __post_init__(self):
        object.__setattr__(self, "method", METHOD.canonical(self.method))
        for knob, (lo, hi) in KNOB_RANGES.items():
            value = getattr(self, knob)
            if value is not None and (not_a_number(value) or int(value) != value
                                      or not lo <= value <= hi):
                raise ValueError(f"{knob}={value!r}: expected an integer from {lo} to {hi}")
        if self.tol is not None and (not_a_number(self.tol)
                                     or not 0 < self.tol < float("inf")):
            raise ValueError(f"tol={self.tol!r}: expected a finite number > 0")

    @property
    def spec(self) -> InversionMethod:
        """The method's registry entry."""
        return METHOD[self.method]

    def resolved(self, double: bool) -> "MethodConfig":
        """This config with every knob left at None set to its default for the precision.
        float64 (``double``) promises rho within DOUBLE_RHO_TOL: the memo's float bisection in
        alpha' cannot (docs/model.md "Stiffness"), so it is refused there."""
        spec = self.spec
        if double and spec.refused_in_float64:
            raise ValueError(spec.refused_in_float64)
        changes = {knob: spec.default(knob, bool(double)) for knob, *_ in spec.defaults
                   if getattr(self, knob) is None}
        return replace(self, **changes) if changes else self

    @property
    def table_n(self) -> int:
        """Intervals per segment of the table the kernel reads (0: none)."""
        return getattr(self, self.spec.table) if self.spec.table else 0

    def defines(self, double: bool) -> dict:
        """The build options (``BD_<NAME>``: value) of kernels/invert.cl for this config."""
        c, spec = self.resolved(double), self.spec
        return {spec.define: None, **{name: KNOB_FORMAT.get(knob, _as_given)(getattr(c, knob))
                                      for name, knob in spec.defines}}

    def describe(self, double: bool = False) -> str:
        """A short label for tables and logs (not parsed back: data use ``fields``); the
        defaults of the precision shown (float32's for a method float64 refuses). Secant's
        default tol shows as 'default'."""
        spec = self.spec
        c = self.resolved(bool(double) and not spec.refused_in_float64)
        values = {k: getattr(c, k) for k in KNOBS}
        values.update({k: "default" if getattr(self, k) is None else getattr(self, k)
                       for k in spec.label_as_given})
        return spec.label.format(**values)

    def fields(self) -> dict:
        """The knobs that matter for this method, as plain data (JSON)."""
        spec = self.spec
        values = {k: getattr(self, k) for k in spec.fields}
        for k in spec.fields_resolved:
            if values[k] is None:
                values[k] = spec.default(k, False)
        return {"method": self.method, **values}

    @classmethod
    def from_fields(cls, fields: dict) -> "MethodConfig":
        return cls(**{k: v for k, v in fields.items() if v is not None})


def _as_given(value):
    return value


@dataclass(frozen=True)
class InversionChoice:
    """One measured inversion configuration (``bdipole-cl report``)."""

    config: MethodConfig
    precision: str            # "f32" or "f64"
    max_rho_error: float      # max relative error of rho over the workloads and every eta
    median_s: float
    monotone: bool = False    # alpha' non-decreasing in Rd by construction at every eta
    etas: tuple = ()          # the etas the error was measured at


@dataclass(frozen=True)
class BlurChoice:
    """One measured blur configuration on the workload of one kernel radius."""

    method: str
    tol: float                # truncation tolerance
    radius: int               # the workload's kernel radius (texels) at tol 1e-3
    mfp: float                # the workload's mfp (texels)
    max_error: float          # max |M - exact| / (max E Rd)
    median_s: float


#: what a stretched blur does at UV chart borders (docs/stretch.md "Chart borders")
CHART_BORDER = Registry.of(
    "charts", clamp="each texel gathers from its own chart only, the chart continued beyond "
                    "its edge by its nearest texel (the default)",
    zero="each texel gathers from its own chart only, nothing beyond its edge",
    none="charts ignored: the blur crosses chart borders as in the plain blur")
CHART_BORDERS = CHART_BORDER.names
