"""The option groups of ``bdipole-cl`` (applications layer): the global options every command
takes before or after it (``--device``, ``--working-space``, ``--debug``), the colour-name
argument types (docs/colour.md), and the groups several commands share (inversion method,
cluster). Every choice comes from its registry, never retyped."""
from __future__ import annotations

import argparse
import contextlib

from ..methods.registry import METHOD_OR_AUTO
from ..physics.models import MODEL
from .cli_types import size, spelling_of


def working_space_arg(text):
    """A working space of the active OCIO config (an argparse type: an unknown name is a
    usage error listing the known ones)."""
    from ..io.colour import resolve_working_space
    if not text.strip():          # an empty name would silently be the default
        raise argparse.ArgumentTypeError("an empty name; give a colour space of the config, "
                                         "e.g. ACEScg (leave the option out for the default)")
    try:
        return resolve_working_space(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def colorspace_arg(text):
    """"auto" or a colour space of the active OCIO config (an argparse type)."""
    from ..io.colour import check_colorspace
    try:
        check_colorspace(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return text


def add_global_args(p, default):
    """The global options on ``p``: ``default`` None on the main parser, SUPPRESS on each
    command's (so that one given before the command is kept when not repeated after it)."""
    p.add_argument("--device", metavar="SPEC", default=default,
                   help="OpenCL device: P:D as listed by `devices`, or part of its platform "
                        "or name ('intel', 'pocl'); default: the automatic choice")
    p.add_argument("--working-space", metavar="NAME", type=working_space_arg, default=default,
                   help="the colour space albedo and irradiance are converted into and every "
                        "output is in: a scene-linear space of the OCIO config ($OCIO, else "
                        "ocio://default), e.g. ACEScg; default: $OCIO's scene_linear role, else "
                        "lin_rec709_scene (scenes: entries without working_space)")
    p.add_argument("--debug", action="store_true",
                   default=False if default is None else default, help="show tracebacks")


def add_method_args(p):
    """The inversion method and its knobs (``invert``)."""
    p.add_argument("--method", default="table", choices=METHOD_OR_AUTO.names,
                   help="inversion method (auto: the cheapest meeting --tol in rho)")
    p.add_argument("--model", default="better", type=spelling_of(MODEL), choices=MODEL.names,
                   help="Better Dipole (memo; also spelled better-dipole, as in scene files) "
                        "or Jensen's classical dipole")
    p.add_argument("--exact", action="store_true",
                   help="exact Fresnel moments (quadrature) instead of d'Eon's fits")
    p.add_argument("--iterations", type=int, help="bisection/memo iterations, secant maximum")
    p.add_argument("--tol", type=float,
                   help="secant relative tolerance; with --method auto, the rho accuracy")
    p.add_argument("--table-size", type=int, help="table intervals per segment (256 if not given)")
    p.add_argument("--polish", type=int, help="Newton steps after the table lookup")
    p.add_argument("--seed-size", type=int, help="secant seed table intervals (16 if not given)")


def method_knobs(args):
    """The knobs given on the command line (None: the method's default)."""
    return {k: getattr(args, k) for k in ("iterations", "tol", "table_size", "polish",
                                          "seed_size") if getattr(args, k) is not None}


def add_scheduler_args(p):
    """``--scheduler`` and ``--worker-memory`` (the commands that run on a Dask cluster)."""
    p.add_argument("--scheduler", metavar="ADDRESS", type=scheduler_address,
                   help="run on a Dask cluster: tcp://host:8786 joins a running scheduler, "
                        "local:N starts N worker processes here (needs bdipole-cl[dask])")
    p.add_argument("--worker-memory", type=size, metavar="SIZE",
                   help="with --scheduler local:N, each worker's memory limit (e.g. 1G)")


def scheduler_address(text: str) -> str:
    """``--scheduler``'s value: not empty (an empty one ran in this process, unsaid)."""
    if not text.strip():
        raise argparse.ArgumentTypeError("expected local:N (N worker processes here) or a "
                                         "scheduler address such as tcp://host:8786")
    return text


@contextlib.contextmanager
def cluster_client(args):
    """The Dask client of ``--scheduler`` (its dashboard link printed)."""
    from ..cluster import connect
    with connect(args.scheduler, memory_limit=args.worker_memory) as client:
        print(f"dask dashboard: {client.dashboard_link}", flush=True)
        yield client
