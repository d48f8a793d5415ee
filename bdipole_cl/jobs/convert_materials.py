"""The materials of ``bdipole-cl convert`` runs (the jobs layer): each input texture set's
converted ``colour.*`` / ``radius.*`` file, wired into the render targets whose convention
is the run's target (``io.targets``: van-de-hulst -> openpbr, better-dipole -> pxrsurface),
as a UsdShade ``Material`` under ``/bdipole_materials`` of ``bdipole_convert.usda`` and the
same network in ``bdipole_convert.mtlx``, beside the outputs (docs/materials.md).

The texture nodes read each layer from a file of its own (``layer_files``:
``skin.van-de-hulst.colour.exr``, ``.radius.exr``): MaterialX's generators read a file's
first channels. Runs into one folder share the two files: each run's networks join those of
the earlier runs (kept as plain data in the layer's ``customLayerData``; a run replaces only
its own material's network of its own target), so a second run never drops the first's. The
layer states ``metersPerUnit`` (the first run's ``--unit``; a later run's distances are
converted into it) and ``upAxis``. Each file is rewritten only when its content changes,
never over a file this tool did not write there.
"""
from __future__ import annotations

import glob
import json
import os
import re
from dataclasses import replace
from pathlib import Path

from ..io import tiles
from ..io.channels import COLOUR_LAYERS
from ..io.colour import resolve_working_space
from ..io.images import TextureError, is_regular_file
from ..io.mipmaps import texture_options
from ..io.networks import (BakedMaterial, NotWritten, TextureRead, identifier, layer_path,
                           network_of, network_record, networks, next_identifier,
                           relative_file)
from ..io.scene_file import UNIT_METERS
from ..io.targets import TARGET
from .layer_files import layer_files
from .results import FileResult
from .scene_layer import FILE_MATERIALS, LAYER_MARK
from .scene_records import own_document, write_if_changed

LAYER = "bdipole_convert.usda"
DOCUMENT = "bdipole_convert.mtlx"
#: the layer's customLayerData key of every network it holds, as JSON: {material's identifier:
#: {target: networks.network_record}}
RECORDS = "bdipole_convert"
#: the layer's customLayerData key of what each material converts, as JSON: {identifier: its
#: input file or tile pattern, relative to the folder}: a set converted again keeps its name
SOURCES = "bdipole_convert_sources"
#: the up axis the layer states (USD's fallback; the layer holds no geometry)
UP_AXIS = "Y"


def convention_targets(convention: str) -> tuple:
    """The render targets whose inputs are in ``convention``, the first of each context."""
    chosen, contexts = [], set()
    for t in TARGET:
        if t.convention == convention and t.context not in contexts:
            chosen.append(t.name)
            contexts.add(t.context)
    return tuple(chosen)


def output_pattern(output: str, pattern: str, convention: str) -> str:
    """A convert run's output pattern for one input pattern: its fields filled from the
    pattern itself, its tile token kept (``{dir}/{stem}.{target}.exr`` of
    ``tex/skin.<UDIM>.exr`` is ``tex/skin.<UDIM>.van-de-hulst.exr``)."""
    p = Path(pattern)
    stem = p.name.rsplit(".", 1)[0] if "." in p.name else p.name
    text = output.replace("{target}", convention).replace("{dir}", str(p.parent))
    return text.replace("{stem}", stem).replace("{name}", p.name)


def material_name(pattern: str) -> str:
    """A texture set's name: its file name without extension nor tile token (with the one
    separator that joins the token: ``skin.<UDIM>.exr`` is ``skin``); every other character
    kept (``_skin.exr`` is ``_skin``; ``identifier`` makes it a name, docs/materials.md)."""
    name = Path(pattern).name.rsplit(".", 1)[0]
    conv = tiles.token_of(name)
    if conv:
        name = re.sub(r"[._-]\0|\0[._-]?", "", "\0".join(conv.parts))
    return name or "material"


def layered(pattern: str, files: list, working_space: str, folder: str, inputs, written,
            texture, convention: str):
    """The (colour, radius) TextureReads of one converted set: each layer's own file beside
    each output file (``layer_files``; ``texture``: the run's TextureOptions), named by the
    output's pattern and the ``convention`` (a run to another convention into the same
    output writes files of its own: an earlier network never reads its data)."""
    working = resolve_working_space(working_space)
    options = texture_options(texture)
    wrap = options.wrap_mode if options else "clamp"     # what the layer files declare
    for f in files:
        try:
            layer_files(f, COLOUR_LAYERS, working, written, inputs, texture, convention)
        except TextureError as exc:
            raise NotWritten(str(exc)) from None
    return tuple(TextureRead(layer, relative_file(layer_path(pattern, layer, convention),
                                                  folder), space, wrap=wrap)
                 for layer, space in (("colour", working_space), ("radius", "raw")))


def source_of(path: str, folder: str) -> str:
    """What a converted set is, as its material's record keeps it: its input file or tile
    pattern (tile token as ``<UDIM>``) relative to the materials' ``folder``."""
    conv = tiles.token_of(path)
    path = path.replace(conv.token, "<UDIM>") if conv else path
    try:
        return os.path.relpath(os.path.abspath(path), folder).replace(os.sep, "/")
    except ValueError:                   # another drive
        return os.path.abspath(path).replace(os.sep, "/")


def converted_sets(inputs, output: str, convention: str, results) -> dict:
    """{folder: [(its input, material name, output pattern, its output files)]} of a convert
    run: a tile pattern's files are one set (its output pattern keeps the token); every other
    converted file is a set of its own, whatever named it (a path or a glob: the file, never
    the pattern's text), in the folder its output is in."""
    done = {os.path.abspath(r.output): r for r in results
            if r.status in ("ok", "skipped") and r.output}
    sets, taken = {}, set()
    for pattern in map(str, inputs):
        if not tiles.token_of(pattern) or os.path.exists(pattern):
            continue
        out = os.path.abspath(output_pattern(output, pattern, convention))
        files = [h for h, _ in tiles.expand(out) if os.path.abspath(h) in done]
        if files:
            taken.update(os.path.abspath(f) for f in files)
            sets.setdefault(os.path.dirname(out), []).append(
                (pattern, material_name(pattern), out, files))
    for out, r in done.items():
        if out not in taken:
            sets.setdefault(os.path.dirname(out), []).append(
                (r.path, material_name(r.path), out, [out]))
    return sets


def convert_materials(inputs, output: str, convention: str, eta, unit: str,
                      working_space: str, results, texture=None) -> list:
    """Write the materials of a convert run (``results``: its FileResults) beside its outputs,
    in each folder they are in; [FileResult] of each file written or refused, and a failed
    one for each material that could not be written ([] when there is no target for
    ``convention`` or nothing was converted). ``texture``: the run's TextureOptions (the
    layer files are textures as the outputs are)."""
    targets = convention_targets(convention)
    sets = converted_sets(inputs, output, convention, results)
    if not targets or not sets:
        return []
    if unit not in UNIT_METERS:
        return [FileResult(os.path.join(folder, LAYER), error=f"no materials: unit {unit!r} "
                           f"is not a length unit ({', '.join(list(UNIT_METERS)[:10])}, ...)")
                for folder in sets]
    sources = {os.path.realpath(r.path) for r in results}
    rows = []
    for folder, found in sets.items():
        rows += folder_materials(folder, found, targets, convention, eta, unit, working_space,
                                 sources, texture)
    return rows


def folder_materials(folder, found, targets, convention, eta, unit, working_space, sources,
                     texture) -> list:
    """The materials of one folder's converted sets ``found`` (``converted_sets``) joined to
    the earlier runs' there: [FileResult]."""
    earlier, made_from, stage_unit_m, lost = earlier_networks(folder)
    stage_unit_m = stage_unit_m or UNIT_METERS[unit]
    rows, written = [], []
    if lost:
        rows.append(FileResult(os.path.join(folder, LAYER), os.path.join(folder, LAYER),
                               status="ok", notes=["materials", lost], companion=True))
    for source, name, out, files in found:
        try:
            colour, radius = layered(out, files, working_space, folder, sources, written,
                                     texture, convention)
        except NotWritten as exc:      # an unwritten material is a failure, named
            rows.append(FileResult(name, os.path.join(folder, LAYER),
                                   error=f"{name}: no material: {exc}", companion=True))
            continue
        ident, was = claimed_identifier(earlier, made_from, source_of(source, folder),
                                        (colour, radius), folder)
        if was:
            rows.append(FileResult(name, os.path.join(folder, LAYER), status="ok",
                                   notes=["materials", was], companion=True))
        ident = ident or material_identifier(source_of(source, folder), name, made_from)
        baked = BakedMaterial(ident, "", working_space, (1.0,), (1.0,), "diffuse", "better",
                              tuple(eta), unit, stage_unit_m, targets,
                              maps={convention: {"layers": (colour, radius)}})
        made, not_written = networks(baked, folder)
        earlier.setdefault(ident, {}).update({n.target.name: n for n in made})
        rows += [FileResult(name, os.path.join(folder, LAYER), error=f"{name}: {t} not "
                            f"written: {w}", companion=True) for t, w in not_written.items()]
    rows += [FileResult(p, p, status="ok", notes=["layer file"], companion=True)
             for p in written]
    gone = drop_unread(earlier, folder)
    if gone:
        rows.append(FileResult(os.path.join(folder, LAYER), os.path.join(folder, LAYER),
                               status="ok", notes=["materials", gone], companion=True))
    return rows + write_convert_records(earlier, made_from, stage_unit_m, folder)


def is_read(read: TextureRead, folder: str) -> bool:
    """Whether the file (or a tile of the set) a network reads is there: ``read.file``
    relative to ``folder``; one in a package is taken as there (the package is the user's)."""
    if "[" in read.file:
        return True
    path = os.path.join(folder, read.file)
    return bool(glob.glob(glob.escape(path).replace("<UDIM>", "[1-9][0-9][0-9][0-9]"))) \
        if read.tiled else os.path.isfile(path)


def drop_unread(materials: dict, folder: str) -> str | None:
    """Drop from ``materials`` ({identifier: {target: Network}}) each network a file it
    reads is gone from (a kept network would render nothing, or what comes there next), and
    each material left without one; what was dropped (None: nothing)."""
    gone = []
    for ident, by_target in list(materials.items()):
        for target, network in list(by_target.items()):
            missing = [r.file for r in network.textures if not is_read(r, folder)]
            if missing:
                del by_target[target]
                gone.append(f"{ident} ({target}: {', '.join(missing)} gone)")
        if not by_target:
            del materials[ident]
    return (f"{'; '.join(gone)}: not kept (convert them again)") if gone else None


def reads_of(network, folder: str) -> set:
    """The files ``network`` (or a TextureRead tuple) reads, as paths under ``folder``."""
    textures = getattr(network, "textures", network)
    return {os.path.normpath(os.path.join(folder, r.file)) for r in textures}


def claimed_identifier(materials: dict, sources: dict, source: str, reads, folder: str):
    """(identifier, what to say or None) of the kept material whose networks read a file of
    ``reads`` (the new material's TextureReads, now rewritten by converting ``source``):
    ``source``'s own if one reads them, else the first other, which converts ``source`` from
    now on (its networks dropped, ``sources`` updated, said); any other reading them is
    dropped, so no two materials ever read one set of files. (None, None) where none does.
    A material written before sources were recorded (None) is matched so too: by its
    files, never by its name."""
    new = reads_of(reads, folder)
    readers = sorted(i for i, by in materials.items()
                     if any(reads_of(n, folder) & new for n in by.values()))
    if not readers:
        return None, None
    ident = next((i for i in readers if sources.get(i) == source), readers[0])
    was = sources.get(ident)
    for i in readers:
        if i != ident:
            materials.pop(i, None)
            sources.pop(i, None)
    if was == source:
        return ident, None
    materials[ident], sources[ident] = {}, source
    return ident, (f"{ident}: now converts {source} (was {was}; this run rewrote the files "
                   f"it reads)" if was else None)


def material_identifier(source: str, name: str, sources: dict) -> str:
    """The identifier of the material converting ``source`` (``source_of``), its prim's and
    its MaterialX element's name: the one an earlier run gave it (``sources``: {identifier:
    source, None where a run before the sources were recorded wrote it: never claimed by
    its name, only by its files, ``claimed_identifier``), else ``name``'s, numbered past
    every other material's (``next_identifier``): an existing material keeps its name,
    whatever is converted after it. ``sources`` gets it."""
    ident = next((i for i, s in sources.items() if s == source), None)
    ident = ident or next_identifier(name, sources)
    sources[ident] = source
    return ident


def legacy_identifiers(names) -> dict:
    """{name: its prim's name} of the records of a run before the sources were kept (keyed
    by name): USD's ``TfMakeValidIdentifier``, a clash numbered in sorted order, as that run
    named them; kept, so that an existing material keeps its name (each is a valid
    ``identifier``: the .mtlx names it alike)."""
    from pxr import Tf
    out = {}
    for name in sorted(names):
        ident, k = Tf.MakeValidIdentifier(name), 1
        while ident.casefold() in {i.casefold() for i in out.values()}:
            k += 1
            ident = f"{Tf.MakeValidIdentifier(name)}_{k}"
        out[name] = ident
    return out


def earlier_networks(folder) -> tuple:
    """({identifier: {target: Network}} of the convert layer in ``folder`` (this tool's),
    {identifier: what it converts (``source_of``; None: not recorded)}, its metres per unit
    (None: no such layer), and what of it cannot be kept (None: all))."""
    path = os.path.join(folder, LAYER)
    if not (is_regular_file(path) and _own_layer(path)):
        return {}, {}, None, None
    from pxr import Sdf, UsdGeom
    layer = Sdf.Layer.OpenAsAnonymous(path)
    unit_m = layer.pseudoRoot.GetInfo(UsdGeom.Tokens.metersPerUnit) \
        if layer.pseudoRoot.HasInfo(UsdGeom.Tokens.metersPerUnit) else None
    found, sources = {}, {}
    try:
        sources = {str(i): str(s) for i, s in json.loads(
            layer.customLayerData.get(SOURCES, "{}")).items()}
        records = json.loads(layer.customLayerData.get(RECORDS, "{}"))
        idents = {n: n for n in records} if sources else legacy_identifiers(records)
        for name, by_target in records.items():
            found[idents[name]] = {t: replace(network_of(r), material=idents[name])
                                   for t, r in by_target.items()}
    except (KeyError, TypeError, ValueError, AttributeError):
        found, sources = {}, {}
    sources = {i: sources.get(i) for i in found}
    root = layer.GetPrimAtPath(FILE_MATERIALS)
    names = sorted(c.name for c in root.nameChildren) if root else []
    lost = [n for n in names if n not in found]
    note = (f"{', '.join(lost)}: written by an earlier version, without the records a "
            f"merge needs; not kept (convert them again)") if lost else None
    return found, sources, (unit_m if found else None), note


def write_convert_records(materials: dict, sources: dict, stage_unit_m: float, folder) -> list:
    """The layer and document of ``materials`` ({identifier: {target: Network}}; ``sources``:
    {identifier: what it converts}), metres per unit ``stage_unit_m``; [FileResult] of each
    file written or refused."""
    from pxr import Sdf, Usd, UsdGeom, UsdShade

    from ..io import usd_networks
    from ..io.mtlx_networks import document_text
    layer = Sdf.Layer.CreateAnonymous(".usda")
    layer.comment = (f"{LAYER_MARK}converted textures: their materials (docs/materials.md)")
    stage = Usd.Stage.Open(layer)
    UsdGeom.SetStageMetersPerUnit(stage, stage_unit_m)
    UsdGeom.SetStageUpAxis(stage, UP_AXIS)
    documented = []
    for ident in sorted(materials):
        path = f"{FILE_MATERIALS}/{ident}"
        UsdShade.Material.Define(stage, path)
        by_target = [materials[ident][t] for t in sorted(materials[ident])]
        for network in by_target:
            usd_networks.author(stage, path, network)
        documented.append((ident, by_target, (), stage_unit_m))
    layer.customLayerData = {
        RECORDS: json.dumps({ident: {t: network_record(n) for t, n in by.items()}
                             for ident, by in materials.items()}, sort_keys=True),
        SOURCES: json.dumps({i: s for i, s in sources.items() if i in materials and s},
                            sort_keys=True)}
    texts = {os.path.join(folder, LAYER): layer.ExportToString(),
             os.path.join(folder, DOCUMENT): document_text(
                 documented, f"{LAYER_MARK}converted textures: their materials")}
    rows = []
    for path, text in texts.items():
        if os.path.lexists(path) and not (is_regular_file(path) and own_document(path)
                                          or _own_layer(path)):
            rows.append(FileResult(path, path, error=f"{path} exists and was not written by "
                                                     f"bdipole-cl: the materials go there; "
                                                     f"move it", companion=True))
        elif write_if_changed(path, text):
            rows.append(FileResult(path, path, status="ok", notes=["materials"],
                                   companion=True))
    return rows


def _own_layer(path) -> bool:
    try:
        from pxr import Sdf
        layer = Sdf.Layer.OpenAsAnonymous(path) if is_regular_file(path) else None
    except Exception:                    # pxr raises Tf.ErrorException on a bad layer
        return False
    return layer is not None and layer.comment.startswith(LAYER_MARK)
