"""``bdipole-cl crosscheck --user-kernel``: a renderer's own OpenCL C function against the
float64 reference, as its developer needs to read it.

Signatures (float32; the Fresnel terms are d'Eon's 2 C1 and 3 C2 at ``--eta``)::

    rd:           float NAME(float alpha_prime, float two_c1, float three_c2)
    invert:       float NAME(float rd, float two_c1, float three_c2)      // returns alpha'
    invert-rho:   float NAME(float rd, float two_c1, float three_c2)      // returns rho
    invert-both:  void NAME(float rd, float two_c1, float three_c2,
                            float *alpha_prime, float *rho)
    profile:      float NAME(float r, float alpha_prime, float sigma_t, float two_c1,
                             float three_c2)

Verdicts:

- A float32 alpha' is judged by its distance, in ulps, from the correctly rounded alpha'
  (ALPHA_ULPS): no float32 alpha' can carry rho near alpha' = 1 (docs/model.md "Stiffness"),
  so rho derived from a returned alpha' is shown, not judged. A returned rho is judged by the
  accuracy contract (1e-4 relative).
- Errors are reported per Rd range (RD_RANGES), each with its worst point, its NaN count and
  the non-monotone steps along increasing Rd (RD_RANGES each swept with ``n`` points).
- When the function follows Jensen's dipole (Rd ~ alpha') rather than the Better Dipole
  (Rd ~ alpha'^2) better, a row says so.
- The function runs in a child process that is stopped after ``timeout`` seconds (a kernel that
  loops forever cannot hang the tool); build and lookup errors name the expected signature and
  point at lines of the user's file.
"""
from __future__ import annotations

import multiprocessing
import re
from pathlib import Path

import numpy as np

from ..physics import reference as ref
from ..physics.models import BETTER, DIPOLE
from .crosscheck import Row

SIGNATURES = {
    "rd": "float {name}(float alpha_prime, float two_c1, float three_c2)",
    "invert": "float {name}(float rd, float two_c1, float three_c2)  /* returns alpha' */",
    "invert-rho": "float {name}(float rd, float two_c1, float three_c2)  /* returns rho */",
    "invert-both": ("void {name}(float rd, float two_c1, float three_c2, float *alpha_prime, "
                    "float *rho)"),
    "profile": ("float {name}(float r, float alpha_prime, float sigma_t, float two_c1, "
                "float three_c2)"),
}
#: the call in the evaluation kernel, per kind (x, y, z: the inputs; out, out2: the results)
_CALLS = {
    "rd": "out[i] = {name}(x[i], two_c1, three_c2);",
    "invert": "out[i] = {name}(x[i], two_c1, three_c2);",
    "invert-rho": "out[i] = {name}(x[i], two_c1, three_c2);",
    "invert-both": "float a, r; {name}(x[i], two_c1, three_c2, &a, &r); out[i] = a; out2[i] = r;",
    "profile": "out[i] = {name}(x[i], y[i], z[i], two_c1, three_c2);",
}
#: Rd ranges reported separately (where kernels fail differently: clamps near 0, the split,
#: the stiff end)
RD_RANGES = ((0.0, 1e-3), (1e-3, 0.5), (0.5, 0.9), (0.9, 0.99), (0.99, 1.0))
#: a float32 alpha' within this many ulps of the correctly rounded one passes: the table
#: methods measure <= 3 ulps (8 ulps near alpha' = 0, where alpha' ulps are tiny next to Rd's)
ALPHA_ULPS = 8
RHO_BOUND = 1e-4           # the accuracy contract (docs/model.md "Accuracy")
PHYSICS_BOUND = 16 * 2.0**-24
DEFAULT_TIMEOUT = 120.0


class UserKernelError(ValueError):
    """The user's file cannot be built or lacks the function (a usage error: exit 2)."""


class UserKernelRunError(UserKernelError):
    """The user's kernel was built but its run did not finish or died (a failure: exit 1)."""


def signature(kind: str, name: str) -> str:
    return SIGNATURES[kind].format(name=name)


def _strip_comments(text: str) -> str:
    text = re.sub(r"/\*.*?\*/", lambda m: "\n" * m.group(0).count("\n"), text, flags=re.S)
    return re.sub(r"//[^\n]*", "", text)


def find_function(source: str, name: str) -> int | None:
    """The line (1-based) where ``name`` is defined in ``source``, or None."""
    code = _strip_comments(source)
    m = re.search(r"^[^\n;{}]*\b(float|void|double|int|real)\s+" + re.escape(name) + r"\s*\(",
                  code, flags=re.M)
    return None if m is None else code[:m.start()].count("\n") + 1


def evaluation_source(source: str, path: str, name: str, kind: str) -> str:
    """The user's text with ``#line`` markers (messages name its own lines), then the kernel
    that calls the function on every element."""
    call = _CALLS[kind].format(name=name)
    return (f'#line 1 "{path}"\n{source}\n#line 1 "bdipole-cl crosscheck wrapper"\n'
            "__kernel void bdipole_user_eval(__global const float *x, __global const float *y,"
            " __global const float *z, __global float *out, __global float *out2,"
            " const float two_c1, const float three_c2, const uint n)\n"
            "{\n    uint i = get_global_id(0);\n    if (i >= n) return;\n"
            f"    {call}\n}}\n")


#: a compiler's error line, whatever names the file: clang's ``file:LINE:COL: error: text``
#: (Intel's runtime, PoCL), ``<kernel>:LINE:COL: error:`` or ``file(LINE): error`` (other
#: drivers' logs): the line and the message
COMPILER_ERROR = re.compile(r"(?::(\d+)(?::\d+)?|\((\d+)\))\s*:?\s*error\s*:?\s*(.*)", re.I)


def _build_error(path, name, kind, log: str) -> str:
    """One line: the user's file and line of the compiler's first error, its words, and the
    signature expected; else every error line of the log. The source given to the compiler
    marks the user's lines (``#line``), so the compiler's line is the user's."""
    for ln in str(log).splitlines():
        found = COMPILER_ERROR.search(ln)
        if found and "wrapper" not in ln:
            line = found.group(1) or found.group(2)
            return (f"{path}:{line}: error: {found.group(3).strip()[:300]} (building {name}; "
                    f"expected: {signature(kind, name)})")
    lines = [ln.strip() for ln in str(log).splitlines() if path in ln or "error" in ln.lower()]
    detail = "; ".join(dict.fromkeys(lines)) or str(log).strip().splitlines()[-1]
    return (f"{path}: building {name} failed (expected: {signature(kind, name)}): "
            f"{detail[:600]}")


def _evaluate(path, name, kind, eta, inputs, device):
    """Build and run the user's function on ``inputs`` (x, y, z arrays): (out, out2)."""
    import pyopencl as cl

    from ..device import get_runtime
    from ..device.runtime import build_quietly
    source = Path(path).read_text()
    rt = get_runtime(device)
    try:
        prg = build_quietly(rt.context, evaluation_source(source, str(path), name, kind))
    except cl.RuntimeError as exc:
        raise UserKernelError(_build_error(str(path), name, kind, exc)) from None
    c1, c2 = ref.fresnel_moments(eta)
    x, y, z = (np.ascontiguousarray(v, np.float32).reshape(-1) for v in inputs)
    mf = cl.mem_flags
    bufs = [cl.Buffer(rt.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=v) for v in (x, y, z)]
    outs = [np.full_like(x, np.nan) for _ in range(2)]
    obufs = [cl.Buffer(rt.context, mf.WRITE_ONLY, max(o.nbytes, 4)) for o in outs]
    try:
        cl.Kernel(prg, "bdipole_user_eval")(rt.queue, (x.size,), None, *bufs, *obufs,
                                            np.float32(2 * c1), np.float32(3 * c2),
                                            np.uint32(x.size))
        for o, b in zip(outs, obufs):
            cl.enqueue_copy(rt.queue, o, b)
        rt.queue.finish()
    except cl.Error as exc:  # built, yet no kernel or no run: the runtime's compiler broke it
        raise UserKernelRunError(
            f"{path}: {name} built, but {rt.describe()} could not run it ({exc}); its compiler "
            f"may break what it built, e.g. 16-float vectors where it misnames the CPU "
            f"(docs/runtimes.md \"Vector widths: PoCL on a CPU its LLVM misnames\"): try "
            f"another --device") from None
    return outs[0].astype(np.float64), outs[1].astype(np.float64)


def _child(conn, args):
    try:
        conn.send(("ok", _evaluate(*args)))
    except Exception as exc:  # anything the driver says goes back as text
        conn.send(("run-error" if isinstance(exc, UserKernelRunError) else "error", str(exc)))
    finally:
        conn.close()


def evaluate_isolated(path, name, kind, eta, inputs, device_index, timeout):
    """``_evaluate`` in a child process stopped after ``timeout`` seconds."""
    ctx = multiprocessing.get_context("spawn")
    parent, child = ctx.Pipe(duplex=False)
    proc = ctx.Process(target=_child, daemon=True,
                       args=(child, (path, name, kind, eta, inputs, device_index)))
    proc.start()
    child.close()
    try:
        if not parent.poll(timeout):
            raise UserKernelRunError(f"{path}: {name} did not finish within {timeout:g} s (an "
                                  f"endless loop?); its run was stopped (--timeout sets the "
                                  f"limit)")
        status, payload = parent.recv()
    except EOFError:
        raise UserKernelRunError(f"{path}: the run of {name} died (exit code "
                              f"{proc.exitcode})") from None
    finally:
        if proc.is_alive():
            proc.kill()
        proc.join(5)
    if status == "run-error":
        raise UserKernelRunError(payload)
    if status == "error":
        raise UserKernelError(payload)
    return payload


def sorted_sweep(n: int) -> np.ndarray:
    """``n`` float32 albedos per RD_RANGE, increasing (geometric in each), and the largest
    float32 below 1."""
    parts = []
    for lo, hi in RD_RANGES:
        lo = max(lo, 1e-7)
        if hi < 1.0:
            parts.append(np.geomspace(lo, hi, n, endpoint=False))
        else:                                   # towards 1: geometric in 1 - Rd
            parts.append(1.0 - np.geomspace(1.0 - lo, 2**-24, n))
    rd = np.unique(np.float32(np.concatenate(parts)))
    return rd[(rd > 0) & (rd < 1)].astype(np.float64)


def _range_rows(label, rd, got, want, bound, unit, err_fn, increasing):
    rows = []
    for lo, hi in RD_RANGES:
        sel = (rd >= lo) & (rd < hi)
        if not np.any(sel):
            continue
        g, w, r = got[sel], want[sel], rd[sel]
        nan = int(np.count_nonzero(~np.isfinite(g)))
        with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
            err = np.where(np.isfinite(g), err_fn(g, w), np.inf)   # a NaN: an infinite error
        i = int(np.argmax(err))
        steps = np.diff(g[np.isfinite(g)])
        reversals = int(np.count_nonzero(steps < 0 if increasing else steps > 0))
        where = f"Rd={r[i]:.9g}; NaN {nan}; non-monotone steps {reversals}"
        worst = float(err[i]) if np.isfinite(err[i]) else float("inf")
        rows.append(Row(f"{label}, Rd in [{lo:g}, {hi:g})", "f32", worst, unit, bound, where))
    return rows


def _ulps32(got, want):
    """Distance in float32 ulps of ``got`` (float32 values) from ``want`` rounded to float32."""
    a = np.float32(got).view(np.int32).astype(np.int64)
    b = np.float32(want).view(np.int32).astype(np.int64)
    return np.abs(a - b).astype(np.float64)


def _relative(got, want):
    return np.abs(got / want - 1.0)


def _model_note(label, rd, alpha, eta):
    """A row naming the model the inverse follows when it is Jensen's dipole."""
    ok = np.isfinite(alpha) & (rd > 1e-4) & (rd < 0.9)
    if not np.any(ok):
        return []
    errs = {m: float(np.median(_relative(alpha[ok], ref.invert_rd_rho(rd[ok], eta,
                                                                        model=m)[0])))
            for m in (BETTER.name, DIPOLE.name)}
    better, dipole = errs[BETTER.name], errs[DIPOLE.name]
    if dipole < 0.1 * better:
        return [Row(f"{label} follows Jensen's dipole (Rd ~ alpha'), not the Better Dipole "
                    f"(Rd ~ alpha'^2)", "f32", better, "rel", None,
                        f"median alpha' error {dipole:.2g} vs the dipole, "
                        f"{better:.2g} vs the Better Dipole")]
    return []


def check_user_kernel(path, function, against, *, eta=1.4, n=500, device=None,
                      timeout=DEFAULT_TIMEOUT):
    """Rows judging ``function`` of ``path`` (see the module docstring); ``device`` is a
    device spec string (``"0:0"``, ``"intel"``) or None, opened by the child process."""
    if against not in SIGNATURES:
        raise UserKernelError(f"--against {against!r}: expected one of {', '.join(SIGNATURES)}")
    path = str(path)
    try:
        source = Path(path).read_text()
    except OSError as exc:
        raise UserKernelError(f"{path}: {exc.strerror or exc}") from None
    if find_function(source, function) is None:
        raise UserKernelError(f"{path}: no function named {function} (expected: "
                              f"{signature(against, function)})")
    ref.check_eta(eta)
    label = f"{function} (eta {eta})"
    if against in ("rd", "profile"):
        return _check_forward(path, function, against, eta, n, device, timeout, label)
    rd = sorted_sweep(n)
    out, out2 = evaluate_isolated(path, function, against, eta, (rd, rd * 0, rd * 0), device,
                                  timeout)
    want_a, want_rho = ref.invert_rd_rho(rd, eta)
    alpha = {"invert": out, "invert-rho": 1.0 - out, "invert-both": out}[against]
    rho = {"invert": 1.0 - out, "invert-rho": out, "invert-both": out2}[against]
    rows = []
    if against in ("invert", "invert-both"):
        rows += _range_rows(f"{label} alpha'", rd, alpha, want_a, ALPHA_ULPS,
                            "ulp", _ulps32, increasing=True)
    rho_judged = against in ("invert-rho", "invert-both")
    rows += _range_rows(f"{label} rho" + ("" if rho_judged else " = 1 - alpha'"),
                        rd, rho, want_rho, RHO_BOUND if rho_judged else None, "rel",
                        _relative, increasing=False)
    return rows + _model_note(label, rd, alpha, eta)


def _check_forward(path, function, against, eta, n, device, timeout, label):
    if against == "rd":
        a = np.unique(np.float32(np.concatenate([np.geomspace(1e-6, 0.5, n),
                                                 1 - np.geomspace(2**-24, 0.5, n)])))
        a = a.astype(np.float64)
        got, _ = evaluate_isolated(path, function, "rd", eta, (a, a * 0, a * 0), device,
                                   timeout)
        want = ref.rd(a, eta)
        err = np.where(np.isfinite(got), _relative(got, want), np.inf)
        i = int(np.argmax(err))
        rows = [Row(label, "f32", float(err[i]), "rel", PHYSICS_BOUND,
                        f"alpha'={a[i]:.9g}; NaN {int(np.count_nonzero(~np.isfinite(got)))}")]
        dip = float(np.median(_relative(got[np.isfinite(got)],
                                        ref.rd(a[np.isfinite(got)], eta, model=DIPOLE.name))))
        bet = float(np.median(err[np.isfinite(err)]))
        if dip < 0.1 * bet:
            rows.append(Row(f"{label} follows Jensen's dipole (Rd ~ alpha'), not the Better "
                            f"Dipole", "f32", bet, "rel", None,
                                f"median error {dip:.2g} vs the dipole, {bet:.2g} vs the Better "
                                f"Dipole"))
        return rows
    # the built-in profile sweep's radii and albedos (sigma_t' = 1)
    r = np.float32(np.concatenate([[0.0], np.geomspace(1e-4, 1e3, max(n // 4, 2))]))
    alphas = np.float32([1e-3, 0.3, 0.9, 0.999, 1 - 1e-6])
    rr, aa = (v.astype(np.float64) for v in np.meshgrid(r, alphas))
    got, _ = evaluate_isolated(path, function, "profile", eta,
                               (rr.ravel(), aa.ravel(), np.ones(rr.size)), device, timeout)
    got = got.reshape(rr.shape)
    want = ref.profile(rr, aa, 1.0, eta)
    ok = want > 1e-30
    err = np.where(ok, np.abs(got - want) / np.where(ok, want, 1.0), 0.0)
    err = np.where(np.isfinite(got), err, np.inf)
    j = np.unravel_index(int(np.argmax(err)), err.shape)
    mu_d = ref.mu_tr_over_sigma_t(1 - aa[j]) * np.hypot(rr[j], 3.0)
    return [Row(label, "f32", float(err[j]), "rel", PHYSICS_BOUND * (1 + mu_d),
                    f"r={rr[j]:.3g}, alpha'={aa[j]:.9g}, sigma_t=1")]
