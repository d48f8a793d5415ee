"""The command line's argument types and help: one-line usage errors, defaults shown
(applications layer; ``cli`` builds its parser from these)."""
from __future__ import annotations

import argparse
import re
from dataclasses import replace

from ..io.mipmaps import TextureOptions
from ..io.patterns import PATTERN_FIELDS
from ..methods.registry import TEXTURE_RESIZE, TEXTURE_WRAP

#: what argparse takes for a negative number (a value, not an option): its own rule (-5,
#: -.5) widened to exponents and size suffixes, so that ``--max-memory -5M`` or ``--tol -1e-3``
#: reach the option's type and its one-line error, not "expected one argument"
NEGATIVE_NUMBER = re.compile(r"^-(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?[KMGkmg]?$")


def output_pattern(*extra):
    """An ``-o`` pattern's argparse type: every ``{field}`` in it one the command fills
    (``PATTERN_FIELDS`` and ``extra``); another is a usage error naming it (it was written as
    a folder of that name)."""
    fields = PATTERN_FIELDS + extra

    def check(text):
        unknown = [f for f in re.findall(r"\{([^{}]*)\}", str(text)) if f not in fields]
        if unknown:
            raise argparse.ArgumentTypeError(
                f"{text!r}: {{{unknown[0]}}} is no field; expected "
                f"{', '.join('{' + f + '}' for f in fields)} (or a tile token)")
        return text
    return check


def size(text):
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


def floats(text):
    """'1.4' or '1.3,1.4,1.5' -> a tuple of finite floats (an argparse type)."""
    try:
        values = tuple(float(v) for v in str(text).split(","))
    except ValueError:
        values = ()
    if not values or not all(v == v and abs(v) != float("inf") for v in values):
        raise argparse.ArgumentTypeError(f"{text!r}: expected a number or a comma list such as "
                                         f"1.3,1.4,1.5")
    return values


def number(convert, valid, expected):
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


positive_int = number(int, lambda v: v >= 1, "a whole number >= 1")
positive_float = number(float, lambda v: 0 < v < float("inf"), "a number > 0")
fraction = number(float, lambda v: 0 < v < 1, "a number in (0, 1), e.g. 1e-3")


def number_list(text):
    """The floats of 'v' or 'r,g,b' (nan and inf included), or None if text is not numbers
    (a texture's path)."""
    try:
        return tuple(float(v) for v in str(text).split(","))
    except ValueError:
        return None


def constants(name):
    """An argparse type for constant(s) of parameter ``name``: ``floats``, each meeting the
    parameter's constant rule (``ops.blur.params.CONSTANT_RULES``), else a one-line usage
    error naming the value and the rule."""
    def parse(text):
        from ..ops.blur.params import CONSTANT_RULES
        rule, valid = CONSTANT_RULES[name]
        values = floats(text)
        if not all(bool(valid(v)) for v in values):
            raise argparse.ArgumentTypeError(f"{text!r}: expected {name} in {rule}, one or per "
                                             f"channel 'r,g,b'")
        return values
    return parse


def constant_or_texture(name):
    """An argparse type for parameter ``name`` given as constant(s) or a texture: a path is
    kept as given (its texels are checked when it is read); numbers must each meet the
    parameter's constant rule (``ops.blur.params.CONSTANT_RULES``), else a one-line usage error
    naming the option and value, not a texel error of the whole map."""
    def parse(text):
        from ..ops.blur.params import CONSTANT_RULES
        rule, valid = CONSTANT_RULES[name]
        values = number_list(text)
        if values is not None and not all(bool(valid(v)) for v in values):
            raise argparse.ArgumentTypeError(f"{text!r}: expected {name} in {rule}, one or per "
                                             f"channel 'r,g,b' (or a texture)")
        return text
    return parse


def length_unit(text):
    """A length unit of the scene files' table (``io.scene_file.UNIT_METERS``): a usage
    error (exit 2) before any file is written, not a failure of the materials after."""
    from ..io.scene_file import UNIT_METERS
    if text not in UNIT_METERS:
        raise argparse.ArgumentTypeError(f"{text!r}: expected a length unit, one of "
                                         f"{', '.join(UNIT_METERS)}")
    return text


def shown(value):
    if isinstance(value, (tuple, list)):
        return ",".join(f"{v:g}" if isinstance(v, float) else str(v) for v in value)
    return str(value).replace("%", "%%")


class HelpFormatter(argparse.RawDescriptionHelpFormatter):
    """Help texts with each option's default shown (``ArgumentDefaultsHelpFormatter``'s rule,
    less the options that have none) and descriptions and epilogs kept as written."""

    def _get_help_string(self, action):
        text = action.help or ""
        if ("%(default)" in text or not action.option_strings
                or action.default in (None, False, argparse.SUPPRESS)):
            return text
        return f"{text} (default: {shown(action.default)})"


class Parser(argparse.ArgumentParser):
    """argparse with one-line usage errors (``prog: error: ...``, exit 2), no usage block."""

    def __init__(self, *args, **kwargs):
        kwargs.setdefault("formatter_class", HelpFormatter)
        super().__init__(*args, **kwargs)
        self._negative_number_matcher = NEGATIVE_NUMBER

    def error(self, message):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def spelling_of(registry):
    """An argparse type for an option of ``registry`` (``vocabulary.Registry``): an alias is
    taken as its canonical name; anything else is passed on as given, for the ``choices``
    check to report (give ``choices=registry.names``)."""
    def canonical(text):
        return registry.canonical(text) if text in registry else text
    canonical.__name__ = registry.kind
    return canonical


def output_list(text):
    from ..methods.registry import OUTPUTS
    names = tuple(o.strip() for o in str(text).split(",") if o.strip())
    unknown = [o for o in names if o not in OUTPUTS]
    if not names or unknown:
        raise argparse.ArgumentTypeError(f"{text!r}: {', '.join(unknown) or 'empty'} not "
                                         f"allowed; choose from {', '.join(OUTPUTS)}")
    twice = sorted({o for o in names if names.count(o) > 1})
    if twice:
        raise argparse.ArgumentTypeError(f"{text!r}: {', '.join(twice)} given more than once")
    return names


def add_texture_arg(p):
    """``--texture`` of the commands that write images (invert, blur), and the options of the
    texture (``--texture-wrap``, ``--texture-tile``, ``--texture-resize``, as maketx's
    ``--wrap``, ``--tile``, ``--resize`` and txmake's ``-mode``, ``-resize``): each makes
    ``args.texture`` a TextureOptions (one of them alone implies ``--texture``)."""
    p.add_argument("--texture", action=TextureAction, nargs=0, default=False,
                   help="write renderer-ready textures: tiled 64x64, mip-mapped EXRs (as maketx "
                        "makes; each level keeps its parent's mean; a .tx/TIFF output is "
                        "refused: it drops channel names)")
    # dest "texture" keeps --texture's default (False); each default is the option's own
    p.add_argument("--texture-wrap", action=TextureAction, dest="texture", field="wrap",
                   choices=TEXTURE_WRAP.names, metavar="MODE", default="clamp",
                   help=f"lookups beyond the edges: {', '.join(TEXTURE_WRAP.names)} (default "
                        "clamp: no seam at a tile's edge; a blur: as its --border)")
    p.add_argument("--texture-tile", action=TextureAction, dest="texture", field="tile",
                   type=positive_int, metavar="N", default=64,
                   help="tile side in texels (default 64)")
    p.add_argument("--texture-resize", action=TextureAction, dest="texture", field="resize",
                   choices=TEXTURE_RESIZE.names, metavar="HOW", default="none",
                   help=f"level 0 to powers of two: {', '.join(TEXTURE_RESIZE.names)} "
                        "(default none)")


class TextureAction(argparse.Action):
    """``--texture`` and its options, gathered into one TextureOptions in ``args.texture``."""

    def __init__(self, option_strings, dest, field=None, **kwargs):
        self.field = field
        super().__init__(option_strings, dest, **kwargs)

    def __call__(self, parser, namespace, values, option_string=None):
        current = getattr(namespace, self.dest, False)
        options = current if isinstance(current, TextureOptions) else TextureOptions()
        if self.field is not None:
            try:
                options = replace(options, **{self.field: values})
            except ValueError as exc:
                parser.error(f"{option_string}: {exc}")
        setattr(namespace, self.dest, options)


def target_list(text):
    """``--target``: a comma list of render targets (``io.targets.TARGET``), one per render
    context."""
    from ..io.targets import parse_targets
    try:
        return parse_targets(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
