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
from dataclasses import dataclass, field

import numpy as np

from . import tiles
from .scene_file import UNIT_METERS, ImportedMaterial, SceneError


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
        "OpenPBR Surface", ("ND_open_pbr_surface_surfaceshader", "open_pbr_surface"),
        "subsurface_color", ("subsurface_radius", "subsurface_radius_scale"), "specular_ior",
        "subsurface_weight", "extinction",
        "OpenPBR Surface specification, Subsurface: the radius is the mean free path of the medium",
        {"subsurface_weight": (0.0,), "subsurface_color": (0.8, 0.8, 0.8),
         "subsurface_radius": (1.0,), "subsurface_radius_scale": (1.0, 0.5, 0.25),
         "specular_ior": (1.5,), "subsurface_scatter_anisotropy": (0.0,)},
        "subsurface_scatter_anisotropy"),
    ShaderMapping(
        "Standard Surface", ("ND_standard_surface_surfaceshader", "standard_surface"),
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

#: USD and MaterialX nodes whose file is a texture a scene can bake from
TEXTURE_NODES = ("UsdUVTexture", "image", "tiledimage")

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


def _texel_refusals(inp, is_albedo) -> list:
    """Why a texture's texels cannot be baked as they are (its colour channels, the
    distance's scaled): one channel, a bias, a scale of the albedo (never ignored)."""
    t = inp.texture
    if t is None:
        return []
    why = []
    if t.channel is not None:
        why.append(f"{inp.name} reads {t.channel} of {t.node}, one channel: a bake reads a "
                   f"texture's colour channels (UsdUVTexture outputs:rgb, a color3 image)")
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
    mapping = BY_ID.get(shader_id)
    if mapping is None:
        return ImportedMaterial(name, path, shader_id or "no surface shader", None, {}, {},
                                {}, unit_m, f"no subsurface ({shader_id or 'no surface'}"
                                            f" shader): left out", bound=bound)
    names = (mapping.weight, mapping.albedo, *mapping.distance, mapping.eta,
             *((mapping.anisotropy,) if mapping.anisotropy else ()),
             *((mapping.unit_length,) if mapping.unit_length else ()))
    try:                               # an input that cannot be read (a unit that is not
        inputs = {n: read(n) or default_input(mapping, n) for n in names}   # a distance)
    except SceneError as exc:          # leaves this material out, named; the others bake
        return ImportedMaterial(name, path, mapping.name, mapping.mfp_kind, {}, {}, {}, unit_m,
                                f"not bakeable: {exc}", bound=bound)
    described = {n: i.describe() for n, i in inputs.items()}

    def left(reason):
        return ImportedMaterial(name, path, mapping.name, mapping.mfp_kind, {}, {}, described,
                                unit_m, reason, bound=bound)

    weight = inputs[mapping.weight]
    if weight.value is not None and not weight.value[0] > 0:
        return left(f"no subsurface ({mapping.weight} = {weight.value[0]:g}): left out")
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
    tile = tiles.token_of(albedo.texture.file) if albedo.texture is not None else None
    output = f"{out_dir}/{name}.{tile.output_token}.exr" if tile else f"{out_dir}/{name}.exr"
    return ImportedMaterial(name, path, mapping.name, mapping.mfp_kind, facts,
                            {"output": output}, described, unit_m, None,
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
