"""Surface shaders a scene reads subsurface materials from, and how their inputs map to a
scene material (I/O; the readers are ``usd_scene`` and ``mtlx_scene``).

===================  ==================  ==============================  ==============  =====
shader               albedo              distance                        eta             kind
===================  ==================  ==============================  ==============  =====
OpenPBR Surface      subsurface_color    subsurface_radius x             specular_ior    ext.
                                         subsurface_radius_scale
Standard Surface     subsurface_color    subsurface_radius x             specular_IOR    ext.
                                         subsurface_scale
PxrSurface           subsurfaceColor     subsurfaceDmfp x                subsurfaceIor   diff.
                                         subsurfaceDmfpColor x
                                         unitLength
===================  ==================  ==============================  ==============  =====

A shader is known by its USD ``info:id`` or MaterialX category: MaterialX's versioned
nodedefs too (``ND_standard_surface_surfaceshader_100``, Standard Surface 1.0.0: any
``ND_..._<digits>`` of a known nodedef, ``shader_mapping``) and Arnold's (``arnold:``).

A material counts when its weight (``subsurface_weight``, ``subsurface``, ``subsurfaceGain``)
is > 0 (or a texture). Every other shader (UsdPreviewSurface, ...) has no subsurface and is
left out. Inputs not authored take the shader's default (below: the MaterialX 1.39 nodedefs
and RenderMan's PxrSurface defaults). The distance's convention (docs/model.md "Mean free
path"): OpenPBR and Standard Surface give the medium's mean free path ("extinction"),
PxrSurface's dmfp is ld = 1/mu_tr ("diffuse"); RenderMan documents PxrSurface's
``unitLength`` (default 0.1: a dmfp in mm on a stage in cm) as a multiplier on the mean free
path distance, so it multiplies the distance (a constant; a texture is refused).

A reader hands each input over as an ``Input``: a constant, a ``Texture`` (file, colour
space, the node it comes from) or a refusal (a procedural network: named, never replaced by a
default); ``imported_material`` turns a shader's inputs into the scene keys of one material.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass, field

import numpy as np

from ..errors import one_line
from . import tiles
from .channels import classify_channels
from .images import image_header
from .scene_file import UNIT_METERS, ImportedMaterial, SceneError
from .targets import DEFAULT_TARGETS


@dataclass(frozen=True)
class ShaderMapping:
    name: str
    ids: tuple                   # USD info:id values and MaterialX node categories
    albedo: str
    distance: tuple              # two inputs whose product is the mean free path
    eta: str
    weight: str
    mfp_kind: str
    source: str                  # where the convention is defined
    defaults: dict = field(default_factory=dict)
    anisotropy: str | None = None
    unit_length: str | None = None   # a third constant factor of the distance (PxrSurface)


SHADERS = (
    ShaderMapping(
        "OpenPBR Surface", ("ND_open_pbr_surface_surfaceshader", "open_pbr_surface",
                            "arnold:openpbr_surface"),
        "subsurface_color", ("subsurface_radius", "subsurface_radius_scale"), "specular_ior",
        "subsurface_weight", "extinction",
        "OpenPBR Surface specification, Subsurface: the radius is the mean free path of the medium",
        {"subsurface_weight": (0.0,), "subsurface_color": (0.8, 0.8, 0.8),
         "subsurface_radius": (1.0,), "subsurface_radius_scale": (1.0, 0.5, 0.25),
         "specular_ior": (1.5,), "subsurface_scatter_anisotropy": (0.0,)},
        "subsurface_scatter_anisotropy"),
    ShaderMapping(
        "Standard Surface", ("ND_standard_surface_surfaceshader", "standard_surface",
                             "arnold:standard_surface"),
        "subsurface_color", ("subsurface_radius", "subsurface_scale"), "specular_IOR",
        "subsurface", "extinction",
        "Autodesk Standard Surface specification, Subsurface: the radius is the mean free path",
        {"subsurface": (0.0,), "subsurface_color": (1.0, 1.0, 1.0),
         "subsurface_radius": (1.0, 1.0, 1.0), "subsurface_scale": (1.0,),
         "specular_IOR": (1.5,), "subsurface_anisotropy": (0.0,)},
        "subsurface_anisotropy"),
    ShaderMapping(
        "PxrSurface", ("PxrSurface",),
        "subsurfaceColor", ("subsurfaceDmfp", "subsurfaceDmfpColor"), "subsurfaceIor",
        "subsurfaceGain", "diffuse",
        "RenderMan PxrSurface: dmfp is the diffuse mean free path (Christensen-Burley)",
        {"subsurfaceGain": (0.0,), "subsurfaceColor": (0.830, 0.791, 0.753),
         "subsurfaceDmfp": (10.0,), "subsurfaceDmfpColor": (0.851, 0.557, 0.395),
         "subsurfaceIor": (1.4,), "unitLength": (0.1,)}, unit_length="unitLength"),
)
BY_ID = {i: s for s in SHADERS for i in s.ids}


def shader_mapping(shader_id) -> ShaderMapping | None:
    """The mapping of a shader id or category, None for a shader with no subsurface: a
    MaterialX nodedef of an older version (``ND_<node>_<type>_<version digits>``, as
    ``ND_standard_surface_surfaceshader_100``: the same inputs, defaults and meaning) as its
    current one."""
    found = BY_ID.get(shader_id or "")
    versioned = re.fullmatch(r"(ND_\w+?)_\d+", shader_id or "")
    return found if found is not None or versioned is None else BY_ID.get(versioned[1])


#: USD, MaterialX, RenderMan and Arnold nodes whose file is a texture a scene can bake from
TEXTURE_NODES = ("UsdUVTexture", "image", "tiledimage", "PxrTexture", "arnold:image")

SHORT_UNITS = ("m", "cm", "mm", "um", "nm", "km", "in", "ft", "yd", "mi")


def unit_name(meters: float) -> str:
    """The short name of a unit of ``meters`` metres, else '<meters> m'."""
    for name in SHORT_UNITS:
        if math.isclose(UNIT_METERS[name], meters, rel_tol=1e-9):
            return name
    return f"{meters:g} m"


def unit_meters(name: str, where: str) -> float:
    meters = UNIT_METERS.get(name)
    if meters is None:
        raise SceneError(f"{where}: unit {name!r} is not a distance unit; expected one of "
                         f"{', '.join(UNIT_METERS)}")
    return meters


@dataclass(frozen=True)
class Texture:
    file: str                    # absolute path or <UDIM> pattern
    colorspace: str              # as declared; "auto" when nothing is
    node: str                    # the texture node, for messages
    scale: tuple | None = None   # per channel, multiplies the texels (UsdUVTexture scale)
    bias: tuple | None = None    # per channel, added after the scale (UsdUVTexture bias)
    channel: str | None = None   # the one channel read (UsdUVTexture outputs:r ...); None: rgb
    channel_index: int | None = None   # that channel's place in the file (0: R, the first)
    layer: str | None = None     # the file's layer read (MaterialX image ``layer``); None: ''


@dataclass(frozen=True)
class Input:
    """One shader input as read: ``value`` (floats), ``texture``, or ``refused`` (why it
    cannot be baked); ``unit`` the declared distance unit (MaterialX), if any."""

    name: str
    value: tuple | None = None
    texture: Texture | None = None
    refused: str | None = None
    unit: str | None = None
    authored: bool = True
    animated: str | None = None      # animated (USD time samples): the time it was read at

    def describe(self) -> str:
        if self.texture is not None:
            t = self.texture
            return f"{self.name} <- {t.file} ({t.colorspace})" + (
                f" x {', '.join(f'{v:g}' for v in t.scale)}" if t.scale else "") + (
                f" (animated: at {self.animated})" if self.animated else "")
        if self.refused:
            return self.refused
        text = ", ".join(f"{v:g}" for v in self.value)
        return f"{self.name} {text}" + (f" {self.unit}" if self.unit else "") \
            + ("" if self.authored else " (default)") \
            + (f" (animated: at {self.animated})" if self.animated else "")


def default_input(mapping: ShaderMapping, name: str) -> Input:
    return Input(name, value=mapping.defaults[name], authored=False)


def one_channel(node_type: str) -> str | None:
    """What a MaterialX image node of ``node_type`` reads when that is one channel of its
    file (a ``float`` image: the first), else None."""
    return f"out (a {node_type} image: the file's first channel)" if node_type == "float" \
        else None


def file_colour(file, layer=None) -> tuple | None:
    """(the colour channels a bake reads, every channel) of a texture file, names as in the
    file (``channels.classify_channels``, of ``layer`` where one is named; a <UDIM> pattern:
    its first tile); None where no such file can be read now."""
    hits = tiles.expand(file) if tiles.is_pattern(file) else [(file, None)]
    spec = image_header(hits[0][0]) if hits else None
    if spec is None:
        return None
    names = [str(n) for n in spec.channelnames]
    colour, _, _ = classify_channels(names, spec.alpha_channel, layer=layer)
    return [names[i] for i in colour], names


def layer_at(file, first: int) -> str | None:
    """The layer of ``file`` whose colour channels start at channel ``first`` (where a
    PxrTexture's ``firstChannel`` points: ``diffuse`` of ``R, G, B, diffuse.R, ...`` at 3),
    else None."""
    found = file_colour(file)
    if found is None or not 0 < first < len(found[1]):
        return None
    layer = found[1][first].rsplit(".", 1)[0] if "." in found[1][first] else ""
    colour = file_colour(file, layer)[0]
    return layer if colour and colour[0] == found[1][first] else None


class NotBakeable(Exception):
    """Why a material with a subsurface shader cannot be baked (one line)."""


def _distance(mapping, inputs, unit_m, where):
    """(mfp constants or texture, mfp_scale) of the product of the two distance inputs, in
    the scene unit (a declared MaterialX unit converted)."""
    a, b = (inputs[n] for n in mapping.distance)
    if a.texture is not None and b.texture is not None:
        raise NotBakeable(f"{a.name} and {b.name} are both textures: their product is not "
                          f"bakeable")
    declared = [i.unit for i in (a, b) if i.unit]
    factor = unit_meters(declared[0], where) / unit_m if declared else 1.0
    if mapping.unit_length:              # RenderMan: a multiplier on the mean free path
        length = inputs[mapping.unit_length]
        if length.texture is not None or not length.value[0] > 0:
            raise NotBakeable(f"{mapping.unit_length} must be a positive constant (a "
                              f"multiplier on the mean free path), not "
                              f"{length.texture.file if length.texture else length.value[0]}")
        factor *= length.value[0]
    if a.texture is None and b.texture is None:
        try:
            mfp = np.asarray(a.value) * np.asarray(b.value) * factor
        except ValueError:
            raise NotBakeable(f"{a.name} has {len(a.value)} values and {b.name} "
                              f"{len(b.value)}") from None
        return [float(v) for v in mfp], [1.0]
    tex, const = (a, b) if a.texture is not None else (b, a)
    scale = np.asarray(const.value) * factor
    if tex.texture.scale is not None:    # the texture node's scale multiplies its texels
        try:
            scale = scale * np.asarray(tex.texture.scale)
        except ValueError:
            raise NotBakeable(f"{const.name} has {len(const.value)} values and "
                              f"{tex.texture.node}'s scale {len(tex.texture.scale)}") from None
    return tex.texture.file, [float(v) for v in scale]


def _layer_refusal(inp) -> str | None:
    """Why the layer a texture node names (MaterialX ``layer``) cannot be baked, or None: a
    bake reads that layer (the material's ``albedo_layer``, ``mfp_layer``), so only a file
    that cannot be read, or has no colour channel in that layer, is refused."""
    t = inp.texture
    if not t.layer:
        return None
    found = file_colour(t.file, t.layer)
    if found is None:
        return (f"{inp.name} reads layer {t.layer!r} of {t.file} ({t.node}), a file that "
                f"cannot be read to find that layer")
    colour, names = found
    if colour:
        return None
    return (f"{inp.name} reads layer {t.layer!r} of {t.file} ({t.node}), which has no colour "
            f"channel in that layer (its channels: {', '.join(names)})")


def _one_channel_refusal(inp, is_albedo) -> str | None:
    """Why a texture node's one channel cannot be baked, or None: a distance may be one
    channel (OpenPBR's radius is a float) where it is the first of a file whose colour is
    that one channel (the mfp texture then has one channel, times the scale per channel);
    an albedo is the colour channels (an rgb output, a color3 image)."""
    t = inp.texture
    if t.channel is None:
        return None
    head = f"{inp.name} reads {t.channel} of {t.node}, one channel"
    if is_albedo:
        return (f"{head}: a bake reads a texture's colour channels (UsdUVTexture outputs:rgb, "
                f"a color3 image)")
    found = file_colour(t.file, t.layer)
    if found is not None and len(found[0]) == 1 and t.channel_index == 0:
        return None
    which = "R" if not t.channel_index else "RGBA"[t.channel_index]
    if found is not None and t.channel_index is not None and t.channel_index < len(found[1]):
        which = found[1][t.channel_index]
    return (f"{head} of {t.file}"
            + (f", whose colour is {', '.join(found[0])}" if found else "")
            + f": write that channel to a one-channel file (oiiotool {t.file} --ch {which} "
              f"-o {inp.name}.exr) and read that")


def _texel_refusals(inp, is_albedo) -> list:
    """Why a texture's texels cannot be baked as they are (its colour channels, the
    distance's scaled): a layer other than the one read, one channel (but a distance's of a
    one-channel file), a bias, a scale of the albedo (never ignored)."""
    t = inp.texture
    if t is None:
        return []
    why = [w for w in (_layer_refusal(inp), _one_channel_refusal(inp, is_albedo)) if w]
    for what, values in (("bias", t.bias), ("scale", t.scale if is_albedo else None)):
        if values is not None:
            why.append(f"{inp.name}: UsdUVTexture scale/bias not supported ({t.node} has "
                       f"{what} {', '.join(f'{v:g}' for v in values)}"
                       + (", on the albedo)" if what == "scale" else ")"))
    return why


def _check_bakeable(mapping, inputs):
    weight, eta, albedo = (inputs[n] for n in (mapping.weight, mapping.eta, mapping.albedo))
    used = [inputs[n] for n in (mapping.weight, mapping.albedo, *mapping.distance, mapping.eta,
                                *((mapping.unit_length,) if mapping.unit_length else ()))]
    refused = [i.refused for i in used if i.refused]
    if refused:
        raise NotBakeable("; ".join(refused))
    if eta.texture is not None:
        raise NotBakeable(f"{mapping.eta} is a texture ({eta.texture.file}); eta must be "
                          f"constant")
    texels = [w for i in (albedo, *(inputs[n] for n in mapping.distance))
              for w in _texel_refusals(i, i is albedo)]
    if texels:
        raise NotBakeable("; ".join(texels))
    if albedo.texture is None and any(inputs[n].texture for n in mapping.distance):
        raise NotBakeable(f"{mapping.albedo} is constant and the distance a texture: a bake "
                          f"is driven by an albedo texture")


def _notes(mapping, inputs) -> tuple:
    """What the plan should say about inputs that are read but not applied."""
    notes = [f"{i.name} is animated: baked with its value at {i.animated}"
             for i in inputs.values() if i.animated]
    weight = inputs[mapping.weight]
    if weight.texture is not None:
        notes.append(f"{mapping.weight} is a texture ({weight.texture.file}): baked as a "
                     f"subsurface material, the weight not applied")
    aniso = inputs.get(mapping.anisotropy)
    if aniso is not None and aniso.value is not None and aniso.value[0] != 0:
        notes.append(f"{mapping.anisotropy} = {aniso.value[0]:g}: the distance is read as "
                     f"1/sigma_t' (reduced), docs/model.md \"Mean free path\"")
    elif aniso is not None and aniso.value is None:
        notes.append(f"{mapping.anisotropy} is not a constant: not applied (the distance is "
                     f"read as 1/sigma_t')")
    for n in mapping.distance:
        t = inputs[n].texture
        if t is not None and t.colorspace not in ("auto", "raw"):
            notes.append(f"the distance texture declares {t.colorspace}: read as data (no "
                         f"colour conversion)")
    return tuple(notes)


def imported_material(name, path, shader_id, read, *, unit_m, out_dir, bound) -> \
        ImportedMaterial:
    """A material from its surface shader's id and ``read(input name) -> Input | None``
    (None: not authored); ``out_dir`` the default folder of its outputs."""
    mapping = shader_mapping(shader_id)
    if mapping is None:
        return ImportedMaterial(name, path, shader_id or "no surface shader", None, {}, {},
                                {}, unit_m, f"no subsurface ({shader_id or 'no surface'}"
                                            f" shader): left out", bound=bound,
                                subsurface=False)
    names = (mapping.weight, mapping.albedo, *mapping.distance, mapping.eta,
             *((mapping.anisotropy,) if mapping.anisotropy else ()),
             *((mapping.unit_length,) if mapping.unit_length else ()))
    inputs = {}
    for n in names:                    # an input that cannot be read (a unit that is not a
        try:                           # distance, a value USD cannot give) leaves this
            inputs[n] = read(n) or default_input(mapping, n)   # material out, named; the
        except SceneError as exc:                              # others bake
            why = str(exc)
        except Exception as exc:       # noqa: BLE001 (a reader's fault is this material's)
            why = f"{n} cannot be read: {type(exc).__name__}: {one_line(exc)}"
        else:
            continue
        return ImportedMaterial(name, path, mapping.name, mapping.mfp_kind, {}, {}, {}, unit_m,
                                f"not bakeable: {why}", bound=bound)
    described = {n: i.describe() for n, i in inputs.items()}

    def left(reason, subsurface=True):
        return ImportedMaterial(name, path, mapping.name, mapping.mfp_kind, {}, {}, described,
                                unit_m, reason, bound=bound, subsurface=subsurface)

    weight = inputs[mapping.weight]
    if weight.value is not None and not weight.value[0] > 0:
        return left(f"no subsurface ({mapping.weight} = {weight.value[0]:g}): left out", False)
    try:
        _check_bakeable(mapping, inputs)
        mfp, scale = _distance(mapping, inputs, unit_m, f"{path}: {mapping.distance[0]}")
    except (NotBakeable, SceneError) as exc:
        return left(f"not bakeable: {exc}")
    albedo = inputs[mapping.albedo]
    facts = {"albedo": albedo.texture.file if albedo.texture else list(albedo.value),
             "mfp": mfp, "mfp_scale": scale, "eta": list(inputs[mapping.eta].value),
             "mfp_kind": mapping.mfp_kind, "unit": unit_name(unit_m)}
    if albedo.texture is not None:
        facts["colorspace"] = albedo.texture.colorspace
    distance = next((inputs[n].texture for n in mapping.distance if inputs[n].texture), None)
    for key, texture in (("albedo_layer", albedo.texture), ("mfp_layer", distance)):
        if texture is not None and texture.layer:
            facts[key] = texture.layer       # the layer the node reads: the one baked
    # <UDIM> whatever the albedo's tile token: it is the one USD and MaterialX resolve, so the
    # records name the files (a <UVTILE> output's record resolved to nothing)
    tile = tiles.token_of(albedo.texture.file) if albedo.texture is not None else None
    output = f"{out_dir}/{name}.<UDIM>.exr" if tile else f"{out_dir}/{name}.exr"
    return ImportedMaterial(name, path, mapping.name, mapping.mfp_kind, facts,
                            {"output": output, "targets": list(DEFAULT_TARGETS)}, described,
                            unit_m, None,
                            _notes(mapping, inputs), bound=bound)


def unique_names(paths) -> dict:
    """{prim path: material name}: the last path element, or the whole path joined by '_'
    where two materials share a last element; a name that is still not unique (/A/skin and
    /A_skin both give A_skin), also when only its case differs (Skin and skin: one file on a
    case-insensitive share), gets _2, _3, ... in path order after its first."""
    last = [p.rstrip("/").rsplit("/", 1)[-1].casefold() for p in paths]
    names = [p.rstrip("/").rsplit("/", 1)[-1] if last.count(n) == 1
             else p.strip("/").replace("/", "_") for p, n in zip(paths, last)]
    given, out, taken = {n.casefold() for n in names}, {}, set()
    for p, n in sorted(zip(paths, names)):
        name, k = n, 1                 # a suffixed name never takes another material's own
        while name.casefold() in taken or (k > 1 and name.casefold() in given):
            k += 1
            name = f"{n}_{k}"
        out[p] = name
        taken.add(name.casefold())
    return {p: out[p] for p in paths}
