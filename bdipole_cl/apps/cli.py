"""``bdipole-cl``: command-line entry point (a thin layer over the Python API)."""
from __future__ import annotations

import argparse
import contextlib
import functools
import signal
import sys
import threading

from ..errors import POLICIES
from .cli_globals import add_global_args, colorspace_arg

EPILOG = """examples:
  bdipole-cl demo                                   # built-in example, writes ./bdipole_demo
  bdipole-cl plan scene.toml                        # what a bake computes and leaves out
  bdipole-cl bake scene.toml                        # run it (only what changed)
  bdipole-cl devices
  bdipole-cl invert diffuse.<UDIM>.exr --mfp mfp.<UDIM>.exr --eta 1.4 -o out/{stem}_coeffs.exr
  bdipole-cl invert 'textures/*.tif' --mfp 1.2,0.6,0.3 --unit mm --half --jobs 2
  bdipole-cl --working-space ACEScg invert albedo.png --mfp 1.2,0.6,0.3   # README: Colour
  bdipole-cl crosscheck                             # every kernel vs the float64 reference
  bdipole-cl crosscheck --user-kernel mine.cl --function computeRd --against rd
  bdipole-cl blur irradiance.exr --albedo 0.8,0.6,0.4 --mfp 1.2,0.6,0.3 --texel-size 0.1 -o sss.exr
"""


def _size(text):
    """'512M', '2G', '1048576' -> bytes (an argparse type: bad values are usage errors)."""
    raw = str(text).strip().upper()
    mult = {"K": 1 << 10, "M": 1 << 20, "G": 1 << 30}.get(raw[-1:], 1)
    try:
        value = int(float(raw[:-1] if raw[-1:] in "KMG" else raw) * mult)
    except ValueError:
        value = 0
    if value <= 0:
        raise argparse.ArgumentTypeError(f"{text!r}: expected a size such as 512M, 2G or "
                                         f"1048576 (bytes)")
    return value


def _floats(text):
    """'1.4' or '1.3,1.4,1.5' -> a tuple of finite floats (an argparse type)."""
    try:
        values = tuple(float(v) for v in str(text).split(","))
    except ValueError:
        values = ()
    if not values or not all(v == v and abs(v) != float("inf") for v in values):
        raise argparse.ArgumentTypeError(f"{text!r}: expected a number or a comma list such as "
                                         f"1.3,1.4,1.5")
    return values


def _number(convert, valid, expected):
    """An argparse type: ``convert(text)`` that ``valid`` accepts, else one-line usage error."""
    def parse(text):
        try:
            value = convert(text)
        except ValueError:
            value = None
        if value is None or not valid(value):
            raise argparse.ArgumentTypeError(f"{text!r}: expected {expected}")
        return value
    return parse


_positive_int = _number(int, lambda v: v >= 1, "a whole number >= 1")
_positive_float = _number(float, lambda v: 0 < v < float("inf"), "a number > 0")
_fraction = _number(float, lambda v: 0 < v < 1, "a number in (0, 1), e.g. 1e-3")


class _Parser(argparse.ArgumentParser):
    """argparse with one-line usage errors (``prog: error: ...``, exit 2), no usage block."""

    def error(self, message):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def _output_list(text):
    from ..ops.invert import OUTPUTS
    names = tuple(o.strip() for o in str(text).split(",") if o.strip())
    unknown = [o for o in names if o not in OUTPUTS]
    if not names or unknown:
        raise argparse.ArgumentTypeError(f"{text!r}: {', '.join(unknown) or 'empty'} not "
                                         f"allowed; choose from {', '.join(OUTPUTS)}")
    return names


class _Stop:
    """SIGINT/SIGTERM during a batch: set ``event`` so that files stop at their next band
    (temporaries removed, finished files kept), remember the signal for the exit code."""

    def __init__(self):
        self.event = threading.Event()
        self.signum = None

    def install(self):
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, self._handle)
        return self

    def _handle(self, signum, frame):
        self.signum = signum
        self.event.set()

    @property
    def exit_code(self):
        return 128 + self.signum if self.signum else None


def _finish(report, stop) -> int:
    """Print a batch's summary; its exit code (128 + the signal if one stopped it)."""
    print(report.summary())
    if stop.exit_code:
        print(f"interrupted by signal {stop.signum}: finished files kept, unfinished ones not "
              f"written", file=sys.stderr)
        return stop.exit_code
    return report.exit_code


@contextlib.contextmanager
def _cluster(args):
    """The Dask client of ``--scheduler`` (its dashboard link printed)."""
    from ..dask import connect
    with connect(args.scheduler, memory_limit=args.worker_memory) as client:
        print(f"dask dashboard: {client.dashboard_link}", flush=True)
        yield client


def _add_method_args(p):
    from ..methods.registry import METHODS
    p.add_argument("--method", default="table", choices=METHODS + ("auto",),
                   help="inversion method (auto: the cheapest meeting --tol in rho)")
    p.add_argument("--model", default="better", choices=("better", "dipole"),
                   help="Better Dipole (memo) or Jensen's classical dipole")
    p.add_argument("--exact", action="store_true",
                   help="exact Fresnel moments (quadrature) instead of d'Eon's fits")
    p.add_argument("--iterations", type=int, help="bisection/memo iterations, secant maximum")
    p.add_argument("--tol", type=float,
                   help="secant relative tolerance; with --method auto, the rho accuracy")
    p.add_argument("--table-size", type=int, help="table intervals per segment (default 256)")
    p.add_argument("--polish", type=int, help="Newton steps after the table lookup")
    p.add_argument("--seed-size", type=int, help="secant seed table intervals (default 16)")


def _method_knobs(args):
    return {k: getattr(args, k) for k in ("iterations", "tol", "table_size", "polish",
                                          "seed_size") if getattr(args, k) is not None}


def _cmd_invert(args) -> int:
    if args.scheduler:
        from ..dask import file_runner
        with _cluster(args) as client:
            return _invert(args, file_runner(client, device=args.device,
                                             progress=not args.no_progress))
    return _invert(args, None)


def _invert(args, run_files) -> int:
    from ..io.batch import process_textures
    stop = _Stop().install()
    report = process_textures(
        args.inputs, mfp=args.mfp, eta=args.eta, output=args.output, cancel=stop.event,
        outputs=args.outputs, method=args.method,
        model=args.model, exact=args.exact, half=args.half, colorspace=args.colorspace,
        working_space=args.working_space,
        alpha=args.alpha, on_invalid=args.on_invalid, max_memory=args.max_memory,
        jobs=args.jobs, skip_existing=args.skip_existing, unit=args.unit, double=args.double,
        mfp_scale=args.mfp_scale, progress=not args.no_progress and run_files is None,
        run_files=run_files, **_method_knobs(args))
    return _finish(report, stop)


def _is_number_list(text):
    try:
        _floats(text)
        return True
    except argparse.ArgumentTypeError:
        return False


def _param(text, what, **colour):
    """A blur parameter: numbers ('0.8' or 'r,g,b', in the working space), else the path of
    a texture (``colour``: colorspace= and working= of an albedo texture, converted)."""
    if _is_number_list(text):
        return _floats(text)
    else:
        from ..io.images import read_parameter_texture
        return read_parameter_texture(text, what, colour=bool(colour), **colour)


def _cmd_blur(args) -> int:
    from ..io.blur_file import blur_file
    from ..io.images import Cancelled, TextureError
    if args.alpha_prime is None and (args.albedo is None or args.mfp is None):
        print("bdipole-cl blur: error: give --albedo and --mfp (values or textures), or "
              "--alpha-prime and --sigma-t", file=sys.stderr)
        return 2
    if args.alpha_prime is not None and args.sigma_t is None:
        print("bdipole-cl blur: error: --alpha-prime needs --sigma-t", file=sys.stderr)
        return 2
    sources = {name: v for name, v in (("albedo", args.albedo), ("mfp", args.mfp),
                                       ("alpha", args.alpha_prime), ("sigma_t", args.sigma_t))
               if v is not None and not _is_number_list(v)}
    stop = _Stop().install()
    kw = dict(eta=args.eta, texel_size=args.texel_size, tol=args.tol,
              method=args.method, border=args.border, on_invalid=args.on_invalid,
              exact=args.exact, colorspace=args.colorspace, working_space=args.working_space)
    try:
        if args.alpha_prime is not None:
            kw.update(alpha=_param(args.alpha_prime, "alpha'"),
                      sigma_t=_param(args.sigma_t, "sigma_t'"))
        else:
            kw.update(albedo=_param(args.albedo, "albedo", colorspace=args.colorspace,
                                    working=args.working_space),
                      mfp=_param(args.mfp, "mfp"))
        if args.scheduler:
            from ..dask import blur_file_on_cluster
            with _cluster(args) as client:
                n = blur_file_on_cluster(args.input, args.output, client, half=args.half,
                                         max_memory=args.max_memory, device=args.device, **kw)
            print(f"{n} bands blurred on the cluster; wrote {args.output}")
            return 0
        info = blur_file(args.input, args.output, half=args.half, sources=sources,
                         max_memory=args.max_memory, cancel=stop.event, **kw)
    except Cancelled as exc:
        print(f"bdipole-cl {args.command}: error: {exc}", file=sys.stderr)
        return stop.exit_code or 1
    except TextureError as exc:
        print(f"bdipole-cl {args.command}: error: {exc}", file=sys.stderr)
        return 1
    for c in info.channels:
        rd = f"Rd {c.rd:.4f}" if c.rd is not None else "Rd per texel"
        print(f"channel {c.channel}: {c.method}, radius {c.radius} texels, {rd}, "
              f"error <= {c.error_bound:.1e} x max(E) x Rd")
    print(f"wrote {args.output}")
    return 0


def _cmd_crosscheck(args) -> int:
    from .crosscheck import format_rows, run_all_devices, run_crosscheck
    from .user_kernel import UserKernelError, UserKernelRunError, check_user_kernel
    if args.user_kernel:
        if not (args.function and args.against):
            print("bdipole-cl crosscheck: error: --user-kernel needs --function and --against",
                  file=sys.stderr)
            return 2
        try:
            rows = []
            for eta in args.eta:
                rows += check_user_kernel(args.user_kernel, args.function, args.against,
                                          eta=eta, n=args.n, device=args.device,
                                          timeout=args.timeout)
        except UserKernelError as exc:
            print(f"bdipole-cl crosscheck: error: {exc}", file=sys.stderr)
            return 1 if isinstance(exc, UserKernelRunError) else 2
    elif args.all_devices:
        rows = run_all_devices(args.eta, n=args.n)
    else:
        rows = run_crosscheck(args.eta, n=args.n)
    if not args.all_devices:
        from ..device import get_runtime
        print(f"device: {get_runtime().describe()}")
    print(format_rows(rows))
    return 1 if any(r.status == "FAIL" for r in rows) else 0


def _cmd_plan(args) -> int:
    from ..io.scene import load
    plan = load(args.scene, args.working_space).plan(force=args.force)
    print(plan.to_json() if args.json else plan.describe())
    return 0


def _cmd_bake(args) -> int:
    from ..io.scene import load
    plan = load(args.scene, args.working_space).plan(force=args.force)
    for problem in plan.missing:            # every missing input, before any work starts
        print(f"cannot run: {problem}", file=sys.stderr)
    stop = _Stop().install()

    def progress(job, result):
        if not args.no_progress:
            print(f"{result.status:9s} {job.kind} {job.name}"
                  + (f" [{job.udim}]" if job.udim else "") + f" -> {job.output}", flush=True)

    if args.scheduler:
        from ..dask import bake_on_cluster
        with _cluster(args) as client:
            report = bake_on_cluster(plan, client, device=args.device,
                                     progress=not args.no_progress)
    else:
        report = plan.run(cancel=stop.event, progress=progress)
    return _finish(report, stop)


def _cmd_report(args) -> int:
    from .report import run_report
    run_report(args.output, n=args.n, blur_size=args.blur_size, repeats=args.repeats,
               write_choice_to=args.write_choice)
    return 0


def _cmd_demo(args) -> int:
    from .demo import run_demo
    return run_demo(args.dir, progress=not args.no_progress)


def _cmd_devices(args) -> int:
    from ..device import REMEDIES, DeviceError, get_runtime, survey
    from ..device.icd import register_environment_runtimes
    states = survey()
    try:
        chosen = get_runtime().device.int_ptr
    except DeviceError as exc:
        chosen = None
        problem = str(exc)
    for s in states:
        mark = "*" if s.device.int_ptr == chosen else " "
        print(f"{mark} {s.describe()}")
    for r in register_environment_runtimes():
        how = "registered" if r.registered else "not registered"
        print(f"  environment runtime: {r.name} at {r.library} ({how}"
              + (f"; {r.note}" if r.note else "") + ")")
    if chosen is None:
        print(f"bdipole-cl devices: error: {problem}", file=sys.stderr)
        return 1
    print("* = the device bdipole-cl uses (--device or PYOPENCL_CTX choose another)")
    if not any(s.works for s in states):
        print(REMEDIES)
    return 0


def _add_scheduler_args(p):
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="run on a Dask cluster: tcp://host:8786 joins a running scheduler, "
                        "local:N starts N worker processes here (needs bdipole-cl[dask])")
    p.add_argument("--worker-memory", type=_size, metavar="SIZE",
                   help="with --scheduler local:N, each worker's memory limit (e.g. 1G)")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="bdipole-cl", description=__doc__.split("\n")[0],
        epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_global_args(parser, None)
    common = argparse.ArgumentParser(add_help=False)
    add_global_args(common, argparse.SUPPRESS)   # after the command too, not overriding
    sub = parser.add_subparsers(dest="command", required=True)
    command = functools.partial(sub.add_parser, parents=[common])
    p = command("devices", help="list OpenCL devices and the one in use")
    p.set_defaults(func=_cmd_devices)

    p = command("demo", help="make a built-in example and run the main jobs on it")
    p.add_argument("--dir", default="bdipole_demo", help="folder for inputs and results")
    p.add_argument("--no-progress", action="store_true")
    p.set_defaults(func=_cmd_demo)

    p = command("crosscheck",
                       help="every kernel (or your own OpenCL function) vs the float64 reference")
    p.add_argument("--eta", type=_floats, default=(1.0, 1.4, 2.5),
                   help="etas to sweep (comma list)")
    p.add_argument("--n", type=_positive_int, default=500,
                   help="points per sweep segment (user kernels: per Rd range)")
    p.add_argument("--user-kernel", help="an OpenCL C file with your function")
    p.add_argument("--function",
                   help="its name (signatures: bdipole_cl/apps/user_kernel.py, README)")
    p.add_argument("--all-devices", action="store_true",
                   help="run the built-in checks on every working device, in one table")
    p.add_argument("--against", choices=("rd", "profile", "invert", "invert-rho",
                                         "invert-both"),
                   help="what it computes: rd(alpha', 2C1, 3C2), profile(r, alpha', sigma_t', "
                        "2C1, 3C2), invert(Rd, 2C1, 3C2) -> alpha', invert-rho -> rho, or "
                        "invert-both(Rd, 2C1, 3C2, float *alpha', float *rho)")
    p.add_argument("--timeout", type=_positive_float, default=120.0,
                   help="seconds a user kernel's run may take before it is stopped")
    p.set_defaults(func=_cmd_crosscheck)

    p = command("plan", help="what a scene's bake computes and leaves out, per job")
    p.add_argument("scene", help="scene file (TOML)")
    p.add_argument("--json", action="store_true", help="the plan as JSON")
    p.add_argument("--force", action="store_true", help="plan every job, up to date or not")
    p.set_defaults(func=_cmd_plan)

    p = command("bake", help="run a scene's plan: only what is needed, only what changed")
    p.add_argument("scene", help="scene file (TOML)")
    p.add_argument("--force", action="store_true", help="rebuild every output")
    p.add_argument("--no-progress", action="store_true", help="no line per job")
    _add_scheduler_args(p)
    p.set_defaults(func=_cmd_bake)

    p = command("report", help="error against run time for every method (md, csv, png)")
    p.add_argument("-o", "--output", default="report_out", help="folder for the report")
    p.add_argument("--n", type=int, default=1 << 20, help="albedos in the inversion workload")
    p.add_argument("--blur-size", type=int, default=512, help="side of the blur workload")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--write-choice", metavar="PATH",
                   help="also write every measured configuration as method='auto' choice data "
                        "(JSON; use it with BDIPOLE_CL_CHOICE_DATA=PATH)")
    p.set_defaults(func=_cmd_report)

    p = command("blur", help="blur an irradiance map with the Better Dipole profile R(r)")
    p.add_argument("input", help="irradiance image (EXR/TIFF/PNG...)")
    p.add_argument("-o", "--output", required=True, help="output EXR")
    p.add_argument("--albedo",
                   help="Rd: one value, per channel 'r,g,b', or a texture (texture-varying)")
    p.add_argument("--mfp", help="mean free path ld = 1/mu_tr, same unit as "
                                 "--texel-size; value(s) or a texture")
    p.add_argument("--alpha-prime", help="alpha': value(s) or a texture (instead of "
                                         "--albedo/--mfp)")
    p.add_argument("--sigma-t", help="sigma_t', 1/unit: value(s) or a texture (with "
                                     "--alpha-prime)")
    p.add_argument("--eta", type=_floats, default=(1.4,), help="one or per channel 'r,g,b'")
    p.add_argument("--texel-size", type=_positive_float, default=1.0,
                   help="world size of a texel")
    p.add_argument("--tol", type=_fraction, default=1e-3, help="energy left out, relative to Rd")
    p.add_argument("--method", default="auto", choices=("auto", "direct", "gaussians", "fft"))
    p.add_argument("--border", default="clamp", choices=("clamp", "zero", "wrap"))
    p.add_argument("--on-invalid", default="raise", choices=POLICIES,
                   help="NaN/Inf irradiance or parameter texels out of range: fail, or clamp "
                        "(irradiance: unlit, 0; parameters: into their valid range)")
    p.add_argument("--exact", action="store_true", help="exact Fresnel moments")
    p.add_argument("--colorspace", default="auto", type=colorspace_arg,
                   help="colour space of the irradiance and an albedo texture (auto: as "
                        "declared, else as for invert); mfp is never converted")
    p.add_argument("--half", action="store_true")
    p.add_argument("--max-memory", type=_size, default="256M",
                   help="host memory for bands of rows (each with a halo of the radius)")
    _add_scheduler_args(p)
    p.set_defaults(func=_cmd_blur)

    p = command(
        "invert", help="albedo (+ mfp) textures -> scattering-coefficient EXRs",
        epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("inputs", nargs="+", help="albedo files, globs or <UDIM> patterns")
    p.add_argument("--mfp", default="1",
                   help="mean free path ld = 1/mu_tr: constant(s) 'v' or 'r,g,b', or a texture "
                        "path/pattern ({stem}, {dir}, <UDIM>) (default 1)")
    p.add_argument("--unit", default="mm", help="length unit of the mfp (default mm)")
    p.add_argument("--mfp-scale", type=float, default=1.0, help="multiplies mfp values")
    p.add_argument("--eta", type=_floats, default=(1.4,),
                   help="relative IOR, one or per channel 'r,g,b'")
    p.add_argument("--outputs", type=_output_list, default="sigma_a,sigma_s",
                   help="comma list from alpha, rho, sigma_a, sigma_s, sigma_t")
    p.add_argument("-o", "--output", default="{dir}/{stem}.bdipole.exr",
                   help="output path pattern: {dir} {stem} {name} {udim} <UDIM>")
    p.add_argument("--half", action="store_true", help="write half floats")
    p.add_argument("--colorspace", default="auto", type=colorspace_arg,
                   help="colour space of the albedo files (auto: as each declares, else sRGB "
                        "for 8-bit, the working space for 16-bit/float); mfp never converted")
    p.add_argument("--alpha", default="keep", choices=("keep", "drop"),
                   help="alpha channel: copied through or dropped (never inverted)")
    p.add_argument("--on-invalid", default="raise", choices=POLICIES,
                   help="NaN/Inf/>=1 albedo or bad mfp texels: fail the file, or clamp")
    p.add_argument("--max-memory", type=_size, default="256M",
                   help="host memory per file (e.g. 512M)")
    p.add_argument("-j", "--jobs", type=_positive_int, default=1,
                   help="files processed at once")
    p.add_argument("--skip-existing", action="store_true",
                   help="skip files whose output is newer than their inputs")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--double", action="store_true",
                   help="compute in float64 (devices with cl_khr_fp64); written as float/half")
    _add_method_args(p)
    _add_scheduler_args(p)
    p.set_defaults(func=_cmd_invert)
    return parser


def main(argv=None) -> int:
    """Usage errors (bad options or values) exit 2, failures 1, a signal 128 + its number; each
    is one line on stderr, with the traceback only under --debug."""
    args = build_parser().parse_args(argv)
    from ..device import DeviceError, use_device
    from ..io.images import TextureError
    try:
        if args.device:
            use_device(args.device)
        return args.func(args)
    except KeyboardInterrupt:
        if args.debug:
            raise
        print("interrupted", file=sys.stderr)
        return 130
    except Exception as exc:
        if args.debug:
            raise
        usage = isinstance(exc, ValueError) and not isinstance(exc, TextureError)
        expected = isinstance(exc, (ValueError, DeviceError, TextureError, OSError))
        kind = "" if expected else f"{type(exc).__name__}: "
        hint = "" if expected else " (an unexpected error: rerun with --debug for the traceback)"
        text = " ".join(str(exc).split()) if not isinstance(exc, DeviceError) else str(exc)
        print(f"bdipole-cl {args.command}: error: {kind}{text}{hint}", file=sys.stderr)
        return 2 if usage else 1


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
