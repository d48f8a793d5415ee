"""The materials of a ``bdipole-cl convert`` run (the jobs layer): each input texture set's
converted ``colour.*`` / ``radius.*`` files, wired into the render targets whose convention
is the run's target (``io.targets``: van-de-hulst -> openpbr, better-dipole -> pxrsurface),
as a UsdShade ``Material`` under ``/bdipole_materials`` of ``bdipole_convert.usda`` and the
same network in ``bdipole_convert.mtlx``, beside the outputs (docs/materials.md). Each is
rewritten only when its content changes, never over a file this tool did not write there.
"""
from __future__ import annotations

import os
from pathlib import Path

from ..io import tiles
from ..io.images import image_header, is_regular_file
from ..io.networks import BakedMaterial, NotWritten, TextureRead, networks, relative_file
from ..io.scene_file import UNIT_METERS
from ..io.targets import TARGET
from .results import FileResult
from .scene_layer import FILE_MATERIALS, LAYER_MARK
from .scene_records import own_document, write_if_changed

LAYER = "bdipole_convert.usda"
DOCUMENT = "bdipole_convert.mtlx"


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
    """A texture set's name: its file name without extension nor tile token."""
    conv = tiles.token_of(pattern)
    name = Path(pattern).name.rsplit(".", 1)[0]
    name = name.replace(conv.token, "") if conv else name
    return name.strip("._-") or "material"


def layered(pattern: str, files: list, convention: str, working_space: str, folder: str):
    """The manifest-like maps entry of one converted set: one file, layers colour and radius
    (where each starts, as OpenImageIO reads the first file)."""
    spec = image_header(files[0])
    names = list(spec.channelnames) if spec is not None else []
    first = {layer: next((i for i, n in enumerate(names) if n.startswith(f"{layer}.")), None)
             for layer in ("colour", "radius")}
    if None in first.values():
        raise NotWritten(f"{files[0]}: no colour.* and radius.* channels")
    file = relative_file(pattern, folder)
    return (TextureRead("colour", file, working_space, "colour", first["colour"]),
            TextureRead("radius", file, "raw", "radius", first["radius"]))


def convert_materials(inputs, output: str, convention: str, eta, unit: str,
                      working_space: str, results) -> list:
    """Write the materials of a convert run (``results``: its FileResults) beside its outputs;
    [FileResult] of each file written or refused ([] when there is no target for
    ``convention`` or nothing was converted)."""
    targets = convention_targets(convention)
    done = [r.output for r in results if r.status in ("ok", "skipped") and r.output]
    if not targets or not done:
        return []
    folder = os.path.dirname(os.path.abspath(done[0]))
    found = []
    for pattern in inputs:
        out = os.path.abspath(output_pattern(output, str(pattern), convention))
        files = [f for f in done if os.path.abspath(f) == out or (
            tiles.token_of(out) and any(os.path.abspath(f) == h for h, _ in tiles.expand(out)))]
        if not files or os.path.dirname(out) != folder:
            continue
        try:
            colour, radius = layered(out, files, convention, working_space, folder)
        except NotWritten as exc:
            found.append((material_name(str(pattern)), None, str(exc)))
            continue
        baked = BakedMaterial(material_name(str(pattern)), "", working_space, (1.0,), (1.0,),
                              "diffuse", "better", tuple(eta), unit, UNIT_METERS[unit],
                              targets, maps={convention: {"layers": (colour, radius)}})
        found.append((baked.name, baked, None))
    return write_convert_records(found, folder)


def write_convert_records(found, folder) -> list:
    """The layer and document of ``found`` ([(name, BakedMaterial or None, why not)])."""
    from pxr import Sdf, Tf, Usd, UsdShade

    from ..io import usd_networks
    from ..io.mtlx_networks import document_text
    layer = Sdf.Layer.CreateAnonymous(".usda")
    layer.comment = (f"{LAYER_MARK}converted textures: their materials (docs/materials.md)")
    stage = Usd.Stage.Open(layer)
    rows, documented = [], []
    for name, baked, why in found:
        if baked is None:
            rows.append(FileResult(name, os.path.join(folder, LAYER), status="ok",
                                   notes=[f"no material: {why}"]))
            continue
        written, not_written = networks(baked, folder)
        path = f"{FILE_MATERIALS}/{Tf.MakeValidIdentifier(name)}"
        UsdShade.Material.Define(stage, path)
        for network in written:
            usd_networks.author(stage, path, network)
        documented.append((name, written, ()))
        rows += [FileResult(name, os.path.join(folder, LAYER), status="ok",
                            notes=[f"{t} not written: {w}"]) for t, w in not_written.items()]
    texts = {os.path.join(folder, LAYER): layer.ExportToString(),
             os.path.join(folder, DOCUMENT): document_text(
                 documented, f"{LAYER_MARK}converted textures: their materials")}
    for path, text in texts.items():
        if os.path.lexists(path) and not (is_regular_file(path) and own_document(path)
                                          or _own_layer(path)):
            rows.append(FileResult(path, path, error=f"{path} exists and was not written by "
                                                     f"bdipole-cl: the materials go there; "
                                                     f"move it"))
        elif write_if_changed(path, text):
            rows.append(FileResult(path, path, status="ok", notes=["materials"]))
    return rows


def _own_layer(path) -> bool:
    try:
        from pxr import Sdf
        layer = Sdf.Layer.OpenAsAnonymous(path) if is_regular_file(path) else None
    except Exception:                    # pxr raises Tf.ErrorException on a bad layer
        return False
    return layer is not None and layer.comment.startswith(LAYER_MARK)
