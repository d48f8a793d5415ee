"""The scene files' keys (I/O; ``scene_file`` reads the files): each key's kinds, check and
what is allowed, the required keys and defaults, the length units, and how a blur's texel
lengths are given (``texel_size``, or ``stretch``: docs/scenes.md "Stretch")."""
from __future__ import annotations

from pathlib import Path

from ..errors import POLICY
from ..methods.registry import (BLUR_METHOD, BORDER, CHART_BORDER, METHOD_OR_AUTO, MFP_KIND,
                                OUTPUTS, TEXTURE_RESIZE, TEXTURE_WRAP)
from ..ops.blur.params import CONSTANT_RULES
from ..physics.models import MODEL
from .mipmaps import MAX_TILE
from .scene_values import as_list, mfp_constants, number, numbers_or_number, positive
from .targets import TARGET, parse_targets

#: files a blur's ``stretch`` computes its maps from: USD stages and OBJ meshes
STAGE_SUFFIXES = (".usd", ".usda", ".usdc", ".usdz")
MESH_SUFFIXES = STAGE_SUFFIXES + (".obj",)
#: ``stretch``'s value for the meshes the stage binds the blur's material to
BOUND = "bound"


#: each key: (kinds it belongs to, check, what is allowed)
KEYS = {
    "name": ({"material", "blur"}, lambda v: isinstance(v, str) and v, "a non-empty string"),
    "albedo": ({"material"}, lambda v: (isinstance(v, str) and v) or numbers_or_number(v),
               "a texture path or pattern, or constants (a number or one per channel)"),
    "mfp": ({"material"}, lambda v: mfp_constants(v) or (isinstance(v, str) and v),
            f"a number in {CONSTANT_RULES['mfp'][0]}, a list of one per channel, or a texture "
            f"path"),
    "albedo_layer": ({"material"}, lambda v: isinstance(v, str), "an EXR layer's name of the "
                     "albedo texture (\"\": its unlayered channels)"),
    "mfp_layer": ({"material"}, lambda v: isinstance(v, str), "an EXR layer's name of the mfp "
                  "texture (\"\": its unlayered channels)"),
    "mfp_kind": ({"material"}, lambda v: v in MFP_KIND, MFP_KIND.listing('"')),
    "mfp_scale": ({"material"}, lambda v: numbers_or_number(v) and min(as_list(v)) > 0,
                  "a number > 0 or one per channel"),
    "eta": ({"material"}, lambda v: numbers_or_number(v), "a number or one per channel"),
    "outputs": ({"material"}, lambda v: isinstance(v, list) and v and set(v) <= set(OUTPUTS)
                and len(set(v)) == len(v), f"a list from {', '.join(OUTPUTS)}, each once"),
    "output": ({"material", "blur"}, lambda v: isinstance(v, str) and v.endswith(".exr"),
               "an .exr path or pattern (a .tx/TIFF texture drops the channel names: "
               "texture = true writes tiled, mip-mapped EXRs)"),
    "mask": ({"material", "blur"}, lambda v: isinstance(v, str) and v,
             "\"alpha\" or a texture path"),
    "half": ({"material", "blur"}, lambda v: isinstance(v, bool), "true or false"),
    "texture": ({"material", "blur"}, lambda v: isinstance(v, bool),
                "true (tiled, mip-mapped EXR textures) or false"),
    "texture_wrap": ({"material", "blur"}, lambda v: v in TEXTURE_WRAP,
                     TEXTURE_WRAP.listing('"') + " (implies texture = true)"),
    "texture_tile": ({"material", "blur"},
                     lambda v: isinstance(v, int) and not isinstance(v, bool)
                     and 1 <= v <= MAX_TILE,
                     f"a whole number of texels in 1..{MAX_TILE} (implies texture = true)"),
    "texture_resize": ({"material", "blur"}, lambda v: v in TEXTURE_RESIZE,
                       TEXTURE_RESIZE.listing('"') + " (implies texture = true)"),
    "unit": ({"material", "blur"}, lambda v: isinstance(v, str) and v, "a unit name"),
    "tol": ({"material", "blur"}, lambda v: number(v) and 0 < v < 1, "a number in (0, 1)"),
    "model": ({"material"}, lambda v: v in MODEL, MODEL.listing('"')),
    "method": ({"material"}, lambda v: v in METHOD_OR_AUTO,
               f"one of {', '.join(METHOD_OR_AUTO.names)}"),
    "blur_method": ({"blur"}, lambda v: v in BLUR_METHOD,
                    f"one of {', '.join(BLUR_METHOD.names)}"),
    "border": ({"blur"}, lambda v: v in BORDER, f"one of {', '.join(BORDER.names)}"),
    "exact": ({"material"}, lambda v: isinstance(v, bool), "true or false"),
    "double": ({"material"}, lambda v: isinstance(v, bool), "true or false"),
    "on_invalid": ({"material", "blur"}, lambda v: v in POLICY, POLICY.listing()),
    "colorspace": ({"material", "blur"}, lambda v: isinstance(v, str) and v,
                   "auto or a colour space of the OCIO config"),
    "working_space": ({"material", "blur"}, lambda v: isinstance(v, str) and v,
                      "a scene-linear colour space of the OCIO config"),
    "material": ({"blur"}, lambda v: isinstance(v, str) and v, "a material's name"),
    "irradiance": ({"blur"}, lambda v: isinstance(v, str) and v, "a texture path or pattern"),
    "texel_size": ({"blur"}, positive, "a finite number > 0 (in the unit of mfp)"),
    "stretch": ({"blur"}, lambda v: isinstance(v, str) and v,
                '"bound" (the meshes a stage binds the material to), a mesh file (' +
                ", ".join(MESH_SUFFIXES) + ") or stretch maps (.exr, a tile pattern)"),
    "charts": ({"blur"}, lambda v: v in CHART_BORDER, CHART_BORDER.listing('"')
               + " (with stretch: the blur at UV chart borders)"),
    "mesh_unit": ({"blur"}, lambda v: v in UNIT_METERS,
                  "the unit of an OBJ stretch mesh's positions (mm, cm, m, in, ...)"),
    "targets": ({"material"}, lambda v: isinstance(v, list) and _targets_ok(v),
                f"a list from {TARGET.listing(chr(34))}, one per render context"),
}


def _targets_ok(value) -> bool:
    try:
        parse_targets([str(v) for v in value])
    except ValueError:
        return False
    return all(isinstance(v, str) for v in value)


REQUIRED = {"material": ("name", "albedo", "output"),
            "blur": ("name", "material", "irradiance", "output")}    # and texel_size or stretch
DEFAULTS = {"eta": 1.4, "unit": "mm", "model": "better", "mfp": 1.0, "half": False,
            "texture": False,
            "outputs": ["sigma_a", "sigma_s"], "method": "auto", "blur_method": "auto",
            "border": "clamp", "exact": False, "double": False, "on_invalid": "raise",
            "colorspace": "auto", "mfp_kind": "diffuse", "mfp_scale": 1.0, "charts": "clamp"}
#: tol when neither the entry nor [defaults] gives one: the inversion's accuracy contract, the
#: blur's usual truncation
DEFAULT_TOL = {"material": 1e-4, "blur": 1e-3}

#: metres per unit (MaterialX ``distance`` unit names and their short forms)
UNIT_METERS = {"m": 1.0, "cm": 0.01, "mm": 1e-3, "um": 1e-6, "nm": 1e-9, "km": 1e3,
               "in": 0.0254, "ft": 0.3048, "yd": 0.9144, "mi": 1609.344,
               "meter": 1.0, "centimeter": 0.01, "millimeter": 1e-3, "micron": 1e-6,
               "nanometer": 1e-9, "kilometer": 1e3, "inch": 0.0254, "foot": 0.3048,
               "yard": 0.9144, "mile": 1609.344}


def blur_lengths(fail, index, entry, defaults, merged, material, from_stage, resolve) -> tuple:
    """(texel_size, stretch, mesh_unit) of a checked [[blur]] (``merged``: with [defaults]):
    one texel size, or ``stretch`` (BOUND, or the absolute path of a mesh file or stretch
    maps) whose lengths are in ``material``'s unit. The entry's own choice wins over
    [defaults]'; both in one place is an error, as is neither. ``from_stage``: the material
    is a USD stage's (BOUND needs one)."""
    pair = ("texel_size", "stretch")
    given = [k for k in pair if k in entry]
    if len(given) == 2:
        fail("blur", index, "stretch", "texel_size and stretch: give one (stretch maps give "
                                       "each texel its own lengths)")
    if not given:
        given = [k for k in pair if k in defaults]
        if len(given) == 2:
            fail("defaults", 0, "stretch", "texel_size and stretch in [defaults]: give one, or "
                                           "either in each [[blur]]")
    if not given:
        fail("blur", index, None, f"[[blur]] #{index + 1} needs 'texel_size' "
                                  f"({KEYS['texel_size'][2]}) or 'stretch' ({KEYS['stretch'][2]})")
    for key in ("charts", "mesh_unit"):
        if given[0] == "texel_size" and key in entry:
            fail("blur", index, key, f"{key} is for a blur with stretch; this one has texel_size")
    if given[0] == "texel_size":
        return float(merged["texel_size"]), None, None
    where = ("blur", index) if "stretch" in entry else ("defaults", 0)
    value, mesh_unit = merged["stretch"], merged.get("mesh_unit")
    if material.unit not in UNIT_METERS:
        fail(*where, "stretch", f"stretch: material '{material.name}' has unit = "
                                f"{material.unit!r}; stretch lengths need one of "
                                f"{', '.join(UNIT_METERS)}")
    suffix = Path(value).suffix.lower()
    if value == BOUND and not from_stage:
        fail(*where, "stretch", f'stretch = "{BOUND}": material \'{material.name}\' is not a USD '
                                f"stage's (materials_from); name a mesh file or stretch maps")
    elif value != BOUND and suffix not in MESH_SUFFIXES + (".exr",):
        fail(*where, "stretch", f"stretch = {value!r}: expected {KEYS['stretch'][2]}")
    if suffix == ".obj" and mesh_unit is None:
        fail(*where, "stretch", f"stretch = {value!r}: an OBJ has no unit; give mesh_unit "
                                f"(the unit of its positions: mm, cm, m, in, ...)")
    if suffix != ".obj" and mesh_unit is not None:
        at = ("blur", index) if "mesh_unit" in entry else ("defaults", 0)
        fail(*at, "mesh_unit", f"mesh_unit is for an OBJ stretch mesh; stretch = {value!r} "
                               f"has its own unit (a stage's metersPerUnit, a map's header)")
    return None, (value if value == BOUND else resolve(value)), mesh_unit
