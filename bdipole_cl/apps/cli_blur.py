"""``bdipole-cl blur``: an irradiance file blurred into an exitance EXR, as one blur job run
by the job runner (``jobs.runner.run_job``), or its bands on a Dask cluster (``--scheduler``).
Usage errors (exit 2) are found before any work; a failed or stopped blur is one line."""
from __future__ import annotations

import contextlib
import sys

from ..signals import SignalStop, Stopped
from .cli_options import cluster_client
from .cli_types import number_list


def parameter(text, what, role, **colour):
    """A blur parameter: numbers ('0.8' or 'r,g,b', in the working space), else the path of
    a texture read as the input ``role`` (``colour``: colorspace= and working= of an albedo
    texture, converted)."""
    values = number_list(text)     # constants were checked at parse time (constant_or_texture)
    if values is not None:
        return values
    else:
        from ..io.images import read_parameter_texture
        return read_parameter_texture(text, what, colour=bool(colour), role=role, **colour)


def blur_job(args, sources):
    """The CLI blur's job: its parameters (constants, or textures read here) and options."""
    from ..io.freshness import input_identities
    from ..jobs.job import BlurWork, Job
    from ..ops.blur import Scattering
    inputs = {"irradiance": args.input, **sources}
    if getattr(args, "stretch", None):
        inputs["stretch"] = args.stretch
    identities = input_identities(inputs)      # before the first read (of a parameter)
    stretch = None
    if getattr(args, "stretch", None):
        from ..io.stretch_maps import read_stretch
        stretch = read_stretch(args.stretch)
    if args.alpha_prime is not None:
        scattering = Scattering(
            alpha_prime=parameter(args.alpha_prime, "alpha' (--alpha-prime)", "alpha"),
            sigma_t=parameter(args.sigma_t, "sigma_t' (--sigma-t)", "sigma_t"),
            eta=args.eta, texel_size=args.texel_size, stretch=stretch)
    else:
        scattering = Scattering(
            parameter(args.albedo, "albedo (--albedo)", "albedo", colorspace=args.colorspace,
                      working=args.working_space),
            parameter(args.mfp, "mfp (--mfp)", "mfp"), args.eta, args.texel_size,
            stretch=stretch)
    work = BlurWork(scattering, tol=args.tol, method=args.method, border=args.border,
                    exact=args.exact, on_invalid=args.on_invalid, half=args.half,
                    texture=args.texture, colorspace=args.colorspace,
                    working=args.working_space, max_memory=args.max_memory,
                    charts=getattr(args, "charts", "clamp"))
    return Job("blur", args.input, args.output, inputs, work, identities=identities)


#: the options of the blur that may name a texture: filled per tile of a tile pattern
TEXTURE_OPTIONS = ("albedo", "mfp", "alpha_prime", "sigma_t", "stretch")


def cmd_blur(args) -> int:
    """One irradiance file, or each tile of a tile pattern (``irr.<UDIM>.exr -o
    out.<UDIM>.exr``, the tokens of ``io.tiles``; parameter textures filled per tile): a
    tile's failure is its own line, the others run."""
    import argparse
    import os

    from ..io import tiles
    from ..io.patterns import companion_path, outputs_of
    patterned = tiles.has_tokens(args.output) or (tiles.is_pattern(args.input)
                                                  and not os.path.exists(args.input))
    if not patterned:
        return blur_one(args)
    code = 0
    rows = outputs_of([args.input], args.output, lambda p: p)
    stretch = getattr(args, "stretch", None)
    if stretch and len(rows) > 1 and not tiles.is_pattern(stretch):
        print(f"bdipole-cl blur: error: --stretch {stretch} is one tile's map, and "
              f"{args.input} names {len(rows)} tiles: give a tile pattern "
              f"(stretch.<UDIM>.exr), each tile's lengths its own", file=sys.stderr)
        return 2
    for path, tile, out, err in rows:
        one = argparse.Namespace(**vars(args))
        one.input, one.output = path, out
        try:
            for key in TEXTURE_OPTIONS:
                value = getattr(args, key)
                if value is not None and number_list(value) is None:
                    setattr(one, key, companion_path(value, path, tile))
        except (ValueError, tiles.TileError) as exc:
            err = err or str(exc)
        if err is not None:
            print(f"bdipole-cl {args.command}: error: {err}", file=sys.stderr)
            code = max(code, 1)
            continue
        code = max(code, blur_one(one))
        if code >= 128:                           # a stop: the other tiles are not begun
            break
    return code


def blur_one(args) -> int:
    from ..io.collisions import Claim, check_claim
    from ..io.images import TextureError, check_output_format
    from ..jobs import runner
    from ..jobs.blur_file import clamped_text
    if args.alpha_prime is None and (args.albedo is None or args.mfp is None):
        print("bdipole-cl blur: error: give --albedo and --mfp (values or textures), or "
              "--alpha-prime and --sigma-t", file=sys.stderr)
        return 2
    if args.alpha_prime is not None and args.sigma_t is None:
        print("bdipole-cl blur: error: --alpha-prime needs --sigma-t", file=sys.stderr)
        return 2
    if (args.alpha_prime is None) != (args.sigma_t is None) or (
            args.alpha_prime is not None and (args.albedo is not None or args.mfp is not None)):
        print("bdipole-cl blur: error: give --albedo and --mfp, or --alpha-prime and "
              "--sigma-t, not both pairs", file=sys.stderr)
        return 2
    from ..physics.fresnel import check_eta
    check_eta(args.eta, args.exact)   # the model's range: a usage error before any file
    sources = {name: v for name, v in (("albedo", args.albedo), ("mfp", args.mfp),
                                       ("alpha", args.alpha_prime), ("sigma_t", args.sigma_t))
               if v is not None and number_list(v) is None}
    check_output_format(args.output)            # usage errors (exit 2) before any work
    check_claim(Claim(args.input, args.output, {"irradiance": args.input, **sources}),
                args.force)
    if getattr(args, "stretch", None) and args.texel_size != 1.0:
        print(f"bdipole-cl blur: error: --texel-size {args.texel_size:g} with --stretch: the "
              f"stretch map gives each texel's lengths; leave --texel-size out",
              file=sys.stderr)
        return 2
    if args.scheduler and getattr(args, "stretch", None):     # before any device or cluster
        print("bdipole-cl blur: error: --stretch with --scheduler: the cluster blurs bands of "
              "rows, and a stretched blur reads the whole image at once; blur without "
              "--scheduler, or bake a scene on the cluster (each tile its own job)",
              file=sys.stderr)
        return 2
    stop = SignalStop().install()
    if args.scheduler:
        return blur_on_cluster(args, sources, stop)
    try:
        job = blur_job(args, sources)
    except TextureError as exc:
        print(f"bdipole-cl {args.command}: error: {exc}", file=sys.stderr)
        return 1
    with texel_bar(args.input, "blur", not args.no_progress) as bar:
        result = runner.run_job(job, cancel=stop.event, progress=bar)
    if result.status != "ok":
        print(f"bdipole-cl {args.command}: error: {result.error}", file=sys.stderr)
        return (stop.exit_code or 1) if result.status == "cancelled" else 1
    info = result.info
    for c in (info.channels if info is not None else ()):
        rd = f"Rd {c.rd:.4f}" if c.rd is not None else "Rd per texel"
        print(f"channel {c.channel}: {c.method}, radius {c.radius} texels, {rd}, "
              f"error <= {c.error_bound:.1e} x max(E) x Rd")
    texels = result.texels
    clamped = clamped_text(result.invalid)
    print(f"wrote {args.output}: {texels} texels in {result.seconds:.2f} s "
          f"({texels / max(result.seconds, 1e-9) / 1e6:.3g} Mtexel/s)"
          + (f", {clamped}" if clamped else ""))
    return stopped_after_writing(stop, args.output)


def stopped_after_writing(stop, output) -> int:
    """0, or where a stop signal came while the last write finished (the output complete and
    verified), 128 + the signal, said: a stopped command never exits 0."""
    if not stop.exit_code:
        return 0
    print(f"interrupted by signal {stop.signum} as {output} was written: it is complete",
          file=sys.stderr)
    return stop.exit_code


def blur_on_cluster(args, sources, stop) -> int:
    """``bdipole-cl blur --scheduler``: the bands of one blur as cluster tasks."""
    from ..cluster import ClusterStartError
    from ..dask import blur_file_on_cluster
    from ..io.images import Cancelled, TextureError
    from ..jobs.blur_file import clamped_text
    job = blur_job(args, sources)
    s = job.work.scattering
    if s.textured:
        print("bdipole-cl blur: error: --scheduler takes constant parameters (one value or one "
              "per channel); with parameter textures, blur without --scheduler",
              file=sys.stderr)
        return 2
    clamped = {}
    try:
        with cluster_client(args) as client:
            n = blur_file_on_cluster(args.input, args.output, client, half=args.half,
                                     clamped=clamped, identities=job.identities,
                                     max_memory=args.max_memory, device=args.device,
                                     texture=args.texture, colorspace=args.colorspace,
                                     working_space=args.working_space, albedo=s.albedo,
                                     mfp=s.mfp, eta=s.eta, texel_size=s.texel_size,
                                     alpha=s.alpha_prime, sigma_t=s.sigma_t, tol=args.tol,
                                     method=args.method, border=args.border,
                                     on_invalid=args.on_invalid, exact=args.exact,
                                     progress=not args.no_progress, force=args.force)
    except TextureError as exc:
        print(f"bdipole-cl {args.command}: error: {exc}", file=sys.stderr)
        return (stop.exit_code or 1) if isinstance(exc, Cancelled) else 1
    except ClusterStartError as exc:    # the one job, named: nothing written
        print(f"bdipole-cl {args.command}: error: {args.input}: not blurred, nothing written: "
              f"{exc}", file=sys.stderr)
        return 1
    except Stopped:                     # while the cluster started or the blur was planned
        print(f"bdipole-cl {args.command}: interrupted: nothing written", file=sys.stderr)
        return stop.exit_code or 130
    clamped = clamped_text(clamped)
    print(f"{n} bands blurred on the cluster; wrote {args.output}"
          + (f", {clamped}" if clamped else ""))
    return stopped_after_writing(stop, args.output)


@contextlib.contextmanager
def texel_bar(path, desc, enabled):
    """A tqdm bar over ``path``'s texels (None when disabled)."""
    if not enabled:
        yield None
        return
    from tqdm import tqdm

    from ..io.images import texel_count
    with tqdm(total=texel_count(path), unit="texel", unit_scale=True, desc=desc,
              disable=None) as bar:                 # None: shown on a terminal only
        yield bar
