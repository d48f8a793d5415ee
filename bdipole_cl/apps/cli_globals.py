"""The options every ``bdipole-cl`` command takes, before or after the command (``--device``,
``--working-space``, ``--debug``), and the colour-name argument types (README: Colour)."""
from __future__ import annotations

import argparse


def working_space_arg(text):
    """A working space of the active OCIO config (an argparse type: an unknown name is a
    usage error listing the known ones)."""
    from ..io.colour import resolve_working_space
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
