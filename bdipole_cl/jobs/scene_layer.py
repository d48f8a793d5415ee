"""The bake's own USD layer, ``bdipole.usda`` (the jobs layer; written by ``scene_records``):
an ``over`` on each baked material prim with its records (``bdipole:`` attributes: each
output's files as USD resolves them, the EXR layer and channels that are its own, a constant
material's coefficients) and its material networks for the bake's render targets
(``io.networks``, authored by ``io.usd_networks``). docs/materials.md says how to use it.
"""
from __future__ import annotations

import os
from dataclasses import dataclass

from ..io import tiles
from ..io.channels import classify_channels
from ..io.colour import resolve_working_space
from ..io.images import image_header
from ..io.networks import (BakedMaterial, coefficient_reads, has_fields, networks,
                           next_identifier)
from ..io.scene_file import UNIT_METERS

#: the first words of the records layer's comment: the mark of this tool's own layer
LAYER_MARK = "bdipole-cl bake of "


def baked_material(m, entry: dict, stage_unit_m: float) -> BakedMaterial:
    """What the networks need of a baked material (``entry``: its manifest entry)."""
    return BakedMaterial(
        m.name, m.albedo, m.colorspace, m.mfp, tuple(m.mfp_scale), m.mfp_kind, m.model,
        tuple(m.eta), m.unit, stage_unit_m, tuple(m.targets),
        None if m.constant else m.output, tuple(m.outputs), entry.get("channels", {}),
        entry.get("first_channel", {}), entry.get("maps"),
        resolve_working_space(m.working_space).name, painted_layers(m),
        m.texture.wrap_mode if m.texture else "clamp")


def painted_layers(m) -> dict:
    """{"albedo"/"mfp": (layer, its first channel)} of the painted textures ``m`` reads a
    layer of (its first tile's header; a file that cannot be read now: channel 0)."""
    found = {}
    for role, path, layer in (("albedo", m.albedo, m.albedo_layer), ("mfp", m.mfp, m.mfp_layer)):
        if layer is None or not isinstance(path, str):
            continue
        hits = tiles.expand(path) if tiles.is_pattern(path) else [(path, None)]
        spec = image_header(hits[0][0]) if hits else None
        colour = classify_channels(spec.channelnames, spec.alpha_channel, layer=layer)[0] \
            if spec is not None else []
        found[role] = (layer, colour[0] if colour else 0)
    return found



def output_channels(files, outputs) -> tuple:
    """({output: its channel names}, {output: the index of its first channel}) in the files
    of one material as OpenImageIO reads them (the first file's header: every tile of a
    material has the same channels). One file holds every output, each as an EXR layer
    (``sigma_a.R``...): a reader of the file's first colour channels gets the first output,
    so each record names its own ({}, {} when no file was written)."""
    spec = next((h for h in (image_header(f) for f in files) if h is not None), None)
    if spec is None:
        return {}, {}
    names = list(spec.channelnames)
    channels = {o: [n for n in names if n.startswith(f"{o}.")] for o in outputs}
    return channels, {o: names.index(c[0]) for o, c in channels.items() if c}


def usd_asset_records(output: str, files: list) -> tuple:
    """(the ``<UDIM>`` asset path or file a USD record names for an output pattern relative
    to the layer, None) where USD resolves that pattern itself (``UsdShade.UdimUtils`` knows
    ``<UDIM>`` only: Houdini's ``%(UDIM)d`` names the same files and is written as it), else
    (None, [each tile file]) for the UV tile conventions and the fields a pattern fills per
    file (``{stem}``, ``{udim}``...), which USD cannot resolve."""
    if has_fields(output):              # {stem}, {udim}...: filled per file, no pattern
        return None, ["./" + f.replace(os.sep, "/") for f in files]   # USD can resolve
    conv = tiles.token_of(output)
    if conv is None:
        return output, None
    if conv.is_udim():
        return output.replace(conv.token, "<UDIM>"), None
    return None, ["./" + f.replace(os.sep, "/") for f in files]



#: where the records of a material inside an instance go: USD ignores an ``over`` on a prim
#: of an instance's prototype (an instance proxy), so they are a prim of their own there, named
#: as the material, whose ``bdipole:material`` relationship targets the material's path
INSTANCED_RECORDS = "/bdipole_instanced"


#: where a scene file's own materials (no prim of a stage) are defined, as materials
FILE_MATERIALS = "/bdipole_materials"


@dataclass(frozen=True)
class Recorded:
    """Where a baked material's records and networks go: an ``over`` on its prim (``kind``
    "over"), a prim of its own that targets it (``"instanced"``), or a new material of a
    scene file (``"def"``); ``unit_m`` the metres per unit of the stage its networks are for."""

    name: str
    path: str
    kind: str
    unit_m: float
    target: str | None = None


def recorded(scene, records: dict) -> list:
    """[(Recorded, manifest entry, Material)] of every baked material with records: each
    imported one, and a scene file's own ones with targets."""
    by_name = {e["name"]: e for e in records["materials"]}
    materials = {m.name: m for m in scene.materials}
    found, taken = [], set()
    for imp in scene.imports:
        entry = by_name.get(imp.name)
        if entry and entry.get("baked"):
            where = (Recorded(imp.name, f"{INSTANCED_RECORDS}/{imp.name}", "instanced",
                              imp.unit_m, imp.path) if imp.instanced else
                     Recorded(imp.name, imp.path, "over", imp.unit_m))
            found.append((where, entry, materials[imp.name]))
    imported = {imp.name for imp in scene.imports}
    unit_m = layer_unit(scene)
    for m in scene.materials:
        entry = by_name.get(m.name)
        if m.name in imported or not m.targets or not entry or not entry.get("baked"):
            continue
        ident = next_identifier(m.name, taken)   # two names one identifier (a-b, a_b)
        taken.add(ident)
        found.append((Recorded(m.name, f"{FILE_MATERIALS}/{ident}", "def", unit_m), entry, m))
    return found


def layer_unit(scene) -> float:
    """The metres per unit of the records layer (its ``metersPerUnit``): the stage's, else
    the unit of the scene file's first material with targets (each material's distances are
    converted into it), else metres."""
    if scene.imports:
        return scene.imports[0].unit_m
    return next((UNIT_METERS[m.unit] for m in scene.materials if m.targets), 1.0)


def layer_up_axis(scene) -> str:
    """The records layer's ``upAxis``: the stage's root layer's, else USD's fallback (a
    MaterialX document or a scene file has none)."""
    from pxr import Sdf, UsdGeom
    layer = None
    if scene.source and not str(scene.source).lower().endswith(".mtlx"):
        try:
            layer = Sdf.Layer.FindOrOpen(str(scene.source))
        except Exception:                # pxr raises Tf.ErrorException on a bad layer
            layer = None
    if layer is not None and layer.pseudoRoot.HasInfo(UsdGeom.Tokens.upAxis):
        return str(layer.pseudoRoot.GetInfo(UsdGeom.Tokens.upAxis))
    return str(UsdGeom.GetFallbackUpAxis())


def record_prim(layer, where: Recorded):
    """The records layer's prim spec for an imported material: an ``over`` on its prim (its
    parents ``over`` too), or for one inside an instance (``imp.instanced``) a prim under
    INSTANCED_RECORDS targeting it."""
    from pxr import Sdf
    spec = Sdf.CreatePrimInLayer(layer, Sdf.Path(where.path))
    if where.kind == "over":
        record_prim_over(spec)
        return spec
    spec.specifier = Sdf.SpecifierDef
    spec.typeName = "Material"             # its networks are a material of their own
    spec.nameParent.specifier = Sdf.SpecifierDef
    if where.target:
        rel = Sdf.RelationshipSpec(spec, "bdipole:material", custom=True)
        rel.targetPathList.explicitItems = [Sdf.Path(where.target)]
    return spec


def usd_layer_text(scene, records: dict, folder) -> str:
    """bdipole.usda: an ``over`` on each baked imported material prim; its
    ``metersPerUnit`` and ``upAxis`` those its networks' distances are in (the stage's)."""
    from pxr import Sdf, UsdGeom, Vt
    layer = Sdf.Layer.CreateAnonymous(".usda")
    layer.pseudoRoot.SetInfo(UsdGeom.Tokens.metersPerUnit, layer_unit(scene))
    layer.pseudoRoot.SetInfo(UsdGeom.Tokens.upAxis, layer_up_axis(scene))
    layer.comment = (f"{LAYER_MARK}{os.path.basename(str(scene.source or scene.path))}: "
                     f"put it over the stage (the first of a root layer's sublayers, then the "
                     f"stage) to find each material's coefficients (bdipole: attributes) and "
                     f"its networks for the bake's targets (docs/materials.md)")
    wired = []
    for where, entry, m in recorded(scene, records):
        spec = record_prim(layer, where)
        wired.append((str(spec.path), baked_material(m, entry, where.unit_m),
                      where.kind != "over"))

        def attr(name, type_name, value):
            a = Sdf.AttributeSpec(spec, f"bdipole:{name}", type_name)
            a.default = value

        attr("mfp_kind", Sdf.ValueTypeNames.Token, entry["mfp_kind"])
        attr("unit", Sdf.ValueTypeNames.String, entry["coefficient_unit"])
        attr("eta", Sdf.ValueTypeNames.FloatArray, Vt.FloatArray(entry["eta"]))
        for output in entry["outputs"]:
            if "coefficients" in entry:
                values = (entry["coefficients"] or {}).get(output, [])
                attr(output, Sdf.ValueTypeNames.FloatArray, Vt.FloatArray(values))
                continue
            file_attributes(attr, output, entry["output"], entry["files"])
            channels = entry.get("channels", {}).get(output)
            if channels:               # which of the file's channels are this output's
                attr(f"{output}:layer", Sdf.ValueTypeNames.String, output)
                attr(f"{output}:channels", Sdf.ValueTypeNames.StringArray,
                     Vt.StringArray(channels))
                attr(f"{output}:firstChannel", Sdf.ValueTypeNames.Int,
                     entry["first_channel"][output])
        stretch_attributes(spec, entry.get("stretch") or {}, attr)
    author_networks(layer, wired, folder)
    return layer.ExportToString()


def file_attributes(attr, name: str, output: str, files) -> None:
    """``name`` as USD resolves an output's ``files``: an asset path with ``<UDIM>`` where
    one pattern names them all (``usd_asset_records``), else ``{name}:tiles``, each file."""
    from pxr import Sdf
    pattern, tile_files = usd_asset_records(output, files)
    if pattern is not None:
        attr(name, Sdf.ValueTypeNames.Asset, Sdf.AssetPath(pattern))
    else:
        attr(f"{name}:tiles", Sdf.ValueTypeNames.AssetArray,
             Sdf.AssetPathArray([Sdf.AssetPath(f) for f in tile_files]))


def stretch_attributes(spec, records: dict, attr):
    """The stretch maps of a material's blurs (``records``: the manifest entry's ``stretch``)
    on its record prim ``spec``, each blur's under ``bdipole:stretch:{blur}``: the files as
    USD resolves them (an asset path with ``<UDIM>``, else ``:tiles``), ``:unit``,
    ``:channels`` and, for meshes a stage binds, a ``:meshes`` relationship to them."""
    from pxr import Sdf, Tf, Vt
    taken = set()
    for blur, record in sorted(records.items()):
        if not record.get("files"):
            continue
        name, k = f"stretch:{Tf.MakeValidIdentifier(blur)}", 1
        while name in taken:                  # two blurs one identifier (a-b, a_b)
            k += 1
            name = f"stretch:{Tf.MakeValidIdentifier(blur)}_{k}"
        taken.add(name)
        file_attributes(attr, name, record["maps"], record["files"])
        attr(f"{name}:unit", Sdf.ValueTypeNames.String, record["unit"])
        attr(f"{name}:channels", Sdf.ValueTypeNames.StringArray,
             Vt.StringArray(record["channels"]))
        if record.get("prims"):
            rel = Sdf.RelationshipSpec(spec, f"bdipole:{name}:meshes", custom=True)
            rel.targetPathList.explicitItems = [Sdf.Path(p) for p in record["prims"]]


def author_networks(layer, wired, folder):
    """Each baked material's networks for its targets and its coefficients node graph, on
    its prim of ``layer`` (``wired``: [(prim path, BakedMaterial)])."""
    if not wired:
        return
    from pxr import Usd

    from ..io import usd_networks
    stage = Usd.Stage.Open(layer)
    for path, baked, _ in wired:
        for network in networks(baked, folder)[0]:
            usd_networks.author(stage, path, network)
        usd_networks.author_coefficients(stage, path, coefficient_reads(baked, folder))
    for path, _, instanced in wired:   # defining shaders made their ancestors defs: the
        if not instanced:              # user's material (and its parents) stay overs
            record_prim_over(layer.GetPrimAtPath(path))


def record_prim_over(spec):
    """``spec`` and its parents as ``over``: the layer adds to the user's prims, never
    defines one (a renamed material would otherwise appear as a prim of its own)."""
    from pxr import Sdf
    while spec and spec.path != Sdf.Path.absoluteRootPath:
        spec.specifier = Sdf.SpecifierOver
        spec = spec.nameParent


def mtlx_text(scene, records: dict, folder) -> str:
    """bdipole.mtlx: each baked imported material's MaterialX networks and coefficients graph
    (``io.mtlx_networks``), the same as the layer's, a scene file's material named as its
    prim is."""
    from ..io.mtlx_networks import document_text
    found = []
    for where, entry, m in recorded(scene, records):
        baked = baked_material(m, entry, where.unit_m)
        name = where.path.rsplit("/", 1)[-1] if where.kind == "def" else where.name
        found.append((name, networks(baked, folder)[0], coefficient_reads(baked, folder),
                      where.unit_m))
    return document_text(found, f"{LAYER_MARK}{os.path.basename(str(scene.source or scene.path))}"
                                f": the materials of bdipole.usda as MaterialX "
                                f"(docs/materials.md)")


def target_lines(m, stage_unit_m, folder) -> list:
    """What the plan says of a material's render targets: the networks the bake writes, and
    why any other is not written."""
    from .scene_maps import conventions_needed, conversion_problem
    problems = {c: {"error": f"its {c} maps: {p}"} for c in conventions_needed(m)
                if (p := conversion_problem(m.model, c, m.eta[0]))}
    written, why = networks(baked_material(m, {"maps": problems} if problems else {},
                                           stage_unit_m), folder)
    lines = [f"  targets: {', '.join(n.target.name for n in written)} (bdipole.usda"
             + (", bdipole.mtlx" if any(n.target.mtlx for n in written) else "") + ")"] \
        if written else []
    return lines + [f"  target {t}: not written: {w}" for t, w in why.items()]
