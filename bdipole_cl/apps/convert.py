"""``bdipole-cl convert``: texture sets from one renderer's subsurface convention to another's
(docs/conventions.md), a thin layer over ``jobs.convert_file.convert_textures``."""
from __future__ import annotations

from ..errors import POLICIES
from ..methods.registry import ALPHA_CHANNEL
from ..physics.conventions import CONVENTION
from .cli_options import colorspace_arg
from .cli_types import (add_texture_arg, constant_or_texture, floats, length_unit,
                        output_pattern, positive_float, positive_int, size, spelling_of)

EPILOG = """examples:
  bdipole-cl convert skin.<UDIM>.exr --radius 1.2,0.6,0.3 --source pxrsurface --target openpbr
  bdipole-cl convert skin.exr --radius {stem}_dmfp.exr --target cycles-random-walk --eta 1.4
  bdipole-cl convert skin.exr --radius 1 --target random-walk -o out/{stem}.medium.exr
  bdipole-cl conventions                           # what each convention means and renders
"""


def add_command(command):
    """Add ``convert`` to the CLI (``command``: the subparsers' add_parser)."""
    names = ", ".join(CONVENTION.spellings)
    p = command("convert", help="texture sets from one renderer's subsurface convention to "
                                "another's (same reflectance, same spread)", epilog=EPILOG)
    p.add_argument("inputs", nargs="+",
                   help="colour files, globs or tile patterns (<UDIM>, <UVTILE>, ...)")
    p.add_argument("--radius", default="1", type=constant_or_texture("radius"),
                   help="the source's radius: constant(s) 'v' or 'r,g,b', or a texture "
                        "path/pattern ({stem}, {dir}, <UDIM>)")
    p.add_argument("--radius-scale", type=positive_float, default=1.0,
                   help="multiplies radius values")
    p.add_argument("--source", default="better-dipole", type=spelling_of(CONVENTION),
                   choices=CONVENTION.names, metavar="CONVENTION",
                   help=f"the textures' convention: {names}")
    p.add_argument("--target", default="van-de-hulst", type=spelling_of(CONVENTION),
                   choices=CONVENTION.names, metavar="CONVENTION",
                   help="the convention to write (random-walk: the medium's single-scattering "
                   "albedo and mean free path 1/sigma_t)")
    p.add_argument("--eta", type=floats, default=(1.4,),
                   help="relative IOR of the surface, one or per channel 'r,g,b'")
    p.add_argument("--g", type=float, default=0.0,
                   help="HG mean cosine of the walks (default 0): 0..0.8, the Monte Carlo "
                   "spread table's range (Cycles' conventions clamp it to 0..0.9 first)")
    p.add_argument("--unit", default="mm", type=length_unit, help="length unit of the radius")
    p.add_argument("-o", "--output", default="{dir}/{stem}.{target}.exr",
                   type=output_pattern("target"),
                   help="output path pattern: {dir} {stem} {name} {target} and a tile token; "
                        "channels colour.* and radius.* (random-walk: sigma_a.*, sigma_s.*, "
                        "per unit)")
    p.add_argument("--half", action="store_true", help="write half floats")
    add_texture_arg(p)
    p.add_argument("--colorspace", default="auto", type=colorspace_arg,
                   help="colour space of the colour files (auto: as each declares, else sRGB "
                        "for 8-bit, the working space otherwise); radius never converted")
    p.add_argument("--alpha", default="keep", choices=ALPHA_CHANNEL.names,
                   help="alpha channel: copied through or dropped")
    p.add_argument("--on-invalid", default="raise", choices=POLICIES,
                   help="colour outside [0, 1], radius not > 0, or a reflectance the target "
                        "cannot render: fail the file, or clamp and count")
    p.add_argument("--max-memory", type=size, default="256M",
                   help="host memory per file (e.g. 512M)")
    p.add_argument("-j", "--jobs", type=positive_int, default=1, help="files at once")
    p.add_argument("--force", action="store_true",
                   help="replace existing outputs that bdipole-cl did not write")
    p.set_defaults(func=_cmd_convert)


def _cmd_convert(args) -> int:
    from ..io.colour import resolve_working_space
    from ..jobs.convert_file import convert_textures
    from ..jobs.convert_materials import convert_materials
    from ..jobs.results import BatchReport
    from ..signals import SignalStop
    stop = SignalStop().install()
    report = convert_textures(
        args.inputs, radius=args.radius, source=args.source, target=args.target,
        eta=args.eta, g=args.g, output=args.output, half=args.half,
        colorspace=args.colorspace, working_space=args.working_space, alpha=args.alpha,
        on_invalid=args.on_invalid, max_memory=args.max_memory, jobs=args.jobs,
        unit=args.unit, radius_scale=args.radius_scale, texture=args.texture,
        force=args.force, cancel=stop.event)
    report = BatchReport(report.results + convert_materials(
        args.inputs, args.output, CONVENTION.canonical(args.target), args.eta, args.unit,
        resolve_working_space(args.working_space).name, report.results, args.texture))
    print(report.summary())
    if stop.exit_code:
        return stop.exit_code
    return report.exit_code
