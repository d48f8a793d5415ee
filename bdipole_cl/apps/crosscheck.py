"""``bdipole-cl crosscheck``: every kernel against the float64 reference, on the chosen device.

Each row is one function over a sweep that includes its ends (alpha' -> 0 and -> 1, Rd -> 0
and -> 1, r = 0 and large r), with its max error, the bound it must meet and PASS/FAIL, in the
manner of ``idiff``. Errors are in units of the precision's unit roundoff u (2^-24 float32,
2^-53 float64) for the physics functions, relative for the inversions and the blur.

User kernels: ``bdipole_cl.apps.user_kernel`` (a renderer's own OpenCL C function).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..device import REMEDIES, DeviceError, get_runtime
from ..methods.registry import BLUR_KERNELS
from ..ops import physics_eval as physics
from ..physics import reference as ref

EPS = {False: 2.0**-24, True: 2.0**-53}
#: physics bounds in units of u (tests/test_kernels_physics.py explains them)
PHYSICS_BOUND_U = 16
INVERT_BOUNDS = {"alpha": 1e-6, "rho": 1e-4}   # the accuracy contract (docs/model.md "Accuracy")


@dataclass
class Row:
    function: str
    precision: str
    max_error: float
    unit: str
    bound: float | None
    where: str
    device: str = ""

    @property
    def status(self):
        if self.bound is None:
            return "INFO"
        return "PASS" if self.max_error <= self.bound else "FAIL"


def _albedo_sweep(n):
    return np.float32(np.concatenate([np.geomspace(1e-6, 0.5, n), 1 - np.geomspace(1e-3, 0.5, n),
                                      np.linspace(1e-6, 0.999, n)])).astype(np.float64)


def _physics_rows(etas, double, n, rt):
    u = EPS[double]
    prec = "f64" if double else "f32"
    lo = 1e-300 if double else 1e-37
    rows = []
    a = np.float32(np.concatenate([np.geomspace(1e-6, 0.5, n),
                                   1 - np.geomspace(2**-24, 0.5, n)])).astype(np.float64)
    q = np.float32(np.geomspace(1e-12, 0.7071, n)).astype(np.float64)
    alphas = np.float32([1e-3, 0.3, 0.9, 0.999, 1 - 1e-6, 1.0]).astype(np.float64)[:, None]
    radii = np.float32(np.concatenate([[0.0], np.geomspace(1e-4, 1e3, n // 4)])).astype(
        np.float64)[None, :]
    for eta in etas:
        got = physics.evaluate("rd", a, eta=eta, double=double, device=rt)
        want = ref.rd(a, eta)
        ok = want > lo
        err = np.abs(got[ok] / want[ok] - 1) / u
        i = int(np.argmax(err))
        rows.append(Row(f"rd (eta {eta})", prec, err[i], "u", PHYSICS_BOUND_U,
                        f"alpha'={a[ok][i]:.6g}"))
        got = physics.evaluate("one_minus_rd", q, eta=eta, double=double,
                               device=rt)
        err = np.abs(got / ref.one_minus_rd_of_rho(q * q, eta) - 1) / u
        i = int(np.argmax(err))
        rows.append(Row(f"1 - rd (eta {eta})", prec, err[i], "u", PHYSICS_BOUND_U,
                        f"q={q[i]:.3g}"))
        for func in ("profile", "profile_cdf", "profile_tail"):
            worst, where = 0.0, ""
            for st in (0.1, 1.0, 10.0):
                got = physics.evaluate(func, radii, alphas, st, eta=eta, double=double,
                                       device=rt)
                want = physics.reference_value(func, radii, alphas, st, eta=eta)
                if func == "profile":
                    mu_d = st * ref.mu_tr_over_sigma_t(1 - alphas) * np.sqrt(radii**2 + 9 / st**2)
                    ok = want > lo
                    err = np.where(ok, np.abs(got - want) / (np.where(ok, want, 1) * (1 + mu_d)), 0)
                else:
                    err = np.abs(got - want) / ref.rd(alphas, eta)
                err = err / u
                j = np.unravel_index(int(np.argmax(err)), err.shape)
                if err[j] > worst:
                    worst = float(err[j])
                    where = f"r={radii[0, j[1]]:.3g}, alpha'={alphas[j[0], 0]:.6g}, st={st}"
            unit = "u/(1+mu d)" if func == "profile" else "u of Rd"
            rows.append(Row(f"{func} (eta {eta})", prec, worst, unit, PHYSICS_BOUND_U, where))
    return rows


def _invert_rows(etas, n, rt):
    from ..methods.registry import MethodConfig
    from ..ops.invert import invert_albedo
    rd = _albedo_sweep(n)
    rows = []
    configs = [MethodConfig("table"), MethodConfig("secant"), MethodConfig("bisection"),
               MethodConfig("table", table_size=64, polish=1), MethodConfig("memo")]
    for eta in etas:
        want_a, want_rho = ref.invert_rd_rho(rd, eta)
        for cfg in configs:
            a, rho = invert_albedo(rd.astype(np.float32), eta, cfg, return_rho=True,
                                   device=rt)
            for name, got, want in (("alpha", a, want_a), ("rho", rho, want_rho)):
                err = np.abs(got / want - 1)
                i = int(np.argmax(err))
                bound = None if cfg.spec.baseline else INVERT_BOUNDS[name]
                rows.append(Row(f"invert {cfg.describe()} {name} (eta {eta})", "f32",
                                float(err[i]), "rel", bound, f"Rd={rd[i]:.6g}"))
    return rows


def _blur_rows(rt):
    from ..ops.blur import blur, channel_kernel, channel_parameters
    rows = []
    e = np.zeros((41, 41, 1), np.float32)
    e[20, 20] = 1.0
    for mfp in (0.5, 2.0):
        p = channel_parameters(1, albedo=0.8, mfp=mfp, eta=1.4)[0]
        ck = channel_kernel(*p, 1e-3)
        k = ck.radius
        for method in BLUR_KERNELS:
            out, info = blur(e, albedo=0.8, mfp=mfp, eta=1.4, method=method, border="zero",
                             return_info=True, device=rt)
            got = out[20 - k:21 + k, 20 - k:21 + k, 0]
            err = np.abs(got - ck.weights).max() / ck.rd
            rows.append(Row(f"blur {method} impulse (mfp {mfp} texels)", "f32", float(err),
                            "of Rd", info.channels[0].error_bound, f"radius {k}"))
    return rows


def run_crosscheck(etas=(1.0, 1.4, 2.5), *, n=500, double=None, include=("physics", "invert",
                                                                             "blur"),
                   device=None):
    """All built-in checks on one device (``device``: as for ``invert_albedo``): Rows."""
    rt = get_runtime(device)
    precisions = [False] + ([True] if (double is None and rt.has_fp64) or double else [])
    rows = []
    if "physics" in include:
        for d in precisions:
            rows += _unless_rejected(f"physics {'f64' if d else 'f32'}",
                                     lambda d=d: _physics_rows(etas, d, n, rt))
    if "invert" in include:
        rows += _unless_rejected("inversions", lambda: _invert_rows(etas, n, rt))
    if "blur" in include:
        rows += _unless_rejected("blurs", lambda: _blur_rows(rt))
    return rows


def _unless_rejected(group: str, rows_of):
    """``rows_of()``, or one INFO row where a kernel configuration it needs was rejected by
    the device's probe (the library never builds it there: device.programs)."""
    try:
        return rows_of()
    except DeviceError as exc:
        if "failed this device's probe" not in str(exc):
            raise
        return [Row(f"{group}: rejected by the device's probe, skipped", "-", float("nan"),
                    "-", None, str(exc))]


def run_all_devices(etas=(1.0, 1.4, 2.5), *, n=500, numerics="device"):
    """``run_crosscheck`` on every working device, each row labelled with its device, its
    kernels built for ``numerics`` (``device.numerics.NUMERICS``)."""
    from dataclasses import replace

    from ..device import survey
    rows = []
    states = survey()
    if not any(s.works for s in states):         # nothing checked is not a pass
        found = "; ".join(f"[{s.index}] {s.name} ({s.platform}): {s.reason}" for s in states)
        raise DeviceError(f"no working OpenCL device: {found or 'none found'}; {REMEDIES}")
    for state in states:
        if not state.works:
            # a broken device is reported, not failed: the automatic choice skips it too
            rows.append(Row("device probe: broken, skipped", "-", float("nan"), "-", None,
                            state.reason, f"[{state.index}] {state.platform}"))
            continue
        label = f"[{state.index}] {state.platform}"
        rt = get_runtime(state.device).with_numerics(numerics)
        rows += [replace(r, device=label) for r in run_crosscheck(etas, n=n, device=rt)]
    return rows


def format_rows(rows):
    with_device = any(r.device for r in rows)
    head = (("device",) if with_device else ()) + (
        "function", "prec", "max error", "unit", "bound", "status", "worst at")
    table = [head] + [(((r.device,) if with_device else ()) + (
        r.function, r.precision, f"{r.max_error:.3g}", r.unit,
        "-" if r.bound is None else f"{r.bound:.3g}", r.status, r.where)) for r in rows]
    widths = [max(len(t[i]) for t in table) for i in range(len(head))]
    lines = ["  ".join(c.ljust(w) for c, w in zip(t, widths)).rstrip() for t in table]
    fails = sum(r.status == "FAIL" for r in rows)
    lines.append(f"{len(rows)} checks, {fails} over their bound"
                 + (" (INFO rows are shown, not judged: the memo's baseline, rho derived from a "
                    "float32 alpha', model notes)" if any(r.status == "INFO" for r in rows)
                    else ""))
    if any(r.unit == "ulp" for r in rows):
        lines.append("alpha' errors are ulps from the correctly rounded float32 alpha'; rho "
                     "errors relative to the exact rho")
    return "\n".join(lines)
