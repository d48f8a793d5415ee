"""Which channels of an image are colour, alpha and other, by name (I/O layer):
``classify_channels``, and the colour models that are not linear RGB (``NOT_RGB``)."""
from __future__ import annotations

from ..methods.registry import OUTPUTS

COLOUR_NAMES = ("r", "g", "b", "y", "red", "green", "blue", "l", "gray", "grey")
#: the grey names among them: a grey channel beside R, G and B (an EXR's extra luminance) is
#: left out, not inverted as a fourth colour
GREY_NAMES = ("y", "l", "gray", "grey")
ALPHA_NAMES = ("a", "alpha")


#: a vector's component names: a named layer holding X or Z (any case) is a vector (P, N,
#: motion); unlayered, X marks one too (or CIE XYZ colour: X, Y, Z), while a Z alone is depth
#: beside a luminance Y
VECTOR_NAMES = ("x", "y", "z", "w")


#: the layers of a ``convert`` output: the target's colour and radius, or for the
#: ``random-walk`` target the medium's sigma_a and sigma_s
COLOUR_LAYERS, MEDIUM_LAYERS = ("colour", "radius"), ("sigma_a", "sigma_s")
#: every layer bdipole-cl's outputs write (``invert``'s outputs, ``convert``'s)
OWN_LAYERS = frozenset(OUTPUTS) | set(COLOUR_LAYERS) | set(MEDIUM_LAYERS)
#: the layer of one of those outputs that holds each input role (a job's input role: the
#: albedo or colour, the mfp or radius, blur's alpha' and sigma_t'); an output read as one of
#: these inputs is read by its layer, never by the channels' order
ROLE_LAYER = {"albedo": "colour", "mfp": "radius", "alpha": "alpha", "sigma_t": "sigma_t"}
#: the roles no layer of an output of ours holds: a blur's irradiance
NO_LAYER_ROLES = ("irradiance",)
#: the header entries that name the one layer a file of ours holds: a layer's own file
#: (``bdipole:layer``: jobs.layer_files; a blur's output: "exitance") and a painted map
#: (``bdipole:painted``, "{convention} {layer}": jobs.scene_maps)
HELD_LAYER_KEYS = ("bdipole:layer", "bdipole:painted")
#: header entries that say what a one-layer file of ours holds where it names no layer: a
#: blur's parameters (a blur's output written before it wrote ``bdipole:layer``)
IMPLIED_LAYER_KEYS = {"bdipole:methods": "exitance", "bdipole:texel_size": "exitance",
                      "bdipole:border": "exitance"}
#: one-layer files of ours a role also takes: a blur's exitance blurred again (light is light)
ROLE_ALSO = {"irradiance": ("exitance",)}
#: the held layers that are colour (tagged and shown as colour); every other one is data
COLOUR_HELD = ("colour", "exitance")


def short_name(name) -> str:
    """A channel's name without its layer ('R' of 'colour.R'): an output's channel is named
    ``{its layer}.{short name}``, never ``sigma_a.colour.R``."""
    return str(name).rsplit(".", 1)[-1]


def layer_of(name) -> str:
    """The layer of a channel name: the part before the last '.' ('' for R, G, B, A)."""
    return str(name).rsplit(".", 1)[0] if "." in str(name) else ""


def classify_channels(names, alpha_channel=-1, role=None, layer=None):
    """(colour, alpha, other) channel indices of a file, by name (the part after the last '.',
    case-insensitive), the file's declared alpha channel, the input ``role`` it is read
    for (a ``ROLE_LAYER`` key, or None) and the ``layer`` asked for (a MaterialX image's
    ``layer``; None: as follows; '' the unlayered channels):

    - alpha: the declared alpha channel, else the first named A or alpha;
    - colour: channels named R, G, B, Y (also red, green, blue, L, gray, grey), in file order,
      of one layer: the role's layer of an output of ours (``radius.R`` for an mfp) where
      the file has it, else the unlayered one (R, G, B) where it has colour, else the first
      layer that has (``albedo.R``...): other layers (AOVs: specular.R, N.R) are left out. A
      file whose layers are all our outputs' but not the role's (an inversion's ``sigma_a``
      read as an mfp) has none: it is not that input. A ``layer`` asked for is the one read
      (none where it has no colour). Y only in capitals, and not in a vector's layer (a
      named one that holds X or Z: P.X, P.Y, P.Z; the unlayered channels when one is X: X,
      Y, Z is a vector or CIE XYZ colour, not a luminance; a lower-case y is a component too: N.y, motion.y, uv.y); a grey one only
      where the layer has no R, G or B (beside them it is an extra luminance);
    - a file whose channels have none of these names but exactly one non-alpha channel: that
      channel is grey (a 1-channel file of any name; 2 channels of which one is alpha);
    - everything else (Z, depth, masks, vectors, other layers, ...) is other: never inverted,
      never written.

    So 1 channel is grey; 2 are grey + alpha when one is alpha, else as named (e.g. R and G);
    4 or more are R, G, B (+ A) with any extra channels left out."""
    last = [str(n).rsplit(".", 1)[-1].strip() for n in names]
    short = [n.lower() for n in last]
    layers = [layer_of(n) for n in names]
    vectors = {layers[i] for i in range(len(names))
               if (short[i] in ("x", "z") and layers[i]) or (short[i] == "x" and not layers[i])}
    alpha = alpha_channel if 0 <= alpha_channel < len(names) else next(
        (i for i, s in enumerate(short)
         if s in ALPHA_NAMES and (not layers[i] or layers[i] not in vectors)), -1)
    rest = [i for i in range(len(names)) if i != alpha]
    colour = [i for i in rest if short[i] in COLOUR_NAMES and last[i] != "y"
              and not (short[i] in VECTOR_NAMES and layers[i] in vectors)]
    if colour:                        # one layer: the role's, the unlayered one, the first
        held = {layers[i] for i in colour}
        if layer is None:
            layer = (ROLE_LAYER.get(role) if ROLE_LAYER.get(role) in held else
                     "" if "" in held else layers[colour[0]])
            if (role in ROLE_LAYER or role in NO_LAYER_ROLES) and \
                    layer != ROLE_LAYER.get(role) and held <= OWN_LAYERS:
                layer = None          # an output of ours without this role's layer: refused
        colour = [i for i in colour if layers[i] == layer]
    if any(short[i] not in GREY_NAMES for i in colour):
        colour = [i for i in colour if short[i] not in GREY_NAMES]
    if not colour and len(rest) == 1 and layer in (None, layers[rest[0]]):
        colour = rest
    other = [i for i in rest if i not in colour]
    return colour, alpha, other


def role_missing(names, role) -> str | None:
    """Why a file of channels ``names`` holds no ``role`` (an output of ours, all its layers
    ours, none the role's), else None."""
    layers = sorted({layer_of(n) for n in names} - {""})
    if (role not in ROLE_LAYER and role not in NO_LAYER_ROLES) or not layers \
            or not set(layers) <= OWN_LAYERS or ROLE_LAYER.get(role) in layers:
        return None
    if role in NO_LAYER_ROLES:
        return (f"layers {', '.join(layers)} of a bdipole-cl output: none is an {role}; "
                f"give the {role} itself")
    return (f"layers {', '.join(layers)} of a bdipole-cl output: none is the "
            f"{ROLE_LAYER[role]}.* layer that holds the {role}; give the file that has it")


def held_layer(spec) -> tuple | None:
    """(the layer, the header entry that says it) of a one-layer file of ours (its channels
    are plain R, G, B: only its header says what it holds), else None. ``spec``: an
    ImageSpec or a {name: value} of its attributes. Ours by any ``bdipole:*`` entry (a
    file of an earlier version may lack ``bdipole:version`` or ``bdipole:layer``): the
    layer it names, else the one its other entries imply (``IMPLIED_LAYER_KEYS``)."""
    get = spec.get if isinstance(spec, dict) else spec.getattribute
    names = spec.keys() if isinstance(spec, dict) else [a.name for a in spec.extra_attribs]
    if not any(str(n).startswith("bdipole:") for n in names):
        return None
    for key in HELD_LAYER_KEYS:
        text = str(get(key) or "").split()
        if text:
            return text[-1], key
    return next(((layer, key) for key, layer in IMPLIED_LAYER_KEYS.items()
                 if get(key) is not None), None)


def role_refused(spec, role, what) -> str | None:
    """Why a one-layer file of ours (``held_layer``) is not the input ``role`` (a
    ``ROLE_LAYER`` key or a NO_LAYER_ROLES one) it is read as (``what``: its name or
    option), else None: the header decides, so a colour is never read as a radius because
    both are R, G, B."""
    held = held_layer(spec)
    if held is None or (role not in ROLE_LAYER and role not in NO_LAYER_ROLES) \
            or held[0] == ROLE_LAYER.get(role) or held[0] in ROLE_ALSO.get(role, ()):
        return None
    wanted = (f"the {what} is an output's {ROLE_LAYER[role]} layer" if role in ROLE_LAYER
              else f"of bdipole-cl's outputs only a blur's "
                   f"{' or '.join(ROLE_ALSO.get(role, ()))} is an {role}")
    return (f"holds a bdipole-cl output's {held[0]} layer ({held[1]}), given as the "
            f"{what}; {wanted}")


#: channel name sets that are colour models other than linear RGB: never read as R, G, B, A
NOT_RGB = ({"L", "a", "b"}, {"Y", "RY", "BY"})    # Lab; OpenEXR's luminance/chroma
