"""The material networks a bake writes for its render targets (I/O): one typed description
per material and target (``Network``: the shader's inputs, each a constant or a
``TextureRead``), which ``usd_networks`` authors as UsdShade prims and ``mtlx_networks`` as a
MaterialX document: the same network in both (docs/materials.md).

A texture read names everything a renderer needs to read the texels a bake means: the file
relative to the records folder, with ``<UDIM>`` as its tile token (the one USD and MaterialX
resolve; Houdini's ``%(UDIM)d`` names the same files), its colour space (``raw`` for data:
every coefficient and distance), and the EXR layer or first channel it reads (one file holds
every output of a material, ``sigma_a.R``...). A target whose inputs are in another
convention than the bake's needs ``convert`` (``physics.conventions``); until then it is
not written, and the manifest and plan say why.
"""
from __future__ import annotations

import glob
import math
import os
import re
from dataclasses import asdict, dataclass, field

from . import tiles, usdz
from ..methods.registry import TEXTURE_WRAP
from ..physics.conventions import CONVENTION
from .colour import active_config
from .patterns import PATTERN_FIELDS
from .scene_file import UNIT_METERS
from .targets import TARGET, Target


@dataclass(frozen=True)
class TextureRead:
    """One texture a network reads: ``file`` relative to the records folder (``./a.<UDIM>.exr``,
    or absolute where it is on another drive), ``colorspace`` (a declared name, ``raw`` for
    data, ``auto``: as the file declares), ``layer`` (the EXR layer, None: the file's first
    channels) and ``first_channel`` (where it starts in the file as OpenImageIO reads it);
    ``wrap``: how a lookup beyond the edges reads it, as the file declares (a TEXTURE_WRAP
    name; "clamp" where it declares none: the library's default)."""

    role: str                        # albedo, mfp, or an output's name
    file: str
    colorspace: str
    layer: str | None = None
    first_channel: int = 0
    channels: int = 3
    wrap: str = "clamp"

    @property
    def tiled(self) -> bool:
        return "<UDIM>" in self.file

    @property
    def is_data(self) -> bool:
        return self.colorspace == "raw"


@dataclass(frozen=True)
class Network:
    """A target's shader for one material: its inputs (name -> floats or TextureRead)."""

    target: Target
    material: str
    inputs: dict
    notes: tuple = ()

    @property
    def textures(self) -> tuple:
        return tuple(v for v in self.inputs.values() if isinstance(v, TextureRead))


def network_record(network: Network) -> dict:
    """``network`` as plain data (JSON, a layer's customLayerData): what ``network_of`` reads
    back."""
    return {"target": network.target.name, "material": network.material,
            "inputs": {k: ({"texture": asdict(v)} if isinstance(v, TextureRead) else
                           [float(x) for x in v]) for k, v in network.inputs.items()},
            "notes": list(network.notes)}


def network_of(record: dict) -> Network:
    """The Network of a ``network_record`` (KeyError, TypeError, ValueError on another)."""
    return Network(TARGET[record["target"]], str(record["material"]),
                   {k: (TextureRead(**v["texture"]) if isinstance(v, dict) else
                        tuple(float(x) for x in v)) for k, v in record["inputs"].items()},
                   tuple(record.get("notes", ())))


@dataclass(frozen=True)
class BakedMaterial:
    """What a bake knows of one baked material, as networks need it. Paths are absolute
    (patterns with their own tile token); distances in ``unit_m`` metres (the material's
    unit), which ``stage_unit_m`` (the unit of the stage the networks go into) may differ
    from."""

    name: str
    albedo: str | tuple
    colorspace: str
    mfp: str | tuple
    mfp_scale: tuple
    mfp_kind: str
    model: str
    eta: tuple
    unit: str
    stage_unit_m: float
    targets: tuple
    output: str | None = None        # the coefficient files' pattern (None: constants)
    outputs: tuple = ()
    channels: dict = field(default_factory=dict)
    first_channel: dict = field(default_factory=dict)
    maps: dict | None = None         # {convention: the manifest's maps entry}; absent: planned
    working_space: str = "auto"      # the colour maps' space (the bake's working space)
    layers: dict = field(default_factory=dict)   # {"albedo"/"mfp": (the EXR layer read, its
    #                                              first channel in the file)}
    wrap: str = "clamp"              # the wrap its maps and coefficient files declare

    @property
    def unit_m(self) -> float:
        return UNIT_METERS[self.unit]


def identifier(name: str) -> str:
    """A material's name as USD (a prim) and MaterialX (an element) both take it, the one
    name in the ``.usda`` and the ``.mtlx``: every character outside [A-Za-z0-9_] becomes
    ``_`` (one per character), a leading digit gets one before it (``1skin``: ``_1skin``)."""
    name = re.sub(r"[^A-Za-z0-9_]", "_", name) or "_"
    return f"_{name}" if name[0].isdigit() else name


def next_identifier(name: str, taken) -> str:
    """``identifier(name)``, else where another material has it (``taken``, compared
    casefolded: a-b, a_b; USD's and file systems' case may not tell them apart) the first
    of ``_2``, ``_3``... that is free."""
    taken = {t.casefold() for t in taken}
    ident, k = identifier(name), 1
    while ident.casefold() in taken:
        k += 1
        ident = f"{identifier(name)}_{k}"
    return ident


class NotWritten(Exception):
    """Why a target's network is not written for a material (one line)."""


def has_fields(path: str) -> bool:
    """Whether an output pattern holds fields filled per input file (``{stem}``, ``{udim}``,
    ...: ``patterns.PATTERN_FIELDS``), which no USD or MaterialX resolver fills."""
    return any(f"{{{f}}}" in path for f in PATTERN_FIELDS)


def is_literal(path: str, conv) -> bool:
    """Whether a path with glob characters names files literally (``tex[v2]/a.exr``, as
    ``tiles.expand`` tries first): it exists, or its tiles do under its literal prefix."""
    if conv is None:
        return os.path.exists(path)
    prefix = path.split(conv.token)[0]
    return any(f.startswith(prefix) for f, _ in tiles.expand(path))


def relative_file(path: str, folder: str) -> str:
    """``path`` (a pattern or file) relative to ``folder`` as ``./...`` with ``/``, its tile
    token as ``<UDIM>`` (NotWritten for a UV-tile token or a per-file field: USD cannot
    resolve them)."""
    if has_fields(path):
        raise NotWritten(f"{path}: its fields ({', '.join(PATTERN_FIELDS)}) are filled per "
                         f"file; a texture node needs one pattern: name the outputs with "
                         f"<UDIM>")
    conv = tiles.token_of(path)
    literal = path.replace(conv.token, "") if conv else path
    if glob.has_magic(literal) and not is_literal(path, conv):
        raise NotWritten(f"{path}: a glob names several files; a texture node needs one file "
                         f"or a <UDIM> set")
    if conv is not None and not conv.is_udim():
        raise NotWritten(f"{path}: {conv.token} names tiles as {conv.convention}, which USD "
                         f"and MaterialX texture nodes do not resolve; name the files with "
                         f"<UDIM>")
    if conv is not None:
        path = path.replace(conv.token, "<UDIM>")
    packaged = usdz.origin(path.replace("<UDIM>", conv.token) if conv else path)
    if packaged is not None:           # the package's member, not the cache's copy
        match = usdz.PACKAGED.match(packaged)
        member = match["member"].replace(conv.token, "<UDIM>") if conv else match["member"]
        return f"{relative_file(match['package'], folder)}[{member}]"
    try:
        rel = os.path.relpath(path, folder)
    except ValueError:                 # another drive: as it is
        return path.replace(os.sep, "/")
    return "./" + rel.replace(os.sep, "/")


def mtlx_address(read: TextureRead) -> str:
    """MaterialX's image address mode (``uaddressmode``, ``vaddressmode``) of the wrap the
    file ``read`` declares (``TextureWrap.mtlx_address``)."""
    return TEXTURE_WRAP[read.wrap].mtlx_address


#: MaterialX's colour space names (its default colour management system's)
MTLX_SPACES = ("srgb_texture", "lin_rec709", "g22_rec709", "g18_rec709", "acescg", "lin_ap1",
               "g22_ap1", "g18_ap1", "lin_srgb", "adobergb", "lin_adobergb", "srgb_displayp3",
               "lin_displayp3")
#: USD's colour space names (``colorSpace`` metadata, USD 25.05's GfColorSpace names)
USD_SPACES = ("lin_rec709_scene", "srgb_rec709_scene", "g22_rec709_scene", "lin_ap1_scene",
              "lin_ap0_scene", "srgb_ap1_scene", "g22_ap1_scene", "lin_p3d65_scene",
              "srgb_p3d65_scene", "g22_adobergb_scene", "identity", "raw")


def texture_space(colorspace: str) -> str:
    """A texture's colour space as a network names it: ``raw`` for data (a space the config
    calls data), ``auto`` where nothing is declared, else the config's name."""
    if not colorspace or colorspace == "auto":
        return "auto"
    config = active_config()
    space = config.space(colorspace)
    return "raw" if colorspace.casefold() == "raw" or (space and config.is_data(space)) \
        else colorspace


def space_name(colorspace: str, vocabulary) -> str:
    """The name another system knows a config's colour space by (MTLX_SPACES, USD_SPACES:
    the first alias there), else the config's own name (an OCIO-managed renderer reads it)."""
    if colorspace in ("auto", "raw"):
        return colorspace
    return active_config().alias_in(colorspace, vocabulary) or colorspace


def colour(values) -> tuple:
    """Three floats of a constant (one value: grey)."""
    v = tuple(float(x) for x in values)
    return v * 3 if len(v) == 1 else v[:3]


def one_eta(b: BakedMaterial) -> float:
    """The material's one index of refraction (a shader's IOR is one number)."""
    if len(set(b.eta)) > 1:
        raise NotWritten(f"eta differs per channel ({', '.join(f'{e:g}' for e in b.eta)}); "
                         f"the shader's IOR is one number")
    return float(b.eta[0])


def painted_read(b: BakedMaterial, role: str, path: str, space: str, folder: str):
    """A TextureRead of a painted texture (``role``: albedo, mfp), its layer's first channel
    where the material reads a layer."""
    layer, first = b.layers.get(role, (None, 0))
    return TextureRead(role, relative_file(path, folder), space, layer, first)


def albedo_input(b: BakedMaterial, folder: str):
    if isinstance(b.albedo, str):
        return painted_read(b, "albedo", b.albedo, texture_space(b.colorspace), folder)
    return colour(b.albedo)


def first_channels(read) -> None:
    """NotWritten where ``read`` is a layer that does not start at the file's first channel:
    UsdUVTexture and MaterialX's image nodes read a file's first channels (MaterialX's GLSL
    generator ignores ``layer``, its OSL one takes it for a subimage's name)."""
    if isinstance(read, TextureRead) and read.first_channel:
        raise NotWritten(f"its {read.role} is layer {read.layer!r} of {read.file}, from "
                         f"channel {read.first_channel}: this target's texture node reads a "
                         f"file's first channels (RenderMan's PxrTexture reads the layer)")


def preview_network(target, b: BakedMaterial, folder) -> Network:
    """UsdPreviewSurface: the painted albedo as the diffuse colour (it has no subsurface)."""
    first_channels(albedo_input(b, folder))
    return Network(target, b.name, {"diffuseColor": albedo_input(b, folder),
                                    "ior": (one_eta(b),)},
                   ("UsdPreviewSurface has no subsurface: the albedo is shown as its diffuse "
                    "colour",))


def painted_directly(b: BakedMaterial, convention: str) -> bool:
    """Whether ``b``'s painted colour and distance are already in ``convention``."""
    return b.mfp_kind == "diffuse" and CONVENTION.canonical(b.model) == convention


def converted_inputs(b: BakedMaterial, convention: str, folder: str) -> tuple:
    """(colour, radius) of ``b`` in ``convention``: TextureReads of the maps the bake wrote
    (one file per layer, ``colour`` and ``radius``) or a constant material's numbers (radius in the
    material's unit); NotWritten where the maps could not be made."""
    entry = (b.maps or {}).get(convention)
    if entry is None:                    # the plan: the maps the bake will write (a bake
        entry = {layer: f"{b.output[:-4]}.{convention}.{layer}.exr"   # records every one
                 for layer in ("colour", "radius")} if b.output else \
            {"constants": {"colour": [0.0], "radius": [1.0]}}         # it made, or why not)
    if not entry or entry.get("error"):
        raise NotWritten(entry.get("error") if entry else f"no {convention} maps were made")
    if "constants" in entry:
        return colour(entry["constants"]["colour"]), colour(entry["constants"]["radius"])
    if "layers" in entry:                # one file of both layers (bdipole-cl convert's)
        return entry["layers"]
    return tuple(TextureRead(layer, relative_file(os.path.join(folder, entry[layer]), folder),
                             space, wrap=b.wrap) for layer, space in (
                                 ("colour", texture_space(b.working_space)),
                                 ("radius", "raw")))


def pxrsurface_network(target, b: BakedMaterial, folder) -> Network:
    """PxrSurface: the painted colour and the diffuse mean free path, which is this library's
    convention (Better Dipole, mfp = ld = 1/mu_tr) as PxrSurface's inputs read it; the whole
    distance in the stage's unit in ``subsurfaceDmfpColor`` x ``subsurfaceDmfp``, with
    ``unitLength`` 1 (RenderMan's default 0.1 would scale it)."""
    to_stage = b.unit_m / b.stage_unit_m          # a distance in the material's unit, in
    scale = [s * to_stage for s in b.mfp_scale]   # the stage's
    inputs = {"subsurfaceGain": (1.0,), "subsurfaceColor": albedo_input(b, folder),
              "subsurfaceIor": (one_eta(b),), "unitLength": (1.0,)}
    if target.convention in (b.maps or {}) or not painted_directly(b, target.convention):
        col, radius = converted_inputs(b, target.convention, folder)
        inputs["subsurfaceColor"] = col
        if isinstance(radius, TextureRead):
            inputs["subsurfaceDmfpColor"], inputs["subsurfaceDmfp"] = radius, (to_stage,)
        else:
            inputs["subsurfaceDmfpColor"] = tuple(r * to_stage for r in radius)
            inputs["subsurfaceDmfp"] = (1.0,)
        return Network(target, b.name, inputs)
    if isinstance(b.mfp, str):
        if len(set(scale)) > 1:
            raise NotWritten(f"the dmfp texture has a scale per channel "
                             f"({', '.join(f'{s:g}' for s in scale)}); subsurfaceDmfp is one "
                             f"number")
        inputs["subsurfaceDmfpColor"] = painted_read(b, "mfp", b.mfp, "raw", folder)
        inputs["subsurfaceDmfp"] = (scale[0],)
    else:
        mfp = colour(b.mfp)
        scale3 = colour(scale)
        inputs["subsurfaceDmfpColor"] = tuple(m * s for m, s in zip(mfp, scale3))
        inputs["subsurfaceDmfp"] = (1.0,)
    if not all(math.isfinite(v) for k, vs in inputs.items() if not isinstance(vs, TextureRead)
               for v in vs):
        raise NotWritten("a distance or IOR that is not finite")
    return Network(target, b.name, inputs)


#: per MaterialX target: weight, colour, (radius float, radius colour: which one is the map),
#: IOR input names
MTLX_INPUTS = {
    "openpbr": ("subsurface_weight", "subsurface_color", "subsurface_radius",
                "subsurface_radius_scale", "specular_ior"),
    "standard-surface": ("subsurface", "subsurface_color", "subsurface_scale",
                         "subsurface_radius", "specular_IOR"),
}


def converted_network(target, b: BakedMaterial, folder) -> Network:
    """OpenPBR and Standard Surface: colour and radius in the target's convention (van de
    Hulst), from this library's through ``bdipole_cl.convert``: the colour map, the radius
    map (data) times the stage's unit."""
    weight, col_name, scale_name, radius_name, ior = MTLX_INPUTS[target.name]
    col, radius = converted_inputs(b, target.convention, folder)
    to_stage = b.unit_m / b.stage_unit_m
    if not isinstance(radius, TextureRead):
        radius, to_stage = tuple(r * to_stage for r in radius), 1.0
    return Network(target, b.name, {weight: (1.0,), col_name: col, scale_name: (to_stage,),
                                    radius_name: radius, ior: (one_eta(b),)})


BUILDERS = {"preview": preview_network, "pxrsurface": pxrsurface_network,
            "openpbr": converted_network, "standard-surface": converted_network}


def networks(b: BakedMaterial, folder: str) -> tuple:
    """([Network] written, {target: why not}) of a baked material's targets."""
    written, why = [], {}
    for name in b.targets:
        target = TARGET[name]
        try:
            written.append(BUILDERS[target.name](target, b, folder))
        except NotWritten as exc:
            why[target.name] = str(exc)
    return written, why


def layer_path(path: str, layer: str, convention: str | None = None) -> str:
    """The file (or pattern) of one layer of an output of ours that holds several (``layer``
    of ``skin.<UDIM>.exr`` is ``skin.<UDIM>.{layer}.exr``): its channels alone, first, for
    the texture nodes that read a file's first channels (``jobs.layer_files`` writes it).
    ``convention``: the conversion's, named in the file where the output's name does not
    already end with it (``skin.exr``: ``skin.van-de-hulst.colour.exr``), so that a run to
    another convention into the same output never rewrites the files an earlier network
    reads."""
    base = path[:-4]
    if convention and not base.endswith(f".{convention}"):
        base = f"{base}.{convention}"
    return f"{base}.{layer}.exr"


def coefficient_reads(b: BakedMaterial, folder: str) -> tuple:
    """A TextureRead of each output of a textured material (its own file of that layer of the
    coefficient files, data), () for a constant one or an output pattern USD cannot
    resolve."""
    if b.output is None:
        return ()
    try:
        return tuple(TextureRead(o, relative_file(layer_path(b.output, o), folder), "raw",
                                 None, 0, len(b.channels.get(o, ())) or 3, b.wrap)
                     for o in b.outputs if b.channels.get(o))
    except NotWritten:
        return ()
