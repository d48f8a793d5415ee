"""``bdipole-cl``: command-line entry point (a thin layer over the Python API)."""
from __future__ import annotations

import argparse
import functools
import os
import sys
import warnings

from ..device.numerics import NUMERICS
from ..errors import POLICIES
from ..io.targets import DEFAULT_TARGETS, TARGET
from ..methods.registry import ALPHA_CHANNEL, BLUR_METHODS, BORDERS, CHART_BORDERS
from ..signals import SignalStop, Terminated, end_startup, terminate_raises
from ..version import __version__
from .cli_blur import cmd_blur
from .cli_crosscheck import cmd_crosscheck
from .cli_options import (add_global_args, add_method_args, add_scheduler_args, cluster_client,
                          colorspace_arg, method_knobs)
from .cli_types import (Parser, add_texture_arg, constant_or_texture, floats, fraction,
                        length_unit, output_list, output_pattern, positive_float,
                        positive_int, size, spelling_of, target_list)
from .user_kernel import SIGNATURES

DESCRIPTION = """\
Better Dipole subsurface scattering (d'Eon 2012) with Hery's albedo inversion, on OpenCL:
invert albedo (+ mean free path) textures into scattering coefficients, blur irradiance maps
with the diffusion profile, plan and bake whole scenes, and check every kernel against a
float64 reference. Outputs are OpenEXR, written atomically and verified; inputs are never
overwritten. Run `bdipole-cl COMMAND --help` for a command's options."""

EPILOG = """examples:
  bdipole-cl demo                                   # built-in example, writes ./bdipole_demo
  bdipole-cl plan scene.toml                        # what a bake computes and leaves out
  bdipole-cl bake scene.toml                        # run it (only what changed)
  bdipole-cl devices
  bdipole-cl invert diffuse.<UDIM>.exr --mfp mfp.<UDIM>.exr --eta 1.4 -o out/{stem}_coeffs.exr
  bdipole-cl invert skin_<UVTILE>.exr --mfp 1.2,0.6,0.3 --texture -o out/skin.<UDIM>.exr
  bdipole-cl invert 'textures/*.tif' --mfp 1.2,0.6,0.3 --unit mm --half --jobs 2
  bdipole-cl --working-space ACEScg invert albedo.png --mfp 1.2,0.6,0.3   # docs/colour.md
  bdipole-cl crosscheck                             # every kernel vs the float64 reference
  bdipole-cl crosscheck --user-kernel mine.cl --function computeRd --against rd
  bdipole-cl blur irradiance.exr --albedo 0.8,0.6,0.4 --mfp 1.2,0.6,0.3 --texel-size 0.1 -o sss.exr
"""


def _finish(report, stop) -> int:
    """Print a batch's summary; its exit code (128 + the signal if one stopped it)."""
    print(report.summary())
    if stop.exit_code:
        print(f"interrupted by signal {stop.signum}: finished files kept, unfinished ones not "
              f"written", file=sys.stderr)
        return stop.exit_code
    return report.exit_code


def _cmd_invert(args) -> int:
    from ..jobs.batch import check_scaled_mfp, parse_constant
    # a constant --mfp x --mfp-scale out of range is a usage error whatever --on-invalid (a
    # constant is the user's option, no texel: the API's on_invalid="clamp" clamps it)
    check_scaled_mfp(parse_constant(args.mfp, "mfp"), float(args.mfp_scale))
    if args.scheduler:
        from ..cluster import ClusterStartError
        from ..dask import file_runner, not_started_runner
        try:
            with cluster_client(args) as client:
                return _invert(args, file_runner(client, device=args.device,
                                                 progress=not args.no_progress))
        except ClusterStartError as exc:     # every file fails, named, in the summary
            print(f"bdipole-cl {args.command}: error: {exc}", file=sys.stderr)
            return _invert(args, not_started_runner(exc.short))
    return _invert(args, None)


def _invert(args, run_files) -> int:
    from ..jobs.batch import process_textures
    stop = SignalStop().install()
    report = process_textures(
        args.inputs, mfp=args.mfp, eta=args.eta, output=args.output, cancel=stop.event,
        outputs=args.outputs, method=args.method,
        model=args.model, exact=args.exact, half=args.half, colorspace=args.colorspace,
        working_space=args.working_space,
        alpha=args.alpha, on_invalid=args.on_invalid, max_memory=args.max_memory,
        jobs=args.jobs, skip_existing=args.skip_existing, unit=args.unit, double=args.double,
        mfp_scale=args.mfp_scale, mfp_kind=args.mfp_kind,
        progress=not args.no_progress and run_files is None,
        run_files=run_files, texture=args.texture, force=args.force, **method_knobs(args))
    return _finish(report, stop)


def _cmd_plan(args) -> int:
    from ..jobs.scene import load
    plan = load(args.scene, args.working_space, args.target).plan(
        force=args.force, max_memory=args.max_memory)
    print(plan.to_json() if args.json else plan.describe())
    return 0


def _cmd_bake(args) -> int:
    from ..jobs.scene import load
    from ..signals import Stopped
    stop = SignalStop().install()
    try:
        plan = load(args.scene, args.working_space, args.target).plan(
            force=args.force, max_memory=args.max_memory)
    except Stopped:
        print(f"interrupted by signal {stop.signum} while planning: nothing written",
              file=sys.stderr)
        return stop.exit_code
    if stop.exit_code:                  # stopped as the plan finished: nothing started
        print(f"interrupted by signal {stop.signum} before any job: nothing written",
              file=sys.stderr)
        return stop.exit_code
    if args.preview:                        # its pictures land on no file of the run
        from .bake_page import preview_clashes
        clashes, page_clash = preview_clashes(plan, force=args.force)
        if page_clash:                      # the page is the run's own: a usage error
            raise ValueError(page_clash)
        for i, clash in clashes.items():    # a sheet: its job cannot run, the others do
            plan.jobs[i].problem, plan.jobs[i].up_to_date = clash, False
    for problem in plan.missing:            # every missing input, before any work starts
        print(f"cannot run: {problem}", file=sys.stderr)
    bar = None
    if not args.no_progress and not args.scheduler:
        from tqdm import tqdm
        bar = tqdm(total=len(plan.jobs), unit="job", desc="bake", disable=None)

    def progress(job, result):
        if bar is not None:
            bar.write(f"{result.status:9s} {job.kind} {job.name}"
                      + (f" [{job.udim}]" if job.udim else "") + f" -> {job.output}")
            bar.update(1)

    if args.scheduler:
        from ..cluster import ClusterStartError
        from ..dask import bake_on_cluster, not_started
        try:
            with cluster_client(args) as client:
                report = bake_on_cluster(plan, client, device=args.device,
                                         progress=not args.no_progress,
                                         max_memory=args.max_memory)
        except ClusterStartError as exc:     # every job to run fails, named, in the summary
            print(f"bdipole-cl {args.command}: error: {exc}", file=sys.stderr)
            report = not_started(plan, exc.short)
    else:
        try:
            report = plan.run(cancel=stop.event, progress=progress,
                              max_memory=args.max_memory)
        finally:
            if bar is not None:
                bar.close()
    code = _finish(report, stop)
    if args.preview and not stop.exit_code:
        from .bake_page import bake_preview
        try:
            pictures = bake_preview(plan, report, force=args.force)
            print(pictures.describe())
            code = code or int(bool(pictures.failed))     # a sheet not drawn fails the bake
        except Stopped:
            print(f"interrupted by signal {stop.signum} during the previews: the sheets "
                  f"written so far are whole, the others and the page not written",
                  file=sys.stderr)
            return stop.exit_code
    return stop.exit_code or code             # a stop as the last picture was written


def _cmd_report(args) -> int:
    """The report or the calibration; SIGTERM ends it as SIGINT does (its files are each
    written whole: nothing half-written is left), exit 128 + the signal."""
    from .report import calibrate, check_report_outputs, run_report
    with terminate_raises():
        if args.calibrate:
            if args.write_choice:
                raise ValueError("--calibrate stores this device's data in the user's cache; "
                                 "--write-choice goes with a report, not with it")
            calibrate()
            return 0
        check_report_outputs(args.output, args.write_choice, args.force)
        run_report(args.output, n=args.n, blur_size=args.blur_size, repeats=args.repeats,
                   write_choice_to=args.write_choice, force=args.force)
    return 0


def _cmd_demo(args) -> int:
    from .demo import run_demo
    return run_demo(args.dir, progress=not args.no_progress)


def _scene_command(command, name, text, force_help, memory_help):
    """A command on a scene: its file, --force and --max-memory."""
    p = command(name, help=text)
    p.add_argument("scene", help="scene file (TOML), USD stage (.usda, .usd, .usdc, .usdz) or "
                                 "MaterialX document (.mtlx)")
    p.add_argument("--force", action="store_true", help=force_help)
    p.add_argument("--max-memory", type=size, default="256M", help=memory_help)
    p.add_argument("--target", type=target_list, default=None,
                   help=f"material networks to write, a comma list of "
                        f"{', '.join(TARGET.names)} (default: each material's targets, else "
                        f"{','.join(DEFAULT_TARGETS)}; docs/materials.md)")
    return p


def build_parser() -> argparse.ArgumentParser:
    parser = Parser(prog="bdipole-cl", description=DESCRIPTION, epilog=EPILOG)
    parser.add_argument("--version", action="version", version=f"bdipole-cl {__version__}")
    add_global_args(parser, None)
    common = argparse.ArgumentParser(add_help=False)
    add_global_args(common, argparse.SUPPRESS)   # after the command too, not overriding
    sub = parser.add_subparsers(dest="command", required=True)
    command = functools.partial(sub.add_parser, parents=[common])
    from . import devices, stretch
    devices.add_command(command)
    stretch.add_command(command)

    p = command("demo", help="make a built-in example and run the main jobs on it")
    p.add_argument("--dir", default="bdipole_demo", help="folder for inputs and results")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.set_defaults(func=_cmd_demo)

    p = command("crosscheck",
                       help="every kernel (or your own OpenCL function) vs the float64 reference")
    p.add_argument("--eta", type=floats, default=(1.0, 1.4, 2.5),
                   help="etas to sweep (comma list)")
    p.add_argument("--n", type=positive_int, default=500,
                   help="points per sweep segment (user kernels: per Rd range)")
    p.add_argument("--user-kernel", help="an OpenCL C file with your function")
    p.add_argument("--function",
                   help="its name (signatures: bdipole_cl/apps/user_kernel.py, docs/cli.md)")
    p.add_argument("--all-devices", action="store_true",
                   help="run the built-in checks on every working device, in one table")
    p.add_argument("--against", choices=tuple(SIGNATURES),
                   help="what it computes: rd(alpha', 2C1, 3C2), profile(r, alpha', sigma_t', "
                        "2C1, 3C2), invert(Rd, 2C1, 3C2) -> alpha', invert-rho -> rho, or "
                        "invert-both(Rd, 2C1, 3C2) -> alpha' and rho through two float "
                        "pointers")
    p.add_argument("--timeout", type=positive_float, default=120.0,
                   help="seconds a user kernel's run may take before it is stopped")
    p.add_argument("--numerics", default=NUMERICS.names[0], type=spelling_of(NUMERICS),
                   choices=NUMERICS.names,
                   help="the float32 arithmetic the built-in kernels are built for: the "
                        "device's own, or a GPU's on any device: ftz (subnormals flushed to "
                        "zero), inexact (sqrt and division off by up to 2 ulps), gpu (both; "
                        "docs/numerics.md)")
    p.set_defaults(func=cmd_crosscheck)

    p = _scene_command(command, "plan", "what a scene's bake computes and leaves out, per job",
                       "plan every job, up to date or not, as if replacing existing outputs "
                       "bdipole-cl did not write",
                       "host memory for the statistics pass's bands of rows")
    p.add_argument("--json", action="store_true", help="the plan as JSON")
    p.set_defaults(func=_cmd_plan)

    p = _scene_command(command, "bake", "run a scene's plan: only what is needed, only what "
                       "changed", "rebuild every output, and replace existing outputs "
                       "bdipole-cl did not write",
                       "host memory per job for bands of rows (e.g. 512M)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar and job lines")
    p.add_argument("--preview", action="store_true",
                   help="a contact sheet beside each output (.preview.png) and one page for the "
                        "bake (scene.preview.png): every material's thumbnails and profile")
    add_scheduler_args(p)
    p.set_defaults(func=_cmd_bake)

    from . import cache, conventions_report, convert, preview, profile
    convert.add_command(command)
    conventions_report.add_command(command)
    preview.add_command(command)
    profile.add_command(command)
    cache.add_command(command)

    p = command("report", help="error against run time for every method (md, csv, png)")
    p.add_argument("-o", "--output", default="report_out", help="folder for the report")
    p.add_argument("--n", type=positive_int, default=1 << 20,
                   help="albedos in the inversion workload")
    p.add_argument("--blur-size", type=positive_int, default=512,
                   help="side of the blur workload (texels)")
    p.add_argument("--repeats", type=positive_int, default=3,
                   help="timed runs per configuration (the fastest is kept)")
    p.add_argument("--write-choice", metavar="PATH",
                   help="also write every measured configuration as method='auto' choice data "
                        "(JSON; use it with BDIPOLE_CL_CHOICE_DATA=PATH)")
    p.add_argument("--calibrate", action="store_true",
                   help="measure this device (a minute or two) and store the data in the user's "
                        "cache ($XDG_CACHE_HOME/bdipole_cl), where method='auto' on this device "
                        "then decides from it")
    p.add_argument("--force", action="store_true",
                   help="replace report files or a --write-choice file bdipole-cl did not write")
    p.set_defaults(func=_cmd_report)

    p = command("blur", help="blur an irradiance map with the Better Dipole profile R(r)")
    p.add_argument("input", help="irradiance image (EXR/TIFF/PNG...)")
    p.add_argument("-o", "--output", required=True, help="output EXR")
    p.add_argument("--force", action="store_true",
                   help="replace an existing -o file that bdipole-cl did not write")
    p.add_argument("--albedo", type=constant_or_texture("albedo"),
                   help="Rd: one value, per channel 'r,g,b', or a texture (texture-varying)")
    p.add_argument("--mfp", type=constant_or_texture("mfp"),
                   help="mean free path ld = 1/mu_tr, same unit as --texel-size; value(s) or "
                        "a texture")
    p.add_argument("--alpha-prime", type=constant_or_texture("alpha"),
                   help="alpha': value(s) or a texture (instead of --albedo/--mfp)")
    p.add_argument("--sigma-t", type=constant_or_texture("sigma_t"),
                   help="sigma_t', 1/unit: value(s) or a texture (with --alpha-prime)")
    p.add_argument("--eta", type=floats, default=(1.4,), help="one or per channel 'r,g,b'")
    p.add_argument("--texel-size", type=positive_float, default=1.0,
                   help="world size of a texel")
    p.add_argument("--stretch", default=None,
                   help="a stretch map (bdipole-cl stretch; a tile pattern with the input's): "
                        "per-texel surface lengths instead of --texel-size (docs/stretch.md)")
    p.add_argument("--charts", default="clamp", choices=CHART_BORDERS,
                   help="with --stretch: at UV chart borders, the chart continued by its edge "
                        "(clamp), nothing beyond it (zero), or charts ignored (none; only then "
                        "does --border apply to a map with charts)")
    p.add_argument("--tol", type=fraction, default=1e-3,
                   help="error bound relative to max(E) * Rd, for any irradiance")
    p.add_argument("--method", default="auto", choices=BLUR_METHODS,
                   help="blur method (auto: the cheapest meeting --tol)")
    p.add_argument("--border", default="clamp", choices=BORDERS,
                   help="texels beyond the image edge: nearest edge texel, zero, or wrapped")
    p.add_argument("--on-invalid", default="raise", choices=POLICIES,
                   help="NaN/Inf irradiance or parameter texels out of range: fail, or clamp "
                        "(irradiance: unlit, 0; parameters: into their valid range)")
    p.add_argument("--exact", action="store_true", help="exact Fresnel moments")
    p.add_argument("--colorspace", default="auto", type=colorspace_arg,
                   help="colour space of the irradiance and an albedo texture (auto: as "
                        "declared, else as for invert); mfp is never converted")
    p.add_argument("--half", action="store_true", help="write half floats")
    add_texture_arg(p)
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--max-memory", type=size, default="256M",
                   help="host memory for bands of rows (each with a halo of the radius)")
    add_scheduler_args(p)
    p.set_defaults(func=cmd_blur)

    p = command(
        "invert", help="albedo (+ mfp) textures -> scattering-coefficient EXRs", epilog=EPILOG)
    p.add_argument("inputs", nargs="+",
                   help="albedo files, globs or tile patterns: <UDIM>, <udim>, $UDIM, "
                        "%%(UDIM)d (1001...), <UVTILE>, <tile>, u<U>_v<V> (u1_v1), <UVTILE0>, "
                        "<uvtile> (u0_v0), ... (docs/tiles.md)")
    p.add_argument("--mfp", default="1", type=constant_or_texture("mfp"),
                   help="mean free path ld = 1/mu_tr: constant(s) 'v' or 'r,g,b', or a texture "
                        "path/pattern ({stem}, {dir}, <UDIM>)")
    p.add_argument("--unit", default="mm", type=length_unit, help="length unit of the mfp")
    p.add_argument("--mfp-scale", type=positive_float, default=1.0, help="multiplies mfp values")
    from ..methods.registry import MFP_KINDS
    p.add_argument("--mfp-kind", default="diffuse", choices=MFP_KINDS,
                   help="what --mfp is: diffuse, ld = 1/mu_tr (Jensen/Hery); extinction, the "
                        "medium's mean free path 1/sigma_t' (OpenPBR, Standard Surface)")
    p.add_argument("--eta", type=floats, default=(1.4,),
                   help="relative IOR, one or per channel 'r,g,b'")
    p.add_argument("--outputs", type=output_list, default="sigma_a,sigma_s",
                   help="comma list from alpha, rho, sigma_a, sigma_s, sigma_t")
    p.add_argument("-o", "--output", default="{dir}/{stem}.bdipole.exr", type=output_pattern(),
                   help="output path pattern: {dir} {stem} {name} {udim} and a tile token "
                        "(may differ from the input's: tiles are converted)")
    p.add_argument("--half", action="store_true", help="write half floats")
    add_texture_arg(p)
    p.add_argument("--colorspace", default="auto", type=colorspace_arg,
                   help="colour space of the albedo files (auto: as each declares, else sRGB "
                        "for 8-bit, the working space for 16-bit/float); mfp never converted")
    p.add_argument("--alpha", default="keep", choices=ALPHA_CHANNEL.names,
                   help="alpha channel: copied through or dropped (never inverted)")
    p.add_argument("--on-invalid", default="raise", choices=POLICIES,
                   help="NaN/Inf/>=1 albedo or bad mfp texels: fail the file, or clamp")
    p.add_argument("--max-memory", type=size, default="256M",
                   help="host memory per file (e.g. 512M)")
    p.add_argument("-j", "--jobs", type=positive_int, default=1,
                   help="files processed at once")
    p.add_argument("--skip-existing", action="store_true",
                   help="skip files whose output is newer than their inputs and was made with "
                        "the same settings")
    p.add_argument("--force", action="store_true",
                   help="replace existing outputs that bdipole-cl did not write")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--double", action="store_true",
                   help="compute in float64 (devices with cl_khr_fp64); written as float/half")
    add_method_args(p)
    add_scheduler_args(p)
    p.set_defaults(func=_cmd_invert)
    return parser


def one_line_warning(message, category, filename, lineno, line=None) -> str:
    """A warning as the CLI shows it: ``bdipole-cl: warning: <message>`` (its kind for
    non-bdipole warnings), without the source line."""
    kind = "" if category.__module__.startswith("bdipole_cl") else f"{category.__name__}: "
    return f"bdipole-cl: warning: {kind}{' '.join(str(message).split())}\n"


def main(argv=None) -> int:
    """Usage errors (bad options or values) exit 2, failures 1, a signal 128 + its number; each
    is one line on stderr, with the traceback only under --debug."""
    args = build_parser().parse_args(argv)
    shown = warnings.formatwarning
    if not args.debug:                # a warning is one line, as an error is (--debug: Python's)
        warnings.formatwarning = one_line_warning
    try:
        return run_command(args)
    finally:                          # a caller's process keeps its own format
        warnings.formatwarning = shown


def run_command(args) -> int:
    """The parsed command, its errors as ``main`` says."""
    from ..device import DeviceError, use_device
    from ..io.images import TextureError
    try:
        end_startup()                 # loaded: the command's own signal handling from here
        check_forced_widths()
        with terminate_raises():      # a command without its own stop checks (preview,
            if args.device and args.command != "devices":      # profile, demo, plan) ends
                use_device(args.device)          # on SIGTERM as on SIGINT: its temporaries
            return args.func(args)               # removed on the way out, exit 143
    except (KeyboardInterrupt, Terminated) as exc:
        if args.debug:
            raise
        print("interrupted", file=sys.stderr)
        return 128 + exc.signum if isinstance(exc, Terminated) else 130
    except Exception as exc:
        if args.debug:
            raise
        usage = isinstance(exc, ValueError) and not isinstance(exc, TextureError)
        expected = isinstance(exc, (ValueError, DeviceError, TextureError, OSError,
                                    ImportError))
        kind = "" if expected else f"{type(exc).__name__}: "
        hint = "" if expected else " (an unexpected error: rerun with --debug for the traceback)"
        text = " ".join(str(exc).split()) if not isinstance(exc, DeviceError) else str(exc)
        print(f"bdipole-cl {args.command}: error: {kind}{text}{hint}", file=sys.stderr)
        return 2 if usage else 1


def check_forced_widths():
    """The kernels' width variables (``BDIPOLE_CL_TABLE_WIDTH``, ``BDIPOLE_CL_GATHER_WIDTH``)
    checked before any work: a bad value is a usage error naming the variable, not a failure
    of each input file that reaches a kernel."""
    from ..device.runtime import forced_width
    from ..methods.choice import GATHER_WIDTHS_ALLOWED, TABLE_WIDTHS_ALLOWED
    from ..ops.blur.dispatch import GATHER_WIDTH_VARIABLE
    from ..ops.inversion_kernel import TABLE_WIDTH_VARIABLE
    forced_width(TABLE_WIDTH_VARIABLE, TABLE_WIDTHS_ALLOWED)
    forced_width(GATHER_WIDTH_VARIABLE, GATHER_WIDTHS_ALLOWED)


#: the exit codes of a command a signal stopped (SIGINT, SIGTERM)
STOPPED_CODES = (130, 143)


def console_main() -> int:
    """The ``bdipole-cl`` command: ``main``, then the process's exit. Where a stop request
    ended the command, or abandoned a texture build that still runs
    (``mipmaps.builds_running``), the process ends at once with the status (``os._exit``,
    streams flushed): the interpreter's teardown would crash under the build, or wait on a
    worker thread the stop caught half-started."""
    from ..io.mipmaps import builds_running
    for stream in (sys.stdout, sys.stderr):   # a file name that is not UTF-8 (Latin-1 from a
        try:                                  # share), or any text the locale cannot encode,
            stream.reconfigure(errors="backslashreplace")    # is printed escaped, not a
        except (AttributeError, ValueError):                 # UnicodeEncodeError
            pass
    rc = main()
    if builds_running() or rc in STOPPED_CODES:
        # a stop can land while a worker thread is being started (a pool's submit), and the
        # interpreter's exit then waits on that thread for ever: once the command has ended
        # (its files closed, temporaries removed), the process ends at once
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(rc)
    return rc


if __name__ == "__main__":  # pragma: no cover
    sys.exit(console_main())
