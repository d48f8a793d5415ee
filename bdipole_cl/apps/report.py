"""``bdipole-cl report``: error against run time for every method and its cost knob.

On the current device, on fixed workloads (seeded), it measures for each configuration the max
and mean error against the float64 reference and the median run time, and writes
``report.md`` (table), ``report.csv`` and ``report.png`` (log-log error vs time, one curve per
method, Pareto front circled). With ``--write-choice PATH`` it also writes every measured
configuration, as structured fields, to the JSON file ``method="auto"`` picks from
(``bdipole_cl.methods.choice``: the package's ``bdipole_cl/data/choice.json`` is written this
way from a source checkout; ``BDIPOLE_CL_CHOICE_DATA`` makes an installed package use another).
``--calibrate`` (``calibrate``) measures the same configurations on smaller workloads (a minute
or two) and stores them, keyed by the device, in the user's cache, where ``auto`` finds them on
that device (``bdipole_cl.methods.choice.calibration_path``).

Inversion error: max relative error of rho (= sigma_a/sigma_t', the stiff quantity; alpha'
errors are smaller for every method but the memo's, whose rho is reported as it is).
Blur error: max |M - exact| / (max E * Rd), the exact discrete convolution computed with
tol = 1e-9 weights in float64 by FFT.
"""
from __future__ import annotations

import csv
import hashlib
import io
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..device import get_runtime
from ..device.programs import kernels_digest
from ..io.collisions import refusal
from ..methods.choice import (ChoiceData, DeviceKey, KernelTuning, calibration_ignored,
                              calibration_path, is_choice_data, write_choice_data)
from ..methods.registry import BLUR_KERNELS, BlurChoice, InversionChoice, MethodConfig
from ..ops.invert import InversionKernel
from ..device.runtime import forced
from .benchmark import (GATHER_WIDTH_CHOICES, TABLE_WIDTH_CHOICES, fitted_gather_costs,
                        gather_rows, inversion_workload, reference_inverse, stiff_workload,
                        table_width_times, time_inversion)
from .preview import replaced_together

INVERSION_SWEEP = (
    [MethodConfig("memo", iterations=i) for i in (12, 24, 50)]
    + [MethodConfig("bisection", iterations=i) for i in (12, 20, 32)]
    + [MethodConfig("bisection")]
    + [MethodConfig("secant", tol=t) for t in (1e-2, 1e-4, 1e-6, 2e-7)]
    + [MethodConfig("secant", tol=2e-7, seed_size=s) for s in (4, 64)]
    + [MethodConfig("table", table_size=n) for n in (4, 8, 16, 32, 64, 128, 256, 1024)]
    + [MethodConfig("table", table_size=n, polish=1) for n in (4, 16)]
)
INVERSION_SWEEP_F64 = [MethodConfig("secant", tol=1e-12), MethodConfig("secant"),
                       MethodConfig("bisection"),
                       MethodConfig("table", table_size=256, polish=1),
                       MethodConfig("table", table_size=64, polish=2), MethodConfig("table")]
#: the errors the choice data hold are the max over these etas (the fits' valid range, end to
#: end): auto's tol then holds at every eta, not only at the timing workload's 1.4
ERROR_ETAS = (0.5, 0.7, 0.9, 1.0, 1.1, 1.25, 1.4, 1.6, 1.8, 2.0, 2.2, 2.4, 2.5, 2.6, 2.7, 2.79)
BLUR_SWEEP = [(m, t) for m in BLUR_KERNELS for t in (1e-2, 1e-3, 1e-4)]
#: blur workloads: mfp in texels (kernel radius 2, 6 and 17 at albedo 0.8, tol 1e-3: auto takes
#: the nearest radius's, so a radius of 4-11 no longer decides from radius 2's timings)
BLUR_WORKLOADS = (0.5, 1.5, 4.0)
#: channels of the blur workloads: an RGB map, as the blur's users give it (the host FFT
#: transforms all channels at once, the device kernels one after the other)
BLUR_CHANNELS = 3


@dataclass
class Point:
    kind: str          # inversion | blur
    method: str        # curve name
    config: str
    precision: str
    seconds: float
    max_error: float
    mean_error: float
    pareto: bool = False
    choice: InversionChoice | BlurChoice | None = None    # the measurement as choice data


#: the calibration's (smaller) workloads: albedos, blur map size, repeats
CALIBRATION = {"n": 1 << 18, "blur_size": 256, "repeats": 3, "gather_size": 1024}
#: the table widths are timed on at least this many albedos (16 MiB: beyond the caches, as a
#: texture's are)
TABLE_TUNING_TEXELS = 1 << 22


def error_over_eta(cfg, double, stiff, references, etas=ERROR_ETAS):
    """(max relative rho error on the stiff workload over ``etas``, monotone at every eta)."""
    worst, monotone = 0.0, True
    for eta in etas:
        kernel = InversionKernel((eta,), cfg, double=double)
        rho = kernel.run(stiff.astype(kernel.dtype), None, ("rho",))["rho"]
        worst = max(worst, float(np.max(np.abs(rho / references[eta] - 1.0))))
        monotone = monotone and kernel.monotone
    return worst, monotone


def inversion_points(n=1 << 20, eta=1.4, repeats=3, progress=print, etas=ERROR_ETAS,
                     sweep=None, sweep_f64=None):
    """Every configuration (of ``sweep`` and ``sweep_f64``, default INVERSION_SWEEP and
    INVERSION_SWEEP_F64): run time on ``n`` uniform albedos at ``eta``; max rho error on
    those and on a stiff sweep at every eta of ``etas``; monotone or not."""
    rt = get_runtime()
    rd = inversion_workload(n)
    want_a, want_rho = reference_inverse(rd, eta)
    stiff = stiff_workload()
    references = {e: reference_inverse(stiff, e)[1] for e in etas}
    runs = [(c, False) for c in (INVERSION_SWEEP if sweep is None else sweep)]
    if rt.has_fp64:
        runs += [(c, True) for c in (INVERSION_SWEEP_F64 if sweep_f64 is None else sweep_f64)]
    points = []
    for cfg, double in runs:
        r = time_inversion(cfg, rd, eta, want_a, want_rho, double=double, repeats=repeats)
        over_eta, monotone = error_over_eta(cfg, double, stiff, references, etas)
        err = max(r.max_err_rho, over_eta)
        prec = "f64" if double else "f32"
        label = cfg.describe(double)
        choice = InversionChoice(cfg.resolved(double), prec, err, r.seconds, monotone,
                                 tuple(etas))
        points.append(Point("inversion", f"{cfg.method} {prec}", label, prec, r.seconds, err,
                            r.mean_err_rho, choice=choice))
        progress(f"  {label:34s} {prec}  {r.seconds * 1e3:9.2f} ms  max rho err {err:.2e}"
                 f"{'  monotone' if monotone else ''}")
    return points


def blur_points(size=512, mfps=BLUR_WORKLOADS, repeats=3, progress=print, sweep=BLUR_SWEEP):
    """Every blur method and truncation tol of ``sweep`` on one workload per mfp (kind
    "blur mfp <m>"): a size^2 RGB map, the same albedo in every channel; errors the max over
    the channels."""
    import statistics
    import time

    from ..ops.blur import blur, channel_kernel, channel_parameters
    from ..ops.blur.fft import fft_blur_channel
    rng = np.random.default_rng(1)
    e = rng.uniform(0, 1, (size, size, BLUR_CHANNELS)).astype(np.float32)
    points = []
    for mfp in mfps:
        params = channel_parameters(1, albedo=0.8, mfp=mfp, eta=1.4)[0]
        exact_k = channel_kernel(*params, 1e-9)
        exact = np.stack([fft_blur_channel(e[..., c], exact_k.weights, "clamp")
                          for c in range(BLUR_CHANNELS)], axis=-1)
        norm = e.max() * exact_k.rd
        radius = channel_kernel(*params, 1e-3).radius
        for method, tol in sweep:
            blur(e[:32, :32], albedo=0.8, mfp=mfp, tol=tol, method=method)      # build, fit
            times = []
            for _ in range(repeats):
                t0 = time.perf_counter()
                out = blur(e, albedo=0.8, mfp=mfp, tol=tol, method=method)
                times.append(time.perf_counter() - t0)
            err = np.abs(out - exact) / norm
            seconds = statistics.median(times)
            p = Point(f"blur mfp {mfp:g}", method, f"{method}(tol={tol:g})", "f32",
                      seconds, float(err.max()), float(err.mean()),
                      choice=BlurChoice(method, tol, radius, mfp, float(err.max()), seconds))
            points.append(p)
            progress(f"  mfp {mfp:g} (radius {radius}) {p.config:22s} {p.seconds * 1e3:9.1f} ms"
                     f"  max err {p.max_error:.2e}")
    return points


def mark_pareto(points):
    """Flag the points no other point of the same kind beats in both time and error."""
    for p in points:
        p.pareto = not any(q is not p and q.kind == p.kind and q.seconds <= p.seconds
                           and q.max_error <= p.max_error
                           and (q.seconds < p.seconds or q.max_error < p.max_error)
                           for q in points)
    return points


#: the mark of this tool's reports: report.md's first line (an HTML comment, invisible when
#: rendered), with the sha256 of the rest of report.md and of report.csv and report.png, so
#: that an edited report file is the user's (``report_is_ours``)
REPORT_MARK = "bdipole_cl report"
CSV_HEADER = ("kind", "method", "config", "precision", "median_s", "max_error", "mean_error",
              "pareto")
REPORT_FILES = ("report.csv", "report.md", "report.png")


def mark_line(md_body: bytes, csv_bytes: bytes, png_bytes: bytes) -> str:
    """report.md's first line: REPORT_MARK and the three files' digests."""
    digests = [hashlib.sha256(b).hexdigest() for b in (md_body, csv_bytes, png_bytes)]
    return f"<!-- {REPORT_MARK} md:{digests[0]} csv:{digests[1]} png:{digests[2]} -->"


def recorded_digests(folder) -> dict:
    """{file name: sha256} of the report files as report.md's mark records them, where
    report.md is this tool's and unchanged ({} else)."""
    try:
        first, _, body = (Path(folder) / "report.md").read_bytes().partition(b"\n")
    except OSError:
        return {}
    fields = first.decode("utf-8", "replace").split()
    if fields[:3] != ["<!--", "bdipole_cl", "report"] or fields[-1] != "-->":
        return {}
    digests = dict(f.split(":", 1) for f in fields[3:-1] if ":" in f)
    if digests.get("md") != hashlib.sha256(body).hexdigest():
        return {}
    return {f"report.{k}": v for k, v in digests.items()}


def report_is_ours(path) -> bool:
    """Whether ``path`` (an existing regular report file) is one this tool wrote, unchanged
    since (its digest as report.md records it)."""
    path = Path(path)
    recorded = recorded_digests(path.parent)
    if path.name == "report.md":                   # its own digest is of the rest of it
        return bool(recorded)
    recorded = recorded.get(path.name)
    try:
        return recorded == hashlib.sha256(path.read_bytes()).hexdigest()
    except OSError:
        return False


def check_report_outputs(folder, choice_path=None, force=False):
    """A ValueError (a usage error, before any measuring) where a report file in ``folder``
    or the ``choice_path`` (``--write-choice``) would replace a file this tool did not write,
    or one it wrote that was changed since (unless ``force``), or is a directory or other
    non-regular file (always); where ``folder`` is a file, or ``choice_path`` is ``folder``
    or one of its report files; where either place cannot be written."""
    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise ValueError(f"-o {folder}: exists and is not a folder; the report is a folder of "
                         f"{', '.join(REPORT_FILES)}")
    targets = [(folder / name, report_is_ours) for name in REPORT_FILES]
    if choice_path:
        real = os.path.realpath(choice_path)
        if real in {os.path.realpath(p) for p, _ in targets} | {os.path.realpath(folder)}:
            raise ValueError(f"--write-choice {choice_path}: is the report's folder or one of "
                             f"its files; give another path")
        targets.append((Path(choice_path), is_choice_data))
    for path, is_ours in targets:
        why = refusal(path, force, is_ours)
        if why:
            raise ValueError(why)
    for where, option in [(folder, "-o")] + ([(Path(choice_path).parent, "--write-choice")]
                                              if choice_path else []):
        place = next(p for p in [where, *where.absolute().parents] if p.exists())
        if not os.access(place, os.W_OK | os.X_OK):
            raise ValueError(f"{option} {where}: {place} cannot be written (read-only or not "
                             f"this user's): nothing was measured")


def write_outputs(points, folder, device, workloads):
    """report.csv, report.md and report.png in ``folder``, written together
    (``replaced_together``: all three, or none of them changed)."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    table = io.StringIO(newline="")
    w = csv.writer(table)
    w.writerow(CSV_HEADER)
    for p in points:
        w.writerow([p.kind, p.method, p.config, p.precision, f"{p.seconds:.6g}",
                    f"{p.max_error:.3e}", f"{p.mean_error:.3e}", int(p.pareto)])
    lines = [f"Device: {device}", "", *workloads, ""]
    for kind in dict.fromkeys(p.kind for p in points):
        err_name = "max rel err rho" if kind == "inversion" else "max err / (max E Rd)"
        mono = kind == "inversion"
        lines += [f"| {kind} config | prec | median ms | {err_name} | mean err | Pareto |"
                  + (" monotone |" if mono else ""),
                  "|---|---|---:|---:|---:|:---:|" + ("---|" if mono else "")]
        for p in sorted((p for p in points if p.kind == kind), key=lambda p: p.seconds):
            flag = ("yes |" if p.choice is not None and p.choice.monotone else "no |") \
                if mono else ""
            lines.append(f"| {p.config} | {p.precision} | {p.seconds * 1e3:.2f} | "
                         f"{p.max_error:.2e} | {p.mean_error:.2e} | {'*' if p.pareto else ''} |"
                         + (f" {flag}" if mono else ""))
        lines.append("")
    picture = io.BytesIO()
    _plot(points, picture, device)
    csv_bytes, body = table.getvalue().encode(), "\n".join(lines).encode()
    md = (mark_line(body, csv_bytes, picture.getvalue()) + "\n").encode() + body
    replaced_together([
        (folder / "report.csv", lambda tmp: tmp.write_bytes(csv_bytes)),
        (folder / "report.md", lambda tmp: tmp.write_bytes(md)),
        (folder / "report.png", lambda tmp: tmp.write_bytes(picture.getvalue()))])
    return folder


def _plot(points, path, device):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    kinds = list(dict.fromkeys(p.kind for p in points))
    fig, axes = plt.subplots(1, len(kinds), figsize=(6.2 * len(kinds), 5.2), squeeze=False)
    for ax, kind in zip(axes[0], kinds):
        pts = [p for p in points if p.kind == kind]
        for method in dict.fromkeys(p.method for p in pts):
            mp = [p for p in pts if p.method == method]        # in knob order
            ax.plot([p.seconds * 1e3 for p in mp], [max(p.max_error, 1e-17) for p in mp],
                    "o-", label=method, ms=4)
        front = [p for p in pts if p.pareto]
        ax.scatter([p.seconds * 1e3 for p in front], [max(p.max_error, 1e-17) for p in front],
                   s=140, facecolors="none", edgecolors="k", label="Pareto front")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("median run time [ms]")
        ax.set_ylabel("max relative error of rho" if kind == "inversion"
                      else "max error / (max E * Rd)")
        ax.set_title(kind)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    fig.suptitle(f"bdipole_cl error vs run time on {device}", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110, format="png", metadata={"Software": REPORT_MARK})
    plt.close(fig)


def read_csv(path):
    """Points back from a report.csv (to re-plot or re-table without re-measuring; blur
    points come back without their ``choice``)."""
    with open(path, newline="") as f:
        return [Point(r["kind"], r["method"], r["config"], r["precision"], float(r["median_s"]),
                      float(r["max_error"]), float(r["mean_error"]), r["pareto"] == "1")
                for r in csv.DictReader(f)]


def write_choice(points, path, kernels=None):
    """Every measured configuration as choice data for ``method="auto"``, cheapest first, with
    the device's KernelTuning ``kernels`` (if measured)."""
    inv = sorted((p.choice for p in points if p.kind == "inversion"), key=lambda c: c.median_s)
    blur = sorted((p.choice for p in points if p.kind.startswith("blur")),
                  key=lambda c: (c.radius, c.median_s))
    rt = get_runtime()
    return write_choice_data(ChoiceData(rt.describe(), tuple(inv), tuple(blur),
                                        DeviceKey.of(rt.device), kernels), path)


def kernel_tuning(n, gather_size, repeats, progress=print) -> KernelTuning:
    """The current device's fastest table width (the default table inversion of ``n`` albedos,
    at least TABLE_TUNING_TEXELS), fastest gather width (the texture-varying gather at near
    field 3), and gather costs at that width (``benchmark.gather_rows``, a ``gather_size``
    map); only the widths the device's probe passed are timed (a rejected one is never built:
    ``device.isolation``)."""
    from ..device import get_runtime
    from ..ops.blur.dispatch import GATHER_WIDTH_VARIABLE
    from ..ops.widths import passes
    rt = get_runtime()
    table = table_width_times(max(n, TABLE_TUNING_TEXELS), repeats,
                              [w for w in TABLE_WIDTH_CHOICES if passes(rt, "invert_table", w)])
    progress("  table widths: " + ", ".join(f"{w}: {t * 1e3:.2f} ms" for w, t in table.items()))
    gather = {}
    for width in [w for w in GATHER_WIDTH_CHOICES if passes(rt, "blur_textured", w)]:
        with forced(GATHER_WIDTH_VARIABLE, width):
            gather[width] = gather_rows(gather_size, repeats=repeats, radii=(3,))[0][0].seconds
    progress("  gather widths: " + ", ".join(f"{w}: {t * 1e3:.2f} ms" for w, t in gather.items()))
    best = min(gather, key=gather.get)
    with forced(GATHER_WIDTH_VARIABLE, best):
        costs, _ = fitted_gather_costs(*gather_rows(gather_size, repeats=repeats))
    progress(f"  gather costs (cell, term, weight) in basis blurs: "
             f"{', '.join(f'{c:.3g}' for c in costs)}")
    return KernelTuning(min(table, key=table.get), best, costs, kernels_digest())


def calibrate(*, n=CALIBRATION["n"], blur_size=CALIBRATION["blur_size"],
              repeats=CALIBRATION["repeats"], progress=print, **sweeps):
    """``bdipole-cl report --calibrate``: measure the inversion and blur configurations on the
    current device (smaller workloads than the report) and store them in the user's cache for
    this device; returns the file. ``sweeps``: ``sweep``, ``sweep_f64`` (inversion) and
    ``blur_sweep`` in place of the report's, ``gather_size`` (a short calibration). It also
    measures the kernels' widths and the gather's costs (``kernel_tuning``)."""
    with calibration_ignored():         # its own measurements, whatever a calibration says
        return _calibrate(n, blur_size, repeats, progress, sweeps)


def _calibrate(n, blur_size, repeats, progress, sweeps):
    rt = get_runtime()
    progress(f"calibrating {rt.describe()}")
    points = inversion_points(n, repeats=repeats, progress=progress,
                              sweep=sweeps.get("sweep"), sweep_f64=sweeps.get("sweep_f64"))
    points += blur_points(blur_size, repeats=repeats, progress=progress,
                          sweep=sweeps.get("blur_sweep", BLUR_SWEEP))
    progress("kernel shapes:")
    kernels = kernel_tuning(n, sweeps.get("gather_size", CALIBRATION["gather_size"]), repeats,
                            progress)
    path = write_choice(points, calibration_path(DeviceKey.of(rt.device)), kernels)
    progress(f"wrote {path}: method='auto' on this device now decides from it")
    return path


def run_report(folder="report_out", *, n=1 << 20, blur_size=512, repeats=3, write_choice_to=None,
               progress=print, force=False):
    rt = get_runtime()
    progress(f"device: {rt.describe()}")
    progress("inversion sweep:")
    points = inversion_points(n, repeats=repeats, progress=progress)
    progress("blur sweep:")
    points += blur_points(blur_size, repeats=repeats, progress=progress)
    mark_pareto(points)
    workloads = [f"Inversion: {n} float32 albedos uniform on [1e-6, 0.999], eta 1.4, "
                 f"median of {repeats} kernel runs on device buffers. Errors: the max over that "
                 f"workload and a stiff sweep (12,000 albedos to both ends) at each of "
                 f"{len(ERROR_ETAS)} etas from {ERROR_ETAS[0]} to {ERROR_ETAS[-1]}. Monotone: "
                 f"alpha' non-decreasing in Rd by construction (docs/model.md).",
                 f"Blur: {blur_size}x{blur_size} RGB uniform random irradiance, albedo "
                 f"0.8, mfp {', '.join(f'{m:g}' for m in BLUR_WORKLOADS)} texels, eta 1.4, "
                 f"border clamp, median of {repeats} calls (host to host)."]
    check_report_outputs(folder, write_choice_to, force)   # again: files may have come since
    out = write_outputs(points, folder, rt.describe(), workloads)
    if write_choice_to:
        progress(f"wrote {write_choice(points, write_choice_to)}")
    progress(f"wrote {out / 'report.md'}, {out / 'report.csv'}, {out / 'report.png'}")
    return points
