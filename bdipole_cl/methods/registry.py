"""Methods and their knobs: the registry the API, the CLI and the report share.

Inversion (kernels/invert.cl), each a specialization of the one kernel by build options:

=============  ===========================================================  ==================
name           what                                                         knobs
=============  ===========================================================  ==================
``table``      cubic Hermite table of the inverse in split variables        ``table_size``,
               (default; docs/model.md "Inversion"), optional Newton polish ``polish``
``secant``     safeguarded secant in the split variables, seeded from a     ``tol``,
               coarse table (value and slope), bracketed                    ``iterations``,
                                                                            ``seed_size``
``bisection``  bisection in the split variables (robust fallback)           ``iterations``
``memo``       Hery TM 12-11's float bisection in alpha', verbatim          ``iterations``
               (baseline; loses rho near alpha' = 1, docs/model.md)
=============  ===========================================================  ==================

Blur (bdipole_cl/ops/blur): ``direct``, ``gaussians``, ``fft``, and ``auto``; with
texture-varying parameters ``fft``, ``gaussians`` and ``auto``. Borders: clamp, zero, wrap.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

METHODS = ("table", "secant", "bisection", "memo")
BLUR_METHODS = ("auto", "direct", "gaussians", "fft")
TEXTURED_BLUR_METHODS = ("auto", "fft", "gaussians")
BORDERS = ("clamp", "zero", "wrap")
#: what a mean free path is (docs/model.md "Mean free path"): "diffuse", ld = 1/mu_tr
#: (Jensen/Hery, the default), or "extinction", the medium's 1/sigma_t' (OpenPBR, Standard
#: Surface)
MFP_KINDS = ("diffuse", "extinction")

#: knob defaults (None: the method's own default, below). Bisection runs over the unknown's bit
#: patterns and stops when they are adjacent: 31 steps suffice in float32, 63 in float64
DEFAULT_ITERATIONS = {"memo": 50, "bisection": 64, "secant": 40}
#: the secant's relative residual tolerance by precision: a few ulp of the unknown in float32;
#: in float64 small enough that rho (2x the unknown's relative error) is within 1e-12
DEFAULT_SECANT_TOL = {False: 2e-7, True: 1e-14}
#: Newton steps after the table lookup by precision: none in float32 (the table is as accurate
#: as float32 allows); in float64, 2 take the float32-coefficient table's ~1e-7 to ~1e-15
DEFAULT_POLISH = {False: 0, True: 2}
#: what double=True promises: rho within this relative error of the exact inverse
DOUBLE_RHO_TOL = 1e-12


@dataclass(frozen=True)
class MethodConfig:
    """One inversion configuration: a method and its cost knobs."""

    method: str = "table"
    iterations: int | None = None
    tol: float | None = None
    table_size: int = 256
    polish: int | None = None
    seed_size: int = 16

    def __post_init__(self):
        if self.method not in METHODS:
            raise ValueError(f"method={self.method!r}: expected one of {METHODS}")
        for knob in ("iterations", "table_size", "seed_size"):
            value = getattr(self, knob)
            if value is not None and (int(value) != value or value < 1):
                raise ValueError(f"{knob}={value!r}: expected a positive integer")
        if self.polish is not None and (int(self.polish) != self.polish or self.polish < 0):
            raise ValueError(f"polish={self.polish!r}: expected an integer >= 0")
        if self.tol is not None and not self.tol > 0:
            raise ValueError(f"tol={self.tol!r}: expected > 0")

    def resolved(self, double: bool) -> "MethodConfig":
        """This config with every knob left at None set to its default for the precision.
        float64 (``double``) promises rho within DOUBLE_RHO_TOL: the memo's float bisection in
        alpha' cannot (docs/model.md "Stiffness"), so it is refused there."""
        if double and self.method == "memo":
            raise ValueError("method='memo' is the memo's bisection in alpha', a float32 "
                             "baseline: it cannot give rho to 1e-12 near alpha' = 1 "
                             "(docs/model.md \"Stiffness\"); use table, secant or bisection "
                             "with double=True")
        changes = {}
        if self.iterations is None and self.method in DEFAULT_ITERATIONS:
            changes["iterations"] = DEFAULT_ITERATIONS[self.method]
        if self.method == "secant" and self.tol is None:
            changes["tol"] = DEFAULT_SECANT_TOL[bool(double)]
        if self.method == "table" and self.polish is None:
            changes["polish"] = DEFAULT_POLISH[bool(double)]
        return replace(self, **changes) if changes else self

    @property
    def table_n(self) -> int:
        """Intervals per segment of the table the kernel reads (0: none)."""
        return {"table": self.table_size, "secant": self.seed_size}.get(self.method, 0)

    def defines(self, double: bool) -> dict:
        """The build options (``BD_<NAME>``: value) of kernels/invert.cl for this config."""
        c = self.resolved(double)
        m = c.method
        if m in ("memo", "bisection"):
            return {f"BD_METHOD_{m.upper()}": None, "BD_ITERATIONS": c.iterations}
        if m == "secant":
            return {"BD_METHOD_SECANT": None, "BD_ITERATIONS": c.iterations,
                    "BD_TOL": repr(float(c.tol)), "BD_TABLE_N": c.seed_size}
        return {"BD_METHOD_TABLE": None, "BD_TABLE_N": c.table_size, "BD_POLISH": c.polish}

    def describe(self, double: bool = False) -> str:
        """A short label for tables and logs (not parsed back: data use ``fields``); the
        defaults of the precision shown. Secant's default tol shows as 'default'."""
        m = self.method
        c = self.resolved(double) if not (double and m == "memo") else self
        if m in ("memo", "bisection"):
            return f"{m}(iterations={c.iterations or DEFAULT_ITERATIONS[m]})"
        if m == "secant":
            return (f"secant(tol={self.tol if self.tol is not None else 'default'}, "
                    f"seed={self.seed_size})")
        return f"table(size={c.table_size}, polish={c.polish})"

    def fields(self) -> dict:
        """The knobs that matter for this method, as plain data (JSON)."""
        m = self.method
        if m in ("memo", "bisection"):
            return {"method": m, "iterations": self.iterations or DEFAULT_ITERATIONS[m]}
        if m == "secant":
            return {"method": m, "tol": self.tol, "seed_size": self.seed_size,
                    "iterations": self.iterations}
        return {"method": m, "table_size": self.table_size, "polish": self.polish}

    @classmethod
    def from_fields(cls, fields: dict) -> "MethodConfig":
        return cls(**{k: v for k, v in fields.items() if v is not None})


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
